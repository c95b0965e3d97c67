"""``lionjax.diagnose``: where, which and how far is the sim-to-real gap, on recorded data alone
(layer 3). A pipeline of functions of immutable values (docs/method.md, "Diagnosis", states
every rule and why it holds): :func:`~._run.prepare` (settings, the baseline ẍ + aẋ = bF, the
noise floor of ε₁), :func:`~._stages.fit_alone`, :func:`~._stages.stack_effects`,
:func:`~._stages.parsimony`, :func:`~._stages.prune`, :func:`~._verdict.judge`,
:func:`~._confidence.weigh` and :func:`~._report.report`."""

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
from ._confidence import weigh
from ._criteria import Criteria
from ._problem import ROLES
from ._report import report
from ._result import RESERVED, Diagnosis
from ._run import prepare
from ._stages import check_candidates, fit_alone, parsimony, prune, stack_effects
from ._verdict import judge
from .effects import DEFAULT_CANDIDATES, DEFAULT_LOOKALIKES, AbstractCandidate

#: BLAS threads while a diagnosis runs; None leaves the host's setting. The host products are
#: thin (T × at most P_MAX + 1) and run beside XLA's threads: more BLAS threads gain nothing and
#: contend with XLA's (``benchmarks/diagnosis_speed.py --many --blas`` measures it).
BLAS_THREADS: int | None = 1


def _diagnosis_context(fn):
    """``fn`` run with ``jax_enable_x64`` on and :data:`BLAS_THREADS` (both restored after)."""

    @functools.wraps(fn)
    def run(*args, **kwargs):
        with jax.enable_x64(True), threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
            return fn(*args, **kwargs)

    return run


def _check_excites(nm: str, rec: Record) -> None:
    """Refuse a record whose position or force never changes (a dead sensor, the wrong column,
    the drive off): nothing can be identified on it, nor an effect sized against b·F."""
    for col, unit, what, fix in (
        ("x", "m", "position", "of the device moving (check the column mapping and the units)"),
        ("F", "N", "force", "with a varying force (check the column mapping and the logging)"),
    ):
        v = np.asarray(getattr(rec, col), np.float64)
        scale = float(np.max(np.abs(v))) if v.size else 0.0
        if v.size and float(np.ptp(v)) <= 64 * np.finfo(np.float64).eps * scale:
            raise InputError(
                f"diagnose: the {ROLES[nm]} has a constant {what}: {col} ≡ {float(v[0]):g} "
                f"{unit} over all {v.size} samples, so it does not excite the model and nothing "
                f"can be {'identified' if nm == 'train' else 'validated'} on it. Pass a record "
                f"{fix}."
            )


