"""The verdict's confidence (:func:`weigh`; docs/method.md, "The confidence"): BIC weights of
the plausible candidates and of "no effect", the part of the excess the stack explains, the
record's detection limit, and the odds of the rivals the record prefers."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ._fit import Fitted
from ._result import EffectScore
from ._run import Run
from ._stages import Stack
from ._verdict import Verdict, exact_tolerance
from .effects import AbstractCandidate


def _weights(run: Run, effects: list[EffectScore], stk: Stack) -> dict[str, float]:
    """BIC weights exp(score/2) of each plausible candidate alone of at least ``min_size`` and
    of "no effect", whose score is the threshold. The first of candidates stacked together
    counts their joint score where higher; beside a stacked sensor artefact, the device effects
    not stacked drop out (each explained alone what the artefact explains)."""
    crit = run.crit
    plausible = {s.name: s.score for s in effects if s.plausible and s.size >= crit.min_size}
    for k, (sc, _) in stk.together.items():
        plausible[k] = max(plausible.get(k, -math.inf), sc)
    if any(c.artefact() for c in stk.cands):
        kept = {c.name for c in stk.cands} | {c.name for c in run.candidates if c.artefact()}
        plausible = {k: v for k, v in plausible.items() if k in kept}
    top = max([crit.threshold, *plausible.values()])
    raw = {"none": math.exp((crit.threshold - top) / 2)} | {
        k: math.exp((v - top) / 2) for k, v in plausible.items()
    }
    total = sum(raw.values())
    return {k: v / total for k, v in raw.items()}


def uncounted(run: Run, stk: Stack) -> tuple[dict[str, float], list[str]]:
    """({name: score from no floor}, [names]) of the candidates whose columns can fit the
    position noise and explain all the named stack's evidence: in one of its forms the
    candidate alone, counted from no floor, outscores :meth:`~._run.Run.bar`, and the stack adds
    nothing significant to it. A rival, or, where it ``imitates`` a stacked name and the
    baseline lies below its floor, a second reading of the record."""
    if not stk.cands:
        return {}, []
    rivals: dict[str, float] = {}
    readings: list[str] = []
    held, bar = {c.name for c in stk.cands}, run.bar(stk)
    for c in run.candidates:
        if not c.fits_noise() or c.name in held:
            continue
        for form, alone in run.variant_fits.get(c.name, []):
            if form.no_evidence(run.limits):
                continue
            sc = run.score_ms(run.base, alone.ms_valid, form.params(), 0.0)
            if not (math.isfinite(alone.ms_valid) and sc > bar):
                continue
            both = run.try_fit((*stk.cands, form))
            if (
                both is None
                or run.score_ms(alone, both.ms_valid, run.params(stk.cands), 0.0)
                > run.crit.threshold
            ):
                continue
            if set(c.imitates(c.report(alone.physical))) & held:
                if run.base.ms_valid <= run.floor_of([c]) ** 2:
                    readings.append(c.name)
            else:
                rivals[c.name] = max(rivals.get(c.name, -math.inf), sc)
    return rivals, [r for r in dict.fromkeys(readings) if r not in rivals]


def _rivals(
    run: Run, effects: list[EffectScore], stk: Stack, blind: dict[str, float], bar: float
) -> dict[str, float]:
    """Implausible candidates alone of at least ``min_size`` scoring above ``bar``, and the
    rivals of :func:`uncounted` (``blind``): structures the record prefers to the verdict.
    Not one whose stand-in the stack holds, one it knows for a look-alike of a stacked name
    (``imitates``), a failed search, nor in closed loop one whose columns can fit the position
    noise; none against a stack the simulation confirms on a qualitatively wrong baseline."""
    if run.confirmed(stk):
        return {}
    held = {c.name for c in stk.cands} | set(stk.stands_for.values())
    by_name = run.by_name
    out = {
        s.name: s.score
        for s in effects
        if not s.plausible
        and s.size >= run.crit.min_size
        and s.score > bar
        and not by_name[s.name].no_evidence(run.limits)
        and not (run.closed_loop and by_name[s.name].fits_noise())
        and not set(by_name[s.name].imitates(s.params)) & held
        and not _holds_stand_in(held, by_name[s.name])
    }
    return out | {k: v for k, v in blind.items() if v > bar}


def _holds_stand_in(held: set[str], c: AbstractCandidate) -> bool:
    """Whether the names ``held`` include the whole stand-in (``simpler``) of ``c``."""
    return bool(c.simpler) and set(c.simpler) <= held


def _readings(run: Run, effects: list[EffectScore], stk: Stack, verdict: str) -> list[str]:
    """Candidates fitted alone implausibly, perhaps only by bias (``stand_in_doubtful``), whose
    whole stand-in, ``verdict`` among it, the stack holds: the stack is a reading of them too."""
    held, by_name = {c.name for c in stk.cands}, run.by_name
    return [
        s.name
        for s in effects
        if not s.plausible
        and s.name not in held
        and verdict in by_name[s.name].simpler
        and _holds_stand_in(held, by_name[s.name])
        and by_name[s.name].stand_in_doubtful(s.params)
    ]


def _detection(run: Run, fitted: dict[str, Fitted]) -> tuple[float, float]:
    """(the record's detection limit, the largest of its candidates'): the least one-parameter
    effect reaching the threshold, √((threshold + ln N_eff)·MS₀/N_eff) over the input's term;
    a candidate's own where it states one, given its fit alone in ``fitted``
    (``detection_limit``: a force-sensor line the filter barely passes, or one F shows and the
    fit does not resolve);
    for a candidate whose gains count only above the floor σ, the least that lifts MS₀ there
    first, √(max(MS₀, σ²)·exp((threshold + p·ln N_eff)/N_eff) − MS₀) over the input's term."""
    crit, base = run.crit, run.base
    n, ms0 = base.n_eff, base.ms_valid
    generic = math.sqrt((crit.threshold + math.log(n)) * ms0 / n) / run.force_rms
    worst = generic
    for c in run.by_name.values():
        alone = fitted.get(c.name)
        own = c.detection_limit(run.problem, generic, None if alone is None else alone.physical)
        if own is not None:
            worst = max(worst, own)
        lo = run.floor_of([c])
        if lo**2 > ms0:
            grow = math.exp((crit.threshold + c.params() * math.log(n)) / n)
            worst = max(worst, math.sqrt(lo**2 * grow - ms0) / run.force_rms)
    return generic, worst


