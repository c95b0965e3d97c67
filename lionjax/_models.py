"""Model structures: each turns a record into the regressors (W, W₀) of ε = Wθ + W₀.

A model is linear in its parameters θ. Every parameter θⱼ owns one *column*: a raw signal uⱼ
(built from the record), its intersample assumption, an order mⱼ and a sign sⱼ, and contributes

    ε₁ ∋ sⱼ·(s^mⱼ/Λ)[uⱼ]·θⱼ,    ε₂ ∋ sⱼ·(s^(mⱼ+1)/Λ)[uⱼ]·θⱼ,

to the two equation errors (ε₂ = dε₁/dt). W₀ is (s²/Λ, s³/Λ)[x] = (V₃, V₄). For the mass–damper
ẍ + aẋ = bF this gives the paper's W = [[V₂, −Q₁], [V₃, −Q₂]], W₀ = [V₃, V₄] (GUIDE §2).

Across regions (GUIDE §3) masking filtered signals is wrong — the filter has memory. Instead,
with 1ᵢ(x)ẋ = d/dt gᵢ(x), gᵢ(x) = clip(x, loᵢ, hiᵢ), the model ẍ + Σᵢ 1ᵢ(x)(aᵢẋ − bᵢF) = 0 is
exactly linear in (aᵢ, bᵢ) with columns (s/Λ)[gᵢ(x)] and −(1/Λ)[1ᵢ(x)·F].

Effects (offset, Coulomb friction, spring …) are :class:`AbstractEffect` columns appended with
:class:`Augmented`; the estimators only ever see (W, W₀), so they need no change.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._errors import InputError
from ._filters import FilterBank, Hold, check_hold
from ._record import Record


class Column(eqx.Module):
    """One regressor column: sign·(s^order/Λ)[signal] (row 1) and its derivative (row 2)."""

    signal: str = eqx.field(static=True)
    order: int = eqx.field(static=True)
    sign: float = eqx.field(static=True)


class Regressors(eqx.Module):
    """The regressors of ε = Wθ + W₀ at every sample.

    Attributes:
        W: shape ``(T, 2, p)``; W0: shape ``(T, 2)``; names: the p parameter names.
    """

    W: Float[Array, "T 2 p"]
    W0: Float[Array, "T 2"]
    names: tuple[str, ...] = eqx.field(static=True)


class AbstractModel(eqx.Module):
    """A model structure linear in its parameters (see module docstring)."""

    @property
    @abc.abstractmethod
    def names(self) -> tuple[str, ...]:
        """Parameter names, one per column."""

    @abc.abstractmethod
    def columns(self) -> tuple[Column, ...]:
        """One :class:`Column` per parameter, in the order of :attr:`names`."""

    @abc.abstractmethod
    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]:
        """Raw signals (shape ``(T,)``) named by the columns, with their intersample holds."""

    def physical(self, theta: Float[Array, " p"]) -> dict[str, Array]:
        """Parameters by name, in physical units (the default: θ itself)."""
        return {n: theta[..., i] for i, n in enumerate(self.names)}

    def regressors(self, record: Record, bank: FilterBank) -> Regressors:
        """Filter every signal once and assemble (W, W₀) — shapes ``(T, 2, p)``, ``(T, 2)``."""
        sigs = self.signals(record)
        if "x" not in sigs:
            raise InputError(f"{type(self).__name__}.signals must provide 'x' (for W₀).")
        filtered = {k: bank(u, record.dt, hold) for k, (u, hold) in sigs.items()}
        cols = []
        for c in self.columns():
            out = filtered[c.signal]
            cols.append(c.sign * out[:, c.order : c.order + 2])
        W = jnp.stack(cols, axis=-1)
        W0 = filtered["x"][:, 2:4]
        return Regressors(W, W0, self.names)


class MassDamper(AbstractModel):
    """ẍ + aẋ = bF  (a = C/M [1/s], b = 1/M [1/kg]); parameters ``("a", "b")``.

    Attributes:
        x_hold, F_hold: intersample assumptions (defaults ``"foh"`` and ``"zoh"``, GUIDE §4).
    """

    x_hold: Hold = eqx.field(static=True, default="foh")
    F_hold: Hold = eqx.field(static=True, default="zoh")

    def __check_init__(self):
        check_hold(self.x_hold, "x_hold")
        check_hold(self.F_hold, "F_hold")

    @property
    def names(self) -> tuple[str, ...]:
        return ("a", "b")

    def columns(self) -> tuple[Column, ...]:
        return (Column("x", 1, 1.0), Column("F", 0, -1.0))

    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]:
        return {"x": (record.x, self.x_hold), "F": (record.F, self.F_hold)}


def _region_fractions(x: Array, lo: float, hi: float) -> Array:
    """Fraction of each interval [t_k, t_{k+1}] spent in [lo, hi], x linear in between.

    The zero-order-held force F[k] acts over [t_k, t_{k+1}]; weighting it by this fraction
    keeps the integral of 1ᵢ(x)·F exact when x crosses a bound inside an interval.
    """
    x1 = jnp.concatenate([x[1:], x[-1:]])
    xa, xb = jnp.minimum(x, x1), jnp.maximum(x, x1)
    span = xb - xa
    overlap = jnp.clip(jnp.minimum(xb, hi) - jnp.maximum(xa, lo), 0.0, None)
    flat = span <= 0
    inside = ((x >= lo) & (x <= hi)).astype(x.dtype)
    frac = overlap / jnp.where(flat, 1.0, span)
    return jnp.where(flat, inside, frac)


class Piecewise(AbstractModel):
    """ẍ + aᵢẋ = bᵢF in region i, regions split by sorted ``bounds`` [m] (GUIDE §3).

    Region 1 is x < bounds[0], the last region x > bounds[-1]. Parameters are named
    ``a_1, b_1, a_2, b_2, …``. Columns are exact across regions: (s/Λ)[clip(x, loᵢ, hiᵢ)] for aᵢ
    and −(1/Λ)[1ᵢ(x)·F] for bᵢ, where 1ᵢ(x)·F over each held-force interval is weighted by the
    fraction of that interval x spends in region i (x linear between samples).
    """

    bounds: tuple[float, ...] = eqx.field(static=True)
    x_hold: Hold = eqx.field(static=True, default="foh")
    F_hold: Hold = eqx.field(static=True, default="zoh")

    def __init__(self, bounds: Sequence[float], x_hold: Hold = "foh", F_hold: Hold = "zoh"):
        b = np.atleast_1d(np.asarray(bounds, dtype=np.float64))
        if b.ndim != 1 or b.size < 1:
            raise InputError(
                "Piecewise: bounds must be a non-empty 1-D sequence of positions [m], got "
                f"{bounds!r}."
            )
        if not np.all(np.isfinite(b)):
            raise InputError(f"Piecewise: bounds must be finite, got {b.tolist()}.")
        if np.any(np.diff(b) <= 0):
            raise InputError(
                f"Piecewise: bounds must be strictly increasing, got {b.tolist()}; sort them "
                "(region 1 is below the first bound)."
            )
        self.bounds = tuple(float(v) for v in b)
        self.x_hold = check_hold(x_hold, "x_hold")
        self.F_hold = check_hold(F_hold, "F_hold")

    @property
    def n_regions(self) -> int:
        return len(self.bounds) + 1

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"{p}_{i + 1}" for i in range(self.n_regions) for p in ("a", "b"))

    def _limits(self) -> list[tuple[float, float]]:
        edges = (-np.inf, *self.bounds, np.inf)
        return list(zip(edges[:-1], edges[1:], strict=True))

    def columns(self) -> tuple[Column, ...]:
        cols = []
        for i in range(self.n_regions):
            cols += [Column(f"g_{i + 1}", 1, 1.0), Column(f"F_{i + 1}", 0, -1.0)]
        return tuple(cols)

    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]:
        x, F = record.x, record.F
        out: dict[str, tuple[Array, Hold]] = {"x": (x, self.x_hold)}
        for i, (lo, hi) in enumerate(self._limits()):
            out[f"g_{i + 1}"] = (jnp.clip(x, lo, hi), self.x_hold)
            weight = (
                _region_fractions(x, lo, hi)
                if self.F_hold == "zoh"
                else (((x >= lo) & (x <= hi)).astype(x.dtype))
            )
            out[f"F_{i + 1}"] = (weight * F, self.F_hold)
        return out

    def region_of(self, x: ArrayLike) -> Array:
        """Region index (1-based) of each position."""
        return jnp.searchsorted(jnp.asarray(self.bounds), jnp.asarray(x), side="left") + 1


class AbstractEffect(eqx.Module):
    """An unmodelled effect acting on the force (GUIDE §6), linear in its parameters.

    ẍ + aẋ = b·(F + F₀ − Fc·sgn ẋ − k(x − x₀)): each effect adds columns whose parameters are
    b times the physical ones (e.g. c = b·F₀); :meth:`physical` divides by b.
    """

    @property
    @abc.abstractmethod
    def names(self) -> tuple[str, ...]: ...

    @abc.abstractmethod
    def columns(self) -> tuple[Column, ...]: ...

    @abc.abstractmethod
    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]: ...

    @abc.abstractmethod
    def physical(self, theta: Array, b: Array) -> dict[str, Array]: ...


class Offset(AbstractEffect):
    """Constant force F₀ [N]: column −(1/Λ)[1] for the parameter b·F₀ [m/s²]."""

    @property
    def names(self) -> tuple[str, ...]:
        return ("bF0",)

    def columns(self) -> tuple[Column, ...]:
        return (Column("one", 0, -1.0),)

    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]:
        return {"one": (jnp.ones_like(record.x), "zoh")}

    def physical(self, theta: Array, b: Array) -> dict[str, Array]:
        return {"F0": theta[..., 0] / b}


class Augmented(AbstractModel):
    """A base model plus effect columns; parameters ``base.names + effect names``."""

    base: AbstractModel
    effects: tuple[AbstractEffect, ...]

    def __init__(self, base: AbstractModel, effects: Sequence[AbstractEffect]):
        if isinstance(base, Augmented):
            raise InputError("Augmented: base must be a plain model, not another Augmented.")
        self.base = base
        self.effects = tuple(effects)
        names = self.names
        if len(set(names)) != len(names):
            raise InputError(f"Augmented: parameter names repeat: {names}; add each effect once.")

    @property
    def names(self) -> tuple[str, ...]:
        return self.base.names + tuple(n for e in self.effects for n in e.names)

    def columns(self) -> tuple[Column, ...]:
        return self.base.columns() + tuple(c for e in self.effects for c in e.columns())

    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]:
        out = self.base.signals(record)
        for e in self.effects:
            out.update(e.signals(record))
        return out

    def physical(self, theta: Array) -> dict[str, Array]:
        out = self.base.physical(theta)
        b = out.get("b", theta[..., self.base.names.index("b")] if "b" in self.base.names else 1.0)
        i = len(self.base.names)
        for e in self.effects:
            k = len(e.names)
            out.update(e.physical(theta[..., i : i + k], b))
            i += k
        return out
