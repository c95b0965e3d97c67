"""The stages that build the stack, each returning a new :class:`~._run.Run` or :class:`Stack`:
every candidate alone (:func:`fit_alone`); greedy stacking (:func:`stack_effects`), the best
significant candidate on the stack until none is, then a stand-in, a pair or three effects that
hide each other (:func:`_stand_in`, :func:`_pair`, :func:`_hidden`); the parsimony pass
(:func:`parsimony`) and backward elimination (:func:`prune`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

from .._errors import InputError
from .._progress import counted
from ._filtering import P_MAX
from ._fit import Fitted, fit
from ._objective import Objective
from ._result import EffectScore
from ._run import Run
from .effects import AbstractCandidate, check_library
from .effects._lookalikes import structure_key


@dataclasses.dataclass(frozen=True)
class Stack:
    """The greedy stack: its candidates in the order added (in their chosen forms), the steps'
    scores and its fit."""

    cands: tuple[AbstractCandidate, ...]
    steps: tuple[EffectScore, ...]
    fit: Fitted
    #: which stand-in replaced which candidate
    stands_for: dict[str, str] = dataclasses.field(default_factory=dict)
    #: (joint score, names) of each step that added candidates together (a stand-in or a pair),
    #: under the first of them: evidence none of them has alone
    together: dict[str, tuple[float, tuple[str, ...]]] = dataclasses.field(default_factory=dict)
    #: the stand-ins among those steps: candidates standing in for one, one law in several columns
    laws: tuple[tuple[str, ...], ...] = ()


def held(cands) -> int:
    """The effects ``cands`` hold, against ``Criteria.max_effects``: a candidate another of them
    contains (an offset beside a spring) adds no column and takes no place."""
    inside = {n for k in cands for n in k.subsumes}
    return sum(c.name not in inside for c in cands)


def fits_in(run: Run, stk: Stack, ks: tuple) -> bool:
    """Whether the stack with ``ks`` added holds at most ``max_effects`` effects: one that
    contains a stacked candidate (a spring beside an offset) takes its place, so it may join a
    full stack."""
    return held((*stk.cands, *ks)) <= run.crit.max_effects


def _excludes(k: AbstractCandidate, c: AbstractCandidate) -> bool:
    """Whether ``k`` excludes ``c`` or a candidate ``c`` contains."""
    return bool(set(k.excludes) & {c.name, *c.subsumes})


def fits_with(c: AbstractCandidate, added) -> bool:
    """Whether ``c`` may be stacked after ``added``: not after one that contains it (spring ⊃
    offset), nor beside one the data cannot tell apart from it or from what it contains."""
    return all(
        c.name != k.name
        and c.name not in k.subsumes
        and not _excludes(k, c)
        and not _excludes(c, k)
        for k in added
    )


def compatible(c: AbstractCandidate, k: AbstractCandidate) -> bool:
    """Whether ``c`` and ``k`` may be added together: neither contains nor excludes the other."""
    return fits_with(c, (k,)) and k.name not in c.subsumes


def resolve(run: Run, cand: AbstractCandidate, base: tuple = ()) -> AbstractCandidate:
    """``cand`` with its nonlinear parameters found beside ``base`` on the training record
    (:meth:`~.effects.AbstractCandidate.profile`)."""
    out = cand.profile(Objective(run.problem, base), run.limits)
    # the candidate's own class, or one it derives from (a subclass may search its parent's
    # grid), of the same name
    kin = isinstance(out, type(cand)) or (
        isinstance(out, AbstractCandidate) and isinstance(cand, type(out))
    )
    if not kin or out.name != cand.name:
        raise InputError(
            f"{type(cand).__name__}.profile must return a {type(cand).__name__} "
            f"(name {cand.name!r}), got {out!r}."
        )
    return out


def fit_alone(run: Run) -> tuple[Run, dict[str, Fitted]]:
    """Every candidate alone on the baseline in each of its ``variants``, each profiled; the
    candidate's ``pick`` of their validated scores (counted from the estimated floor where its
    columns can fit the position noise) keeps one. Returns the run with the resolved candidates,
    every variant's fit and the fitted floor, and each candidate's chosen fit."""
    resolved, fits, variant_fits = {}, {}, {}
    for c in counted(run.candidates, "fitting the candidates alone", "candidates"):
        tries = []
        for v in c.variants(run.limits, tuple(resolved.values())):
            v = resolve(run, v)
            f = run.try_fit((v,))
            if f is None:
                raise InputError(
                    f"diagnose: candidate {v.name!r} ({type(v).__name__}) has too many columns: "
                    f"with the mass–damper's a and b and the filter's initial-state columns, its "
                    f"design alone is wider than the {P_MAX} columns a diagnosis fits; give it "
                    f"fewer parameters."
                )
            lo = run.floor if v.fits_noise() else 0.0
            tries.append((run.score_ms(run.base, f.ms_valid, v.params(), lo), f, v))
        variant_fits[c.name] = [(v, f) for _, f, v in tries]
        _, fits[c.name], resolved[c.name] = tries[c.pick(tries, run.limits)]
    # the estimated floor is an upper bound only for white, independent noise on x and F (in
    # closed loop F carries the controller's answer to it); the validation error of any fitted
    # model bounds the true floor from above, unless its columns can fit that noise
    run = dataclasses.replace(
        run,
        resolved=resolved,
        variant_fits=variant_fits,
        fit_floor=min(run.floor, run.base.equation_gap),
    )
    return run.lowered([((resolved[c.name],), fits[c.name]) for c in run.candidates]), fits


def fit_on(run: Run, stk: Stack, ks: tuple) -> Fitted | None:
    """The best validated fit of ``ks`` on the stack over the combinations of their
    ``stack_variants`` (its structure holds the forms chosen); None where too wide."""
    combos: list[tuple] = [()]
    for k in ks:
        combos = [(*cmb, w) for cmb in combos for w in k.stack_variants()]
    combos = list({structure_key(cmb): cmb for cmb in combos}.values())
    fits = [run.try_fit((*stk.cands, *cmb)) for cmb in combos]
    return min((f for f in fits if f is not None), key=lambda f: f.ms_valid, default=None)


def step_of(run: Run, stk: Stack, ks: tuple, f: Fitted | None = None):
    """(score, fit, ks) of ``ks`` added to the stack as one step, fitted in ``f`` (default
    :func:`fit_on`), where significant; else None (also where the design is too wide)."""
    f = fit_on(run, stk, ks) if f is None else f
    if f is None:
        return None
    sc = run.assess(stk.fit, f, ks, run.floor_of((*stk.cands, *ks)))
    return (sc, f, ks) if sc.significant else None


def _stand_in(run: Run, trials, pool, stk: Stack):
    """The first implausible trial's stand-in (``simpler``: two or more candidates of the pool)
    significant as one step, in score order; or None."""
    names = {c.name: c for c in pool}
    stand_ins = (
        tuple(names[n] for n in c.simpler)
        for sc, _, c in trials
        if not sc.plausible and len(c.simpler) >= 2 and all(n in names for n in c.simpler)
    )
    steps = (step_of(run, stk, ks) for ks in stand_ins if fits_in(run, stk, ks))
    return next((s for s in steps if s is not None), None)


def _pair(run: Run, trials, stk: Stack):
    """The best pair of plausible trials that gain on the stack (share > 0), significant as
    one step (effects that hide each other), or None: the n(n − 1)/2 compatible pairs of the
    highest summed scores of the 2n best (n = ``pair_from``); none once the stack removes
    ``explained_full`` of the baseline's excess."""
    ex0 = run.excess(run.base.ms_valid)
    if not ex0 > 0 or run.excess(stk.fit.ms_valid) <= (1 - run.crit.explained_full) * ex0:
        return None
    n = run.crit.pair_from
    top = [t for t in trials if t[0].plausible and t[0].share > 0][: 2 * n]
    pairs = [
        (ti, tj)
        for i, ti in enumerate(top)
        for tj in top[i + 1 :]
        if compatible(ti[2], tj[2]) and fits_in(run, stk, (ti[2], tj[2]))
    ]
    # compatible pairs only: near-duplicates (an offset, a drifting offset, a spring) cannot
    # pair with each other and would fill the best n
    pairs.sort(key=lambda p: -(p[0][0].score + p[1][0].score))
    found = [step_of(run, stk, (ti[2], tj[2])) for ti, tj in pairs[: n * (n - 1) // 2]]
    return max((s for s in found if s is not None), key=lambda t: t[0].score, default=None)


def _hidden(run: Run, trials, stk: Stack):
    """Effects that hide each other, or None. Where the stack's error lies above
    ``floor_factor`` × the floor and two more effects fit: every compatible pair of the device
    candidates (plausible alone, or implausible for their own parameters: one's misfit can bias
    another's sign), then the ``pair_from`` best pairs each with every compatible third, fitted
    on the stack. The best significant as one step that removes ``explained_full`` of the
    stack's excess is taken: hidden effects are a whole explanation together, an
    out-of-library effect fitted so leaves more."""
    crit = run.crit
    if not crit.pair_from or stk.fit.equation_gap <= crit.floor_factor * run.floor:
        return None
    # a candidate refused alone for what the record shows against it (a look-alike that
    # validates better, the loop's noise), not for its own fitted parameters, stays out
    pool = [
        t[2]
        for t in trials
        if not t[2].artefact()
        and not t[2].fits_noise()
        and (t[0].plausible or t[2].implausible(t[1].physical, run.limits))
    ]

    def fitted(combos) -> list:
        return [(ks, f) for ks in combos if (f := fit_on(run, stk, ks)) is not None]

    def whole(fits: list) -> list:
        steps = (step_of(run, stk, ks, f) for ks, f in fits)
        return [s for s in steps if s is not None and s[0].share >= crit.explained_full]

    fits = fitted(
        (a, b)
        for i, a in enumerate(pool)
        for b in pool[i + 1 :]
        if compatible(a, b) and fits_in(run, stk, (a, b))
    )
    found = whole(fits)
    if not found:
        best = [ks for ks, _ in sorted(fits, key=lambda t: t[1].ms_valid)[: crit.pair_from]]
        order = {c.name: i for i, c in enumerate(pool)}
        thirds = {}
        for ks in best:
            for c in pool:
                if all(compatible(c, k) for k in ks) and fits_in(run, stk, (*ks, c)):
                    trio = tuple(sorted((*ks, c), key=lambda k: order[k.name]))
                    thirds[tuple(k.name for k in trio)] = trio
        found = whole(fitted(thirds[n] for n in sorted(thirds)))
    return max(found, key=lambda t: t[0].score, default=None)


def stack_effects(
    run: Run, alone: dict[str, tuple[EffectScore, Fitted]], start: Stack | None = None
) -> tuple[Run, Stack]:
    """Greedy stacking on an empty stack (or ``start``: after a stand-in, what the candidate it
    replaced excluded may join): the best significant candidate until none is. When none is,
    or an implausible candidate outranks the best, an implausible candidate's stand-in
    significant as one step is tried and the better score taken; then a pair, then effects
    that hide each other. Every validated fit lowers the fitted floor (the run returned)."""
    stk = Stack((), (), run.base) if start is None else start
    # a candidate a stand-in replaced does not come back: its own parameters were not needed
    gone = set(stk.stands_for.values())
    lib = [run.resolved.get(c.name, c) for c in run.candidates]
    pool = [c for c in lib if fits_with(c, stk.cands) and c.name not in gone]
    while pool := [c for c in pool if fits_in(run, stk, (c,))]:
        fits = [(c, alone[c.name][1] if not stk.cands else fit_on(run, stk, (c,))) for c in pool]
        fits = [(c, f) for c, f in fits if f is not None]
        if not fits:
            break
        # this step's fits lower the floor too: else the first effect's fit is the floor and no
        # second effect can gain on it
        run = run.lowered([((*stk.cands, c), f) for c, f in fits])
        trials = [(run.assess(stk.fit, f, c, run.floor_of((*stk.cands, c))), f, c) for c, f in fits]
        trials.sort(key=lambda t: -t[0].score)
        best = next((t for t in trials if t[0].significant), None)
        above = [t for t in trials if best is None or t[0].score > best[0].score]
        alt = _stand_in(run, above, pool, stk) if above else None
        joint = best is None or (alt is not None and alt[0].score > best[0].score)
        if joint:
            best = alt or _pair(run, trials, stk) or _hidden(run, trials, stk)
            if best is None:
                break
        sc, f, ks = best
        added = f.structure[len(stk.cands) :]  # the forms the fit chose
        together, laws, steps = stk.together, stk.laws, (sc,)
        if joint:
            names = tuple(k.name for k in ks)
            together = {**together, names[0]: (sc.score, names)}
            laws = (*laws, names) if best is alt else laws
            steps = tuple(
                dataclasses.replace(
                    sc,
                    name=k.name,
                    params=k.report(f.physical),
                    reason="significant together with "
                    + ", ".join(o.name for o in added if o.name != k.name)
                    + " (not alone)",
                )
                for k in added
            )
        stk = Stack((*stk.cands, *added), (*stk.steps, *steps), f, stk.stands_for, together, laws)
        pool = [c for c in pool if fits_with(c, added)]
    return run, stk


def parsimony(run: Run, stk: Stack) -> Stack:
    """A stacked candidate with a simpler stand-in (spring → offset, asymmetric friction →
    Coulomb + offset) is replaced by it unless its own extra parameters are significant on
    validation, provided the stand-in is itself a significant, plausible step where the
    candidate stood. Where the windowed simulation models both, the candidate must not make the
    simulated gap worse than its stand-in, and with no more parameters it must make it better:
    asymmetric friction with F⁺, F⁻ > 0 and Coulomb friction with |F₀| < F_c are one law."""
    by_name, crit = run.by_name, run.crit
    for c in list(stk.cands):
        names_now = [k.name for k in stk.cands]
        missing = [n for n in c.simpler if n not in names_now]
        if not missing or any(n not in by_name for n in missing):
            continue  # nothing to stand in, or a stand-in outside the library
        simpler = [by_name[n] for n in missing]
        i = names_now.index(c.name)
        alt = (*stk.cands[:i], *simpler, *stk.cands[i + 1 :])
        f_alt = fit(run.problem, alt)
        rest = tuple(k for k in stk.cands if k.name != c.name)
        prev = fit(run.problem, rest) if rest else run.base
        cur = stk.fit
        extra = c.params() - run.params(simpler)
        keep = run.score_ms(f_alt, cur.ms_valid, extra, run.floor_of(stk.cands)) > crit.threshold
        if math.isfinite(f_alt.gap):
            keep = keep and cur.gap <= (1 + crit.max_worsening) * f_alt.gap
            if extra <= 0:
                keep = keep and cur.gap < (1 - crit.max_worsening) * f_alt.gap
        step = run.assess(prev, f_alt, tuple(simpler), run.floor_of(alt))
        if step.significant and not keep:
            # the stand-in's own step: its figures from the stack without the candidate
            why = f"stands in for {c.name} (its own parameters not needed)"
            steps = list(stk.steps)
            j = [s.name for s in steps].index(c.name)
            steps[j : j + 1] = [
                dataclasses.replace(step, name=k.name, params=k.report(f_alt.physical), reason=why)
                for k in simpler
            ]
            laws = (*stk.laws, tuple(k.name for k in simpler)) if len(simpler) > 1 else stk.laws
            stk = dataclasses.replace(
                stk,
                cands=alt,
                fit=f_alt,
                steps=tuple(steps),
                stands_for={**stk.stands_for, simpler[0].name: c.name},
                laws=laws,
            )
    return stk


def prune(run: Run, stk: Stack) -> Stack:
    """Backward elimination: while some stacked candidate's evidence given all the others is at
    most the threshold, the weakest is dropped (an early step can lose its place to later ones
    that explain what it stood in for). A dropped candidate's joint step (``Stack.together``)
    passes its evidence to the step's next member; a stand-in's candidates (``Stack.laws``) are
    one law and stay."""
    in_law = {n for law in stk.laws for n in law}
    while len(stk.cands) > 1:
        weak = []
        for c in stk.cands:
            rest = tuple(k for k in stk.cands if k.name != c.name)
            f = None if c.name in in_law else run.try_fit(rest)
            if f is not None:
                sc = run.evidence(f, stk.fit, (c,), run.floor_of(stk.cands))
                if sc <= run.crit.threshold:
                    weak.append((sc, c, f))
        if not weak:
            break
        sc, c, f = min(weak, key=lambda w: w[0])
        together = dict(stk.together)
        if c.name in together:
            score, names = together.pop(c.name)
            left = tuple(n for n in names if n != c.name)
            if left:
                together[left[0]] = (score, left)
        stk = dataclasses.replace(
            stk,
            cands=tuple(k for k in stk.cands if k.name != c.name),
            fit=f,
            steps=tuple(
                dataclasses.replace(
                    s, reason=f"{s.reason}; {c.name} dropped ({sc:.3g} given the rest)"
                )
                for s in stk.steps
                if s.name != c.name
            ),
            stands_for={k: v for k, v in stk.stands_for.items() if k != c.name},
            together=together,
        )
    return stk


def check_candidates(candidates: Sequence[Any], reserved) -> tuple[AbstractCandidate, ...]:
    """The library as a tuple, or an :class:`~lionjax.InputError` naming what is wrong."""
    candidates = tuple(candidates)
    bad = [c for c in candidates if not isinstance(c, AbstractCandidate)]
    if bad:
        raise InputError(
            "diagnose: argument 'candidates' must hold lionjax.diagnosis candidates (instances "
            f"of AbstractCandidate, e.g. a ForceEffect subclass), got {bad[0]!r}."
        )
    names = [c.name for c in candidates]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise InputError(
            f"diagnose: argument 'candidates': the name(s) {dup} are used by more than one "
            f"candidate ({', '.join(type(c).__name__ for c in candidates if c.name in dup)}); "
            "give each candidate its own name (a candidate added twice: pass it once)."
        )
    try:
        check_library(candidates, reserved)
    except ValueError as e:
        raise InputError(f"diagnose: argument 'candidates': {e}") from None
    return candidates