def _explains(run: Run, stk: Stack, v: Verdict) -> float:
    """The part of a named verdict's confidence its stack's fit earns: min(1, explained /
    ``explained_full``); for a stack of exact candidates also × tol/rest for each rest of the
    excess above tol (here and the other way) and × the other way's odds over "no effect",
    1/(1 + exp((threshold − s)/2)); 0 where a stacked candidate refuses the other way's fit."""
    out = min(1.0, max(v.explained, 0.0) / run.crit.explained_full)
    if v.reverse is not None and v.reverse[2]:
        return 0.0
    tol = exact_tolerance(stk)
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


@dataclasses.dataclass(frozen=True)
class Confidence:
    verdict: str  # "none" may become "unexplained", either "inconclusive" (:func:`weigh`)
    confidence: float
    weights: dict[str, float]
    ambiguous: list[str]
    detection: float  # the record's detection limit (share of the input's term)
    detection_worst: float  # the largest of its candidates' limits (:func:`_detection`)
    rivals: dict[str, float]  # implausible candidates that beat the stack (:func:`_rivals`)
    #: why the record cannot decide, and what to record instead (None: it can)
    inconclusive: dict | None = None


#: Least effective sample count of the baseline's validation residual at which the record can
#: decide: below it a one-parameter effect must remove over a third of the mean square to
#: reach the threshold (1 − exp(−(threshold + ln N)/N) at N = 30, threshold 10).
N_EFF_LEAST = 30
#: Detection limit (size, over the input's term b·F) at which a record cannot decide: effects
#: worth naming run from ``min_size`` to the drive's own size, and at half of it most of that
#: range (1 − ln 2 / ln(1/min_size) on a log scale, 0.87 at min_size 0.005) could hide unseen.
DETECTION_MOST = 0.5
#: Reversals (moves back by 10× the position noise, :attr:`~.effects.Limits.reversals`) a
#: record needs for friction to be told apart from a constant force.
REVERSALS_LEAST = 10


