"""Plain-data helpers shared by the labelled result tables (StudyResult, BatchIdentification)."""

from __future__ import annotations

import math

import numpy as np


def jsonable(obj):
    """Dicts, lists, tuples of numbers → plain JSON values (numpy scalars → Python numbers,
    non-finite floats → ``None``, written as null)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, float | np.floating):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj
