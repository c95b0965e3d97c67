"""The :class:`~lionjax.diagnosis.Diagnosis` of the stages' results (:func:`report`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ._confidence import Confidence
from ._regions import find_regions
from ._result import _UNITS, Diagnosis, EffectScore
from ._run import Run, shrink
from ._stages import Stack
from ._verdict import Verdict
from ._where import where_findings
from .effects import design_of


def qualitatively_wrong(phys: dict[str, float], simulation: str) -> list[str]:
    """Why a fitted mass–damper is no model of a device, in words (empty where it may be)."""
    out = []
    if not phys.get("b", 1.0) > 0:
        out.append(
            "b ≤ 0: the force would accelerate the axis against itself (an effect the model "
            "leaves out dominates the response: a spring stiffer than the filter corner holds, "
            "friction that sticks the axis)"
        )
    if not phys.get("a", 1.0) >= 0:
        out.append("a < 0: negative damping, the free motion would grow")
    if simulation != "ok":
        out.append("its windowed simulation diverges")
    return out


def _final(run: Run, stk: Stack, v: Verdict) -> dict[str, Any]:
    """The stacked model: its physical parameters and units, gaps and the verdict's tests."""
    cur, base = stk.fit, run.base
    names = [c.name for c in stk.cands]
    params = dict(cur.physical)
    units = dict(_UNITS)
    for c in stk.cands:
        params.update(c.report(cur.physical))
        units.update(c.units)
    if "spring" in names and "offset" not in names:
        params.pop("F0", None)
    elif "x0" in params and "spring" not in names:
        params.pop("x0", None)
    ex0 = run.excess(base.ms_valid)
    final = {
        "model": "MassDamper+" + "+".join(names) if names else "MassDamper",
        "params": params,
        "units": {k: units.get(k, "") for k in params},
        "std": {"a": float(cur.std[0]), "b": float(cur.std[1])},
        "gap": cur.gap,
        "shrink": shrink(cur.gap, base.gap),
        "simulation": cur.simulation,
        "measurement": [c.name for c in stk.cands if c.artefact()],
        "equation_gap": cur.equation_gap,
        "equation_shrink": 1 - cur.equation_gap / base.equation_gap,
        "remaining_excess_share": run.excess(cur.ms_valid) / ex0 if ex0 > 0 else 0.0,
        # a stack holding an exact candidate, with the records' roles swapped (else None): its
        # rest, its score and why a stacked candidate refuses that fit ("": none does)
        "reverse": None
        if v.reverse is None
        else dict(zip(("remaining_excess_share", "score", "refused"), v.reverse, strict=True)),
        **params,
        # a final model with b ≤ 0 describes no device: it is reported, never as a result
        "qualitatively_wrong": qualitatively_wrong(cur.physical, cur.simulation),
        "result": cur.physical.get("b", 1.0) > 0,
        "structure": v.s_final,
        "structure_explained": not v.peak_grew,
    }
    for t in v.lookalikes.values():  # each look-alike's validated fit beside the stack
        final.update(t.final)
    return final


def _series_and_where(run: Run, stk: Stack, v: Verdict):
    """The validation signals for plotting, the ``where`` findings and the regions on them."""
    problem, base, cur, valid = run.problem, run.base, stk.fit, run.problem.valid
    series = {
        "t": float(valid.t0) + float(valid.dt) * np.arange(valid.n_samples),
        "x": np.asarray(valid.x),
        "F": np.asarray(valid.F),
        "v": np.asarray(problem.v_valid),
        "residual_base": base.residual,
        "residual_final": cur.residual,
        "sim_base": base.sim_error,
        "sim_final": cur.sim_error,
        "H": np.asarray(problem.H),
    }
    where = where_findings(series, problem.st, run.floor)
    where += [t.finding for t in v.lookalikes.values() if t.finding is not None]
    final = {"residual_final": series["residual_final"] if stk.cands else None}
    regions = find_regions(
        {**series, **final}, alpha=run.crit.alpha, filter_hz=problem.st.filter_hz
    )
    return series, where, regions


def _baseline(run: Run, v: Verdict) -> dict[str, Any]:
    base, valid = run.base, run.problem.valid
    return {
        "model": "MassDamper",
        "params": {"a": base.physical["a"], "b": base.physical["b"]},
        "units": {"a": "1/s", "b": "1/kg"},
        "std": {"a": float(base.std[0]), "b": float(base.std[1])},
        "gap": base.gap,
        "simulation": base.simulation,
        "gap_units": "m",
        "gap_relative": base.gap / max(float(np.std(np.asarray(valid.x))), 1e-300),
        "equation_gap": base.equation_gap,
        "equation_gap_units": "m/s²",
        "noise_floor": run.floor,
        "at_noise_floor": v.at_floor,
        "noise_like": v.noise_like,
        "condition": base.condition,
        "structure": v.s_base,
        "valid_outside_train": run.outside,
        # a baseline that is no model of a device, in words (a dominant effect repairs it)
        "qualitatively_wrong": qualitatively_wrong(base.physical, base.simulation),
    }


def _settings_json(run: Run) -> dict[str, Any]:
    problem, crit, st = run.problem, run.crit, run.problem.st
    return {
        "dt": st.dt,
        "filter_hz": st.filter_hz,
        "velocity_filter_hz": st.velocity_hz,
        "v_eps": st.v_eps,
        "window_s": problem.H * st.dt,
        "state_filter_hz": problem.state_hz if math.isfinite(problem.state_hz) else None,
        "window_note": (
            "windowed simulation restarts every window_s seconds from x and its derivative: "
            "the raw samples and their five-point derivative (state_filter_hz null), else a "
            "zero-phase (s+ω)³ low-pass/derivative filter at state_filter_hz"
        ),
        "threshold": crit.threshold,
        "min_share": crit.min_share,
        "min_size": crit.min_size,
        "floor_factor": crit.floor_factor,
        "alpha": crit.alpha,
        # whether friction's force columns are masked where the axis sticks (the form the
        # candidates chose alone)
        "friction_stick_masked": bool(design_of(tuple(run.resolved.values())).stick),
    }


def report(
    run: Run, effects: list[EffectScore], stk: Stack, v: Verdict, c: Confidence
) -> Diagnosis:
    """The :class:`~lionjax.diagnosis.Diagnosis` of the stages' results."""
    series, where, regions = _series_and_where(run, stk, v)
    stuck = run.problem.stuck
    return Diagnosis(
        baseline=_baseline(run, v),
        where=where,
        effects=effects,
        stack=[k.name for k in stk.cands],
        verdict=c.verdict,
        final=_final(run, stk, v),
        noise={
            "position_std": run.sx,
            "force_std": run.sF,
            "equation_floor": run.floor,
            "n_effective": run.base.n_eff,
            "detection_limit": c.detection,
            "detection_limit_worst": c.detection_worst,
            "feedback_share": run.feedback,
            # the share of each record's samples where the axis sticks
            "stuck_share": {"train": float(np.mean(stuck[0])), "valid": float(np.mean(stuck[1]))},
            "closed_loop": bool(run.closed_loop),
            # the larger of the records' shares of samples at positions passed twice (Limits)
            "passed_twice": run.limits.passed_twice,
            "reversals": run.limits.reversals,
        },
        settings=_settings_json(run),
        steps=stk.steps,
        confidence=c.confidence,
        ambiguous=c.ambiguous,
        weights=c.weights,
        rivals=c.rivals,
        series=series,
        inconclusive=c.inconclusive,
        regions=regions,
    )
