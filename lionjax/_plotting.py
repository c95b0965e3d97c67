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
