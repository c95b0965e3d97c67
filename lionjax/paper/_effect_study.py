"""Beyond the paper: the first picture of the sim-to-real gap. The same identification with one
unmodelled twin effect switched on at a realistic size, validated the same way.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from .. import twin
from .._progress import reporter
from .._record import Record
from ._config import LionSettings, PaperConfig
from ._identification import Identification, identify_records
from ._records import _batchable, twin_runs
from ._verification import verify


@dataclasses.dataclass(frozen=True)
class EffectCase:
    """One effect of the gap study: a name, the twin effect and a one-line description."""

    name: str
    effect: twin.AbstractPlantEffect
    description: str


def realistic_effects() -> tuple[EffectCase, ...]:
    """The effects of the gap study, each at a size plausible for a Falcon axis.

    Sizes are judgement, not measurement (the paper reports none): friction and offset a few %
    of the ≈ 4 N verification force, the spring of the leg's cable-tensioning spring, a delay of a
    few 1-kHz loop periods (the paper's force path runs over a 9600-baud serial link), a
    current limit the verification input reaches, a 10 % drift of the calibration, ±15 %/±10 % of
    a and b over ±20 mm, a cable mode at 25 Hz.
    """
    return (
        EffectCase("coulomb_friction", twin.CoulombFriction(0.1), "Coulomb friction F_c = 0.1 N"),
        EffectCase("offset", twin.ForceOffset(0.2), "constant offset/gravity F₀ = 0.2 N"),
        EffectCase("spring", twin.LinearSpring(20.0), "spring k = 20 N/m to x₀ = 0"),
        EffectCase("delay", twin.InputDelay(0.005), "input delay τ = 5 ms"),
        EffectCase("saturation", twin.HardSaturation(2.5), "hard saturation at 2.5 N"),
        EffectCase(
            "calibration_error",
            twin.ForceCalibration(1.10),
            "force-calibration drift: the device gives 1/1.10 of the calibrated force",
        ),
        EffectCase(
            "position_dependent",
            twin.PositionDependence(alpha_a=0.15, alpha_b=0.10, length=0.02),
            "smooth position dependence a·(1 ± 15 %), b·(1 ± 10 %), tanh(x/20 mm)",
        ),
        EffectCase(
            "flexible_mode",
            twin.FlexibleMode(mass=0.05, frequency=25.0, damping_ratio=0.05),
            "flexible mode m₂ = 50 g at 25 Hz, ζ = 0.05",
        ),
    )


class EffectRow(eqx.Module):
    """The identification and validation with one effect switched on (:func:`effect_study`).

    Attributes:
        name, description: the effect.
        a, b: summary estimates per region [1/s], [1/kg], shape ``(R,)``.
        a_err_pct, b_err_pct: 100·(estimate/truth − 1), shape ``(R,)``.
        nrmse: validation NRMSE with the effect; nrmse_baseline: the same without it.
        growth: nrmse / nrmse_baseline.
    """

    name: str = eqx.field(static=True)
    description: str = eqx.field(static=True)
    a: Float[Array, " R"]
    b: Float[Array, " R"]
    a_err_pct: Float[Array, " R"]
    b_err_pct: Float[Array, " R"]
    nrmse: Float[Array, ""]
    nrmse_baseline: Float[Array, ""]
    growth: Float[Array, ""]

    def to_row(self) -> dict:
        """One row of ``effects.json`` (plain Python values)."""
        return {
            "name": self.name,
            "description": self.description,
            "a": np.asarray(self.a).tolist(),
            "b": np.asarray(self.b).tolist(),
            "a_err_pct": np.asarray(self.a_err_pct).tolist(),
            "b_err_pct": np.asarray(self.b_err_pct).tolist(),
            "nrmse": float(self.nrmse),
            "nrmse_baseline": float(self.nrmse_baseline),
            "growth": float(self.growth),
        }


def identify_regions(
    records: Record, settings: LionSettings | None = None, *, save_every: int = 10
) -> tuple[Array, Array, Identification]:
    """Per-region summary (a, b): median of Lion's final estimates over each region's records.

    ``records`` has batch shape ``(R, I, K)``; returns ``(a (R,), b (R,), identification)``.
    """
    idn = identify_records(records, settings, save_every=save_every)
    R = records.x.shape[0]
    return (
        jnp.median(idn.a.reshape(R, -1), axis=-1),
        jnp.median(idn.b.reshape(R, -1), axis=-1),
        idn,
    )


def effect_study(
    config: PaperConfig | None = None,
    *,
    key: PRNGKeyArray,
    cases: Sequence[EffectCase] | None = None,
    baseline_nrmse: float | Array | None = None,
    calibration_gain: float | Array | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[EffectRow, ...]:
    """Identify (recommended settings) and validate with one twin effect on at a time.

    For each case: the records of :func:`paper_records` from ``config.device(effect)``, the
    per-region summary model (:func:`identify_regions`), and :func:`verify` on the fresh
    verification record of the same device. The same ``key`` serves every case (and the
    baseline), so the rows differ only by the effect. The baseline — the same pipeline without
    effects — is computed unless ``baseline_nrmse`` is given (:func:`reproduce_paper` passes the
    main table's, obtained with the same key).

    Cases whose effect has an exactly neutral value (offset, spring, delay, calibration,
    saturation, position dependence) are simulated together in one batch; the others one by one.
    """
    config = PaperConfig() if config is None else config
    cases = realistic_effects() if cases is None else tuple(cases)
    settings = LionSettings.recommended()
    say = reporter(progress)
    truth_a = np.asarray(config.plant.a, float)
    truth_b = np.asarray(config.plant.b, float)

    def evaluate(effect_sets):
        recs, vers = twin_runs(
            config, key=key, calibration_gain=calibration_gain, effects=effect_sets
        )
        out = []
        for d in range(recs.x.shape[0]):
            rec_d = jax.tree.map(lambda z, d=d: z[d], recs)
            ver_d = jax.tree.map(lambda z, d=d: z[d], vers)
            a, b, _ = identify_regions(rec_d, settings, save_every=config.save_every)
            out.append((a, b, verify(a, b, ver_d, config).nrmse))
        return out

    if baseline_nrmse is None:
        say("effects: baseline (no effect)")
        baseline_nrmse = evaluate([()])[0][2]
    batched = [c for c in cases if _batchable((c.effect,))]
    groups = ([batched] if len(batched) > 1 else []) + [
        [c] for c in cases if not (len(batched) > 1 and c in batched)
    ]
    results = {}
    for group in groups:
        say("effects: " + ", ".join(f"{c.name} ({c.description})" for c in group))
        for c, r in zip(group, evaluate([(c.effect,) for c in group]), strict=True):
            results[c.name] = r
    rows = []
    for case in cases:
        a, b, e = results[case.name]
        rows.append(
            EffectRow(
                name=case.name,
                description=case.description,
                a=a,
                b=b,
                a_err_pct=100 * (a / truth_a - 1),
                b_err_pct=100 * (b / truth_b - 1),
                nrmse=e,
                nrmse_baseline=jnp.asarray(baseline_nrmse),
                growth=e / baseline_nrmse,
            )
        )
    return tuple(rows)
