"""Sec. IV.B results of the paper: Lion's law on every record (:func:`identify_records`), and
the Table 3-like numbers (:func:`paper_table`).

Definitions used in the outputs:

- **var_mm2** (the paper's "var (mm²)", Table 3): the sample variance, over the samples at least
  3·λ₂/λ₃ = 2.25 s after the start of the record, of the equation ("tracking") error
  ε₁ = V₃ + â·V₂ − b̂·Q₁ computed with the *paper's* filter Λ = (s + 4)³ (raw, 1/Λ) on x in mm
  and F in mN, with the record's final estimates (â in 1/s, b̂ in 1/kg). The same definition for
  both settings, so the column is comparable. (Strictly ε₁ has the unit mm·s, since 1/Λ
  integrates three times; the paper writes mm.) It equals 10⁶ × the same variance in SI units.
- **summary estimate** per region and settings (``input = repetition = "all"``): the median over
  the region's inputs × repetitions of the per-record final estimates, separately for a and b. The
  median is robust to the one-sine records whose estimates are noisier (a single frequency
  determines two parameters exactly, with no redundancy against noise).
"""

from __future__ import annotations

import types
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import InputError, raise_if_failed
from .._estimators import lion
from .._filters import FilterBank
from .._models import MassDamper
from .._record import Record
from .._tables import Table
from ._config import LionSettings, PaperConfig


class Identification(eqx.Module):
    """Lion's estimator on a batch of records (result of :func:`identify_records`).

    Attributes:
        settings: the settings' name.
        t: save times [s], shape ``(S,)``.
        theta: θ(t) = (a(t) [1/s], b(t) [1/kg]), shape ``(*batch, S, 2)``.
        a, b: final estimates [1/s], [1/kg], shape ``batch``.
        var_mm2: variance of the paper's equation error ε₁ (module docstring), shape ``batch``.
        eps: the paper's (ε₁, ε₂)(t) with θ(t) [mm·s, mm], shape ``(*batch, S, 2)`` (Fig. 5).
    """

    settings: str = eqx.field(static=True)
    t: Float[Array, " S"]
    theta: Float[Array, "*batch S 2"]
    a: Float[Array, "*batch"]
    b: Float[Array, "*batch"]
    var_mm2: Float[Array, "*batch"]
    eps: Float[Array, "*batch S 2"]


#: Transient excluded from var_mm2: 3·λ₂/λ₃ of the paper's filter [s].
PAPER_TRANSIENT = 3.0 * 48.0 / 64.0


def _paper_regressors(record: Record):
    """Regressors of the paper's definition of ε: Λ = (s+4)³ raw, x in mm, F in mN."""
    rec = Record(record.x * 1e3, record.F * 1e3, record.dt, record.t0)
    return MassDamper().regressors(rec, FilterBank.paper())


@eqx.filter_jit
def _identify_batch(records: Record, settings: LionSettings, save_every: int):
    return jax.vmap(lambda r: _identify_one(r, settings, save_every))(records)


def _identify_one(record: Record, settings: LionSettings, save_every: int):
    model = MassDamper()
    sol = lion(
        model,
        settings.scale(record),
        bank=settings.bank,
        gain=settings.gain,
        save_every=save_every,
        throw=False,
    )
    theta_t = settings.to_si(sol.theta)
    theta_f = settings.to_si(sol.theta_final)
    regs = _paper_regressors(record)
    T = record.n_samples
    idx = np.unique(np.concatenate([np.arange(0, T, save_every), [T - 1]]))
    eps_t = jnp.einsum("sip,sp->si", regs.W[idx], theta_t) + regs.W0[idx]
    eps1 = regs.W[:, 0, :] @ theta_f + regs.W0[:, 0]
    elapsed = record.dt * jnp.arange(T, dtype=record.x.dtype)
    w = (elapsed >= PAPER_TRANSIENT).astype(eps1.dtype)
    n = jnp.sum(w)
    mean = jnp.sum(w * eps1) / n
    var = jnp.sum(w * (eps1 - mean) ** 2) / (n - 1)
    return sol.t, theta_t, theta_f, var, eps_t, sol.result


def identify_records(
    records: Record, settings: LionSettings | None = None, *, save_every: int = 10
) -> Identification:
    """Run Lion's law (one ``MassDamper`` per record) on a batch of records.

    Arguments:
        records: a :class:`lionjax.Record` with any batch shape ``(*batch, T)`` (one region's
            records each; the paper identifies each region from its own experiments).
        settings: :meth:`LionSettings.paper` or :meth:`LionSettings.recommended` (default).
        save_every: keep every n-th sample of θ(t).

    Returns:
        an :class:`Identification` (estimates in SI units whatever the settings' units).

    Raises:
        lionjax.IdentificationError: naming every failed record (e.g. not excited).
    """
    settings = LionSettings.recommended() if settings is None else settings
    if not isinstance(records, Record):
        raise InputError(f"identify_records: records must be a Record, got {type(records)}.")
    if not isinstance(settings, LionSettings):
        raise InputError(
            f"identify_records: settings must be a LionSettings (e.g. LionSettings.paper()), got "
            f"{type(settings).__name__}."
        )
    batch = records.x.shape[:-1]
    T = records.x.shape[-1]
    n = int(np.prod(batch)) if batch else 1
    flat = Record(
        records.x.reshape(n, T),
        records.F.reshape(n, T),
        jnp.broadcast_to(records.dt, batch).reshape(n),
        jnp.broadcast_to(records.t0, batch).reshape(n),
    )
    t, theta_t, theta_f, var, eps_t, result = _identify_batch(flat, settings, save_every)
    raise_if_failed(types.SimpleNamespace(result=result), what=f"Lion ({settings.name} settings)")
    S = theta_t.shape[1]
    return Identification(
        settings=settings.name,
        t=t[0],
        theta=theta_t.reshape(*batch, S, 2),
        a=theta_f[:, 0].reshape(batch),
        b=theta_f[:, 1].reshape(batch),
        var_mm2=var.reshape(batch),
        eps=eps_t.reshape(*batch, S, 2),
    )


