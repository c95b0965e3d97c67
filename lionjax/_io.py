"""Reading and writing records: CSV, NPZ and MATLAB ``.mat`` files.

File formats (SI units: t in s, x in m, F in N):

- **CSV**: a header row naming the columns, then one row per sample, comma separated. Required
  columns ``t,x,F``; other columns are ignored unless asked for with ``extras=``. Blank lines at
  the end of the file are allowed; anywhere else they are an error (so sample index ``k`` is always
  on line ``k + 2``).
- **NPZ** (``numpy.savez``): arrays under the same names, each shape ``(T,)``. A scalar entry
  ``dt`` (written by :func:`save_record`) is the sampling interval; it is checked against ``t``
  and then used exactly, so NPZ files round-trip bit for bit.
- **MATLAB** ``.mat`` (v4–v7, read with ``scipy.io.loadmat``; install ``lionjax[mat]``):
  variables under the same names, row or column vectors; a scalar ``dt`` as for NPZ.

Other names are mapped with ``columns={"t": "time", "x": "pos", "F": "force"}`` (command line:
``--columns t=time,x=pos,F=force``, see :func:`parse_columns`). Every bad input raises
:class:`~lionjax._errors.InputError` naming the file, the column or argument and the first bad
index; nothing is dropped, clipped, interpolated or guessed unless asked for (``resample=True``).
"""

from __future__ import annotations

import contextvars
import csv
import difflib
import logging
import os
import zipfile
import zlib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ._errors import InputError
from ._record import JITTER_TOLERANCE, MIN_SAMPLES, Record, resample as _resample
from ._tables import atomic_path, check_output
from ._units import check_units

logger = logging.getLogger(__name__)

#: File extensions that :func:`load_record` reads and :func:`save_record` writes.
SUFFIXES = (".csv", ".npz", ".mat")
_REQUIRED = ("t", "x", "F")
_MEANING = {"t": "time [s]", "x": "position [m]", "F": "force [N]"}
# Names that often hold t, x, F: only used to suggest a `columns` map in error messages.
_USUAL_NAMES = {
    "t": ("time", "times", "t_s", "timestamp"),
    "x": ("pos", "position", "q", "qm", "x_m"),
    "F": ("force", "f", "u", "tau", "f_n"),
}
# Names with a meaning of their own in NPZ/MAT files (the stored sampling interval).
_RESERVED = ("dt",)

PathLike = str | os.PathLike

#: True while the command line runs: fixes are then worded with its options (``--resample``,
#: ``--columns``) instead of this module's arguments.
cli_hints: contextvars.ContextVar[bool] = contextvars.ContextVar("lionjax_cli_hints", default=False)


def _fix(python: str, cli: str) -> str:
    """The fix worded for the caller: the Python argument, or the command-line option."""
    return cli if cli_hints.get() else python


# --------------------------------------------------------------------------- arguments


def parse_columns(spec: str) -> dict[str, str]:
    """Parse a command-line column map ``"t=time,x=pos,F=force"`` into ``{"t": "time", ...}``.

    Raises:
        InputError: naming ``--columns`` when an item is not ``NAME=COLUMN`` or ``NAME`` is not
            one of ``t``, ``x``, ``F``.
    """
    out: dict[str, str] = {}
    for item in spec.split(","):
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key or not value:
            raise InputError(
                f"--columns: expected items NAME=COLUMN separated by commas (e.g. "
                f"'t=time,x=pos,F=force'), got {item!r} in {spec!r}."
            )
        out[key] = value
    _check_columns(out)
    return out


def _check_columns(columns: Mapping[str, str] | None) -> dict[str, str]:
    """The role -> file-column map, with unmapped roles named as themselves."""
    if columns is None:
        columns = {}
    if not isinstance(columns, Mapping):
        raise InputError(
            f"columns: expected a mapping such as {{'x': 'pos'}} from lionjax names (t, x, F) "
            f"to the names in the file, got {type(columns).__name__}."
        )
    for key, value in columns.items():
        if key not in _REQUIRED:
            raise InputError(
                f"columns: unknown key {key!r}; the keys are lionjax's names 't', 'x', 'F' and "
                f"the values the names in the file, e.g. {{'x': {key!r}}} if the file calls the "
                "position that."
            )
        if not isinstance(value, str) or not value:
            raise InputError(
                f"columns: the file column for {key!r} must be a non-empty string, got {value!r}."
            )
    names = {role: columns.get(role, role) for role in _REQUIRED}
    if len(set(names.values())) != len(names):
        raise InputError(
            f"columns: two of t, x, F are read from the same file column ({names}); map each "
            "to its own column."
        )
    return names


