"""Unit systems of a record: a linear axis (x [m], F [N]) or a rotary one (θ [rad], τ [N·m]).

The method is the same for both: ẍ + aẋ = bF holds for a rotating inertia J with x = θ and
F = τ, b = 1/J. Only the names of the units change, so lionjax computes in whatever units the
record holds and states them in its reports. Every unit the library reports is written for a
linear axis (SI: m, N, kg, s); :func:`unit` rewrites one for the record's system:

    m → rad,   N → N·m,   kg → kg·m²   (so N/m → N·m/rad, 1/kg → 1/(kg·m²), m/s² → rad/s²),

and leaves every other symbol (s, Hz, V, A, 1/s) as it is.
"""

from __future__ import annotations

import re
from typing import Any

from ._errors import InputError

#: The unit systems a record may be in.
UNIT_SYSTEMS = ("linear", "rotary")

#: Each linear base symbol and its rotary counterpart (a force per metre of travel becomes a
#: torque per radian of rotation: the work τ·dθ replaces F·dx).
_ROTARY = {"m": "rad", "N": "N·m", "kg": "kg·m²"}
_TOKEN = re.compile(r"(?<![A-Za-z])(kg|m|N)(?![A-Za-z])")


def check_units(units: Any, argument: str = "units") -> str:
    """``units`` itself, if it is one of :data:`UNIT_SYSTEMS`; else an :class:`InputError`."""
    if not isinstance(units, str) or units not in UNIT_SYSTEMS:
        raise InputError(
            f"{argument}: expected one of {', '.join(map(repr, UNIT_SYSTEMS))} (x in m and F in "
            f"N, or x in rad and F in N·m), got {units!r}."
        )
    return units


def unit(linear: str, units: str = "linear") -> str:
    """The unit ``linear`` (written for a linear axis) in the system ``units``.

    ``unit("N/m", "rotary") == "N·m/rad"``, ``unit("1/kg", "rotary") == "1/(kg·m²)"``;
    a linear record's units are returned unchanged.
    """
    if check_units(units) == "linear" or not linear:
        return linear

    def swap(match: re.Match) -> str:
        new = _ROTARY[match.group(1)]
        divided = match.start() > 0 and linear[match.start() - 1] == "/"
        return f"({new})" if divided and "·" in new else new

    return _TOKEN.sub(swap, linear)


def convert_units(payload: Any, units: str) -> Any:
    """``payload`` with every unit it states rewritten for ``units``: the values of each
    ``"units"`` mapping and each string under a key ending in ``"_units"``, at any depth of
    nested dicts and lists (other values are returned as they are)."""
    check_units(units)
    if units == "linear":
        return payload
    if isinstance(payload, dict):
        out = {}
        for k, v in payload.items():
            if k == "units" and isinstance(v, dict):
                out[k] = {n: unit(u, units) if isinstance(u, str) else u for n, u in v.items()}
            elif isinstance(k, str) and k.endswith("_units") and isinstance(v, str):
                out[k] = unit(v, units)
            else:
                out[k] = convert_units(v, units)
        return out
    if isinstance(payload, list):
        return [convert_units(v, units) for v in payload]
    return payload
