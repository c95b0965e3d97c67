"""The diagnosis' last stages (:func:`lionjax.diagnose`, module :mod:`._core`): the verdict
(:func:`judge`), its confidence (:func:`weigh`) and the report (:func:`report`)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ._candidates import AbstractCandidate
from ._regions import find_regions
from ._result import _UNITS, Diagnosis, EffectScore
from ._stages import Run, Stack, prepare, shrink, sim_share, try_fit
from ._structures import Fitted
from ._where import structure, where_findings


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
    judged: bool  # the stack was judged against the dead zone's look-alike
    lookalike: float  # its validated mean square
    drag: float  # the drag look-alike's validated mean square (inf: not tried)
    periodic_ms: float
    period: float
    periodic_score: float
    periodic_share: float
    periodic_better: bool
    #: a stack holding an exact candidate, with the records' roles swapped: (the rest of the
    #: excess it leaves, its score, why a stacked candidate refuses that fit or ""); None: no
    #: exact candidate stacked (:func:`_reverse`)
    reverse: tuple[float, float, str] | None = None


def _explained(run: Run, stk: Stack) -> float:
    """The share of the excess validation error (above the fitted floor) the stack removes; where
    the baseline is qualitatively wrong, at least the share of the simulated gap."""
    ex0 = run.excess(run.base.ms_valid)
    out = 1.0 - (run.excess(stk.fit.ms_valid) / ex0 if ex0 > 0 else 0.0)
    if run.by_simulation(stk.cands):
        out = max(out, sim_share(stk.fit.gap, run.base.gap))
    return out


def _periodic(run: Run, stk: Stack) -> tuple[float, float, float, float, bool]:
    """(mean square, period, score, share, better) of a force periodic in position (cogging,
    out of the default library) fitted with the stack: its sine and cosine at the period
    profiled on train, scored on validation as a candidate would be (2 coefficients and the
    period). ``better``: it overrules the stack, scoring above ``periodic_score_factor`` times
    the threshold, removing ``min_share`` of what the stack leaves, and holding at least
    ``periodic_over_stack`` of the stack's own evidence (:func:`_bar`). Not tried on a stack
    with an input map (τ, F_max)."""
    cur, crit = stk.fit, run.crit
    if any(c.input_parameter for c in stk.cands):
        ms, period = math.inf, math.nan
    else:
        ms, period = run.fitter.periodic_lookalike(stk.cands)
    score = run.score_ms(cur, ms, 3, 0.0) if math.isfinite(ms) and ms > 0 else -math.inf
    # its validated fit bounds the floor, as every validated fit does (a held-out cogging record
    # at 1.34× the floor: Coulomb friction set the fitted floor to its own error, and the
    # look-alike that scored 193 on it had no excess to take a share of)
    lo2 = min(run.fit_floor**2, ms)
    ex_cur = max(cur.ms_valid - lo2, 0.0)
    share = 1 - max(ms - lo2, 0.0) / ex_cur if ex_cur > 0 and math.isfinite(ms) else 0.0
    better = (
        score > crit.periodic_score_factor * crit.threshold
        and share >= crit.min_share
        and score >= crit.periodic_over_stack * _bar(run, stk)
    )
    return ms, period, score, share, bool(better)


def _confirmed(run: Run, stk: Stack) -> bool:
    """Whether the baseline is qualitatively wrong and the windowed simulation confirms the
    stack: every candidate simulated, removing at least ``dominant_sim_share`` of the gap."""
    return (
        run.by_simulation(stk.cands)
        and sim_share(stk.fit.gap, run.base.gap) >= run.crit.dominant_sim_share
    )


def judge(run: Run, stk: Stack) -> Verdict:
    """The first of the stack, provided the stack explains the residual's structure as well as
    its size, and no out-of-library look-alike explains the gap better; else ``none`` (a
    residual without structure, or a negligible gap) or ``unexplained``."""
    crit, base, cur, st = run.crit, run.base, stk.fit, run.st
    F = np.asarray(run.valid.F)
    at_floor = base.equation_gap <= crit.floor_factor * run.floor
    # a named stack must explain the residual's structure, not only its size: a stack that
    # leaves a sharper spectral peak than the baseline's fits a resonance-like shape to an
    # effect it does not describe (cogging or backlash taken for a flexible mode). (Relative to
    # the median, a line sharpens whenever the broadband rest is removed: the line itself must
    # not have shrunk, else the stack did remove the structure.)
    s_final = structure(cur.residual, F, st)
    # "unexplained" needs a residual with structure (MATLAB resid's cross-correlation with the
    # input beyond its 99 % bound, or a spectral peak): a gap above the estimated floor whose
    # residual is white and input-independent means the floor was underestimated (a coarse
    # encoder at a high sample rate hides its steps from the third-difference estimator)
    s_base = structure(base.residual, F, st)
    noise_like = s_base["input_correlation"] <= 1.0 and s_base["peak"] <= crit.noise_peak
    explained = _explained(run, stk)
    # (a stack that removes at least explained_full of the excess over the floor has explained
    # the gap: a line it leaves sharpened is at the noise level — a held-out offset removing
    # 99.9 % of it left the excitation's line at 206× the median for 95×; the cogging, backlash
    # and dead zones fitted so left 58–70 %)
    # Where the baseline is qualitatively wrong its residual is the whole response, no reference
    # for a sharpened line: there a stack the windowed simulation confirms (removing at least
    # dominant_sim_share of the simulated gap) is not so judged (held-out dominant springs with
    # k fitted within 0.1 % were called `unexplained` at 0.00 for a line their residual kept)
    confirmed = _confirmed(run, stk)
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
    # F_ref, F less the controller's answer to x, as MATLAB resid tests against the reference.
    # Above the floor it stays against F (a closed-loop backlash 4× above the floor looked
    # input-independent against F_ref, 0.86, and was called noise).
    negligible = base.equation_gap / run.force_rms < crit.min_size
    quiet = (
        at_floor
        and (structure(base.residual, run.F_ref, st) if run.closed_loop else s_base)[
            "input_correlation"
        ]
        <= 1.0
    )
    # nor may a dead zone's input F − clip(F, ±d), acting with the sign of the force, explain
    # the gap better on the baseline structure: a named offset, spring or b(x) that leaves more
    # than its error describes the input (ratios 0.004–0.64 on held-out dead zones so named;
    # ≥ 1.2 on 54 held-out records named right). A stack with an input map F → sat(F) is not
    # judged so: the look-alike's free columns F and clip(F, ±d) span a hard saturation.
    judged = bool(stk.cands) and not any(c.saturates_input for c in stk.cands)
    lookalike = run.fitter.dead_zone_lookalike([]) if judged else math.inf
    lookalike_better = lookalike < crit.dead_zone_lookalike_share * cur.ms_valid
    # nor a force quadratic in the velocity (fluid drag, out of the default library): it lowers
    # the response to the largest forces as a saturation does (drag records were named
    # `saturation` at 0.58 and 0.63), but follows the velocity, not the force
    drag = run.fitter.drag_lookalike() if stk.cands else math.inf
    drag_better = drag < crit.drag_lookalike_share * cur.ms_valid
    p_ms, period, p_score, p_share, p_better = _periodic(run, stk)
    # the look-alikes compete in the equation error: no measure against a stack the simulation
    # confirmed that does not lower it (a dominant spring's true k carries the encoder's steps
    # into ε₁ through b·k·x/Λ, above the baseline's whole error)
    lookalikes = lookalike_better or drag_better or p_better
    if confirmed and not cur.ms_valid < base.ms_valid:
        lookalikes = False
    if stk.cands:
        named = not (peak_grew or lookalikes)
        verdict = stk.cands[0].name if named else "unexplained"
    elif p_better:
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
        judged,
        lookalike,
        drag,
        p_ms,
        period,
        p_score,
        p_share,
        p_better,
        reverse,
    )


def _exact_tolerance(stk: Stack) -> float | None:
    """The rest of the excess a true instance of a stack of exact candidates leaves, 1 − the
    least :attr:`~._candidates.AbstractCandidate.exact_share`; None where the stack is empty or
    holds a candidate whose model is not exact."""
    exact = [c.exact_share for c in stk.cands]
    return None if not exact or None in exact else 1.0 - min(exact)


def _reverse(run: Run, stk: Stack) -> tuple[float, float, str] | None:
    """For a stack that holds a candidate whose model is exact
    (:attr:`~._candidates.AbstractCandidate.exact_share`): the stack fitted on the validation
    record and validated on the training record (the settings' filter kept), as (the share of
    the excess above the estimated floor it leaves there, its score against that baseline, why
    the parameters fitted that way do not describe the same effect,
    :meth:`~._candidates.AbstractCandidate.other_way`, "" where they do). An exact model of the
    device holds both ways, as the same effect; an effect it only resembles at one record's
    amplitudes need not (the rest and the score are read only where every stacked model is
    exact: the rest a model that is not exact may leave is unknown; a held-out backlash named
    `flexible_mode` at 1.00 had stacked a spring of negative stiffness beside the mode, which
    was a lag at ζ 0.40 the other way). None for other stacks. Held-out modes were named both
    ways at 1.00, their frequencies within 9 %; backlash between two masses, named
    `flexible_mode` at 1.00 leaving 0.0 % of the excess, scored −16 the other way, the training
    record's baseline already at the floor. Another, named so at 1.00 (ζ 0.18), left nothing
    the other way too, but as a "mode" at ζ 0.40, the search's limit."""
    if not any(c.exact_share is not None for c in stk.cands):
        return None
    rv = prepare(
        run.valid,
        run.train,
        run.candidates,
        run.crit,
        run.st.filter_hz,
        run.st.window_s,
        math.inf,
    )
    f = try_fit(rv, stk.cands)
    if f is None:
        return 1.0, -math.inf, "the design is too wide"
    ex0 = max(rv.base.ms_valid - rv.floor**2, 0.0)
    rest = max(f.ms_valid - rv.floor**2, 0.0) / ex0 if ex0 > 0 else 1.0
    why = next(
        (w for c in stk.cands if (w := c.other_way(stk.fit.physical, f.physical, rv.limits))), ""
    )
    return rest, rv.score_of(rv.base, f, rv.params(stk.cands), rv.floor), why


