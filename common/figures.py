"""Figures as files, for every stage's plots: matplotlib on its Agg backend (no display needed),
imported only when a figure is drawn, and a finished figure written and closed."""

from __future__ import annotations

from pathlib import Path


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend.

    Imported here, on first use, so that a module with plots costs nothing until one is drawn.

    Returns
    -------
    module
        ``matplotlib.pyplot``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def folder_for(folder) -> Path:
    """The folder figures go to, created if missing.

    Parameters
    ----------
    folder : path-like
        The folder.

    Returns
    -------
    Path
        ``folder``, which now exists.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def save(fig, path, dpi: int) -> None:
    """Lay ``fig`` out tightly, write it to ``path`` and close it (pyplot keeps every open figure).

    Parameters
    ----------
    fig : matplotlib Figure
        The finished figure.
    path : path-like
        The image file; its suffix picks the format.
    dpi : int
        The resolution.
    """
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)