def _check_extras(extras: Sequence[str], names: Mapping[str, str]) -> tuple[str, ...]:
    if isinstance(extras, str):
        raise InputError(
            f"extras: expected a sequence of column names, got the string {extras!r}; write "
            f"extras=({extras!r},)."
        )
    out = tuple(extras)
    for e in out:
        if not isinstance(e, str) or not e:
            raise InputError(f"extras: column names must be non-empty strings, got {e!r}.")
        if e in _REQUIRED or e in names.values():
            raise InputError(
                f"extras: {e!r} collides with a required column (t, x, F, or a file column they "
                f"are read from: {names}); extras are further signals, not t/x/F."
            )
        if e in _RESERVED:
            raise InputError(
                f"extras: {e!r} is reserved (the stored sampling interval); rename that column."
            )
    if len(set(out)) != len(out):
        raise InputError(f"extras: a column is listed twice in {out}.")
    return out


def _check_path(path: PathLike, *, what: str = "path") -> Path:
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file ({what}). Check the path and the working directory.")
    if p.is_dir():
        raise InputError(
            f"{p}: is a folder, expected a file ({what}). Use load_records() to read every "
            "record in a folder."
        )
    if p.suffix.lower() not in SUFFIXES:
        raise InputError(
            f"{p}: unknown file type {p.suffix!r}; lionjax reads {', '.join(SUFFIXES)} "
            "(CSV with a header row, numpy.savez archive, MATLAB file). Convert the file or "
            "rename it if it already is one of these."
        )
    if p.stat().st_size == 0:
        raise InputError(
            f"{p}: the file is empty (0 bytes); expected "
            + {
                ".csv": "a header row such as 't,x,F' followed by one row per sample",
                ".npz": "an NPZ archive with arrays 't', 'x', 'F' (numpy.savez)",
                ".mat": "a MATLAB file with variables 't', 'x', 'F'",
            }[p.suffix.lower()]
            + ". Was the export or copy interrupted?"
        )
    return p


# --------------------------------------------------------------------------- readers


def _missing_column(
    path: Path, name: str, role: str | None, found: Sequence[str], kind: str
) -> InputError:
    close = difflib.get_close_matches(name, list(found), n=3, cutoff=0.5)
    usual = _USUAL_NAMES.get(role, ()) if role is not None else ()
    close += [
        f
        for f in found
        if f not in close and (f.lower().startswith(name.lower()) or f.lower() in usual)
    ]
    hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
    if role is None:
        what = f"extra column {name!r} (asked for in `extras`)"
        fix = "Ask only for columns the file has."
    elif name == role:
        what = f"required {kind} {role!r} ({_MEANING[role]})"
        other = close[0] if close else "NAME"
        fix = "If the file calls it something else, map it: " + _fix(
            f"columns={{{role!r}: {other!r}}} (command line: --columns {role}={other}).",
            f"--columns {role}={other}.",
        )
    else:
        what = f"{kind} {name!r} (read as {role!r}, {_MEANING[role]}, via `columns`)"
        fix = _fix("Fix the name in `columns` (command line: --columns).", "Fix --columns.")
    shown = ", ".join(map(repr, found[:30])) + (" ..." if len(found) > 30 else "")
    return InputError(
        f"{path}: {what} not found. {kind.capitalize()}s found: {shown or '(none)'}.{hint} {fix}"
    )


def _wanted(names: Mapping[str, str], extras: Sequence[str]) -> list[tuple[str, str | None]]:
    """(file column, role or None for an extra) for every column to read."""
    return [(names[r], r) for r in _REQUIRED] + [(e, None) for e in extras]