def inconclusive(
    run: Run,
    detection: float,
    worst: float,
    decided: bool,
    absent: bool,
    seen: bool,
    confounded: bool,
) -> dict | None:
    """Why the records cannot decide whether an effect is there, and what to record instead; or
    None. Three reasons, unless a look-alike explains the gap (``decided``: the record shows that
    effect): the validation residual's effective sample count below :data:`N_EFF_LEAST` (its
    evidence too coarse: nothing named is then no evidence of no effect, and a residual with
    structure no evidence of one outside the library), unless even so an effect of ``min_size``
    would have been seen (``detection``, the one-parameter limit, below it: a residual that
    small decides) or a candidate is significant at that sample count all the same (``seen``:
    the record has resolved structure, which a library fit describes or not); or, where the
    verdict would claim no effect (``absent``: "none"), the detection limit (``worst``, the size
    an effect needs to be seen) at or above :data:`DETECTION_MOST` of the input's term; or
    ``confounded``: a candidate scores above the threshold but the records, moving one way,
    cannot tell its force of position or of time from the other
    (:class:`~.effects.AbstractPositionOrTime`). A significant gap no candidate removes
    ("unexplained") is decided however large the limit: a large unmodelled residual itself
    raises it."""
    n = run.base.n_eff
    few = n < N_EFF_LEAST and detection >= run.crit.min_size and not seen
    blind = absent and worst >= DETECTION_MOST
    if decided or not (few or blind or confounded):
        return None
    reasons, advice = [], []
    if confounded:
        reasons.append(
            f"{run.limits.passed_twice:.0%} of the samples lie where the axis passes twice: "
            "moving one way, a force of position (a spring) cannot be told from one of time (a "
            "drift)"
        )
        advice.append("move the axis back and forth over the positions it is to hold")
    if few:
        reasons.append(
            f"the validation residual holds {n:.0f} effective samples (at least {N_EFF_LEAST} "
            "decide: the residual is slow against the record's length)"
        )
        advice.append("record longer, or with an excitation that changes faster")
    reasons.append(f"the detection limit is {max(detection, worst):.2g} of the input's term b·F")
    if blind:
        advice.append(
            "drive the axis harder or measure its position finer (the detection limit scales "
            "with the position noise over the response it drives)"
        )
    lo, hi = run.problem.st.excited
    reversals = run.limits.reversals
    if reversals is not None and reversals < REVERSALS_LEAST:
        advice.append(
            f"reverse direction at least {REVERSALS_LEAST} times (the validation record "
            f"reverses {reversals} time{'' if reversals == 1 else 's'}: friction is then a "
            "constant force)"
        )
    advice.append(
        f"excite the band the model is to hold (this record: {lo:.3g}–{hi:.3g} Hz; up to the "
        f"filter corner {run.problem.st.filter_hz:.3g} Hz and beyond)"
    )
    return {"reason": "; ".join(reasons), "advice": "; ".join(advice)}


def unresolved(run: Run, fitted: dict[str, Fitted], effects: list[EffectScore]) -> float:
    """The largest size of a candidate alone that beats "no effect" but is refused only as
    within the record's resolution (``unresolved``), 0 if none: a bound on the detection
    limit (an effect that large may be there unnamed)."""
    return max(
        (
            e.size
            for e in effects
            if not e.plausible
            and e.score > run.crit.threshold
            and not run.by_name[e.name].no_evidence(run.limits)
            and run.by_name[e.name].unresolved(fitted[e.name].physical, run.limits)
        ),
        default=0.0,
    )


