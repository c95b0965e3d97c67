"""One diagnosis' shared state (:class:`Run`): the problem, the baseline fit, its noise floor, and
how a fit is scored against another (:meth:`Run.assess`)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .._errors import InputError
from .._record import Record
from ._criteria import Criteria
from ._fit import Fitted, fit
from ._problem import ROLES, Problem
from ._regressors import TooWide
from ._result import EffectScore
from ._settings import settings
from ._statistics import _check_memory, _feedback, _passes, _white_noise
from ._streaming import impulse_gains
from .effects import AbstractCandidate, Design, Limits


@dataclasses.dataclass(frozen=True)
class Run:
    """What the stages of one diagnosis share. ``fit_floor``, the floor mean squares count
    from, is lowered as fits come in (:meth:`lowered`, a new Run)."""

    problem: Problem
    candidates: tuple[AbstractCandidate, ...]
    lookalikes: tuple
    base: Fitted
    sx: float  # position noise of the validation record [m]
    sF: float  # force noise [N]
    floor: float  # the estimated floor of ε₁
    force_rms: float  # rms of ε₁'s input term b·F/Λ on validation
    feedback: float
    F_ref: np.ndarray  # F less the controller's answer to x
    closed_loop: bool
    dominant: bool  # the baseline is qualitatively wrong: a ≤ 0 or b ≤ 0
    outside: dict[str, float]
    fit_floor: float = math.inf
    #: each candidate resolved alone (its chosen variant, profiled), by name
    resolved: dict = dataclasses.field(default_factory=dict)
    #: each candidate's fit alone under each of its variants, chosen or not
    variant_fits: dict = dataclasses.field(default_factory=dict)

    @property
    def crit(self) -> Criteria:
        return self.problem.crit

    @property
    def limits(self) -> Limits:
        return self.problem.limits

    @property
    def by_name(self) -> dict[str, AbstractCandidate]:
        """The library's candidates (resolved alone, where they are) by name."""
        return {c.name: self.resolved.get(c.name, c) for c in self.candidates}

    def try_fit(self, structure) -> Fitted | None:
        """The fit of ``structure``, or None when its design would be wider than P_MAX."""
        try:
            return fit(self.problem, structure)
        except TooWide:
            return None

    def by_simulation(self, cands) -> bool:
        """Whether ``cands`` are judged by the windowed simulation as well as the equation
        error: the baseline is qualitatively wrong."""
        return self.dominant and bool(cands)

    def score_ms(self, cur: Fitted, ms_new: float, p: int, lo_rms: float) -> float:
        """−ΔBIC of a validated mean square ``ms_new`` against ``cur``'s with ``p`` more
        parameters, N_eff·ln(MS_cur/MS_new) − p·ln N_eff, N_eff that of ``cur``'s residual;
        mean squares below lo_rms² (a floor) count as lo_rms² (a gain there is on noise)."""
        lo = max(lo_rms**2, 1e-300)
        gain = math.log(max(cur.ms_valid, lo) / max(ms_new, lo))
        ne = cur.n_eff
        return ne * gain - p * math.log(ne)

    def sim_score(self, cur: Fitted, new: Fitted, p: int) -> float:
        """−ΔBIC of the windowed simulation's gap, each window one sample (a window restarts
        from the record's states, so windows' errors are nearly independent, samples within one
        are not): n_w·ln(gap_cur²/gap_new²) − p·ln n_w; −inf where either diverged."""
        n_w = (new.n_sim - new.gap_from) // self.problem.H
        if not (math.isfinite(cur.gap) and math.isfinite(new.gap) and new.gap > 0 and n_w > 1):
            return -math.inf
        return n_w * 2 * math.log(cur.gap / new.gap) - p * math.log(n_w)

    def lowered(self, fits) -> Run:
        """The run with its fitted floor bounded by the validation error of each (structure,
        fit) not able to fit the position noise."""
        rms = math.sqrt(
            min([self.fit_floor**2, *(f.ms_valid for cands, f in fits if not _fits_noise(cands))])
        )
        return dataclasses.replace(self, fit_floor=rms)

    def floor_of(self, cands) -> float:
        """The floor a structure's gains count from: the estimated one where it can fit the
        position noise, else the fitted one."""
        return self.floor if _fits_noise(cands) else self.fit_floor

    def excess(self, ms: float) -> float:
        return max(ms - self.fit_floor**2, 0.0)

    def params(self, cands) -> int:
        return sum(k.params() for k in cands)

    def evidence(self, cur: Fitted, new: Fitted, ks: tuple, lo_rms: float) -> float:
        """The score of ``new`` (``cur`` plus ``ks``) against ``cur``: the validated −ΔBIC, or
        the windowed simulation's where higher and :meth:`by_simulation` (there the equation
        error can grow with the true effect: a dominant spring's carries the encoder's steps)."""
        sc = self.score_ms(cur, new.ms_valid, self.params(ks), lo_rms)
        if self.by_simulation(ks):
            sc = max(sc, self.sim_score(cur, new, self.params(ks)))
        return sc

    def bar(self, stk) -> float:
        """The stack's summed step scores, at least the threshold: the evidence a rival is
        weighed against."""
        return max(self.crit.threshold, sum(s.score for s in stk.steps))

    def joint(self, stk) -> float:
        """The stack's joint score from the baseline (its parameters, the fitted floor)."""
        return self.score_ms(self.base, stk.fit.ms_valid, self.params(stk.cands), self.fit_floor)

    def confirmed(self, stk) -> bool:
        """Whether the windowed simulation confirms the stack where the baseline is
        qualitatively wrong: ``dominant_sim_share`` of the gap gone."""
        return (
            self.by_simulation(stk.cands)
            and sim_share(stk.fit.gap, self.base.gap) >= self.crit.dominant_sim_share
        )

    def assess(self, cur: Fitted, new: Fitted, cand, lo_rms: float) -> EffectScore:
        """``new`` (``cur`` plus ``cand``: one candidate or a tuple added together) scored
        against ``cur``: significant, or why not (:class:`~lionjax.diagnosis.Criteria`)."""
        crit = self.crit
        ks = cand if isinstance(cand, tuple) else (cand,)
        sc = self.evidence(cur, new, ks, lo_rms)
        by_sim = self.by_simulation(ks)
        ex0 = self.excess(cur.ms_valid)
        share = 1 - self.excess(new.ms_valid) / ex0 if ex0 > 0 else 0.0
        why = self._refused(cur, new, ks, sc)
        plausible = not why
        # an effect must not worsen the simulated gap (a fit that does describes the
        # residual, not the device), where the current simulation is a reference at all (it
        # beats holding each window's start position) and the record can judge the effect
        exempt = not any(k.simulated_gap_judges(self.problem.stuck_share, crit) for k in ks)
        worse = (
            math.isfinite(cur.gap)
            and not cur.gap >= self.problem.hold_gap
            and not new.gap <= (1 + crit.max_worsening) * cur.gap
            and not (exempt and math.isfinite(new.gap))
        )
        size = math.sqrt(max(cur.ms_valid - new.ms_valid, 0.0)) / self.force_rms
        # an artefact lives in F, which the filter's passband does not bound: sized against F
        own = [k.measured_rms(new.physical, self.problem.valid, self.problem.v_valid) for k in ks]
        if all(r is not None for r in own):
            F_rms = float(np.sqrt(np.mean(np.square(np.asarray(self.problem.valid.F, np.float64)))))
            size = max(size, sum(own) / max(F_rms, 1e-300))
        if by_sim and math.isfinite(new.gap):  # likewise: the simulated gap it removes
            x_std = max(float(np.std(np.asarray(self.problem.valid.x, np.float64))), 1e-300)
            size = max(size, math.sqrt(max(cur.gap**2 - new.gap**2, 0.0)) / x_std)
        # where the baseline is qualitatively wrong, or after a first effect whose misfit the
        # equation error keeps, the simulated gap's share may stand in for the equation error's
        least = crit.min_share_deep if len(cur.structure) >= 2 else crit.min_share
        sim = sim_share(new.gap, cur.gap)
        shares = (
            share >= least
            or (by_sim and sim >= crit.dominant_sim_share)
            or (bool(cur.structure) and sim >= crit.later_sim_share)
        )
        sig = sc > crit.threshold and shares and size >= crit.min_size and plausible and not worse
        if plausible:
            why = (
                "significant"
                if sig
                else f"score {sc:.3g} ≤ {crit.threshold}"
                if sc <= crit.threshold
                else "removes too little"
                if not shares
                else f"too small ({size:.2g} of the input's term, least {crit.min_size})"
                if size < crit.min_size
                else f"makes the simulated gap worse ({new.gap:.3g} m against {cur.gap:.3g} m)"
            )
        return EffectScore(
            name=ks[0].name,
            params={n: v for k in ks for n, v in k.report(new.physical).items()},
            gap=new.gap,
            shrink=shrink(new.gap, self.base.gap),
            equation_gap=new.equation_gap,
            equation_shrink=1 - new.equation_gap / self.base.equation_gap,
            score=sc,
            share=share,
            significant=bool(sig),
            reason=why,
            plausible=plausible,
            size=size,
            simulation=new.simulation,
        )

    def _refused(self, cur: Fitted, new: Fitted, ks, sc: float) -> str:
        """Why ``ks`` fitted in ``new`` do not describe the device ("" when they may): their
        parameters, a look-alike that explains the step better, or the record."""
        why = next((w for k in ks if (w := k.implausible(new.physical, self.limits))), "")
        why = why or next(
            (w for la in self.lookalikes if (w := la.veto(self, cur, new, ks, sc))), ""
        )
        return why or next((w for k in ks if (w := k.refusal(self.limits, cur.gap, new.gap))), "")