def _check_records(train: Record, valid: Record | None) -> Record:
    """The validation record (``train`` when None), or an :class:`~lionjax.InputError`."""
    check_diagnosis_data(train, valid, ROLES)  # glitches, a pair in different units
    for nm, rec in (("train", train), ("valid", valid)):
        if rec is None:
            continue
        if not isinstance(rec, Record):
            raise InputError(
                f"diagnose: argument {nm!r} must be a lionjax.Record (lionjax.load_record(path)), "
                f"got {type(rec).__name__}."
            )
        if rec.x.ndim != 1:
            raise InputError(
                f"diagnose: argument {nm!r} must be one record, x of shape (T,), got "
                f"{rec.x.shape}; loop over a batch."
            )
        # the estimators' data checks (non-finite, out of range, unit and spike warnings)
        check_record(rec, f"diagnose: the {ROLES[nm]}")
        _check_excites(nm, rec)
    valid = train if valid is None else valid
    if abs(float(valid.dt) - float(train.dt)) > 1e-6 * float(train.dt):
        raise InputError(
            f"diagnose: train and valid must share the sample interval, got dt = "
            f"{float(train.dt)!r} s and {float(valid.dt)!r} s; resample one of them."
        )
    if valid.units != train.units:
        raise InputError(
            f"diagnose: the training record is {train.units} and the validation record "
            f"{valid.units} (Record.units); load both in the same units."
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
    streamed: bool | int | None = None,
    progress: bool = False,
) -> Diagnosis:
    """Diagnose the sim-to-real gap of ẍ + aẋ = bF: where it lies, which unmodelled effect
    explains it, with what confidence (docs/method.md, "Diagnosis" and "The confidence").

    It computes in float64 whether or not ``jax_enable_x64`` is on, so the same records give
    the same verdict in either setting; a float32 record keeps its rounding (~6·10⁻⁸ of |x|).

    Arguments:
        train: training record (x [m], F [N], uniform dt; or x [rad], F [N·m] with
            ``units="rotary"``, :attr:`lionjax.Record.units`, which the report's units follow).
        valid: validation record (default: ``train`` — then nothing is validated; pass one).
        candidates: the effect library (default :data:`DEFAULT_CANDIDATES`: ``offset``,
            ``coulomb_friction``, ``spring``, ``delay``, ``saturation``,
            ``position_dependent``, ``asymmetric_friction``, ``flexible_mode``, and the force
            sensor's ``force_sensor_line`` and ``force_sensor_drift``); add one's own as
            ``DEFAULT_CANDIDATES + (MyEffect(),)``, ``MyEffect`` a
            :class:`~lionjax.diagnosis.ForceEffect` (docs/effects.md).
        filter_hz: corner λ/2π [Hz] of the filter (s + λ)³ (default min(f_s/25, 40 Hz)).
        window_s: restart interval H [s] of the windowed simulation error (default 1/a clipped
            to [20·dt, 2 s] and to an eighth of the validation record).
        threshold, min_share, min_size, floor_factor, max_effects: the most used fields of
            ``criteria`` (significance score, least share of the excess gap, least size against
            the input's term b·F/Λ, the noise floor's factor, the largest stack; defaults 10,
            0.3, 0.005, 1.5, 3), replaced where given.
        max_memory_gb: host memory [GB] the diagnosis may take (default: this machine's
            physical memory): in one chunk about 6.5 kB per padded sample of each record,
            streamed about 1.2 GB plus 160 B per sample. Records that would need more get an
            :class:`~lionjax.InputError` before anything is computed, naming the least
            decimation that fits (:func:`decimation_for`, :meth:`lionjax.Record.decimate`).
        criteria: every threshold (default :class:`~lionjax.diagnosis.Criteria`()).
        streamed: read the records in chunks of 2¹⁶ samples (or of ``streamed`` samples, an
            int ≥ 16), every fit's statistics accumulated chunk by chunk with the filters'
            states carried across, so that no filtered signal, design or profile column is
            held whole: the same verdicts as in one chunk, the numbers equal to the last bits.
            False: one chunk. None (default): chunks where a record's padded length exceeds
            2¹⁷ samples (in one chunk, records of up to 2¹⁷ samples peak below 2 GB).
        progress: draw a status line on stderr (the stage, the points of a search done) once
            the diagnosis has run a few seconds.

    Returns:
        a :class:`Diagnosis`; ``.to_json()`` gives its JSON payload.
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
        args = (DEFAULT_LOOKALIKES, crit, filter_hz, window_s, max_memory_gb, streamed)
        return _pipeline(prepare(train, valid, library, *args), st)


def _pipeline(run, st) -> Diagnosis:
    """Every candidate alone, the stack, its verdict and confidence; ``st`` the status line."""
    st.stage("fitting the candidates alone")
    run, fitted = fit_alone(run)
    by_name = run.by_name
    alone = {
        name: (run.assess(run.base, f, by_name[name], run.floor_of([by_name[name]])), f)
        for name, f in fitted.items()
    }
    effects = sorted((s for s, _ in alone.values()), key=lambda s: -s.score)
    st.stage("stacking")
    run, stk = stack_effects(run, alone)
    stk = parsimony(run, stk)
    if stk.stands_for:
        # a stand-in opens the stack to what the candidate it replaced excluded (asymmetric
        # friction excludes a spring, its stand-in Coulomb friction + offset does not)
        run, stk = stack_effects(run, alone, stk)
        stk = parsimony(run, stk)
    stk = prune(run, stk)
    st.stage("verdict")
    verdict = judge(run, stk)
    confidence = weigh(run, effects, stk, verdict, fitted)
    st.stage("where the gap lies: the regions")
    return report(run, effects, stk, verdict, confidence).in_units(run.problem.train.units)
