"""Matplotlib behind one door: imported lazily, always the Agg backend, figures of an exact pixel size.

Only this module imports matplotlib, and only inside functions, so ``import reloc.viz`` costs nothing and the
package works without the optional ``viz`` extra until a picture is asked for. Figures are made with
``matplotlib.figure.Figure`` (no pyplot global state), so plotting is safe from any thread.
"""

from __future__ import annotations

import os
from pathlib import Path

DPI = 100

# Colours used across every picture, so a reader learns them once.
MAP_COLOR = "#4d4d4d"  # map planes (dark grey)
MAP_FLOOR_COLOR = "#dcdcdc"  # horizontal map planes (floor, ceiling, table tops)
SUBMAP_COLOR = "#1a9850"  # the relocalized submap at the estimated pose (green, as the paper's Fig. 4)
TRUTH_COLOR = "#d62728"  # ground truth (red)
REJECTED_COLOR = "#e08214"  # a submap that was not relocalized (orange, drawn at ground truth)


def require_matplotlib():
    """Import matplotlib (Agg backend) or raise an ImportError that says how to install it."""
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(
            "pictures need matplotlib: install the viz extra (pip install -e '.[viz]' in a checkout, "
            "or pip install 'voxelplane-reloc[viz]')"
        ) from exc
    matplotlib.use("Agg", force=False)
    return matplotlib


def new_figure(width_px: int, height_px: int):
    """A Figure of exactly ``width_px`` x ``height_px`` pixels when saved with :func:`save_figure`."""
    if int(width_px) < 100 or int(height_px) < 100:
        raise ValueError(f"figure size: expected at least 100 x 100 pixels, got {width_px} x {height_px}")
    require_matplotlib()
    from matplotlib.figure import Figure

    fig = Figure(figsize=(int(width_px) / DPI, int(height_px) / DPI), dpi=DPI)
    fig.set_layout_engine("constrained")
    return fig


def save_figure(fig, path: str | os.PathLike) -> Path:
    """Write ``fig`` as a PNG atomically (no partial file on a crash) at its exact pixel size; return the path."""
    import io

    from reloc.atomic import atomic_write_bytes

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"path: expected a .png file name, got {str(path)!r}")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, facecolor=fig.get_facecolor())
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buf.getvalue())
    return path


def plane_colors(n: int):
    """``n`` distinguishable RGB colours (tab20 order, repeating), as an (n, 3) float array."""
    require_matplotlib()
    import numpy as np
    from matplotlib import colormaps

    base = np.asarray(colormaps["tab20"].colors)[[0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 1, 3, 5, 7, 9, 11, 13, 15, 17, 19]]
    return base[np.arange(max(n, 0)) % len(base)]
