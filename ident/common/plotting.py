"""The one plot style of every hdrive report: figures made off-screen, saved as PNG at one resolution, closed.

Units go into axis labels in brackets (``arm increment [µm]``); lengths at the arm are shown in µm."""
from __future__ import annotations

from pathlib import Path
from typing import Any

DPI = 120


def figure(nrows: int = 1, ncols: int = 1, *, size: tuple[float, float] = (6.0, 4.0), **kw: Any) -> tuple[Any, Any]:
    """A new figure and its axes (matplotlib's Agg backend: no screen needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(nrows, ncols, figsize=size, **kw)


def save(fig: Any, path: str | Path) -> Path:
    """Lay out, write ``path`` (PNG, parent folders created) and close ``fig``; returns the path."""
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path
