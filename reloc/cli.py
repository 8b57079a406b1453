"""The ``reloc`` command. Subcommands live in their own modules and are imported only when used.

Command modules keep heavy imports (numba kernels, depthai, matplotlib) inside their functions, so ``reloc --help``
and ``reloc config`` start fast.
"""

from __future__ import annotations

import importlib
import sys

import click

# name -> "module:attribute" of a click command or group.
COMMANDS: dict[str, str] = {
    "config": "reloc.commands.config_cmd:config",
    "demo": "reloc.commands.demo_cmd:demo",
    "eval": "reloc.commands.eval_cmd:eval_cmd",
    "locate": "reloc.commands.locate_cmd:locate",
    "map": "reloc.commands.map_cmd:map_group",
    "devices": "drivers.commands:devices_cmd",
    "firmware-sim": "firmware_bridge.cli:firmware_sim",
    "planes": "reloc.extraction.cli:planes",
    "plot": "reloc.viz.cli:plot",
    "profile": "reloc.commands.profile_cmd:profile",
    "record": "drivers.commands:record_cmd",
    "run": "reloc.live.cli:run",
    "sim": "sim.cli:sim",
}


class LazyGroup(click.Group):
    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(super().list_commands(ctx)) | set(COMMANDS))

    def get_command(self, ctx: click.Context, name: str):
        if name in COMMANDS:
            module_name, attr = COMMANDS[name].split(":")
            return getattr(importlib.import_module(module_name), attr)
        return super().get_command(ctx, name)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 110})
@click.version_option(package_name="voxelplane-reloc")
def cli() -> None:
    """Relocalize an indoor robot from depth-camera point clouds with voxel planes."""


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; errors in user input become one readable line and exit code 2.

    SIGTERM stops a command as Ctrl-C does (files being written are finished or removed, never left half-written);
    a command may install its own handlers (``reloc run`` does).
    """
    import signal

    previous = None
    try:
        if signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
            previous = signal.signal(signal.SIGTERM, _terminate)
    except ValueError:  # not the main thread: leave signals alone
        pass
    try:
        cli.main(args=argv, prog_name="reloc", standalone_mode=False)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        return 130
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except (ValueError, FileNotFoundError) as exc:
        click.echo(f"error: {exc}", err=True)
        return 2
    except OSError as exc:  # the system refused (a full disk, a vanished device): one line, not a traceback
        click.echo(f"error: {exc}", err=True)
        return 1
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    return 0


def _terminate(signum, frame):
    raise KeyboardInterrupt(f"signal {signum}")


if __name__ == "__main__":
    sys.exit(main())