def _weights(run: Run, effects: list[EffectScore], stk: Stack) -> dict[str, float]:
    """BIC weights exp(score/2) of each plausible candidate alone large enough to be named
    (score = −ΔBIC) and of "no effect", whose prior odds are the significance threshold: at
    score = threshold the two tie. Where the stack holds a sensor artefact, a device effect it
    did not stack explained alone what the artefact explains: its evidence is the artefact's.
    The first of candidates stacked together (a stand-in or a pair, a plausible and
    significant step) counts their joint score where it is higher than its own alone, or where
    it was implausible alone (Coulomb friction at 138 alone and 913 with an offset, against a
    spring at 281 alone)."""
    crit = run.crit
    plausible = {s.name: s.score for s in effects if s.plausible and s.size >= crit.min_size}
    for k, (sc, _) in stk.together.items():
        plausible[k] = max(plausible.get(k, -math.inf), sc)
    if any(c.acts_on == "measurement" for c in stk.cands):
        kept = {c.name for c in stk.cands} | {
            c.name for c in run.candidates if c.acts_on == "measurement"
        }
        plausible = {k: v for k, v in plausible.items() if k in kept}
    top = max([crit.threshold, *plausible.values()])
    raw = {"none": math.exp((crit.threshold - top) / 2)} | {
        k: math.exp((v - top) / 2) for k, v in plausible.items()
    }
    total = sum(raw.values())
    return {k: v / total for k, v in raw.items()}


