"""The stages around the greedy stack (:mod:`._stack`): every candidate alone
(:func:`fit_alone`), the parsimony pass (:func:`parsimony`) and backward elimination
(:func:`prune`), each returning a new :class:`~._run.Run` or :class:`~._stack.Stack`."""

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
from ._run import Run
from ._stack import Stack
from .effects import AbstractCandidate, check_library


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
        if c.simulated() and all(k.simulated() for k in simpler) and math.isfinite(f_alt.gap):
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
        weakest = None
        for c in stk.cands:
            if c.name in in_law:
                continue
            rest = tuple(k for k in stk.cands if k.name != c.name)
            f = run.try_fit(rest)
            if f is None:
                continue
            sc = run.evidence(f, stk.fit, (c,), run.floor_of(stk.cands))
            if sc <= run.crit.threshold and (weakest is None or sc < weakest[0]):
                weakest = (sc, c, f)
        if weakest is None:
            break
        sc, c, f = weakest
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
