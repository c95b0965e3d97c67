"""The one serialisation of lionjax's results: one conversion to JSON values (:func:`jsonable`),
one JSON writer, one CSV writer, and the protocol of the result tables (:class:`Table`:
``to_rows()`` and ``payload()``; StudyResult, BatchIdentification, the paper's table) whose
``to_json``/``to_csv`` write through them. The command line writes with the same functions."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from ._errors import InputError


def jsonable(obj):
    """Dicts, lists, tuples, numpy/jax scalars and arrays → plain JSON values (arrays → nested
    lists, numpy scalars → Python numbers, non-finite floats → ``None``, written as null)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if hasattr(obj, "shape") or isinstance(obj, np.generic):
        a = np.asarray(obj)
        return jsonable(a.tolist()) if a.ndim else jsonable(a.item())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    return obj


def check_folder(path: str | Path | None, what: str) -> None:
    """Raise :class:`InputError` when the folder of the output file ``path`` is missing (call
    it before the work that produces the file; ``None``: nothing to check). ``what`` names the
    argument or file in the message."""
    if path is not None and not Path(path).parent.is_dir():
        raise InputError(
            f"{what}: folder {str(Path(path).parent)!r} does not exist; create it first."
        )


def write_json(path: str | Path, payload) -> Path:
    """Write ``jsonable(payload)`` as indented JSON; returns the path."""
    path = Path(path)
    path.write_text(json.dumps(jsonable(payload), indent=2) + "\n")
    return path


def write_csv(path: str | Path, rows: list[dict]) -> Path:
    """Write dict rows as CSV with a header from the first row; list/tuple cells (pole sets,
    initial guesses) joined with ';'; NaN and inf written as such. Returns the path."""
    path = Path(path)
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow(
                {
                    k: ";".join(f"{x:g}" for x in v) if isinstance(v, list | tuple) else v
                    for k, v in r.items()
                }
            )
    return path


class Table:
    """The serialisation protocol of a result table (a mixin; no fields).

    A table says what it holds — :meth:`to_rows` (one dict per row, the CSV) and :meth:`payload`
    (the JSON document; default the rows themselves) — and inherits the writers.
    """

    def to_rows(self) -> list[dict]:
        """One dict per row, in order (the CSV's rows)."""
        raise NotImplementedError

    def payload(self):
        """The JSON document (before :func:`jsonable`); default :meth:`to_rows`."""
        return self.to_rows()

    def to_json(self, path: str | Path) -> Path:
        """Write :meth:`payload` as indented JSON (non-finite numbers as null); returns the path."""
        return write_json(path, self.payload())

    def to_csv(self, path: str | Path) -> Path:
        """Write :meth:`to_rows` as CSV (list cells joined with ';', NaN and inf as such)."""
        return write_csv(path, self.to_rows())