def uncounted(
    run: Run, fitted: dict[str, Fitted], stk: Stack
) -> tuple[dict[str, float], list[str]]:
    """The candidates whose gains count only above the estimated floor (:meth:`Run.floor_of`:
    the flexible mode, whose columns may cancel position noise) and whose columns explain all
    the named stack's evidence: under one of its variants (with the input share or without,
    plausible or not) the candidate alone, counted from no floor, outscores the stack
    (:func:`_bar`), and the stack adds nothing significant to it. That evidence then no more
    decides for the stack's name than for the candidate's.

    Returns ({name: score from no floor} of the rivals, [names]). A variant whose fit the
    candidate knows for a look-alike of the stack's (``imitates``: a heavy mode the input
    passes through, and a delay) is no rival; where the baseline lies below the floor, so that
    nothing the candidate explains counted, it is a second reading of the record (the
    confidence is shared).

    Held-out closed-loop modes changing the response 2.3–3 %: one named ``spring`` at 1.00 (the
    spring scoring 85, the mode's columns 633, and the spring added to them −943); a collocated
    one named ``position_dependent`` at 0.99 (37 against the mode's 28 from the floor and 223
    from none, b(x) adding −48 to it); a non-collocated one named ``delay`` at 1.00 (the delay
    adding −64 to the mode with its input share, which scored 2055)."""
    rivals: dict[str, float] = {}
    readings: list[str] = []
    held = {c.name for c in stk.cands}
    if not stk.cands:
        return rivals, readings
    bar, fitter, keep = _bar(run, stk), run.fitter, run.fitter.variant
    for c in run.candidates:
        if not c.holds_mode or c.name in held:
            continue
        tries = run.variant_fits.get(c.name, [(keep, fitted[c.name])])
        chosen = next(v for v, f in tries if f is fitted[c.name])
        for var, alone in tries:
            # the stack's own variants as they are now, the candidate's as in this fit
            fitter.variant = keep._replace(
                **{k: getattr(var, k) for k in var._fields if getattr(var, k) != getattr(chosen, k)}
            )
            sc = run.score_ms(run.base, alone.ms_valid, run.params([c]), 0.0)
            if not (math.isfinite(alone.ms_valid) and sc > bar):
                continue
            both = try_fit(run, [*stk.cands, c])
            if (
                both is None
                or run.score_ms(alone, both.ms_valid, run.params(stk.cands), 0.0)
                > run.crit.threshold
            ):
                continue
            if set(c.imitates(c.report(alone.physical))) & held:
                # a look-alike whose gains count: the simpler name stands (held-out delays were
                # fitted as heavy modes the input passes through, scoring above the delay)
                if run.base.ms_valid <= run.floor_of([c]) ** 2:
                    readings.append(c.name)
            else:
                rivals[c.name] = max(rivals.get(c.name, -math.inf), sc)
        fitter.variant = keep
    return rivals, [r for r in dict.fromkeys(readings) if r not in rivals]


