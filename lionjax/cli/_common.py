"""Shared by the subcommands: number lists, the text table, the file an error is about and the
one-line form of an error. Files are checked and written by :mod:`lionjax._tables` (the one
JSON/CSV writer, atomic)."""

from __future__ import annotations

import contextlib
import contextvars
import re
from collections.abc import Iterator

import numpy as np

from .._errors import IdentificationError, InputError
from .._units import UNIT_SYSTEMS

#: The file the current step reads (set by :func:`about`): errors and warnings name it.
CURRENT_FILE: contextvars.ContextVar[str | None] = contextvars.ContextVar(
    "lionjax_cli_file", default=None
)

# The library's names of arguments → the command line's (in messages of the core layer and
# of the diagnosis).
_CLI_WORDS = (
    (re.compile(r"argument '?bank'?"), "--poles/--coeffs"),
    (re.compile(r"argument '?theta0'?"), "--theta0"),
    (re.compile(r"argument '?gain'?"), "--gain"),
    (re.compile(r"\bresample=True\b"), "--resample"),
    (re.compile(r"\bfilter_hz\b"), "--filter-hz"),
    (re.compile(r"\bwindow_s\b"), "--window"),
    (re.compile(r"\bmax_memory_gb\b"), "--max-memory-gb"),
    (re.compile(r"argument 'candidates'"), "--candidates"),
)


def cli_words(message: str) -> str:
    """The library's argument names in ``message`` → the command line's options."""
    for pattern, word in _CLI_WORDS:
        message = pattern.sub(word, message)
    return message


def float_list(text: str, argument: str) -> list[float]:
    """Parse ``"-0.01,0.01"`` (commas; complex allowed as ``-6+2j``) into a list of numbers."""
    out = []
    for item in text.split(","):
        item = item.strip()
        try:
            v = complex(item.replace(" ", ""))
        except ValueError:
            raise InputError(
                f"{argument}: expected numbers separated by commas, got {item!r} in {text!r}."
            ) from None
        if not (np.isfinite(v.real) and np.isfinite(v.imag)):
            raise InputError(
                f"{argument}: expected finite numbers separated by commas, got {item!r} in "
                f"{text!r}."
            )
        out.append(v.real if v.imag == 0 else v)
    return out


@contextlib.contextmanager
def about(path) -> Iterator[None]:
    """Errors (and warnings, see :func:`lionjax.cli.main`) raised inside name the file ``path``:
    the message is prefixed with it unless it already names it."""
    token = CURRENT_FILE.set(str(path))
    try:
        yield
    except (InputError, IdentificationError) as e:
        msg = str(e)
        if str(path) in msg or msg.startswith("--"):  # names the file, or an option
            raise
        raise type(e)(f"{path}: {msg}") from None
    finally:
        CURRENT_FILE.reset(token)


def one_line(message: str) -> str:
    """An error message as the command line prints it: the library's argument names replaced by
    the options', and one line — except a list of several files or elements (indented lines
    after a heading), one line each. ``X failed for 1 of 1 element(s):`` + reason becomes
    ``X failed: reason``."""
    message = cli_words(message)
    lines = [ln.rstrip() for ln in message.strip().splitlines() if ln.strip()]
    if not lines:
        return "(no message)"
    tail = " for 1 of 1 element(s):"
    if lines[0].endswith(tail):
        head = lines[0].strip()[: -len(tail)]
        return f"{head}: " + " ".join(ln.strip() for ln in lines[1:])
    listed = len(lines) > 2 and all(ln.startswith("  ") for ln in lines[1:])
    if listed:
        return "\n".join(lines)
    return " ".join(ln.strip() for ln in lines)


def format_table(headers: list[str], rows: list[list], title: str | None = None) -> str:
    """A plain fixed-width text table (NaN, a value that does not exist, shown as —)."""
    cells = [[str(h) for h in headers]] + [[_fmt(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = [title] if title else []
    lines.append("  ".join(h.ljust(w) for h, w in zip(cells[0], widths, strict=True)))
    lines.append("  ".join("-" * w for w in widths))
    for r in cells[1:]:
        lines.append("  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)))
    return "\n".join(lines)


def _fmt(v) -> str:
    if v is None:
        return "—"
    if isinstance(v, float | np.floating):
        if np.isnan(v):
            return "—"
        if np.isinf(v):
            return "inf" if v > 0 else "-inf"
        return f"{v:.6g}"
    return str(v)


def number(v, fmt: str = ".4g", missing: str = "—") -> str:
    """``format(v, fmt)``, or ``missing`` for None/NaN (a value that does not exist)."""
    if v is None or (isinstance(v, float | np.floating) and np.isnan(v)):
        return missing
    return format(v, fmt)


def add_units_argument(group) -> None:
    """``--units linear|rotary``: the unit system of the records (Record.units)."""
    group.add_argument(
        "--units",
        choices=UNIT_SYSTEMS,
        default="linear",
        help="x in m and F in N (linear, default), or x in rad and F in N·m (rotary): the "
        "units the checks and the reports state",
    )
