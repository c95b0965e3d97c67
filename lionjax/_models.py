"""Model structures: each turns a record into the regressors (W, W₀) of ε = Wθ + W₀.

A model is linear in its parameters θ. Every parameter θⱼ owns one *column*: a raw signal uⱼ
(built from the record), its intersample assumption, an order mⱼ and a sign sⱼ, and contributes

    ε₁ ∋ sⱼ·(s^mⱼ/Λ)[uⱼ]·θⱼ,    ε₂ ∋ sⱼ·(s^(mⱼ+1)/Λ)[uⱼ]·θⱼ,

to the two equation errors (ε₂ = dε₁/dt). W₀ is (s²/Λ, s³/Λ)[x] = (V₃, V₄). For the mass–damper
ẍ + aẋ = bF this gives the paper's W = [[V₂, −Q₁], [V₃, −Q₂]], W₀ = [V₃, V₄]
(docs/method.md, "Equation errors").

Across regions (docs/method.md, "Exact regressors across regions") masking filtered signals is
wrong — the filter has memory. Instead, with 1ᵢ(x)ẋ = d/dt gᵢ(x), gᵢ(x) = clip(x, loᵢ, hiᵢ),
the model ẍ + Σᵢ 1ᵢ(x)(aᵢẋ − bᵢF) = 0 is exactly linear in (aᵢ, bᵢ) with columns (s/Λ)[gᵢ(x)]
and −(1/Λ)[1ᵢ(x)·F].

Effects (offset, Coulomb friction, spring …) are :class:`AbstractEffect` columns appended with
:class:`Augmented` (on a multi-region base, one copy per region, scaled by that region's bᵢ);
the estimators only ever see (W, W₀), so they need no change.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import ClassVar

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

    @property
    def gains(self) -> tuple[str, ...]:
        """Names of the input gains b = 1/M [1/kg], one per region, that scale the force.

        An effect acting on the force (:class:`AbstractEffect`) has parameters b times its
        physical ones, in every region. The default is ``("b",)`` when the model has a parameter
        ``b`` and ``()`` (no gain: force effects cannot be added) otherwise.
        """
        return ("b",) if "b" in self.names else ()

    def region_weights(self, record: Record, hold: Hold) -> tuple[Array, ...]:
        """One weight 1ᵢ(x) per region of :attr:`gains` (shape ``(T,)`` each) for a signal held
        by ``hold``: a force effect's signal u becomes one column per region, 1ᵢ(x)·u. The default
        is a single region (weight 1)."""
        return (jnp.ones_like(record.x),)

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
        x_hold, F_hold: intersample assumptions (defaults ``"foh"`` and ``"zoh"``;
            docs/method.md, "Discretisation").
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
    """ẍ + aᵢẋ = bᵢF in region i, regions split by sorted ``bounds`` [m].

    See docs/method.md, "Exact regressors across regions".

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

    @property
    def gains(self) -> tuple[str, ...]:
        return tuple(f"b_{i + 1}" for i in range(self.n_regions))

    def region_weights(self, record: Record, hold: Hold) -> tuple[Array, ...]:
        """1ᵢ(x) per region: for a held (``"zoh"``) signal the fraction of each sample interval
        x spends in region i (exact for a held signal); for ``"foh"`` the indicator at the samples
        (exact except in the intervals where x crosses a bound)."""
        x = record.x
        if hold == "zoh":
            return tuple(_region_fractions(x, lo, hi) for lo, hi in self._limits())
        return tuple(((x >= lo) & (x <= hi)).astype(x.dtype) for lo, hi in self._limits())

    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]:
        x, F = record.x, record.F
        out: dict[str, tuple[Array, Hold]] = {"x": (x, self.x_hold)}
        weights = self.region_weights(record, self.F_hold)
        for i, ((lo, hi), weight) in enumerate(zip(self._limits(), weights, strict=True)):
            out[f"g_{i + 1}"] = (jnp.clip(x, lo, hi), self.x_hold)
            out[f"F_{i + 1}"] = (weight * F, self.F_hold)
        return out

    def region_of(self, x: ArrayLike) -> Array:
        """Region index (1-based) of each position."""
        return jnp.searchsorted(jnp.asarray(self.bounds), jnp.asarray(x), side="left") + 1