def _rivals(
    run: Run, effects: list[EffectScore], stk: Stack, blind: dict[str, float], bar: float
) -> dict[str, float]:
    """Implausible candidates, each alone, that explain the validation error better than the
    whole stack (score above ``bar``, :func:`_bar`: the stack's summed step scores and the
    threshold; at least
    ``min_size``): a structure the record prefers to the verdict, whose fitted parameters no
    device effect of the library has — evidence against the verdict, not for another name (a
    non-collocated mode fitted at ζ 0.28 scored 449 against the named delay's 397; a held-out
    Coulomb record whose friction was taken for a dead zone's look-alike, 83, was ``none`` at
    0.90). Not a rival: one whose stand-in (``simpler``) the stack holds (an asymmetric friction
    with a negative side is Coulomb friction plus an offset), nor any against a stack the
    windowed simulation confirms where the baseline is qualitatively wrong (there the equation
    error is no measure: a mode's columns fitted dominant springs at 800–20 000), nor a
    flexible mode's columns in closed loop, which fit the position noise's path through the
    controller (a clean closed-loop record: ζ 0.4, the search's limit, scoring 1997), nor a
    fit its candidate knows for a look-alike of the stack's (``imitates``: a heavy mode the
    input passes through fits a delay, at 653 against the true delay's 516). The
    rivals of :func:`uncounted` (``blind``) are rivals too, plausible or not."""
    crit = run.crit
    if _confirmed(run, stk):
        return {}
    held = {c.name for c in stk.cands} | set(stk.stands_for.values())
    by_name = run.by_name
    out = {
        s.name: s.score
        for s in effects
        if not s.plausible
        and s.size >= crit.min_size
        and s.score > bar
        and not (run.closed_loop and by_name[s.name].holds_mode)
        and not set(by_name[s.name].imitates(s.params)) & held
        and not _holds_stand_in(held, by_name[s.name])
    }
    return out | {k: v for k, v in blind.items() if v > bar}


