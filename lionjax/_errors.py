"""Errors raised by lionjax and the result codes carried by batched solutions.

Bad input raises :class:`InputError` (a ``ValueError``) whose message names the argument or file,
what was expected, what came, and how to fix it. Failures inside jitted, batched code are carried
as a :class:`RESULTS` code per batch element and raised once, outside the trace, by
:func:`raise_if_failed`, so a batch of 10 000 reports *which* elements failed and why.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Int


class InputError(ValueError):
    """Bad input: the message names the argument/file, what was expected, what came, the fix."""


class IdentificationError(RuntimeError):
    """The identification ran but its answer cannot be trusted (e.g. parameters not excited)."""


class DataWarning(UserWarning):
    """A record or setting that is probably a mistake (units, a spike, a filter too fast for
    the sampling); the estimate is still computed. Also ``lionjax.solutions.DataWarning``."""


class FilterSpeedWarning(DataWarning):
    """The filter is fast for the sampling: max|pole|·dt above ``lionjax._validity.WARN_POLE_DT``
    (0.1), so the estimate is biased (b by about −(max|pole|·dt)²/4). Also
    ``lionjax.solutions.FilterSpeedWarning``."""


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
        "a non-finite value (NaN or inf) appeared in the estimate, or the data are non-finite "
        "or out of range (an overflow); check the data for NaN/inf and for values too large "
        "for their units, and the gain for overflow."
    )


def result_code(result: eqx.Enumeration) -> Int[Array, "..."]:
    """The integer code of a (possibly batched) enumeration item, as a JAX array.

    Works inside ``jit``/``vmap`` (e.g. to put the code in a solver's ``aux``). Any
    ``eqx.Enumeration`` item is accepted (lionjax's :class:`RESULTS`, ``optimistix.RESULTS``, …).
    An item is a PyTree whose single leaf is its code, so this reads it through the public PyTree
    API rather than equinox's private attribute.
    """
    leaves = jax.tree_util.tree_leaves(result)
    if len(leaves) != 1 or not jnp.issubdtype(jnp.result_type(leaves[0]), jnp.integer):
        raise TypeError(
            f"result_code: expected an eqx.Enumeration item (one integer leaf), got "
            f"{type(result).__name__} with {len(leaves)} leaves; pass a solution's ``result``."
        )
    return leaves[0]


def result_codes(result: eqx.Enumeration) -> np.ndarray:
    """The integer codes of a (possibly batched) enumeration item as a numpy array (0 = success
    for lionjax's :class:`RESULTS`). Host-side: call it on a concrete result, outside ``jit``."""
    return np.asarray(result_code(result))


def result_message(code: ArrayLike, enumeration: type[eqx.Enumeration] = RESULTS) -> str:
    """The message of one integer ``code`` of ``enumeration`` (default lionjax's :class:`RESULTS`;
    pass ``optimistix.RESULTS`` for an optimistix solution's code; "" for success).

    Built on equinox's public API: the code is turned back into an item of ``enumeration`` by
    unflattening the PyTree structure of its ``successful`` item (the member every RESULTS-style
    enumeration of lionjax, optimistix, lineax and diffrax has), and ``enumeration[item]`` gives
    the message.
    """
    c = np.asarray(code)
    n = len(enumeration)
    if c.shape != () or not np.issubdtype(c.dtype, np.integer) or not 0 <= int(c) < n:
        raise InputError(
            f"result_message: argument 'code' must be one integer in [0, {n}) "
            f"for {enumeration.__name__}, got {code!r}."
        )
    treedef = jax.tree_util.tree_structure(enumeration.successful)
    item = jax.tree_util.tree_unflatten(treedef, [c.astype(np.int32)])
    return enumeration[item]


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
        msg = result_message(code)
        where = "" if codes.ndim == 0 else f"batch element {tuple(int(i) for i in index)}: "
        lines.append(f"  {where}{msg}")
    more = "" if len(bad) <= 20 else f"\n  ... and {len(bad) - 20} more"
    raise IdentificationError(
        f"{what} failed for {len(bad)} of {codes.size} element(s):\n" + "\n".join(lines) + more
    )
