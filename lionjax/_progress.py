"""Progress on stderr, one implementation for every long run: the study grid's and the pairs'
bar (:func:`run_chunks`, which also turns Ctrl-C into a partial result), a long task's status
line (:class:`Status`: the diagnosis' stages and profile grids, a batch's files), the command
line's time-stamped steps (:func:`stamped`) and the paper reproduction's optional step messages
(:func:`reporter`).

The command line draws progress where stderr is a terminal and ``--quiet`` is not given
(:func:`wanted`): a log file or a pipe gets none, as is the convention; the Python functions
draw it where asked (``progress=True``).
"""

from __future__ import annotations

import contextlib
import contextvars
import sys
import time
from collections.abc import Callable, Iterable, Iterator

#: Seconds a task runs before its status line is first drawn (a short run prints nothing).
QUIET_FOR = 2.0
#: Least seconds between two redraws of a status line.
REDRAW_EVERY = 0.5


def wanted(quiet: bool = False) -> bool:
    """Whether the command line draws progress: not ``quiet`` and stderr a terminal."""
    return not quiet and sys.stderr.isatty()


class Status:
    """One task's status line on stderr, ``label: stage done/total what [12 s]``, redrawn in
    place; drawn only once the task has run :data:`QUIET_FOR` seconds, at most every
    :data:`REDRAW_EVERY` seconds; nothing at all when not ``enabled``. The progress API of a
    long computation: :meth:`stage` names the present step (with its count of units, if known),
    :meth:`step` counts units done; :func:`counted` steps it over an iterable."""

    def __init__(self, label: str, enabled: bool = True):
        self.label, self.enabled = label, enabled
        self.start = time.perf_counter()
        self.what, self.total, self.done, self.unit = "", None, 0, ""
        self._drawn = 0.0
        self._width = 0

    def stage(self, what: str, total: int | None = None, unit: str = "") -> None:
        """Start the step ``what`` of ``total`` units (``unit``: their name)."""
        self.what, self.total, self.done, self.unit = what, total, 0, unit
        self._draw(force=True)

    @property
    def elapsed(self) -> float:
        """Seconds since the task started."""
        return time.perf_counter() - self.start

    def step(self, n: int = 1) -> None:
        """``n`` more units of the present step done."""
        self.done += n
        self._draw()

    def _draw(self, force: bool = False) -> None:
        now = time.perf_counter()
        if not self.enabled or now - self.start < QUIET_FOR:
            return
        if not force and now - self._drawn < REDRAW_EVERY:
            return
        count = ""
        if self.total:
            count = f" {self.done:,}/{self.total:,}{' ' + self.unit if self.unit else ''}"
        line = f"{self.label}: {self.what}{count} [{now - self.start:.0f} s]"
        sys.stderr.write("\r" + line.ljust(self._width))
        sys.stderr.flush()
        self._width, self._drawn = len(line), now

    def close(self) -> None:
        """End the line (if one was drawn)."""
        if self._width:
            sys.stderr.write("\n")
            sys.stderr.flush()
            self._width = 0


_CURRENT: contextvars.ContextVar[Status | None] = contextvars.ContextVar(
    "lionjax_status", default=None
)


@contextlib.contextmanager
def status(label: str, enabled: bool = True) -> Iterator[Status]:
    """A :class:`Status` for the code inside (found there by :func:`current`), closed after."""
    st = Status(label, enabled)
    token = _CURRENT.set(st)
    try:
        yield st
    finally:
        _CURRENT.reset(token)
        st.close()


def current() -> Status:
    """The innermost task's :class:`Status`, or one that draws nothing."""
    st = _CURRENT.get()
    return st if st is not None else Status("", enabled=False)


def counted(items: Iterable, what: str, unit: str = "") -> Iterator:
    """``items`` one by one, each counted as a unit of the step ``what`` of the current task
    (the task's step before it is restored after the last)."""
    items = list(items)
    st = current()
    before = (st.what, st.total, st.done, st.unit)
    st.stage(what, len(items), unit)
    for item in items:
        yield item
        st.step()
    st.what, st.total, st.done, st.unit = before  # back to the enclosing step


def reporter(progress: Callable[[str], None] | None) -> Callable[[str], None]:
    """``progress`` itself, or a callable that says nothing when it is None."""
    return progress or (lambda message: None)


def stamped(start: float | None = None) -> Callable[[str], None]:
    """A callable that prints ``[  12.3 s] message`` to stderr, seconds since ``start``
    (``time.perf_counter()`` value; default now)."""
    start = time.perf_counter() if start is None else start

    def say(message: str) -> None:
        print(f"[{time.perf_counter() - start:6.1f} s] {message}", file=sys.stderr, flush=True)

    return say


def bar(label: str, done: int, total: int, what: str = "chunks", width: int = 30) -> None:
    """Redraw ``label [####....] done/total what`` on stderr; a newline once done."""
    n = int(round(width * done / total))
    sys.stderr.write(f"\r{label} [{'#' * n}{'.' * (width - n)}] {done}/{total} {what}")
    if done == total:
        sys.stderr.write("\n")
    sys.stderr.flush()


def run_chunks(
    jobs: Iterable,
    run: Callable,
    *,
    label: str,
    total: int,
    progress: bool = True,
    partial: str = "returning the grid points done (NaN elsewhere, complete=False)",
    what: str = "chunks",
) -> bool:
    """Call ``run(job)`` for each job, drawing the bar after each if ``progress``.

    Ctrl-C stops between (or inside) jobs: a warning naming how many were done and what is
    returned (``partial``) goes to stderr and False is returned (the caller keeps what ``run``
    stored); True when every job ran. ``what`` names the jobs in the bar and the warning.
    """
    done = 0
    try:
        for job in jobs:
            run(job)
            done += 1
            if progress:
                bar(label, done, total, what)
    except KeyboardInterrupt:
        if progress:
            sys.stderr.write("\n")
        sys.stderr.write(f"warning: {label} interrupted after {done}/{total} {what}; {partial}.\n")
        sys.stderr.flush()
        return False
    return True