def _holds_stand_in(held: set[str], c: AbstractCandidate) -> bool:
    """Whether the names ``held`` include the whole stand-in (``simpler``) of ``c``."""
    return bool(c.simpler) and set(c.simpler) <= held


def _readings(run: Run, effects: list[EffectScore], stk: Stack, verdict: str) -> list[str]:
    """Candidates of which the stack is a reading too: fitted alone implausibly but perhaps
    only by bias (:meth:`~._candidates.AbstractCandidate.stand_in_doubtful`), their stand-in
    (``simpler``) held whole by the stack, ``verdict`` among it. Asymmetric friction whose
    one level is fitted slightly negative and Coulomb friction with an offset larger than it
    are one force while the axis moves: a held-out asymmetric-friction record (levels 0.034 /
    0.167 N, under direction-dependent viscous friction) was named ``offset`` at 1.00."""
    held = {c.name for c in stk.cands}
    out = []
    for s in effects:
        c = run.by_name[s.name]
        if s.plausible or s.name in held or verdict not in c.simpler:
            continue
        if _holds_stand_in(held, c) and c.stand_in_doubtful(s.params):
            out.append(s.name)
    return out


def _bar(run: Run, stk: Stack) -> float:
    """The verdict's evidence a rival is weighed against: the stack's summed step scores, at
    least the threshold ("no effect"'s score for an empty stack)."""
    return max(run.crit.threshold, sum(s.score for s in stk.steps))


def _detection(run: Run) -> tuple[float, float]:
    """(the record's detection limit, the largest of its candidates'): the smallest effect (size
    as in ``min_size``, one parameter) that would have reached the threshold, ΔMS > (threshold
    + ln N_eff)·MS₀/N_eff; and, for candidates whose gains count only above the estimated floor
    (:meth:`Run.floor_of`: the flexible mode), the least that lifts MS₀ there first,
    ΔMS > max(MS₀, floor²)·exp((threshold + p·ln N_eff)/N_eff) − MS₀ (a baseline below the
    estimated floor hides such an effect whole: a held-out closed-loop mode changing the
    response 2.3 % was ``none`` at 0.98 with a limit of 0.0055 while no gain of the mode's could
    count)."""
    crit, base = run.crit, run.base
    n, ms0 = base.n_eff, base.ms_valid
    generic = math.sqrt((crit.threshold + math.log(n)) * ms0 / n) / run.force_rms
    worst = generic
    for c in run.candidates:
        lo = run.floor_of([c])
        if lo**2 > ms0:
            grow = math.exp((crit.threshold + run.params([c]) * math.log(n)) / n)
            worst = max(worst, math.sqrt(lo**2 * grow - ms0) / run.force_rms)
    return generic, worst