class PaperTable(Table, eqx.Module):
    """Table 3 reproduced: per record and summary estimates, for each settings.

    Arrays of shape ``(n_settings, R, I, K)`` unless stated; settings in the order of ``settings``.

    Attributes:
        settings: settings names.
        a, b: final estimates [1/s], [1/kg].
        var_mm2: paper's equation-error variance (module docstring).
        summary_a, summary_b: median over inputs × repetitions, shape ``(n_settings, R)``.
        summary_var_mm2: median var_mm2, shape ``(n_settings, R)``.
        truth_a, truth_b: the twin's a, b per region, shape ``(R,)``.
        operating_points: x_ref per region [m], shape ``(R,)``.
    """

    settings: tuple[str, ...] = eqx.field(static=True)
    a: Float[Array, "S R I K"]
    b: Float[Array, "S R I K"]
    var_mm2: Float[Array, "S R I K"]
    summary_a: Float[Array, "S R"]
    summary_b: Float[Array, "S R"]
    summary_var_mm2: Float[Array, "S R"]
    truth_a: Float[Array, " R"]
    truth_b: Float[Array, " R"]
    operating_points: Float[Array, " R"]

    def to_rows(self) -> list[dict]:
        """The table as JSON-ready rows (``table.json`` and ``table.csv`` of the CLI ``reproduce``).

        Each row: ``region`` (1-based), ``operating_point_mm``, ``settings``, ``input``
        (1-based or ``"all"``), ``repetition`` (1-based or ``"all"``), ``a`` [1/s], ``b``
        [1/kg], ``var_mm2``, ``a_err_pct``, ``b_err_pct`` (100·(estimate/truth − 1)),
        ``a_true``, ``b_true``. The ``"all"`` rows hold the summary (median) estimate.
        """
        a, b, v = (np.asarray(z) for z in (self.a, self.b, self.var_mm2))
        sa, sb, sv = (np.asarray(z) for z in (self.summary_a, self.summary_b, self.summary_var_mm2))
        ta, tb = np.asarray(self.truth_a), np.asarray(self.truth_b)
        xp = np.asarray(self.operating_points)
        out = []
        S, R, I, K = a.shape

        def row(s, r, i, k, av, bv, vv):
            return {
                "region": r + 1,
                "operating_point_mm": round(float(xp[r]) * 1e3, 6),
                "settings": self.settings[s],
                "input": i,
                "repetition": k,
                "a": float(av),
                "b": float(bv),
                "var_mm2": float(vv),
                "a_err_pct": float(100 * (av / ta[r] - 1)),
                "b_err_pct": float(100 * (bv / tb[r] - 1)),
                "a_true": float(ta[r]),
                "b_true": float(tb[r]),
            }

        for s in range(S):
            for r in range(R):
                for i in range(I):
                    for k in range(K):
                        out.append(
                            row(s, r, i + 1, k + 1, a[s, r, i, k], b[s, r, i, k], v[s, r, i, k])
                        )
                out.append(row(s, r, "all", "all", sa[s, r], sb[s, r], sv[s, r]))
        return out


def paper_table(
    records: Record,
    config: PaperConfig | None = None,
    settings: Sequence[LionSettings] | None = None,
    *,
    identifications: Sequence[Identification] | None = None,
) -> PaperTable:
    """Table 3 from the ``(R, I, K, T)`` records of :func:`paper_records`.

    Arguments:
        records: the records (batch shape ``(R, I, K)``).
        config: the configuration the records came from (for the truth and operating points).
        settings: the settings to run (default: paper and recommended).
        identifications: already computed :func:`identify_records` results for ``records``, one
            per settings (skips the estimation).
    """
    config = PaperConfig() if config is None else config
    if identifications is None:
        settings = (
            (LionSettings.paper(), LionSettings.recommended()) if settings is None else settings
        )
        identifications = [
            identify_records(records, s, save_every=config.save_every) for s in settings
        ]
    if records.x.ndim != 4:
        raise InputError(
            f"paper_table: records must have batch shape (regions, inputs, repetitions), got "
            f"x of shape {records.x.shape}."
        )
    a = jnp.stack([idn.a for idn in identifications])
    b = jnp.stack([idn.b for idn in identifications])
    v = jnp.stack([idn.var_mm2 for idn in identifications])
    S, R = a.shape[:2]
    med = lambda z: jnp.median(z.reshape(S, R, -1), axis=-1)
    return PaperTable(
        settings=tuple(idn.settings for idn in identifications),
        a=a,
        b=b,
        var_mm2=v,
        summary_a=med(a),
        summary_b=med(b),
        summary_var_mm2=med(v),
        truth_a=jnp.asarray(np.asarray(config.plant.a, float)),
        truth_b=jnp.asarray(np.asarray(config.plant.b, float)),
        operating_points=jnp.asarray(config.operating_points, float),
    )
