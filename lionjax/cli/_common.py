"""Shared by the subcommands: number lists and the text table. Files are checked and written by
:mod:`lionjax._tables` (the one JSON/CSV writer)."""

from __future__ import annotations

import numpy as np

from .._errors import InputError


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
        out.append(v.real if v.imag == 0 else v)
    return out


def format_table(headers: list[str], rows: list[list], title: str | None = None) -> str:
    """A plain fixed-width text table."""
    cells = [[str(h) for h in headers]] + [[_fmt(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = [title] if title else []
    lines.append("  ".join(h.ljust(w) for h, w in zip(cells[0], widths, strict=True)))
    lines.append("  ".join("-" * w for w in widths))
    for r in cells[1:]:
        lines.append("  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)))
    return "\n".join(lines)


def _fmt(v) -> str:
    if isinstance(v, float | np.floating):
        return "nan" if not np.isfinite(v) else f"{v:.6g}"
    return str(v)