def _read_csv(path: Path, wanted) -> tuple[dict[str, np.ndarray], float | None]:
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as e:
        raise InputError(
            f"{path}: not a UTF-8 text file ({e}); a CSV file with a header row is expected."
        ) from None
    if not text.strip():
        raise InputError(
            f"{path}: the file is empty; expected a header row such as 't,x,F' followed by one "
            "row per sample."
        )
    lines = text.splitlines()
    while not lines[-1].strip():  # blank lines at the end only
        lines.pop()
    for i, line in enumerate(lines):
        if not line.strip():
            raise InputError(
                f"{path}: line {i + 1} is blank; blank lines are allowed only at the end of the "
                "file. Remove it (lionjax does not skip rows for you)."
            )
    rows = list(csv.reader(lines))
    header = [h.strip() for h in rows[0]]
    for j, h in enumerate(header):
        if not h:
            raise InputError(f"{path}: header (line 1) has an empty name in column {j + 1}.")
    if all(_is_number(h) for h in header):
        raise InputError(
            f"{path}: no header row: line 1 ({','.join(header)[:60]}) holds numbers; expected a "
            "header naming the columns t,x,F (time [s], position [m], force [N]) as line 1. Add "
            "it (e.g. the line 't,x,F' when the columns are in that order)."
        )
    seps = [c for c in ";\t|" if len(header) == 1 and c in header[0]]
    if seps:
        raise InputError(
            f"{path}: the header (line 1) {header[0]!r} looks separated by {seps[0]!r}; lionjax "
            "reads comma-separated files. Convert the separators to commas."
        )
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise InputError(f"{path}: header (line 1) names column(s) {dup} more than once.")
    data = rows[1:]
    for i, row in enumerate(data):
        if len(row) != len(header):
            raise InputError(
                f"{path}: line {i + 2} (sample index {i}) has {len(row)} cells but the header "
                f"has {len(header)} columns ({','.join(header)}); every row needs exactly one "
                "value per column (ragged rows are not guessed at)."
            )
    out = {}
    for name, role in wanted:
        if name not in header:
            raise _missing_column(path, name, role, header, "column")
    if not data:
        raise InputError(
            f"{path}: has a header ({','.join(header)}) but no data rows; expected one row per "
            "sample after the header."
        )
    for name, _ in wanted:
        j = header.index(name)
        cells = [row[j] for row in data]
        try:
            out[name] = np.asarray(cells, dtype=np.float64)
        except ValueError:
            i = next(k for k, c in enumerate(cells) if not _is_number(c))
            raise InputError(
                f"{path}: column {name!r}, line {i + 2} (sample index {i}): cannot read "
                f"{cells[i]!r} as a number. Fix or remove that row (write NaN explicitly as "
                "'nan' if a value is missing; lionjax will then report it)."
            ) from None
    return out, None


def _is_number(s) -> bool:
    try:
        float(s)
    except (TypeError, ValueError):
        return False
    return True


def _is_real(v) -> bool:
    """A finite real Python or numpy scalar (not a bool)."""
    return (
        isinstance(v, int | float | np.floating | np.integer)
        and not isinstance(v, bool)
        and bool(np.isfinite(v))
    )


def _as_float(path: Path, name: str, a: np.ndarray, *, kind: str) -> np.ndarray:
    """A stored array as float64, refusing text, objects, complex and structured arrays."""
    a = np.asarray(a)
    if a.dtype.kind == "b":
        raise InputError(
            f"{path}: {kind} {name!r} holds booleans (True/False), expected numbers (t in s, x "
            "in m, F in N); a logical signal is not read as 0/1. Store the measured values as a "
            "float array."
        )
    if a.dtype.kind == "f" and a.dtype.itemsize < 4:
        raise InputError(
            f"{path}: {kind} {name!r} is stored as {a.dtype} (about 3 significant digits): its "
            "precision is too low for identification (a time column cannot even resolve the "
            "sampling interval). Store it as float64 (or float32)."
        )
    if a.dtype.kind in "iuf":
        return a.astype(np.float64)
    if a.dtype.kind in "USO":
        flat = a.ravel()
        bad = next((i for i, v in enumerate(flat) if not _is_number(v)), None)
        where = (
            f"first non-number {flat[bad]!r} at index {bad}"
            if bad is not None
            else "its values are text"
        )
        raise InputError(
            f"{path}: {kind} {name!r} is not numeric (dtype {a.dtype}; {where}). Store it as a "
            "float array."
        )
    raise InputError(
        f"{path}: {kind} {name!r} has dtype {a.dtype}, expected real numbers (float or int). "
        + ("Store the real part or split it." if a.dtype.kind == "c" else "Store a float array.")
    )


