"""The verdict (:func:`judge`; docs/method.md, "The verdict"): the stack's first candidate,
provided the stack explains the residual's structure as well as its size and no look-alike
overrules it; else ``none`` or ``unexplained``."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ._run import Run, prepare, sim_share
from ._stages import Stack, resolve
from ._where import structure
from .effects import LookalikeTest


@dataclasses.dataclass(frozen=True)
class Verdict:
    """The verdict and the tests it was decided by (reported in ``baseline`` and ``final``)."""

    verdict: str
    at_floor: bool
    noise_like: bool
    explained: float  # share of the excess validation error the stack removes
    s_base: dict[str, float]  # the residuals' structure (:func:`._where.structure`)
    s_final: dict[str, float]
    peak_grew: bool
    #: each look-alike fitted beside the stack, by name
    lookalikes: dict[str, LookalikeTest]
    #: (rest of the excess, score, why a stacked candidate refuses the fit or "") of a stack
    #: holding an exact candidate fitted with the records' roles swapped (:func:`_reverse`)
    reverse: tuple[float, float, str] | None = None

    @property
    def decided_by(self) -> list[LookalikeTest]:
        """The look-alikes that overrule even "no effect" (their evidence is their own)."""
        return [t for t in self.lookalikes.values() if t.overrules_none]


def judge(run: Run, stk: Stack) -> Verdict:
    """The first of the stack, provided the stack explains the residual's structure as well as
    its size and no look-alike explains the gap better; else ``none`` (a residual without
    structure, or a negligible gap) or ``unexplained``."""
    crit, base, cur, st = run.crit, run.base, stk.fit, run.problem.st
    F = np.asarray(run.problem.valid.F)
    at_floor = base.equation_gap <= crit.floor_factor * run.floor
    # a residual that depends on the input beyond linearly has structure; its test reads F_ref,
    # F less the controller's answer to x, which a feedback too weak to call closed loop still
    # fills with the position noise (its encoder steps among it)
    s_final = structure(cur.residual, F, st, run.F_ref)
    s_base = structure(base.residual, F, st, run.F_ref)
    linear = s_base["input_odd"] <= 1.0
    noise_like = s_base["input_correlation"] <= 1.0 and s_base["peak"] <= crit.noise_peak and linear
    # the share of the excess the stack removes; where the baseline is qualitatively wrong, at
    # least the share of the simulated gap
    ex0 = run.excess(base.ms_valid)
    explained = 1.0 - (run.excess(cur.ms_valid) / ex0 if ex0 > 0 else 0.0)
    if run.by_simulation(stk.cands):
        explained = max(explained, sim_share(cur.gap, base.gap))
    # a stack that leaves a sharper spectral line than the baseline's, the line itself not
    # shrunk, fits a shape to an effect it does not describe; not where it explains the gap, nor
    # where the simulation confirms it on a qualitatively wrong baseline (whose residual is the
    # whole response)
    confirmed = run.confirmed(stk)
    peak_grew = (
        not confirmed
        and explained < crit.explained_full
        and s_final["peak"] > max(crit.peak_growth * s_base["peak"], crit.noise_peak)
        and s_final["peak_power"] > crit.peak_power_kept * s_base["peak_power"]
    )
    # "none": a residual without structure, at the floor one within its input correlation
    # bound (in closed loop against F_ref, F less the controller's answer to x, as MATLAB resid
    # tests against the reference), or a gap below the least effect worth naming
    negligible = base.equation_gap / run.force_rms < crit.min_size
    ref = structure(base.residual, run.F_ref, st) if at_floor and run.closed_loop else s_base
    quiet = at_floor and ref["input_correlation"] <= 1.0 and linear
    tests = {la.name: la.test(run, stk) for la in run.lookalikes}
    # the look-alikes compete in the equation error: no measure against a stack the simulation
    # confirmed that does not lower it
    overruled = any(t.overrules for t in tests.values())
    if confirmed and not cur.ms_valid < base.ms_valid:
        overruled = False
    if stk.cands:
        verdict = stk.cands[0].name if not (peak_grew or overruled) else "unexplained"
    elif any(t.overrules_none for t in tests.values()):
        verdict = "unexplained"
    elif noise_like or quiet or negligible:
        verdict = "none"
    else:
        verdict = "unexplained"
    reverse = _reverse(run, stk) if stk.cands and verdict != "unexplained" else None
    return Verdict(
        verdict,
        bool(at_floor),
        bool(noise_like),
        explained,
        s_base,
        s_final,
        bool(peak_grew),
        tests,
        reverse,
    )


def exact_tolerance(stk: Stack) -> float | None:
    """The rest of the excess a true instance of a stack of exact candidates leaves, 1 − the
    least ``exact_share``; None where the stack is empty or holds an inexact candidate."""
    exact = [c.exact_share for c in stk.cands]
    return None if not exact or None in exact else 1.0 - min(exact)


def _reverse(run: Run, stk: Stack) -> tuple[float, float, str] | None:
    """A stack holding an exact candidate fitted on the validation record and validated on the
    training record (the filter kept; the library forms searched again beside each other): (the
    share of the excess above the estimated floor it leaves, its score against that baseline,
    why a stacked candidate refuses that fit, ``other_way``, or ""). An exact model holds both
    ways, as the same effect. None for other stacks."""
    if not any(c.exact_share is not None for c in stk.cands):
        return None
    st = run.problem.st
    args = (run.candidates, run.lookalikes, run.crit, st.filter_hz, st.window_s, math.inf)
    rv = prepare(run.problem.valid, run.problem.train, *args)
    lib = {c.name: c for c in run.candidates}
    forms = [lib.get(c.name, c) for c in stk.cands]
    done = {c.name: c for c in forms if c.profiled()}
    for c in forms:  # each search beside the others found so far
        if c.name not in done:
            done[c.name] = resolve(rv, c, tuple(done.values()))
    structure_ = tuple(done[c.name] for c in forms)
    f = rv.try_fit(structure_)
    if f is None:
        return 1.0, -math.inf, "the design is too wide"
    ex0 = max(rv.base.ms_valid - rv.floor**2, 0.0)
    rest = max(f.ms_valid - rv.floor**2, 0.0) / ex0 if ex0 > 0 else 1.0
    why = next(
        (w for c in stk.cands if (w := c.other_way(stk.fit.physical, f.physical, rv.limits))), ""
    )
    return rest, rv.score_ms(rv.base, f.ms_valid, rv.params(structure_), rv.floor), why
