"""Errors raised by lionjax and the result codes carried by batched solutions.

Bad input raises :class:`InputError` (a ``ValueError``) whose message names the argument or file,
what was expected, what came, and how to fix it. Failures inside jitted, batched code are carried
as a :class:`RESULTS` code per batch element and raised once, outside the trace, by
:func:`raise_if_failed`, so a batch of 10 000 reports *which* elements failed and why.
"""

from __future__ import annotations

import equinox as eqx
import numpy as np


class InputError(ValueError):
    """Bad input: the message names the argument/file, what was expected, what came, the fix."""


class IdentificationError(RuntimeError):
    """The identification ran but its answer cannot be trusted (e.g. parameters not excited)."""


class RESULTS(eqx.Enumeration):
    """Per-element outcome of an identification (carried through ``jit``/``vmap``)."""

    successful = ""
    unidentifiable = (
        "the record does not excite every parameter: the regressor matrix is rank deficient "
        "(condition number above the bound). Use a richer excitation, fewer parameters, or "
        "region bounds that the record actually visits."
    )
    unstable_step = (
        "explicit Euler is unstable for this gain and data: dt·‖G‖·‖W‖² > 2 at some sample. Use "
        "the exact step (the default), or lower the gain."
    )
    nonfinite = (
        "a non-finite value (NaN or inf) appeared in the estimate; check the data for NaN/inf "
        "and the gain for overflow."
    )


def result_codes(result: RESULTS) -> np.ndarray:
    """The integer codes of a (possibly batched) ``RESULTS`` value as a numpy array."""
    return np.asarray(result._value)


def raise_if_failed(solution, *, what: str = "identification") -> None:
    """Raise :class:`IdentificationError` listing every failed batch element of ``solution``.

    ``solution`` is any lionjax solution Module with a ``result`` field (batched or not). Call
    it after a ``vmap``-ed run with ``throw=False`` to learn which elements failed and why.
    """
    codes = result_codes(solution.result)
    if not np.any(codes != 0):
        return
    bad = np.argwhere(codes != 0)
    lines = []
    for index in bad[:20]:
        code = int(codes[tuple(index)])
        msg = RESULTS._index_to_message[code]
        where = "" if codes.ndim == 0 else f"batch element {tuple(int(i) for i in index)}: "
        lines.append(f"  {where}{msg}")
    more = "" if len(bad) <= 20 else f"\n  ... and {len(bad) - 20} more"
    raise IdentificationError(
        f"{what} failed for {len(bad)} of {codes.size} element(s):\n" + "\n".join(lines) + more
    )
