"""``reloc config dump`` and ``reloc config check FILE``."""

from __future__ import annotations

import click


@click.group()
def config() -> None:
    """Print the default configuration or validate a config file."""


@config.command()
@click.option("--no-comments", is_flag=True, help="Plain YAML without the field descriptions.")
def dump(no_comments: bool) -> None:
    """Print the default configuration as YAML (with a description of every field)."""
    from reloc.config import dump_config

    click.echo(dump_config(comments=not no_comments), nl=False)


@config.command()
@click.argument("file", type=click.Path(dir_okay=False))
def check(file: str) -> None:
    """Validate FILE and list every problem with its path."""
    from reloc.config import ConfigError, load_config

    try:
        load_config(file)
    except ConfigError as exc:
        click.echo(str(exc), err=True)
        raise SystemExit(1)
    click.echo(f"{file}: ok")
