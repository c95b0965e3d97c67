"""Progress on stderr, one implementation for every long run: the study grid's chunk bar
(:func:`run_chunks`, which also turns Ctrl-C into a partial result), the command line's
time-stamped steps (:func:`stamped`) and the paper reproduction's optional step messages
(:func:`reporter`)."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable


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
