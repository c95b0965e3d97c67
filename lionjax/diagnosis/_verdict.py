"""The verdict (:func:`judge`): the first of the stack, provided the stack explains the
residual's structure as well as its size and no look-alike overrules it; else ``none`` or
``unexplained``. An exact model of the device is also fitted with the records' roles swapped
(:func:`_reverse`)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ._run import Run, prepare, sim_share
from ._stack import Stack
from ._stages import resolve
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
    #: each look-alike fitted beside the stack (:class:`~.effects.LookalikeTest`), by name
    lookalikes: dict[str, LookalikeTest]
    #: a stack holding an exact candidate, with the records' roles swapped: (the rest of the
    #: excess it leaves, its score, why a stacked candidate refuses that fit or ""); None: no
    #: exact candidate stacked (:func:`_reverse`)
    reverse: tuple[float, float, str] | None = None

    @property
    def decided_by(self) -> list[LookalikeTest]:
        """The look-alikes that overrule even "no effect" (their evidence is their own)."""
        return [t for t in self.lookalikes.values() if t.overrules_none]


def _explained(run: Run, stk: Stack) -> float:
    """The share of the excess validation error (above the fitted floor) the stack removes; where
    the baseline is qualitatively wrong, at least the share of the simulated gap."""
    ex0 = run.excess(run.base.ms_valid)
    out = 1.0 - (run.excess(stk.fit.ms_valid) / ex0 if ex0 > 0 else 0.0)
    if run.by_simulation(stk.cands):
        out = max(out, sim_share(stk.fit.gap, run.base.gap))
    return out


def judge(run: Run, stk: Stack) -> Verdict:
    """The first of the stack, provided the stack explains the residual's structure as well as
    its size, and no out-of-library look-alike explains the gap better; else ``none`` (a
    residual without structure, or a negligible gap) or ``unexplained``."""
    crit, base, cur, st = run.crit, run.base, stk.fit, run.st
    F = np.asarray(run.valid.F)
    at_floor = base.equation_gap <= crit.floor_factor * run.floor
    # a named stack must explain the residual's structure, not only its size: a stack that
    # leaves a sharper spectral peak than the baseline's fits a resonance-like shape to an
    # effect it does not describe (relative to the median, a line sharpens whenever the
    # broadband rest is removed: the line itself must not have shrunk, else the stack did
    # remove the structure)
    s_final = structure(cur.residual, F, st)
    # "unexplained" needs a residual with structure (MATLAB resid's cross-correlation with the
    # input beyond its 99 % bound, or a spectral peak): a gap above the estimated floor whose
    # residual is white and input-independent means the floor was underestimated
    s_base = structure(base.residual, F, st)
    noise_like = s_base["input_correlation"] <= 1.0 and s_base["peak"] <= crit.noise_peak
    explained = _explained(run, stk)
    # a stack that removes at least explained_full of the excess over the floor has explained
    # the gap (a line it leaves sharpened is at the noise level). Where the baseline is
    # qualitatively wrong its residual is the whole response, no reference for a sharpened line:
    # there a stack the windowed simulation confirms is not so judged
    confirmed = run.confirmed(stk)
    peak_grew = (
        not confirmed
        and explained < crit.explained_full
        and s_final["peak"] > max(crit.peak_growth * s_base["peak"], crit.noise_peak)
        and s_final["peak_power"] > crit.peak_power_kept * s_base["peak_power"]
    )
    # "none" needs a residual without structure (at the floor a spectral line alone is no
    # structure: a clean open-loop record's ε₁ at the floor carries lines of its excitation), or
    # a whole gap smaller than the least effect worth naming. At the floor the residual is mostly
    # the position noise's path, which F also carries in closed loop: there the test is against
    # F_ref, F less the controller's answer to x, as MATLAB resid tests against the reference
    negligible = base.equation_gap / run.force_rms < crit.min_size
    quiet = (
        at_floor
        and (structure(base.residual, run.F_ref, st) if run.closed_loop else s_base)[
            "input_correlation"
        ]
        <= 1.0
    )
    tests = {la.name: la.test(run, stk) for la in run.lookalikes}
    # the look-alikes compete in the equation error: no measure against a stack the simulation
    # confirmed that does not lower it (a dominant spring's true k carries the encoder's steps
    # into ε₁ through b·k·x/Λ, above the baseline's whole error)
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
    least :attr:`~.effects.AbstractCandidate.exact_share`; None where the stack is empty or
    holds a candidate whose model is not exact."""
    exact = [c.exactness() for c in stk.cands]
    return None if not exact or None in exact else 1.0 - min(exact)


def _reverse(run: Run, stk: Stack) -> tuple[float, float, str] | None:
    """For a stack that holds a candidate whose model is exact
    (:meth:`~.effects.AbstractCandidate.exactness`): the stack fitted on the validation record
    and validated on the training record (the settings' filter kept; the candidates in their
    library forms, their parameters searched again beside each other), as (the share of the
    excess above the estimated floor it leaves there, its score against that baseline, why the
    parameters fitted that way do not describe the same effect,
    :meth:`~.effects.AbstractCandidate.other_way`, "" where they do). An exact model of the
    device holds both ways, as the same effect; an effect it only resembles at one record's
    amplitudes need not. None for other stacks."""
    if not any(c.exactness() is not None for c in stk.cands):
        return None
    rv = prepare(
        run.valid,
        run.problem.train,
        run.candidates,
        run.lookalikes,
        run.crit,
        run.st.filter_hz,
        run.st.window_s,
        math.inf,
    )
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
    return rest, rv.score_of(rv.base, f, rv.params(structure_), rv.floor), why