def _explains(run: Run, stk: Stack, v: Verdict) -> float:
    """The part of a named verdict's confidence its stack's fit earns: min(1, explained /
    ``explained_full``); and where every stacked candidate's model is exact
    (:attr:`~._candidates.AbstractCandidate.exact_share`), times tol/rest where the stack leaves a
    rest of the excess above what a true instance leaves, tol = 1 − the least exact share, in either
    direction; the other way (the records' roles swapped, :func:`_reverse`) also times the odds of
    its score s over the threshold t, 1/(1 + exp((t − s)/2)), as "no effect" is weighed. It is 0
    where a stack holding an exact candidate is not the same effect fitted the other way
    (:meth:`~._candidates.AbstractCandidate.other_way`). Held-out backlash between two
    masses and a clean closed-loop record, each fitted by a flexible mode's columns, were named so
    at 0.98–1.00, leaving 2.7–12 % of the excess."""
    out = min(1.0, max(v.explained, 0.0) / run.crit.explained_full)
    if v.reverse is not None and v.reverse[2]:
        return 0.0
    tol = _exact_tolerance(stk)
    if tol is None:
        return out
    rests = [1.0 - v.explained]
    if v.reverse is not None:
        rest, score, _ = v.reverse
        rests.append(rest)
        out /= 1.0 + math.exp(min((run.crit.threshold - score) / 2, 700.0))
    for rest in rests:
        if rest > tol:
            out *= tol / rest
    return out


def _lookalike_rivals(run: Run, stk: Stack, v: Verdict) -> tuple[dict[str, float], float]:
    """The out-of-library look-alikes (a dead zone's input, two parameters; a force quadratic
    in the velocity, one) that score above the named stack's joint score with fewer parameters,
    each scored from the baseline as the stack is (the same N_eff and fitted floor): ({name:
    score}, the stack's joint score). A simpler force explains what the stack explains, for no
    name of the library (a held-out quadratic drag, open loop, near the floor: the drag's one
    column scored 85, the stack of a delay and a flexible mode 70 with five parameters, named
    ``delay`` at 1.00). None against a stack the windowed simulation confirms where the
    baseline is qualitatively wrong (there the equation error is no measure)."""
    if not stk.cands or _confirmed(run, stk):
        return {}, math.inf
    p, lo = run.params(stk.cands), run.fit_floor
    joint = run.score_ms(run.base, stk.fit.ms_valid, p, lo)
    out = {}
    for name, ms, k in (("dead_zone_lookalike", v.lookalike, 2), ("drag_lookalike", v.drag, 1)):
        if k < p and math.isfinite(ms):
            s = run.score_ms(run.base, ms, k, lo)
            if s > joint:
                out[name] = s
    return out, joint


@dataclasses.dataclass(frozen=True)
class Confidence:
    verdict: str  # "none" may become "unexplained" (below)
    confidence: float
    weights: dict[str, float]
    ambiguous: list[str]
    detection: float  # the record's detection limit (share of the input's term)
    detection_worst: float  # the largest of its candidates' limits (:func:`_detection`)
    rivals: dict[str, float]  # implausible candidates that beat the stack (:func:`_rivals`)


def unresolved(run: Run, fitted: dict[str, Fitted], effects: list[EffectScore]) -> float:
    """The largest size (rms of ε₁ removed over the input's term) of a candidate fitted alone
    that beats "no effect" (score above ``threshold``) but is refused only for lying within the
    record's resolution (:meth:`~._candidates.AbstractCandidate.unresolved`); 0 when none. An
    effect that large may be there unnamed, so the record's detection limit is at least that:
    a held-out closed-loop mode at the floor (response change 3.3 %), whose columns scored 165
    and removed all the excess with a deflection within twice the position noise, was called
    `none` at 0.95 for a limit of 0.0066."""
    return max(
        (
            e.size
            for e in effects
            if not e.plausible
            and e.score > run.crit.threshold
            and run.by_name[e.name].unresolved(fitted[e.name].physical, run.limits)
        ),
        default=0.0,
    )


