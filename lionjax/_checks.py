"""Argument checks shared by the twin and the excitations (private).

Parameters given as Python numbers or numpy arrays are stored as float64 numpy arrays, so that
module-level constants built at import time (``FALCON_PAPER``, ``PAPER_SINE_SETS``) keep full
precision whether or not ``jax_enable_x64`` is switched on later; inside ``jit`` they become arrays
of JAX's default float dtype. JAX arrays (and tracers, under ``vmap``) are stored unchanged, and
value checks are skipped for tracers (they are checked where they are concrete).
"""

from __future__ import annotations

import jax
import numpy as np
from jaxtyping import ArrayLike

from ._errors import InputError


def param(value: ArrayLike, name: str, owner: str, *, ndim: int | None = 0):
    """Store ``value`` as a parameter: float64 numpy for concrete non-JAX input, else unchanged."""
    if isinstance(value, jax.Array):
        arr = value
    else:
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise InputError(
                f"{owner}: argument {name!r} must be a real number (or array of them), got "
                f"{value!r}. Pass a float in SI units."
            ) from err
    if ndim is not None and arr.ndim != ndim:
        shape = "a scalar" if ndim == 0 else f"a {ndim}-D array"
        raise InputError(
            f"{owner}: argument {name!r} must be {shape}, got shape {tuple(arr.shape)}. To batch "
            "over parameter values, build the Module inside `jax.vmap`/`eqx.filter_vmap` instead."
        )
    return arr


def concrete(value) -> np.ndarray | None:
    """The value as a numpy array, or ``None`` when it is a tracer (unknown at trace time)."""
    if isinstance(value, jax.core.Tracer):
        return None
    return np.asarray(value)


def check(value, name: str, owner: str, ok, expected: str, fix: str) -> None:
    """Raise :class:`InputError` unless ``ok(concrete value)`` holds (skipped for tracers)."""
    arr = concrete(value)
    if arr is None:
        return
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{owner}: argument {name!r} must be finite, got {arr.tolist()!r}. {fix}")
    if not np.all(ok(arr)):
        raise InputError(
            f"{owner}: argument {name!r} must be {expected}, got {arr.tolist()!r}. {fix}"
        )


def check_positive(value, name: str, owner: str, fix: str = "") -> None:
    check(value, name, owner, lambda a: a > 0, "> 0", fix or f"Pass a positive {name}.")


def check_nonnegative(value, name: str, owner: str, fix: str = "") -> None:
    check(
        value,
        name,
        owner,
        lambda a: a >= 0,
        ">= 0",
        fix or f"Pass {name} >= 0 (0 switches the effect off).",
    )


def check_finite(value, name: str, owner: str) -> None:
    check(value, name, owner, lambda a: np.ones_like(a, bool), "finite", "Pass finite values.")
