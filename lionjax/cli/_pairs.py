"""``lionjax diagnose --pairs DIR | FILE.csv``: many (train, valid) pairs in one process.

DIR pairs ``NAME_train.*`` with ``NAME_valid.*`` (``.csv``, ``.npz``, ``.mat``); FILE.csv is a
manifest with the columns ``name,train,valid`` (paths relative to the manifest's folder). Every
pair runs through :func:`lionjax.diagnosis.diagnose_many`, so pairs of the same lengths share
the compiled programs; the rows are printed as one table and written by ``--json``/``--csv``.
"""

from __future__ import annotations

import csv
import re
import warnings
from pathlib import Path

from .._errors import InputError
from ._common import format_table, number, one_line

#: A record file of a pair in DIR: NAME_train.EXT or NAME_valid.EXT.
_ROLE = re.compile(r"^(?P<name>.+)_(?P<role>train|valid)$")
#: The manifest's columns.
MANIFEST = ("name", "train", "valid")
#: Widest error shown in the table (the full messages follow it).
_ERROR_WIDTH = 48


def find_pairs(path: str | Path) -> tuple[list[tuple[str, Path, Path]], list[tuple[str, str]]]:
    """``([(name, train, valid)], [(name, error)])`` of ``--pairs``: a folder or a manifest.

    The second list holds the pairs that cannot run (a ``NAME_train`` without ``NAME_valid``,
    or the reverse), reported as rows without stopping the others.

    Raises:
        InputError: naming the path, for a missing path, a folder with no pairs, two files of the
            same role and name (``a_train.csv`` and ``a_train.npz``), or a bad manifest.
    """
    p = Path(path)
    if p.is_dir():
        return _folder_pairs(p)
    if p.is_file() and p.suffix.lower() == ".csv":
        return _manifest_pairs(p), []
    raise InputError(
        f"--pairs {p}: "
        + ("no such file or folder" if not p.exists() else "not a folder or a .csv manifest")
        + "; give a folder of NAME_train.*/NAME_valid.* records or a manifest FILE.csv with the "
        "columns name,train,valid."
    )


def _folder_pairs(root: Path):
    from .._io import record_files

    found: dict[str, dict[str, Path]] = {}
    ignored = []
    for q in record_files(root):
        m = _ROLE.match(q.stem)
        if m is None:
            ignored.append(q.name)
            continue
        seen = found.setdefault(m["name"], {})
        if m["role"] in seen:
            raise InputError(
                f"--pairs {root}: two {m['role']} records for the pair {m['name']!r}: "
                f"{seen[m['role']].name} and {q.name}; keep one of them."
            )
        seen[m["role"]] = q
    if not found:
        raise InputError(
            f"--pairs {root}: the folder holds no pairs of records named NAME_train.* and "
            f"NAME_valid.* (found {', '.join(ignored[:5])}{' ...' if len(ignored) > 5 else ''});"
            " rename the files, or list them in a manifest FILE.csv (columns name,train,valid)."
        )
    if ignored:
        warnings.warn(
            f"--pairs {root}: ignored {len(ignored)} file(s) not named NAME_train.* or "
            f"NAME_valid.*: {', '.join(ignored[:5])}{' ...' if len(ignored) > 5 else ''}",
            stacklevel=2,
        )
    pairs, orphans = [], []
    for name in sorted(found):
        roles = found[name]
        if len(roles) == 2:
            pairs.append((name, roles["train"], roles["valid"]))
        else:
            q = next(iter(roles.values()))
            want = "valid" if "train" in roles else "train"
            orphans.append(
                (name, f"{q}: no {name}_{want}.csv/.npz/.mat beside it; add it or remove {q.name}.")
            )
    return pairs, orphans


def _manifest_pairs(manifest: Path) -> list[tuple[str, Path, Path]]:
    with manifest.open(newline="", encoding="utf-8-sig") as f:
        reader = csv.DictReader(f)
        header = [h.strip() for h in reader.fieldnames or []]
        missing = [c for c in MANIFEST if c not in header]
        if missing:
            raise InputError(
                f"--pairs {manifest}: the manifest lacks the column(s) {', '.join(missing)} "
                f"(found {', '.join(header) or 'no header'}); its first line must be "
                "name,train,valid."
            )
        rows = [{k.strip(): (v or "").strip() for k, v in r.items() if k} for r in reader]
    pairs, lines = [], {}
    for i, r in enumerate(rows, start=2):
        empty = [c for c in MANIFEST if not r.get(c)]
        if empty:
            raise InputError(
                f"--pairs {manifest}: line {i} has no {', '.join(empty)}; give every pair a "
                "name, a train and a valid file."
            )
        if r["name"] in lines:
            raise InputError(
                f"--pairs {manifest}: lines {lines[r['name']]} and {i} both name the pair "
                f"{r['name']!r}; give each pair its own name."
            )
        lines[r["name"]] = i
        pairs.append((r["name"], manifest.parent / r["train"], manifest.parent / r["valid"]))
    if not pairs:
        raise InputError(
            f"--pairs {manifest}: the manifest lists no pairs; add lines name,train,valid."
        )
    return pairs


def table(result) -> str:
    """The rows as one text table, then the full error of every pair that failed."""
    rows = []
    for r in result.rows:
        err = None if r.error is None else one_line(r.error).replace("\n", " ")
        if err is not None and len(err) > _ERROR_WIDTH:
            err = err[: _ERROR_WIDTH - 1] + "…"
        rows.append(
            [
                r.name,
                r.verdict,
                number(r.confidence, ".2f"),
                ", ".join(r.stack) or ("(empty)" if r.error is None else None),
                number(r.shrink, ".3g"),
                number(r.detection_limit, ".2g"),
                err or "",
            ]
        )
    headers = ["name", "verdict", "confidence", "stack", "shrink", "detection limit", "error"]
    text = format_table(headers, rows)
    for name, error in result.failures:
        text += f"\n{name}: {one_line(error)}"
    return text


def check_arguments(args, parser) -> None:
    """The arguments --pairs cannot go with, refused through ``parser.error``."""
    if args.data is not None:
        parser.error(
            f"argument TRAIN ({args.data}) is not allowed with --pairs: give either TRAIN "
            "[--validate VALID] or --pairs DIR|FILE.csv"
        )
    for flag, given, why in (
        ("--validate", args.validate, "each pair names its own validation record"),
        ("--plot", args.plot, "one figure per pair: draw a pair with TRAIN --validate VALID"),
        ("--decimate", args.decimate != 1, "decimate the files, or diagnose one pair alone"),
        ("--F-hold", args.F_hold != "zoh", "hold the files' force, or diagnose one pair alone"),
    ):
        if given:
            parser.error(f"argument {flag} is not allowed with --pairs ({why})")