def _stored_dt(path: Path, store: Mapping, used: Iterable[str], kind: str) -> float | None:
    if "dt" not in store or "dt" in used:
        return None
    a = np.asarray(store["dt"])
    if a.size != 1:  # a per-sample column that happens to be called dt: not metadata
        return None
    dt = float(_as_float(path, "dt", a, kind=kind).ravel()[0])
    if not (np.isfinite(dt) and dt > 0):
        raise InputError(
            f"{path}: stored sampling interval {kind} 'dt' = {dt!r}; expected a positive "
            "finite number of seconds. Fix or remove it (dt is then taken from 't')."
        )
    return dt


def _read_npz(path: Path, wanted) -> tuple[dict[str, np.ndarray], float | None]:
    # the file is opened here (numpy leaves its own handle open when the archive is corrupt)
    with open(path, "rb") as fh:
        return _read_npz_from(path, fh, wanted)


def _read_npz_from(path: Path, fh, wanted) -> tuple[dict[str, np.ndarray], float | None]:
    try:
        store = np.load(fh, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise InputError(
            f"{path}: cannot be read as an NPZ archive ({e}); the file is truncated, corrupt or "
            "not an NPZ archive. Expected a file written by numpy.savez with arrays 't', 'x', "
            "'F'."
        ) from None
    if not isinstance(store, np.lib.npyio.NpzFile):
        raise InputError(
            f"{path}: holds a single array (a .npy file), expected an NPZ archive with arrays "
            "'t', 'x', 'F' (numpy.savez(path, t=..., x=..., F=...))."
        )
    with store:
        found = list(store.files)
        out = {}
        for name, role in wanted:
            if name not in found:
                raise _missing_column(path, name, role, found, "array")
            try:
                raw = store[name]
            except (OSError, EOFError, zipfile.BadZipFile, zlib.error) as e:
                raise InputError(
                    f"{path}: array {name!r} cannot be read ({type(e).__name__}: {e}); the "
                    "archive is truncated or corrupt. Re-export it."
                ) from None
            except ValueError as e:  # object arrays need pickle
                raise InputError(
                    f"{path}: array {name!r} cannot be read without pickle ({e}); store it as a "
                    "float array."
                ) from None
            out[name] = _as_float(path, name, raw, kind="array")
        dt = _stored_dt(path, store, out, "array")
    return out, dt


def _read_mat(path: Path, wanted) -> tuple[dict[str, np.ndarray], float | None]:
    try:
        import scipy.io
    except ImportError as e:
        raise ImportError(
            f"{path}: reading MATLAB .mat files needs scipy, which is not installed. Install "
            "the optional extra: pip install lionjax[mat] (or export the data to .csv/.npz)."
        ) from e
    try:
        store = scipy.io.loadmat(path)
    except NotImplementedError:
        raise InputError(
            f"{path}: MATLAB v7.3 (HDF5) files are not supported by scipy.io.loadmat. Re-save "
            "it in MATLAB with save(..., '-v7') or export it to .csv/.npz."
        ) from None
    except Exception as e:  # noqa: BLE001 — scipy's MatReadError, IndexError, … on a bad file
        raise InputError(
            f"{path}: cannot be read as a MATLAB .mat file ({type(e).__name__}: "
            f"{str(e).strip() or 'no detail'}); the file is truncated, corrupt or not a MATLAB "
            "file. Re-export it (MATLAB: save(..., '-v7')) or export the data to .csv/.npz."
        ) from None
    found = [k for k in store if not k.startswith("__")]
    out = {}
    for name, role in wanted:
        if name not in found:
            raise _missing_column(path, name, role, found, "variable")
        a = _as_float(path, name, store[name], kind="variable")
        if a.ndim == 2 and 1 in a.shape:  # MATLAB vectors are (T, 1) or (1, T)
            a = a.ravel()
        if a.ndim != 1:
            raise InputError(
                f"{path}: variable {name!r} has shape {a.shape}, expected a vector (one value "
                "per sample)."
            )
        out[name] = a
    return out, _stored_dt(path, store, out, "variable")


_READERS = {".csv": _read_csv, ".npz": _read_npz, ".mat": _read_mat}


# --------------------------------------------------------------------------- public API


def load_record(
    path: PathLike,
    *,
    columns: Mapping[str, str] | None = None,
    extras: Sequence[str] = (),
    resample: bool = False,
    resample_dt: float | None = None,
    force_scale: float | None = None,
    jitter_tolerance: float = JITTER_TOLERANCE,
    min_samples: int = MIN_SAMPLES,
    dtype=None,
    units: str = "linear",
) -> Record:
    """Read one record from a CSV, NPZ or MATLAB ``.mat`` file.

    Arguments:
        path: the file; its extension (``.csv``, ``.npz``, ``.mat``) decides the format.
        columns: map from lionjax's names ``t`` [s], ``x`` [m], ``F`` [N] to the names in the
            file, e.g. ``{"x": "pos"}``; unmapped names are read as themselves.
        extras: names of further columns to keep in ``Record.extras`` (each shape ``(T,)``,
            stored under its file name). Other columns are ignored.
        resample: if the sampling is not uniform within ``jitter_tolerance``, resample every
            column onto a uniform grid by linear interpolation (:func:`lionjax._record.resample`)
            instead of refusing the file. This is logged as a WARNING on the ``lionjax._io``
            logger, naming the file, the sample counts and the new ``dt``.
        resample_dt: the uniform grid's interval [s] when resampling (default: the file's
            stored ``dt`` if any, else the median interval of ``t``).
        force_scale: multiply the force column by this (e.g. a drive gain in N/V when the file
            holds a voltage, or a force calibration gain). Default: use F as stored.
        jitter_tolerance: largest accepted relative deviation of a sampling interval from the
            mean interval.
        min_samples: fewest samples accepted.
        dtype: array dtype of the record (default: JAX's default float).
        units: ``"linear"`` (x [m], F [N]) or ``"rotary"`` (x [rad], F [N·m]), kept on the
            record (:attr:`Record.units`) for its checks and reports.

    Returns:
        A :class:`Record` with ``x``, ``F`` of shape ``(T,)``, ``dt`` and ``t0`` from ``t``
        (``dt`` exactly as stored when an NPZ/MAT file has a scalar ``dt``).

    Raises:
        InputError: naming the file, the column or argument and the first bad index, for: a
            missing file, an unknown extension, an empty file, a missing column, a ragged CSV
            row, a cell that is not a number, NaN/inf, ``t`` not strictly increasing, sampling
            jitter beyond ``jitter_tolerance``, fewer than ``min_samples`` samples.
        ImportError: for a ``.mat`` file when scipy is not installed (``pip install lionjax[mat]``).
    """
    p = _check_path(path)
    check_units(units)
    names = _check_columns(columns)
    extras = _check_extras(extras, names)
    if force_scale is not None and not (_is_real(force_scale) and force_scale != 0):
        raise InputError(
            f"force_scale: expected a finite non-zero number (N per unit of the stored force "
            f"column), got {force_scale!r}."
        )
    if resample_dt is not None and not (_is_real(resample_dt) and resample_dt > 0):
        raise InputError(
            f"resample_dt: expected a positive number of seconds, got {resample_dt!r}."
        )
    suffix = p.suffix.lower()
    data, stored_dt = _READERS[suffix](p, _wanted(names, extras))
    t, x, F = (data[names[r]] for r in _REQUIRED)
    if force_scale is not None:
        F = F * float(force_scale)
    ext = {e: data[e] for e in extras}

    notes = []
    mapped = {r: n for r, n in names.items() if r != n}
    if mapped:
        notes.append(
            "(lionjax names are read from file columns: "
            + ", ".join(f"{r} <- {n!r}" for r, n in mapped.items())
            + ")"
        )
    if suffix == ".csv":
        notes.append("(CSV: sample index k is on line k + 2 of the file)")
    note = (" " + " ".join(notes)) if notes else ""

    def build(t, x, F, ext, tolerance):
        try:
            return Record.from_samples(
                t,
                x,
                F,
                extras=ext,
                source=str(p),
                jitter_tolerance=tolerance,
                min_samples=min_samples,
                dtype=dtype,
                units=units,
            )
        except InputError as e:
            raise InputError(f"{e}{note}") from None

    # Everything but uniformity first (finite, increasing, enough samples), then uniformity,
    # so that resampling never runs on data that would be refused anyway.
    build(t, x, F, ext, np.inf)
    try:
        record = build(t, x, F, ext, jitter_tolerance)
    except InputError as e:
        if not resample:
            how = _fix("pass resample=True to load_record", "pass --resample")
            raise InputError(
                f"{e} Or {how} to resample onto a uniform grid by linear interpolation."
            ) from None
        step = resample_dt if resample_dt is not None else stored_dt
        tu, xu, Fu = _resample(t, x, F, dt=step, source=str(p))
        extu = {k: np.interp(tu, t, v) for k, v in ext.items()}  # same grid, same interpolation
        logger.warning(
            "%s: sampling is not uniform within %.3g; resampled (resample=True) by linear "
            "interpolation from %d samples onto a uniform grid of %d samples, dt = %.9g s.",
            p,
            jitter_tolerance,
            t.size,
            tu.size,
            tu[1] - tu[0],
        )
        record = build(tu, xu, Fu, extu, jitter_tolerance)
    if stored_dt is not None:
        mean_dt = float(record.dt)
        if abs(stored_dt - mean_dt) > jitter_tolerance * mean_dt:
            raise InputError(
                f"{p}: stored sampling interval 'dt' = {stored_dt!r} s disagrees with the mean "
                f"interval of 't', {mean_dt!r} s (tolerance {jitter_tolerance:.2%}). Fix or "
                "remove 'dt'."
            )
        record = Record(record.x, record.F, stored_dt, record.t0, record.extras, units=units)
    return record


def record_files(folder: PathLike) -> list[Path]:
    """The record files of a folder: every ``*.csv``, ``*.npz``, ``*.mat`` in it (any case of
    the extension), sorted by name; sub-folders are not searched.

    Raises:
        InputError: naming the folder when it does not exist, is not a folder, or holds no
            record file (listing what it holds instead).
    """
    root = Path(folder)
    if not root.is_dir():
        raise InputError(f"{root}: no such folder.")
    paths = sorted(
        (q for q in root.iterdir() if q.is_file() and q.suffix.lower() in SUFFIXES),
        key=lambda q: q.name,
    )
    if not paths:
        others = sorted(q.name for q in root.iterdir())
        seen = ", ".join(others[:10]) + (" ..." if len(others) > 10 else "")
        raise InputError(
            f"{root}: the folder holds no record files ({', '.join(SUFFIXES)}); "
            + (f"found only: {seen}." if others else "it is empty.")
            + " Point to the folder with the data, or pass the files themselves."
        )
    return paths


def load_records(
    paths_or_folder: PathLike | Iterable[PathLike], **kwargs: Any
) -> list[tuple[Path, Record]]:
    """Read many records at once.

    Arguments:
        paths_or_folder: a folder (every ``*.csv``, ``*.npz``, ``*.mat`` file in it, sorted by
            name; sub-folders are not searched), a single file, or an iterable of files.
        **kwargs: passed to :func:`load_record` for every file.

    Returns:
        ``[(path, record), ...]`` in that order.

    Raises:
        InputError: for a missing or empty folder, an empty list, or any bad file (naming it).
    """
    if isinstance(paths_or_folder, str | os.PathLike):
        root = Path(paths_or_folder)
        if not root.exists():
            raise InputError(f"{root}: no such file or folder (paths_or_folder).")
        paths = record_files(root) if root.is_dir() else [root]
    else:
        paths = [Path(q) for q in paths_or_folder]
        if not paths:
            raise InputError("paths_or_folder: got an empty list of files; pass at least one.")
    return [(q, load_record(q, **kwargs)) for q in paths]


def save_record(path: PathLike, record: Record) -> Path:
    """Write one record to CSV, NPZ or MATLAB ``.mat`` (chosen by the extension).

    Writes ``t`` [s] (``t0 + k·dt``), ``x`` [m], ``F`` [N] and every extra under its name. CSV
    uses ``%.17g`` (float64 values round-trip exactly; ``dt`` is re-derived from ``t`` on
    loading, to ~1e-15 relative). NPZ and MAT also store the scalar ``dt`` and round-trip
    exactly. ``.mat`` needs scipy (``pip install lionjax[mat]``).

    Raises:
        InputError: for an unknown extension, a missing parent folder, a batched record, or an
            extra whose name clashes with ``t``, ``x``, ``F``, ``dt`` or does not fit a CSV header.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in SUFFIXES:
        raise InputError(
            f"{p}: unknown file type {p.suffix!r} for save_record; use one of "
            f"{', '.join(SUFFIXES)}."
        )
    check_output(p, str(p))
    if not isinstance(record, Record):
        raise InputError(f"record: expected a lionjax Record, got {type(record).__name__}.")
    if record.x.ndim != 1:
        raise InputError(
            f"record: save_record writes one record (x of shape (T,)), got a batch of shape "
            f"{record.x.shape}; save each element, e.g. jax.tree.map(lambda a: a[i], record)."
        )
    for name in record.extras:
        if name in _REQUIRED or name in _RESERVED:
            raise InputError(
                f"record: extra signal {name!r} clashes with a reserved name "
                f"({', '.join(_REQUIRED + _RESERVED)}); rename it before saving."
            )
        if suffix == ".csv" and (not name or any(c in name for c in ',"\r\n')):
            raise InputError(
                f"record: extra signal {name!r} cannot be a CSV column name (empty, or holds a "
                "comma, quote or newline); rename it or save as .npz."
            )
        if suffix == ".npz" and name in ("file", "allow_pickle"):
            raise InputError(
                f"record: extra signal {name!r} cannot be an NPZ array name (numpy.savez uses "
                "it as an argument); rename it or save as .csv."
            )
        if suffix == ".mat" and not (name.isidentifier() and not name.startswith("_")):
            raise InputError(
                f"record: extra signal {name!r} is not a MATLAB variable name (a letter, then "
                "letters, digits, underscores); rename it or save as .npz."
            )
    n = record.n_samples
    dt = float(record.dt)
    cols = {
        "t": float(record.t0) + dt * np.arange(n, dtype=np.float64),
        "x": np.asarray(record.x, dtype=np.float64),
        "F": np.asarray(record.F, dtype=np.float64),
        **{k: np.asarray(v, dtype=np.float64) for k, v in record.extras.items()},
    }
    if suffix == ".mat":
        try:
            import scipy.io
        except ImportError as e:
            raise ImportError(
                f"{p}: writing MATLAB .mat files needs scipy, which is not installed. Install "
                "the optional extra: pip install lionjax[mat] (or save as .npz)."
            ) from e
    with atomic_path(p) as tmp:  # a failed write leaves an existing file as it was
        if suffix == ".csv":
            np.savetxt(
                tmp,
                np.column_stack(list(cols.values())),
                fmt="%.17g",
                delimiter=",",
                header=",".join(cols),
                comments="",
            )
        elif suffix == ".npz":
            with open(tmp, "wb") as f:  # a file object: numpy must not append a second ".npz"
                np.savez_compressed(f, dt=np.float64(dt), **cols)
        else:
            scipy.io.savemat(
                tmp, {"dt": np.float64(dt), **{k: v[:, None] for k, v in cols.items()}}
            )
    return p
