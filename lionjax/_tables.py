"""The one serialisation of lionjax's results: one conversion to JSON values (:func:`jsonable`),
one JSON writer, one CSV writer, and the protocol of the result tables (:class:`Table`:
``to_rows()`` and ``payload()``; StudyResult, BatchIdentification, the paper's table) whose
``to_json``/``to_csv`` write through them. The command line writes with the same functions.

Every file lionjax writes (JSON, CSV, figures, reports, records) goes through one helper,
:func:`atomic_path`: the content is written to a temporary file in the destination's folder and
moved over the destination with ``os.replace`` only once complete, so a failed write (a full
disk, an error while drawing) leaves an existing file as it was and no partial file behind.
:func:`check_output` checks a destination before the work that produces it."""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import tempfile
from collections.abc import Iterator
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


def check_output(
    path: str | Path | None, what: str, suffixes: tuple[str, ...] | None = None
) -> None:
    """Raise :class:`InputError` when the output file ``path`` cannot be written: its folder is
    missing or not writable, the path is a folder, or (``suffixes`` given) its extension is not
    one of ``suffixes``. Call it before the work that produces the file (``None``: nothing to
    check). ``what`` names the argument or file in the message."""
    if path is None:
        return
    p = Path(path)
    if p.is_dir():
        example = p / ("out" + (suffixes[0] if suffixes else ".json"))
        raise InputError(
            f"{what}: {str(p)!r} is a folder, expected a file name; give a file in it, e.g. "
            f"{str(example)!r}."
        )
    folder = p.parent
    if not folder.is_dir():
        raise InputError(
            f"{what}: folder {str(folder)!r} does not exist; create it first (or give a path in "
            "an existing folder)."
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(
            f"{what}: folder {str(folder)!r} is not writable; choose a folder you can write to."
        )
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise InputError(
            f"{what}: {str(p)!r} has "
            + (f"the extension {p.suffix!r}" if p.suffix else "no extension")
            + f"; the format is taken from it: use one of {', '.join(suffixes)} (e.g. "
            f"{str(p.with_suffix(suffixes[0]))!r})."
        )


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Write a file atomically: yields a temporary path in ``path``'s folder (same extension) to
    write to; on success it replaces ``path`` (``os.replace``), on any error it is removed and
    ``path`` is left as it was. An :class:`OSError` of the write names ``path`` itself."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(21, "is a folder, expected a file name", str(path))
    try:
        fd, tmp = tempfile.mkstemp(
            dir=path.parent, prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}"
        )
    except OSError as e:
        raise OSError(e.errno, e.strerror, str(path)) from None
    os.close(fd)
    tmp_path = Path(tmp)
    with contextlib.suppress(OSError):  # mkstemp's 0600 → what a plain open() would give
        os.chmod(tmp_path, 0o666 & ~_umask())
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    except OSError as e:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        raise OSError(e.errno, e.strerror, str(path)) from None
    except BaseException:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        raise


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def write_json(path: str | Path, payload) -> Path:
    """Write ``jsonable(payload)`` as indented JSON (strict: non-finite numbers are null, never
    ``NaN``), atomically; returns the path."""
    return write_text(path, json.dumps(jsonable(payload), indent=2, allow_nan=False) + "\n")


def write_csv(path: str | Path, rows: list[dict]) -> Path:
    """Write dict rows as CSV with a header from the first row; list/tuple cells (pole sets,
    initial guesses, a diagnosis' stack of names) joined with ';'; NaN and inf written as such
    (NaN: failed or not run, inf: not settled). Written atomically; returns the path."""
    path = Path(path)
    with atomic_path(path) as tmp, tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow(
                {
                    k: ";".join(_cell(x) for x in v) if isinstance(v, list | tuple) else v
                    for k, v in r.items()
                }
            )
    return path


def _cell(x) -> str:
    """One element of a list cell: numbers as ``%g``, anything else (names) as text."""
    return str(x) if isinstance(x, str) else f"{x:g}"


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