class AbstractEffect(eqx.Module):
    """An unmodelled effect, linear in its parameters (``docs/method.md``, "Effects").

    ẍ + aẋ = b·(F + F₀ − Fc·sgn ẋ − k(x − x₀)): an effect that acts on the force
    (``acts_on_force = True``) adds columns whose parameters are b times the physical ones
    (e.g. c = b·F₀), and :meth:`physical` divides by the b it is given. Its columns must be of
    order 0 (filtered by 1/Λ). On a base model with several regions, :class:`Augmented` repeats
    such an effect once per region (ẍ + aᵢẋ = bᵢ·(F + F₀ − …)), so that it stays exact when
    the bᵢ differ. An effect with ``acts_on_force = False`` (e.g. a modulation of a and b)
    is added once and :meth:`physical` ignores b.
    """

    acts_on_force: ClassVar[bool] = True

    @property
    @abc.abstractmethod
    def names(self) -> tuple[str, ...]: ...

    @abc.abstractmethod
    def columns(self) -> tuple[Column, ...]: ...

    @abc.abstractmethod
    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]: ...

    @abc.abstractmethod
    def physical(self, theta: Array, b: Array) -> dict[str, Array]: ...

    def free_response(self, dt: float, T: int, k0: int = 0):
        """Rows k0 … T − 1 of initial-state columns of its own, shape (T − k0, n), that the
        filtered equation error carries from an unknown initial state of the effect (a flexible
        mode's decaying oscillation), refitted on every record as the filter's are; None for
        most effects."""
        return None


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
    """A base model plus effect columns; parameters ``base.names + effect names``.

    An effect that acts on the force enters every region with that region's gain:

        ẍ + aᵢẋ = bᵢ·(F + F₀ − F_c·sgn ẋ − k·x),   in region i of the base model,

    which is linear in (aᵢ, bᵢ, bᵢF₀, bᵢF_c, bᵢk). On a single-region base (``MassDamper``) its
    parameters keep their names (``bF0``, physical ``F0``); on a base with R regions
    (``Piecewise``) each is repeated per region with the region's suffix (``bF0_1 … bF0_R``,
    physical ``F0_1 … F0_R`` = (bᵢF₀)/bᵢ), its column being 1ᵢ(x)·u (weights from
    :meth:`AbstractModel.region_weights`). A record that stays in one region therefore leaves the
    other regions' effect parameters unexcited, like their aᵢ and bᵢ.
    """

    base: AbstractModel
    effects: tuple[AbstractEffect, ...]

    def __init__(self, base: AbstractModel, effects: Sequence[AbstractEffect]):
        if isinstance(base, Augmented):
            raise InputError("Augmented: base must be a plain model, not another Augmented.")
        self.base = base
        self.effects = tuple(effects)
        for e in self.effects:
            if not e.acts_on_force:
                continue
            if not base.gains:
                raise InputError(
                    f"Augmented: effect {type(e).__name__} acts on the force, but base model "
                    f"{type(base).__name__} has no input gain b (its parameters are "
                    f"{base.names}); use a base with one (MassDamper, Piecewise)."
                )
            if any(c.order != 0 for c in e.columns()):
                raise InputError(
                    f"Augmented: effect {type(e).__name__} acts on the force, so its columns "
                    "must be of order 0 (filtered by 1/Λ); got orders "
                    f"{[c.order for c in e.columns()]}."
                )
        names = self.names
        if len(set(names)) != len(names):
            raise InputError(f"Augmented: parameter names repeat: {names}; add each effect once.")

    def _suffixes(self, effect: AbstractEffect) -> tuple[str, ...]:
        """Name suffixes of the copies of ``effect``: one per region for a force effect on a
        multi-region base, else a single unsuffixed copy."""
        if effect.acts_on_force and len(self.base.gains) > 1:
            return tuple(f"_{i + 1}" for i in range(len(self.base.gains)))
        return ("",)

    @property
    def names(self) -> tuple[str, ...]:
        return self.base.names + tuple(
            n + sfx for e in self.effects for sfx in self._suffixes(e) for n in e.names
        )

    def columns(self) -> tuple[Column, ...]:
        return self.base.columns() + tuple(
            Column(c.signal + sfx, c.order, c.sign)
            for e in self.effects
            for sfx in self._suffixes(e)
            for c in e.columns()
        )

    def signals(self, record: Record) -> dict[str, tuple[Array, Hold]]:
        out = self.base.signals(record)
        for e in self.effects:
            sfxs = self._suffixes(e)
            for name, (u, hold) in e.signals(record).items():
                if sfxs == ("",):
                    out[name] = (u, hold)
                    continue
                weights = self.base.region_weights(record, hold)
                for sfx, w in zip(sfxs, weights, strict=True):
                    out[name + sfx] = (w * u, hold)
        return out

    def physical(self, theta: Array) -> dict[str, Array]:
        """Base parameters as the base reports them, then each effect's physical parameters,
        divided by the gain bᵢ of its region (suffix ``_i`` on a multi-region base)."""
        out = self.base.physical(theta)
        gains = [theta[..., self.base.names.index(g)] for g in self.base.gains]
        i = len(self.base.names)
        for e in self.effects:
            k = len(e.names)
            sfxs = self._suffixes(e)
            for r, sfx in enumerate(sfxs):
                b = gains[r] if e.acts_on_force else jnp.ones_like(theta[..., 0])
                phys = e.physical(theta[..., i : i + k], b)
                out.update({n + sfx: v for n, v in phys.items()})
                i += k
        return out
