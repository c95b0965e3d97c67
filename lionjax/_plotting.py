"""The one way lionjax makes a figure: a ``matplotlib.figure.Figure`` on the Agg canvas (no
pyplot, no GUI, no global state). matplotlib is imported here, lazily, so ``import lionjax`` never
needs it (install the ``plot`` extra)."""

from __future__ import annotations


def figure(width: float, height: float, *, layout: str | None = "constrained"):
    """A new Agg-backed figure of ``width`` × ``height`` inches; save it with ``fig.savefig``."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as err:  # pragma: no cover
        raise ImportError("lionjax figures need matplotlib: pip install 'lionjax[plot]'.") from err
    fig = Figure(figsize=(width, height), layout=layout)
    FigureCanvasAgg(fig)
    return fig


#: Figure formats the command line writes (the format is taken from the file's extension).
FIGURE_SUFFIXES = (".png", ".pdf", ".svg")


def save_figure(fig, path, *, dpi: float = 110):
    """Save ``fig`` to ``path`` atomically (:func:`lionjax._tables.atomic_path`: a failed draw or
    write leaves an existing file as it was), in the format of its extension; returns the path."""
    from pathlib import Path

    from ._tables import atomic_path

    path = Path(path)
    fmt = path.suffix.lower().lstrip(".") or "png"
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=fmt)
    return path
