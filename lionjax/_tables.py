"""Plain-data helpers shared by the labelled result tables (StudyResult, BatchIdentification)
and the command line: one conversion to JSON values, one JSON writer, one CSV writer."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np


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