def weigh(
    run: Run,
    effects: list[EffectScore],
    stk: Stack,
    v: Verdict,
    unseen: tuple[dict[str, float], list[str]],
    below: float = 0.0,
) -> Confidence:
    """The verdict's confidence (:func:`lionjax.diagnose`: "Confidence"); ``unseen``: the
    rivals and readings of :func:`uncounted`; ``below``: the size of an effect the record may
    hold unnamed (:func:`unresolved`), a bound on the detection limit."""
    crit = run.crit
    blind, also = unseen
    weights = _weights(run, effects, stk)
    detection, detection_worst = _detection(run)
    detection_worst = max(detection_worst, below)
    bar = _bar(run, stk)
    rivals = _rivals(run, effects, stk, blind, bar)
    # the rivals' odds against the verdict's evidence, as the BIC weights count them (the
    # look-alikes' against the stack's joint score)
    looks, joint = _lookalike_rivals(run, stk, v)
    odds = [s - bar for s in rivals.values()] + [s - joint for s in looks.values()]
    doubt = 1.0 / (1.0 + sum(math.exp(min(d / 2, 700.0)) for d in odds))
    rivals |= looks
    verdict = v.verdict
    if verdict == "none" and min(weights["none"], doubt) < 1.0 / crit.tie_ratio:
        # a candidate beats "no effect" by more than the tie ratio yet removes too little of
        # the gap to be named, or is implausible: there is an effect the library does not
        # describe (Dahl friction's pre-sliding stiffness) — not "none" with a confidence near 0
        verdict = "unexplained"
    if verdict in stk.stands_for and stk.stands_for[verdict] in weights:
        # the stand-in and the candidate it replaced are one explanation: pool their evidence
        weights[verdict] = weights.get(verdict, 0.0) + weights.pop(stk.stands_for[verdict])
    ambiguous: list[str] = []
    if verdict in weights:
        near = [k for k in weights if weights[k] >= weights[verdict] / crit.tie_ratio]
        if len(near) > 1:
            ambiguous = sorted(near, key=lambda k: -weights[k])
    # "nothing named" is only as sure as the record is sensitive: the share (log scale) of the
    # sizes worth naming, min_size … 1, below the detection limit is where one could hide
    hidden = math.log(max(detection_worst, crit.min_size) / crit.min_size) / math.log(
        1.0 / crit.min_size
    )
    if verdict == "none":
        confidence = weights["none"] * (1.0 - min(hidden, 1.0))
    elif verdict == "unexplained":
        # a fit that removes much of the gap (implausible but beating "no effect", or plausible
        # below the threshold) leaves the question open; "no candidate explains it" holds only
        # where train covered what validation holds (a tanh a(x) at positions 99.97 % outside
        # train's range was "unexplained" at 1.00); a force periodic in position that explains
        # what the stack leaves is evidence of its own
        best_share = max([s.share for s in effects if s.score > 0 or s.plausible], default=0.0)
        coverage = 1.0 - max(run.outside.values())
        against = max(1.0 - best_share, v.periodic_share if v.periodic_better else 0.0)
        confidence = float(np.clip(min(against, coverage), 0.0, 1.0))
        if not v.periodic_better:
            # and, as "none", only as sure as a library effect below the detection limit could
            # not be what is left (a held-out closed-loop mode changing the response 3.4 %, its
            # profile run to the search's edge, was "unexplained" at 0.97 for a limit of 0.013)
            confidence *= 1.0 - min(hidden, 1.0)
    else:
        confidence = weights.get(verdict, 0.0) * _explains(run, stk, v)
    if verdict != "unexplained":
        confidence *= doubt
    readings = list(dict.fromkeys([*_readings(run, effects, stk, verdict), *also]))
    if readings and verdict not in ("none", "unexplained"):
        # one more reading of the same force: the confidence is shared among them
        ambiguous = list(dict.fromkeys([*(ambiguous or [verdict]), *readings]))
        confidence /= 1 + len(readings)
    return Confidence(
        verdict, float(confidence), weights, ambiguous, detection, detection_worst, rivals
    )