def _fits_noise(cands) -> bool:
    return any(k.fits_noise() for k in cands)


def sim_share(gap: float, before: float) -> float:
    """The share of the simulated gap ``before`` that ``gap`` removes: 1 − gap/before (1 where
    only ``before`` diverged, 0 where ``gap`` did)."""
    if not math.isfinite(gap):
        return 0.0
    return shrink(gap, before) if math.isfinite(before) else 1.0


def shrink(gap: float, base_gap: float) -> float:
    """1 − gap/base_gap; NaN (null in JSON) where either simulation diverged."""
    if not (math.isfinite(gap) and math.isfinite(base_gap)):
        return math.nan
    return 1 - gap / base_gap if base_gap > 0 else 0.0


def _problem(train, valid, crit, filter_hz, window_s, max_memory_gb, streamed) -> Problem:
    """The records' problem: the settings adapted to ``train`` and the windowed simulation's
    restart interval spanning their slowest dynamics (:func:`dynamics`)."""
    st = settings(train, filter_hz=filter_hz, window_s=window_s, feedback_share=crit.feedback_share)
    # 20 time constants 1/λ of the filter (s + λ)³, λ = 2π·filter_hz
    least = max(int(math.ceil(20 / (2 * math.pi * st.filter_hz * st.dt))), 200)
    for nm, rec in (("train", train), ("valid", valid)):
        if rec.n_samples < least:
            raise InputError(
                f"diagnose: the {ROLES[nm]} has {rec.n_samples} samples; at least "
                f"{least} are needed (20 filter time constants)."
            )
    chunk = None if isinstance(streamed, bool) or streamed is None else streamed
    streamed = _check_memory(train.n_samples, valid.n_samples, max_memory_gb, streamed)
    problem = Problem.of(train, valid, st, crit, streamed, chunk)
    scale, f_osc = dynamics(problem)
    if filter_hz is None and f_osc > st.filter_hz:
        # a dominant oscillation above the corner is weighed by the filter's tail alone
        # ((f_c/f)³ of it), which biases its fitted frequency towards the corner: the corner
        # moves up to it (at most OSCILLATION_CORNER·f_s)
        fh = min(f_osc, OSCILLATION_CORNER / st.dt)
        st = settings(train, filter_hz=fh, window_s=window_s, feedback_share=crit.feedback_share)
        problem = Problem.of(train, valid, st, crit, streamed, chunk, problem.position_noise)
        scale, _ = dynamics(problem)
    return problem.with_window(scale)


