"""``lionjax.diagnose``: where, which and how far is the sim-to-real gap.

Works on recorded data alone (no twin: layer 3 of the package). Outline:

1. **Settings from the record** (:func:`settings`): the filter Λ = (s + λ)³ with
   λ = 2π·min(f_s/25, 40 Hz) rad/s (40 Hz from 1 kHz up: fast enough that the filter does not
   bias real data — EMPS at 10 Hz is biased 3–7 % — well below Nyquist, and the same weighting
   for the same device sampled faster), a zero-phase velocity filter at 2.5λ (at least
   :data:`VELOCITY_MIN_HZ` below 0.3·f_s) for sgn ẋ, the
   smoothed-sign scale v_ε = 2 % of the median |v̂|, the restart interval H and the profile grids.
2. **Baseline**: ẍ + aẋ = bF by least squares on the filtered equation error ε₁ of the training
   record (:mod:`._fit`).
3. **Gap**, on the validation record: the windowed simulation error (restart every H seconds from
   the estimated state; default H = 1/a, the mechanical time constant, clipped to [20·dt, 2 s]
   and to an eighth of the validation record; the state is x and its derivative in the widest
   band the position noise allows,
   :func:`_start_states`; the first window is not scored
   where a second follows), the filtered equation error ε₁
   with θ fixed from training, and the noise floor of ε₁ from the position/force noise estimated
   by robust third differences (σ² = Var(Δ³)/20 for white noise).
4. **Which**: every candidate fitted on training, scored on validation by
   score = N_eff·ln(MS_before/MS_after) − p·ln N_eff (a validated likelihood ratio with a BIC
   parsimony penalty; N_eff corrects the sample count for the residual's autocorrelation).
   Mean squares count from the *fitted* floor, the smaller of the estimated floor and the
   validation error of every fitted model (the estimate is an upper bound only for white,
   independent noise on x and F: in closed loop F carries the controller's answer to the
   position noise, which partly cancels it in ε₁), except for fits with the flexible mode's
   columns, which can cancel position noise and count from the estimated floor.
   A candidate is *significant* when its score exceeds ``threshold``, its parameters are physical
   (F_c > 0, F_max inside the force range …), it removes at least ``min_share`` of the gap in
   excess of the fitted floor, its size (the rms of ε₁ it removes over the rms of the input's
   term b·F/Λ) is at least ``min_size`` and, if the windowed simulation models it, it does not
   make the simulated gap worse (by more than ``Criteria.max_worsening``); in closed loop at the
   noise floor a candidate that can cancel the position noise fed into F (the delay) must also
   remove its ``loop_noise_shrink`` of the simulated gap. Friction is also tried
   with the force columns masked where the axis sticks (:meth:`_Fitter.stuck`). Greedy stacking
   adds the best significant candidate until none is — or, when none is, the stand-in pair of an
   implausible candidate (asymmetric friction with F⁺ < 0 < F⁻: Coulomb friction and an offset)
   that is significant as one step. Where parsimony puts a stand-in in, stacking goes on from
   it (what the replaced candidate excluded may join).
5. **Verdict**: the first of the stack, provided the stack explains the residual's structure
   as well as its size (its residual's spectral peak is not sharper than the baseline's:
   ``Criteria.peak_growth``, unless it removes ``Criteria.explained_full`` of the excess) and a dead
   zone's look-alike does not validate better (``Criteria.dead_zone_lookalike_share``); ``none``
   when nothing is significant and the residual is noise-like (input correlation within its
   99 % bound and no spectral peak, :func:`._where.structure`; within ``floor_factor`` of the
   estimated floor the input correlation alone decides, tested in closed loop against F less
   the controller's answer to x, :func:`_feedback`) or the whole gap is below ``min_size``,
   unless some plausible candidate's validated evidence beats "no effect" by more than
   ``Criteria.tie_ratio``; ``unexplained`` when a structured gap remains that no candidate removes,
   or that the named stack leaves sharper, or in that exception.

The stages (each a function of a shared :class:`~._stages.Run`): :func:`~._stages.prepare`
(settings, baseline and noise floor) → :func:`~._stages.fit_alone` (each candidate alone) →
scores → :func:`~._stages.stack_effects` → :func:`~._stages.parsimony` →
:func:`~._stages.prune` →
:func:`~._verdict.judge` (the verdict) → :func:`~._verdict.weigh` (its confidence) →
:func:`~._verdict.report`. The thresholds are the fields of :class:`~._criteria.Criteria`.

**Confidence.** Each candidate alone has the score sᵢ = −ΔBIC against the baseline; "no effect" has
the score ``threshold`` (the significance threshold as prior odds: a candidate at the threshold ties
with it). The BIC weights over "no effect" and the plausible candidates of at least ``min_size`` are
wᵢ ∝ exp(sᵢ/2). A named verdict's confidence is its weight times min(1, explained/0.9), explained
being the share of the excess validation error (above the fitted floor) that the final stack
removes, and for a stack of candidates whose models are exact (``exact_share``: the flexible mode, a
linear resonance) times tol/rest where it leaves a rest of the excess above the tolerated tol = 1 −
exact_share (2 %), and the same for the stack fitted with the records' roles swapped, times the odds
of that reverse score s over the threshold t, 1/(1 + exp((t − s)/2)) (``final["reverse"]``: an exact
model of the device holds both ways); ``none`` gets the weight of "no effect" times 1 − h, h =
ln(D/min_size)/ln(1/min_size) the share (log scale) of the sizes worth naming below the record's
detection limit D (``noise["detection_limit"]``: the least one-parameter effect that would have
reached ``threshold``; for h, the largest of the candidates' limits: a flexible mode's gains count
only above the estimated floor, and a baseline below it hides a mode whole; and at least the size of
a fit that beats "no effect" but is refused only as below the record's resolution,
:func:`~._verdict.unresolved`). Both are discounted by the odds of the ``rivals``: implausible
candidates that alone score above the stack's summed steps (``"none"`` turns ``unexplained`` where
they beat it by the tie ratio; not a mode in closed loop, whose columns fit the position noise's
path through the controller), and a flexible mode whose columns leave a named stack nothing
significant to add where its own gains went uncounted below the floor — evidence the record prefers,
for no name of the library — and, at the odds of their score over the stack's joint score, the
out-of-library look-alikes (a dead zone's input, a drag quadratic in the velocity) that score above
the stack with fewer parameters. ``unexplained`` gets 1 − the largest share of a candidate that is
plausible or beats "no effect", at most 1 − the largest share of validation samples outside train's
position, velocity or force range (``baseline["valid_outside_train"]``: there no candidate could be
fitted), times 1 − h as ``none`` unless the periodic look-alike decided. ``ambiguous`` lists every
name (``"none"`` included) within a weight ratio of 1/20 of the verdict, so a near-tie (an offset vs
a spring with equilibrium in closed loop) is reported rather than decided by library order. A stack
that holds the whole stand-in of a candidate fitted implausibly perhaps only by bias
(``stand_in_doubtful``: asymmetric friction with one level slightly negative, against Coulomb
friction plus a larger offset) is a reading of that candidate too: its name joins ``ambiguous`` and
the verdict's confidence is shared, divided by the number of readings. Where the stack holds a
sensor artefact (``acts_on = "measurement"``), a device effect it did not stack explained alone what
the artefact explains, and holds no weight.

**Precision.** The diagnosis computes in float64 whether or not ``jax_enable_x64`` is on (as the
command line does), so the same records give the same verdict in either setting; a float32 record
is read as it is (its rounding, ~6·10⁻⁸ of |x|, stays in the data).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import jax
import numpy as np
from threadpoolctl import threadpool_limits

from .._data_checks import check_diagnosis_data
from .._errors import InputError
from .._progress import status
from .._record import Record
from .._validity import check_record
from ._candidates import AbstractCandidate
from ._criteria import Criteria
from ._library import DEFAULT_CANDIDATES
from ._result import RESERVED, Diagnosis
from ._stages import ROLES, check_candidates, fit_alone, parsimony, prepare, prune, stack_effects
from ._verdict import judge, report, uncounted, unresolved, weigh

#: BLAS threads while a diagnosis runs (:func:`_diagnosis_context`); None leaves the host's setting.
BLAS_THREADS: int | None = 1


def _diagnosis_context(fn):
    """``fn`` run with ``jax_enable_x64`` switched on and the host BLAS on one thread (both
    restored after).

    The diagnosis' host products are thin (T × at most P_MAX + 1 columns) and run beside XLA's
    own threads, which compute the filters and simulations: more BLAS threads gain nothing
    there and contend with XLA's. On an idle two-core machine four compiled diagnoses of 8-s
    pairs at 5 kHz took 20.9 s with one BLAS thread and 25.1 s with the default two, with the
    same verdicts (``benchmarks/diagnosis_speed.py --many --blas``); with another job on the
    cores, one thread took 6.0 s and 10.8 s for pairs that took 14.3 s and 17.8 s.
    :data:`BLAS_THREADS` sets the count."""

    @functools.wraps(fn)
    def run(*args, **kwargs):
        with jax.enable_x64(True), threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
            return fn(*args, **kwargs)

    return run


def _check_excites(nm: str, rec: Record) -> None:
    """Refuse a record the mass–damper can neither be fitted nor scored on: a position or a force
    that never changes (x ≡ 3 mm, F ≡ 0: a dead sensor, the wrong column, the drive off). On a
    training record nothing is identified; on a validation record every gap and effect size,
    measured against the force's term b·F, is meaningless (a dead F gave effect sizes of
    6e+298 and a confident 'unexplained')."""
    for col, unit, what in (("x", "m", "position"), ("F", "N", "force")):
        v = np.asarray(getattr(rec, col), np.float64)
        scale = float(np.max(np.abs(v))) if v.size else 0.0
        if v.size and float(np.ptp(v)) <= 64 * np.finfo(np.float64).eps * scale:
            fix = (
                "a record of the device moving (check the column mapping and the units)"
                if col == "x"
                else "a record with a varying force (an excitation; check the column mapping "
                "and that the force was logged)"
            )
            raise InputError(
                f"diagnose: the {ROLES[nm]} has a constant {what}: {col} ≡ {float(v[0]):g} "
                f"{unit} over all {v.size} samples, so it does not excite the model and nothing "
                f"can be {'identified' if nm == 'train' else 'validated'} on it. Pass {fix}."
            )


def _check_records(train: Record, valid: Record | None) -> Record:
    """The validation record (``train`` when None), or an :class:`~lionjax.InputError`."""
    check_diagnosis_data(train, valid, ROLES)  # glitches, a pair in different units
    for nm, rec in (("train", train), ("valid", valid)):
        if rec is not None and not isinstance(rec, Record):
            raise InputError(
                f"diagnose: argument {nm!r} must be a lionjax.Record (lionjax.load_record(path)), "
                f"got {type(rec).__name__}."
            )
        if rec is not None and rec.x.ndim != 1:
            raise InputError(
                f"diagnose: argument {nm!r} must be one record, x of shape (T,), got "
                f"{rec.x.shape}; loop over a batch."
            )
        if rec is not None:
            # the estimators' data checks (non-finite, out of range, unit and spike warnings)
            check_record(rec, f"diagnose: the {ROLES[nm]}")
            _check_excites(nm, rec)
    valid = train if valid is None else valid
    if abs(float(valid.dt) - float(train.dt)) > 1e-6 * float(train.dt):
        raise InputError(
            f"diagnose: train and valid must share the sample interval, got dt = "
            f"{float(train.dt)!r} s and {float(valid.dt)!r} s; resample one of them."
        )
    return valid


@_diagnosis_context
def diagnose(
    train: Record,
    valid: Record | None = None,
    *,
    candidates: Sequence[AbstractCandidate] = DEFAULT_CANDIDATES,
    filter_hz: float | None = None,
    window_s: float | None = None,
    threshold: float | None = None,
    min_share: float | None = None,
    min_size: float | None = None,
    floor_factor: float | None = None,
    max_effects: int | None = None,
    max_memory_gb: float | None = None,
    criteria: Criteria | None = None,
    streamed: bool | None = None,
    progress: bool = False,
) -> Diagnosis:
    """Diagnose the sim-to-real gap of ẍ + aẋ = bF on a record (module docstring: the method,
    the confidence, the precision).

    Arguments:
        train: training record (x [m], F [N], uniform dt).
        valid: validation record (default: ``train`` — then nothing is validated; pass one).
        candidates: the effect library (default :data:`DEFAULT_CANDIDATES`: ``offset``,
            ``coulomb_friction``, ``spring``, ``delay``, ``saturation``,
            ``position_dependent``, ``asymmetric_friction``, ``flexible_mode``, and the force
            sensor's ``force_sensor_line`` and ``force_sensor_drift``); add effects of one's own
            as ``DEFAULT_CANDIDATES + (MyEffect(),)``, ``MyEffect`` a
            :class:`~lionjax.diagnosis.ForceEffect` (docs/effects.md).
        filter_hz: corner λ/2π [Hz] of the filter (s + λ)³ (default min(f_s/25, 40 Hz)).
        window_s: restart interval H [s] of the windowed simulation error (default 1/a clipped
            to [20·dt, 2 s] and to an eighth of the validation record).
        threshold, min_share, min_size, floor_factor, max_effects: the most used thresholds
            (:class:`~lionjax.diagnosis.Criteria`: significance score, least share of the excess
            gap, least size against the input's term b·F/Λ, the noise floor's factor, the
            largest stack; defaults 10, 0.3, 0.005, 1.5, 3); where given, they replace those
            fields of ``criteria``.
        max_memory_gb: host memory [GB] the diagnosis may take (default: this machine's
            physical memory). In memory its peak grows with the records' padded lengths (about
            3.6 kB per padded sample of each record above 2¹⁸, 6.5 kB below, where designs are
            cached); streamed, by their raw per-sample signals only
            (:func:`~lionjax.diagnosis._fit.memory_estimate`). Records that would need more get
            an :class:`~lionjax.InputError` before anything is computed, not an out-of-memory
            kill, naming the least decimation that fits (:func:`decimation_for`,
            :meth:`lionjax.Record.decimate`).
        criteria: every other threshold (default :class:`~lionjax.diagnosis.Criteria`()).
        streamed: accumulate every fit's statistics chunk by chunk (:mod:`._streamed`: Grams,
            cross products with the profiles' columns and the validation residuals over chunks
            of 2¹⁶ samples, the filters' states carried between chunks), so that no filtered
            signal, design or profile column is held whole; the same verdicts as in memory, the
            numbers equal to the last bits. None (default): streamed where a record's padded
            length exceeds 2¹⁷ samples (in memory, records of up to 2¹⁷ samples peak below 2 GB).
        progress: draw a status line on stderr once the diagnosis has run a few seconds (its
            step, and the grid points of a profile done: :class:`lionjax._progress.Status`).

    Returns:
        a :class:`Diagnosis`; ``.to_json()`` gives the JSON payload (``baseline``, ``where``,
        ``effects``, ``stack``, ``verdict``, ``confidence``, ``ambiguous``, ``weights``,
        ``final``, ``steps``, ``noise``, ``settings``).
    """
    valid = _check_records(train, valid)
    if criteria is not None and not isinstance(criteria, Criteria):
        raise InputError(
            f"diagnose: argument 'criteria' must be a lionjax.diagnosis.Criteria, got "
            f"{type(criteria).__name__}."
        )
    given = {
        "threshold": threshold,
        "min_share": min_share,
        "min_size": min_size,
        "floor_factor": floor_factor,
        "max_effects": max_effects,
    }
    crit = dataclasses.replace(
        criteria or Criteria(), **{k: v for k, v in given.items() if v is not None}
    )
    library = check_candidates(candidates, RESERVED)
    with status("diagnose", enabled=progress) as st:  # the stages on stderr, if asked
        st.stage("baseline and noise floor")
        run = prepare(train, valid, library, crit, filter_hz, window_s, max_memory_gb, streamed)
        st.stage(f"fitting the {len(library)} candidates alone")
        fitted = fit_alone(run)
        alone = {
            c.name: (run.assess(run.base, fitted[c.name], c, run.floor_of([c])), fitted[c.name])
            for c in library
        }
        effects = sorted((s for s, _ in alone.values()), key=lambda s: -s.score)
        st.stage("stacking")
        stk = parsimony(run, stack_effects(run, alone))
        if stk.stands_for and stk.size < crit.max_effects:
            # a stand-in opens the stack to what the candidate it replaced excluded (asymmetric
            # friction excludes a spring, its stand-in Coulomb friction + offset does not)
            stk = parsimony(run, stack_effects(run, alone, stk))
        stk = prune(run, stk)
        st.stage("verdict")
        verdict = judge(run, stk)
        confidence = weigh(
            run,
            effects,
            stk,
            verdict,
            uncounted(run, fitted, stk),
            unresolved(run, fitted, effects),
        )
        return report(run, effects, stk, verdict, confidence)


__all__ = ["diagnose"]