def _std_physical(f: Fitted) -> dict[str, float]:
    """First-order standard deviations of a, b (nominal, lower bounds: rows are correlated)."""
    return {"a": float(f.std[0]), "b": float(f.std[1])}


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
        "std": _std_physical(cur),
        "gap": cur.gap,
        "shrink": shrink(cur.gap, base.gap),
        "simulation": cur.simulation,
        "measurement": [c.name for c in stk.cands if c.acts_on == "measurement"],
        "equation_gap": cur.equation_gap,
        "equation_shrink": 1 - cur.equation_gap / base.equation_gap,
        "remaining_excess_share": run.excess(cur.ms_valid) / ex0 if ex0 > 0 else 0.0,
        # a stack holding an exact candidate, with the records' roles swapped (else None): its
        # rest, its score and why a stacked candidate refuses that fit ("": none does)
        "reverse": None
        if v.reverse is None
        else dict(zip(("remaining_excess_share", "score", "refused"), v.reverse, strict=True)),
    }
    final.update(params)
    final["structure"] = v.s_final
    final["structure_explained"] = not v.peak_grew
    # the dead zone's look-alike's validated mean square over the named stack's (stack only)
    final["dead_zone_lookalike_ratio"] = v.lookalike / cur.ms_valid if v.judged else None
    # the drag look-alike's (a force quadratic in the velocity) likewise (stack only)
    final["drag_lookalike_ratio"] = v.drag / cur.ms_valid if math.isfinite(v.drag) else None
    final["periodic_lookalike"] = {
        "ratio": v.periodic_ms / cur.ms_valid if math.isfinite(v.periodic_ms) else None,
        "score": v.periodic_score if math.isfinite(v.periodic_score) else None,
        "share": v.periodic_share,
        "period": v.period if math.isfinite(v.period) else None,
        "significant": v.periodic_better,
    }
    return final


def _series_and_where(run: Run, stk: Stack, v: Verdict):
    """The validation signals for plotting, the ``where`` findings and the regions on them."""
    valid, fitter, base, cur = run.valid, run.fitter, run.base, stk.fit
    series = {
        "t": float(valid.t0) + float(valid.dt) * np.arange(valid.n_samples),
        "x": np.asarray(valid.x),
        "F": np.asarray(valid.F),
        "v": np.asarray(fitter.v_valid),
        "residual_base": base.residual,
        "residual_final": cur.residual,
        "sim_base": base.sim_error,
        "sim_final": cur.sim_error,
        "H": np.asarray(fitter.H),
    }
    where = where_findings(series, run.st, run.floor)
    if v.periodic_better:
        where.append(
            {
                "kind": "position_period",
                "band": f"period {v.period:.4g} m",
                "period": v.period,
                "share": v.periodic_share,
                "score": v.periodic_score,
                "note": "a force periodic in position (cogging; not in the library) fitted with "
                "the stack: share = its part of the excess validation error the stack leaves",
            }
        )
    final = {"residual_final": series["residual_final"] if stk.cands else None}
    regions = find_regions({**series, **final}, alpha=run.crit.alpha, filter_hz=run.st.filter_hz)
    return series, where, regions


def _baseline(run: Run, v: Verdict) -> dict[str, Any]:
    base, valid = run.base, run.valid
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
    }


def _settings_json(run: Run) -> dict[str, Any]:
    st, fitter, crit = run.st, run.fitter, run.crit
    return {
        "dt": st.dt,
        "filter_hz": st.filter_hz,
        "velocity_filter_hz": st.velocity_hz,
        "v_eps": st.v_eps,
        "window_s": fitter.H * st.dt,
        "state_filter_hz": fitter.state_hz if math.isfinite(fitter.state_hz) else None,
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
        # whether friction's force columns are masked where the axis sticks (chosen by the
        # validated score of the first friction candidate)
        "friction_stick_masked": bool(fitter.stick),
    }


def report(
    run: Run, effects: list[EffectScore], stk: Stack, v: Verdict, c: Confidence
) -> Diagnosis:
    """The :class:`~lionjax.diagnosis.Diagnosis` of the stages' results."""
    series, where, regions = _series_and_where(run, stk, v)
    stuck = run.fitter.stuck_masks
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
            # the share of each record's samples where the axis sticks (_Fitter.stuck)
            "stuck_share": {"train": float(np.mean(stuck[0])), "valid": float(np.mean(stuck[1]))},
            "closed_loop": bool(run.closed_loop),
        },
        settings=_settings_json(run),
        steps=stk.steps,
        confidence=c.confidence,
        ambiguous=c.ambiguous,
        weights=c.weights,
        rivals=c.rivals,
        regions=regions,
        series=series,
    )