def prepare(
    train: Record,
    valid: Record,
    candidates: tuple[AbstractCandidate, ...],
    lookalikes: tuple,
    crit: Criteria,
    filter_hz: float | None,
    window_s: float | None,
    max_memory_gb: float | None,
    streamed: bool | int | None = None,
) -> Run:
    """Settings, the baseline fit, the noise floor of ε₁ and the record-level facts (closed
    loop, limits, a qualitatively wrong baseline) that every later stage reads."""
    problem = _problem(train, valid, crit, filter_hz, window_s, max_memory_gb, streamed)
    st = problem.st
    base = fit(problem, ())
    a, b = base.physical["a"], base.physical["b"]
    # noise floor of ε₁ on the validation record (x's with the encoder's count: else a clean
    # record's gap is taken for an effect); F's noise as the lesser of its two upper bounds: a
    # multisine's third differences are its own, not noise, and a computed F has none
    sx = problem.position_noise[1]
    sF = _white_noise(np.asarray(valid.F))
    gx, gF = impulse_gains(st.bank(), st.dt, a)
    floor = math.sqrt(sx**2 * gx + (b * sF) ** 2 * gF)
    # the scale of ε₁'s input term b·F/Λ on validation, against which an effect's size counts
    Fv = np.asarray(valid.F, np.float64)
    hF = problem.regressors(())[1].mean_square(Fv - np.mean(Fv), "zoh", 0)
    # in closed loop the controller feeds the position noise into F, so a regressor built from
    # F can cancel the noise's path through x in ε₁: at or below the estimated floor a candidate
    # may have to show more than its equation error (Limits.loop_noise)
    feedback, F_ref = _feedback(np.asarray(valid.x), np.asarray(valid.F))
    closed_loop = feedback >= crit.feedback_share
    outside = _outside(train, valid, problem.v_train, problem.v_valid)
    # each record's share of samples where the axis passes twice (a record that is both, once)
    share, reversals = _passes(np.asarray(valid.x), sx)
    shares = [share]
    if train is not valid:
        shares.append(_passes(np.asarray(train.x), problem.position_noise[0])[0])
    xt = np.asarray(train.x)
    limits = Limits(
        float(min(np.max(np.abs(np.asarray(train.F))), np.max(np.abs(Fv)))),
        st.dt,
        sx,
        closed_loop=closed_loop,
        loop_noise=closed_loop and base.ms_valid <= floor**2,
        mode_band=(st.mode_grid[0], st.mode_grid[-1]),
        excited=st.excited,
        x_range=_common_range(xt, np.asarray(valid.x)),
        train_range=(float(np.min(xt)), float(np.max(xt))),
        stuck_share=problem.stuck_share,
        sticks=problem.sticks,
        outside=outside["position"] > 0,
        passed_twice=max(shares),
        reversals=reversals,
    )
    return Run(
        problem=dataclasses.replace(problem, limits=limits),
        candidates=candidates,
        lookalikes=lookalikes,
        base=base,
        sx=sx,
        sF=sF,
        floor=floor,
        force_rms=max(abs(b) * float(np.sqrt(hF)), 1e-300),
        feedback=feedback,
        F_ref=F_ref,
        closed_loop=closed_loop,
        # a dominant effect (a spring with its natural frequency above the filter corner,
        # friction that sticks the axis) leaves the mass–damper nothing physical to fit
        dominant=not (a > 0 and b > 0),
        outside=outside,
    )


