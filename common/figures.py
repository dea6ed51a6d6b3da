"""Figures as files, for every stage's plots: matplotlib on its Agg backend (no display needed),
imported only when a figure is drawn, and a finished figure written and closed."""

from __future__ import annotations

from pathlib import Path

from smartjoint.common import output_path


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
    folder = Path(folder)  # the command line checked a user's --plots by the output rule before any work
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def is_figure(entry: Path) -> bool:
    """A figure a command may replace in its plots folder: a regular PNG file (by the output
    rule, `common.output_path`, anything else there is a user's and refused)."""
    return output_path.kind(entry) == "file" and entry.suffix.lower() == ".png"


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
    try:
        with output_path.writing(path, binary=True) as stream:  # whole, never through a link
            fig.savefig(stream, dpi=dpi, format=Path(path).suffix[1:] or "png")
    finally:
        pyplot().close(fig)