def _unexplained(run: Run, effects: list[EffectScore], v: Verdict, hidden: float) -> float:
    """The confidence of ``unexplained``: 1 − the largest share of a candidate plausible or
    scoring above 0 (a fit that removes much of the gap leaves the question open), or a
    deciding look-alike's share where larger; at most the share of validation inside train's
    ranges; and, unless a look-alike decided, × (1 − ``hidden``) as ``none``."""
    evidence = [s for s in effects if not run.by_name[s.name].no_evidence(run.limits)]
    best_share = max([s.share for s in evidence if s.score > 0 or s.plausible], default=0.0)
    coverage = 1.0 - max(run.outside.values())
    against = max([1.0 - best_share, *(t.share for t in v.decided_by)])
    confidence = float(np.clip(min(against, coverage), 0.0, 1.0))
    return confidence if v.decided_by else confidence * (1.0 - min(hidden, 1.0))


def weigh(
    run: Run, effects: list[EffectScore], stk: Stack, v: Verdict, fitted: dict[str, Fitted]
) -> Confidence:
    """The verdict's confidence, from the candidates alone (``effects``, ``fitted``), the stack
    and its verdict."""
    crit = run.crit
    blind, also = uncounted(run, stk)
    weights = _weights(run, effects, stk)
    detection, detection_worst = _detection(run, fitted)
    detection_worst = max(detection_worst, unresolved(run, fitted, effects))
    bar = run.bar(stk)
    rivals = _rivals(run, effects, stk, blind, bar)
    # the rivals' odds against the verdict's evidence (the look-alikes' against the stack's
    # joint score)
    looks = {k: t.rival for k, t in v.lookalikes.items() if t.rival is not None}
    joint = run.joint(stk) if looks else math.inf
    odds = [s - bar for s in rivals.values()] + [s - joint for s in looks.values()]
    doubt = 1.0 / (1.0 + sum(math.exp(min(d / 2, 700.0)) for d in odds))
    rivals |= looks
    verdict = v.verdict
    if verdict == "none" and min(weights["none"], doubt) < 1.0 / crit.tie_ratio:
        # a candidate beats "no effect" by the tie ratio yet is too small to be named, or
        # implausible: an effect the library does not describe is there
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
        confidence = _unexplained(run, effects, v, hidden)
    else:
        confidence = weights.get(verdict, 0.0) * _explains(run, stk, v)
    if verdict != "unexplained":
        confidence *= doubt
    undecided = None
    if not stk.cands:
        seen = any(
            s.score > crit.threshold and not run.by_name[s.name].no_evidence(run.limits)
            for s in effects
        )
        # no evidence only because the records move one way (not a failed search)
        both_ways = dataclasses.replace(run.limits, passed_twice=1.0)
        confounded = any(
            s.score > crit.threshold
            and run.by_name[s.name].no_evidence(run.limits)
            and not run.by_name[s.name].no_evidence(both_ways)
            for s in effects
        )
        undecided = inconclusive(
            run,
            detection,
            detection_worst,
            bool(v.decided_by),
            verdict == "none",
            seen,
            confounded,
        )
    if undecided is not None:
        # nothing named on a record that cannot decide: an abstention, which claims nothing
        # about the device and so is held with no confidence (its reason says why)
        verdict, confidence, ambiguous = "inconclusive", 0.0, []
    readings = list(dict.fromkeys([*_readings(run, effects, stk, verdict), *also]))
    if readings and verdict not in ("none", "unexplained", "inconclusive"):
        # one more reading of the same force: the confidence is shared among them
        ambiguous = list(dict.fromkeys([*(ambiguous or [verdict]), *readings]))
        confidence /= 1 + len(readings)
    return Confidence(
        verdict,
        float(confidence),
        weights,
        ambiguous,
        detection,
        detection_worst,
        rivals,
        undecided,
    )