#: Periods of an oscillation the windowed simulation spans (:func:`dynamics`).
WINDOW_PERIODS = 4.0
#: Highest filter corner a dominant oscillation moves it to, as a share of f_s.
OSCILLATION_CORNER = 1 / 8


def dynamics(problem: Problem) -> tuple[float, float]:
    """(the slowest dynamics the records show [s], which the windowed simulation's restart
    interval spans; the frequency [Hz] of a dominant oscillation, or 0).

    The mass–damper's time constant 1/a where it is qualitatively right (a, b > 0); else, where
    a spring ẍ + aẋ + kx = bF (+ a constant) is (b > 0, bk > 0), :data:`WINDOW_PERIODS` of its
    damped period or its envelope's time constant 1/(ζωₙ), whichever is shorter (over many
    periods a restarted simulation drifts in phase with any error of the frequency), or its
    slowest real pole's time constant when overdamped; else 0.1 s."""
    from .._model_effects import Offset, Spring
    from .._models import Augmented, MassDamper
    from ._lstsq import fit_batch

    rtr = problem.regressors(Design())[0]

    def physical(effects):
        model = Augmented(MassDamper(), effects)
        th = fit_batch(rtr, model, [(0.0, math.inf)])[0][0]
        return model.physical(np.asarray(th, np.float64))

    ph = physical(())
    a, b = float(ph["a"]), float(ph["b"])
    if a > 0 and b > 0:
        return 1.0 / a, 0.0
    ph = physical((Spring(), Offset()))
    a, b, k = (float(ph[n]) for n in ("a", "b", "k"))
    if not (b > 0 and b * k > 0):
        return 0.1, 0.0
    wn = math.sqrt(b * k)
    zeta = a / (2 * wn)
    if abs(zeta) < 1:
        wd = wn * math.sqrt(1 - zeta * zeta)
        envelope = 1 / (abs(zeta) * wn) if zeta != 0 else math.inf
        return min(WINDOW_PERIODS * 2 * math.pi / wd, envelope), wd / (2 * math.pi)
    slow = wn * (zeta - math.sqrt(zeta * zeta - 1))  # the slowest real pole's rate
    return (1.0 / slow if slow > 0 else 0.1), 0.0


def _common_range(x_train: np.ndarray, x_valid: np.ndarray) -> tuple[float, float]:
    """The positions both records cover; train's range where they do not overlap."""
    lo = max(float(np.min(x_train)), float(np.min(x_valid)))
    hi = min(float(np.max(x_train)), float(np.max(x_valid)))
    return (lo, hi) if hi > lo else (float(np.min(x_train)), float(np.max(x_train)))


def _outside(train: Record, valid: Record, v_train, v_valid) -> dict[str, float]:
    """Shares of the validation samples outside the training record's range: of x and v̂
    outside train's [min, max], of F with |F| above train's largest. An effect acting only
    there cannot be fitted on train: "unexplained" is then at most 1 − the largest share."""

    def share(tr, va, absolute=False):
        tr, va = np.asarray(tr, np.float64), np.asarray(va, np.float64)
        if absolute:
            return float(np.mean(np.abs(va) > np.max(np.abs(tr))))
        return float(np.mean((va < np.min(tr)) | (va > np.max(tr))))

    return {
        "position": share(train.x, valid.x),
        "velocity": share(v_train, v_valid),
        "force": share(train.F, valid.F, absolute=True),
    }
