"""Identify many records in one batched call: one labelled row per record.

:func:`identify_batch` stacks records of any lengths and sampling intervals
(:func:`lionjax.stack_records`: shorter records are padded with their last sample and a
``lengths`` mask makes the padding contribute nothing; each record keeps its own ``dt`` and its
own filter discretisation) and identifies them all in one streamed, jitted call:

- ``method=LeastSquares()``: :func:`lionjax.least_squares_batched`, the LS answer
  θ = −(ΦᵀΦ)⁻¹Φᵀy from sufficient statistics streamed over the samples after the filter
  transient. Per record this is ``lionjax.least_squares(model, record, initial="discard")``:
  no initial-state nuisance columns, and the same check that the filter's free response does
  not excite a parameter alone after the transient (the cross products with the free responses
  streamed in the kernel, float64 records). (The single-record default ``initial="estimate"`` fits
  them and uses every sample — a different estimator, within noise of this one once the record
  is much longer than the transient.) With it the nominal standard deviations
  √diag(σ²(ΦᵀΦ)⁻¹), σ² = RSS/(N − p), as that call reports them.
- ``method=Lion(gain=..., stepper=..., theta0=..., tolerance=...)``: :func:`lionjax.lion_batched`,
  per record Lion's law (``lionjax.lion(model, record, gain=gain, stepper=stepper)``, θ at the
  end of the record), with the streamed LS answer, its condition number and the convergence
  time to within ``tolerance`` of it computed in the same call.

The method is a strategy Module (:class:`AbstractBatchMethod`) whose ``run`` fills the rows:
:func:`identify_batch` itself has no per-method branch.

Nothing is dropped or reordered: row i is ``records[i]``. A record shorter than the filter
transient is not run (``result = -1``); a record whose regressors are not excited (condition
number of the column-normalised Φ at or above ``max_condition``, for either method; a
degenerate all-zero Φ counts as infinite) or whose
answer is not finite is a row with ``result > 0`` (a :class:`lionjax.RESULTS` code) and the
reason in ``messages``; the estimates of every failed row are NaN, never a silent number.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Sequence
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from ._batched import (
    DEFAULT_EXECUTION,
    Execution,
    least_squares_batched,
    lion_batched,
    stack_records,
)
from ._errors import RESULTS, InputError, result_codes, result_message
from ._estimators import AbstractGain, AbstractSampleStepper, AutoGain, ExactStep, default_bank
from ._filters import FilterBank
from ._models import AbstractModel, Piecewise
from ._outputs import ConvergenceTime, LSStatistics
from ._record import Record
from ._solution_tools import by_name, default_transient
from ._tables import Table
from ._validity import (
    check_filter_speed,
    check_record,
    check_theta0,
    duration_fix,
    unexcited_names,
)

#: ``result`` of a record that was not run (shorter than the filter transient).
NOT_RUN = -1


class BatchIdentification(Table, eqx.Module):
    """Results of :func:`identify_batch`: one row per record (B records, p parameters).

    Attributes:
        method: the method's name, ``"ls"`` (:class:`LeastSquares`) or ``"lion"``
            (:class:`Lion`); equals: the per-record estimator the rows equal; model: the
            model's class name; names: the p parameter names (``a``, ``b``; per region
            ``a_1``, ``b_1``, … for ``Piecewise``).
        labels: one label per record (file names on the command line).
        settings: the filter, regions and gain used (plain data, written to JSON).
        theta: estimates, ``(B, p)`` [a in 1/s, b in 1/kg]; NaN for failed rows.
        std: nominal standard deviations of the LS answer ``(B, p)`` (``"ls"``; NaN for failed
            rows), ``None`` for ``"lion"`` (Lion's law has no covariance of its own).
        theta_ls: the streamed LS answer ``(B, p)`` (for ``"ls"`` the same as ``theta``).
        condition: condition number of the column-normalised regressor matrix, ``(B,)``.
        rms: root-mean-square equation error of the LS fit ``(B,)`` (``"ls"``; else None).
        final_J: Lion's cost ½εᵀε at the last sample ``(B,)`` (``"lion"``; else None).
        convergence_time: seconds after which every θᵢ(t) stays within ``tolerance`` of the LS
            answer, ``inf`` if not by the end ``(B,)`` (``"lion"``; else None).
        n_samples: samples per record ``(B,)``; dt: sampling interval per record [s] ``(B,)``.
        result: 0 success, a :class:`lionjax.RESULTS` code > 0 on failure, −1 not run, ``(B,)``.
        messages: ``""`` for a successful row, else why it failed.
        tolerance: the relative band of ``convergence_time``.
    """

    method: str = eqx.field(static=True)
    model: str = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)
    labels: tuple[str, ...] = eqx.field(static=True)
    settings: dict[str, Any] = eqx.field(static=True)
    theta: np.ndarray
    std: np.ndarray | None
    theta_ls: np.ndarray
    condition: np.ndarray
    rms: np.ndarray | None
    final_J: np.ndarray | None
    convergence_time: np.ndarray | None
    n_samples: np.ndarray
    dt: np.ndarray
    result: np.ndarray
    messages: tuple[str, ...] = eqx.field(static=True)
    tolerance: float = eqx.field(static=True, default=0.02)
    equals: str = eqx.field(static=True, default="")

    @property
    def ok(self) -> np.ndarray:
        """True where the row succeeded, ``(B,)``."""
        return self.result == 0

    def params(self) -> dict[str, np.ndarray]:
        """Estimates by name, each ``(B,)``."""
        return by_name(self.names, self.theta)

    def failures(self) -> list[tuple[str, str]]:
        """``(label, reason)`` of every failed row, in order."""
        rows = zip(self.labels, self.messages, self.result, strict=True)
        return [(label, m) for label, m, r in rows if r != 0]

    def to_rows(self) -> list[dict[str, Any]]:
        """One dict per record, in order: ``record``, ``n_samples``, ``dt``, the estimates by
        name, then ``<name>_std`` (when computed), ``<name>_ls``, ``final_J`` and
        ``convergence_time`` (Lion), ``condition``, ``rms`` (LS), ``result``, ``status``
        (``"ok"``, ``"failed"`` or ``"not run"``) and ``message``."""
        rows = []
        for i, label in enumerate(self.labels):
            row: dict[str, Any] = {
                "record": label,
                "n_samples": int(self.n_samples[i]),
                "dt": float(self.dt[i]),
            }
            row.update({n: float(self.theta[i, j]) for j, n in enumerate(self.names)})
            if self.std is not None:
                row.update({f"{n}_std": float(self.std[i, j]) for j, n in enumerate(self.names)})
            if self.method == "lion":
                row.update(
                    {f"{n}_ls": float(self.theta_ls[i, j]) for j, n in enumerate(self.names)}
                )
            if self.final_J is not None:
                row["final_J"] = float(self.final_J[i])
            if self.convergence_time is not None:
                row["convergence_time"] = float(self.convergence_time[i])
            row["condition"] = float(self.condition[i])
            if self.rms is not None:
                row["rms"] = float(self.rms[i])
            code = int(self.result[i])
            row["result"] = code
            row["status"] = "ok" if code == 0 else ("not run" if code == NOT_RUN else "failed")
            row["message"] = self.messages[i]
            rows.append(row)
        return rows

    def payload(self) -> dict[str, Any]:
        """The JSON document of :meth:`to_json`: ``{"method", "model", "names", "equals",
        "settings", "tolerance", "n_records", "n_failed", "rows": to_rows()}``; non-finite
        numbers (NaN of a failed row, ``inf`` not converged) are written as null. :meth:`to_csv`
        writes :meth:`to_rows`, one row per record (NaN and inf written as such)."""
        return {
            "method": self.method,
            "model": self.model,
            "names": list(self.names),
            "equals": self.equals,
            "settings": self.settings,
            "tolerance": self.tolerance,
            "n_records": len(self.labels),
            "n_failed": int(np.sum(self.result != 0)),
            "rows": self.to_rows(),
        }


class _Rows(eqx.Module):
    """What a method computes for the records it runs (R of them, p parameters)."""

    theta: Array  # (R, p)
    theta_ls: Array  # (R, p)
    condition: Array  # (R,)
    result: Array  # (R,) RESULTS codes
    std: Array | None = None  # (R, p)
    unexcited: Array | None = None  # (R, p): parameters the record does not identify
    rms: Array | None = None  # (R,)
    final_J: Array | None = None  # (R,)
    convergence_time: Array | None = None  # (R,)


class AbstractBatchMethod(eqx.Module):
    """How :func:`identify_batch` estimates every record: a strategy Module.

    Concrete methods: :class:`LeastSquares`, :class:`Lion`. ``name`` labels the method in the
    tables and JSON (``"ls"``, ``"lion"``) and ``equals`` states the per-record estimator the
    rows equal.
    """

    name: ClassVar[str]
    equals: ClassVar[str]
    #: The method's own columns of :class:`BatchIdentification` (the others stay None).
    columns: ClassVar[tuple[str, ...]]

    @abc.abstractmethod
    def check(self, model: AbstractModel, n_records: int) -> None:
        """Raise :class:`InputError` for settings that do not fit the model / the records."""

    @abc.abstractmethod
    def run(
        self,
        model: AbstractModel,
        batch: Record,
        rows: np.ndarray,
        *,
        bank: FilterBank,
        lengths: Array | None,
        transient: float | None,
        max_condition: float,
        execution: Execution,
    ) -> _Rows:
        """Estimate the stacked ``batch`` (records ``rows`` of the list) in one batched call."""

    @abc.abstractmethod
    def settings(self) -> dict[str, Any]:
        """The method's settings as plain data (for JSON)."""


class LeastSquares(AbstractBatchMethod):
    """Least squares from streamed statistics (:func:`lionjax.least_squares_batched`): per
    record ``lionjax.least_squares(model, record, initial="discard")``, with the nominal
    standard deviations √diag(σ²(ΦᵀΦ)⁻¹) and the rms equation error."""

    name: ClassVar[str] = "ls"
    columns: ClassVar[tuple[str, ...]] = ("std", "rms")
    equals: ClassVar[str] = (
        "lionjax.least_squares(model, record, initial='discard') per record (streamed "
        "statistics over the samples after the filter transient)"
    )

    def check(self, model, n_records):
        return None

    def run(self, model, batch, rows, *, bank, lengths, transient, max_condition, execution):
        sol = least_squares_batched(
            model,
            batch,
            bank=bank,
            lengths=lengths,
            transient=transient,
            max_condition=max_condition,
            execution=execution,
            throw=False,
        )
        return _Rows(
            theta=sol.theta,
            theta_ls=sol.theta,
            condition=sol.condition,
            result=result_codes(sol.result),
            std=sol.std,
            unexcited=sol.unexcited,
            rms=sol.rms,
        )

    def settings(self):
        return {}


class Lion(AbstractBatchMethod):
    """Lion's estimator (:func:`lionjax.lion_batched`): per record
    ``lionjax.lion(model, record, gain=gain, stepper=stepper, theta0=theta0)`` (θ at the end of
    the record), with the streamed LS answer, its condition number and the convergence time to
    within ``tolerance`` of it.

    Attributes:
        gain: :class:`lionjax.AutoGain` (default, rate 1/s) or :class:`lionjax.FixedGain`.
        stepper: ``ExactStep()`` (default; ``normalisation=μ`` for the normalised law).
        theta0: initial estimate ``(p,)`` or one per record ``(B, p)`` (default zeros).
        tolerance: relative band of the convergence time (default 0.02 = 2 %).
    """

    gain: AbstractGain = AutoGain()
    stepper: AbstractSampleStepper = ExactStep()
    theta0: ArrayLike | None = None
    tolerance: float = 0.02
    name: ClassVar[str] = "lion"
    columns: ClassVar[tuple[str, ...]] = ("final_J", "convergence_time")
    equals: ClassVar[str] = (
        "lionjax.lion(model, record, gain=gain, stepper=stepper) per record (theta at the end "
        "of the record); *_ls columns: least_squares(initial='discard')"
    )

    def __check_init__(self):
        if not isinstance(self.gain, AbstractGain):
            raise InputError(
                f"Lion: gain must be a FixedGain or AutoGain, got {type(self.gain).__name__}."
            )
        if not isinstance(self.stepper, AbstractSampleStepper):
            raise InputError(
                "Lion: stepper must be an AbstractSampleStepper (lionjax.ExactStep(...), "
                f"lionjax.EulerStep()), got {type(self.stepper).__name__}."
            )
        if not (isinstance(self.tolerance, int | float) and 0 < self.tolerance < 1):
            raise InputError(
                f"Lion: tolerance must be in (0, 1) (0.02 = 2 %), got {self.tolerance!r}."
            )

    def check(self, model, n_records):
        p = len(model.names)
        check_theta0(self.theta0, p, model.names, "identify_batch: Lion", batch=n_records)

    def run(self, model, batch, rows, *, bank, lengths, transient, max_condition, execution):
        theta0 = None
        if self.theta0 is not None:  # (p,) for all, or (n_records, p): the rows that run
            th0 = np.asarray(self.theta0, float)
            theta0 = jnp.asarray(th0[rows] if th0.ndim == 2 else th0, batch.x.dtype)
        sol = lion_batched(
            model,
            batch,
            bank=bank,
            gain=self.gain,
            stepper=self.stepper,
            theta0=theta0,
            lengths=lengths,
            outputs=(LSStatistics(transient), ConvergenceTime(tolerance=self.tolerance)),
            execution=execution,
            throw=False,
        )
        return _Rows(
            theta=sol.theta,
            theta_ls=sol.theta_ls,
            condition=sol.ls_condition,
            result=result_codes(sol.result),
            unexcited=sol.unexcited,
            final_J=sol.J,
            convergence_time=sol.t_converged,
        )

    def settings(self):
        mu = self.stepper.normalisation
        return {
            "gain": {type(self.gain).__name__: _gain_fields(self.gain)},
            "stepper": type(self.stepper).__name__,
            "normalisation": 0.0 if mu is None else float(mu),
        }


def _check(model, records, method, labels, bank) -> tuple[list[Record], tuple[str, ...]]:
    if not isinstance(model, AbstractModel):
        raise InputError(
            f"identify_batch: model must be a lionjax model (e.g. MassDamper()), got "
            f"{type(model).__name__}."
        )
    if not isinstance(method, AbstractBatchMethod):
        hint = {"ls": "LeastSquares()", "lion": "Lion(gain=..., stepper=..., theta0=...)"}.get(
            method if isinstance(method, str) else None
        )
        raise InputError(
            "identify_batch: method must be a method Module, lionjax.LeastSquares() or "
            f"lionjax.Lion(...), got {method!r}"
            + (f"; for method={method!r} pass method=lionjax.{hint}." if hint else ".")
        )
    if isinstance(records, Record):
        raise InputError(
            "identify_batch: records must be a list of Records (each x of shape (T,), any "
            "lengths), got one Record; pass [record], or use least_squares_batched / "
            "lion_batched for an already stacked batch."
        )
    records = list(records)
    if not records:
        raise InputError("identify_batch: got no records; pass at least one.")
    for i, r in enumerate(records):
        if not isinstance(r, Record):
            raise InputError(
                f"identify_batch: records[{i}] is a {type(r).__name__}, expected a Record "
                "(lionjax.load_record reads one from a file)."
            )
        if r.x.ndim != 1:
            raise InputError(
                f"identify_batch: records[{i}] has x of shape {r.x.shape}, expected one record "
                "of shape (T,); list the records of a batch one by one."
            )
    if labels is None:
        labels = tuple(str(i) for i in range(len(records)))
    else:
        labels = tuple(str(v) for v in labels)
        if len(labels) != len(records):
            raise InputError(
                f"identify_batch: got {len(labels)} labels for {len(records)} records; give "
                "one label per record."
            )
    if not isinstance(bank, FilterBank):
        raise InputError(f"identify_batch: bank must be a FilterBank, got {type(bank).__name__}.")
    if bank.coeffs.ndim != 1:
        raise InputError(
            f"identify_batch: bank must be one filter (coeffs of shape (n,)), got coeffs of "
            f"shape {bank.coeffs.shape}."
        )
    method.check(model, len(records))
    return records, labels


def identify_batch(
    model: AbstractModel,
    records: Sequence[Record],
    *,
    method: AbstractBatchMethod | None = None,
    labels: Sequence[str] | None = None,
    bank: FilterBank | None = None,
    transient: float | None = None,
    max_condition: float = 1e7,
    execution: Execution = DEFAULT_EXECUTION,
) -> BatchIdentification:
    """Identify every record of a list in one batched call; one labelled row per record.

    Arguments:
        model: the model structure, the same for every record (``MassDamper()``,
            ``Piecewise(bounds)``).
        records: records of shape ``(T,)`` each, any lengths T and sampling intervals dt
            (padded and masked; each record keeps its own dt and filter discretisation).
        method: :class:`LeastSquares` ``()`` (default; equals ``least_squares(...,
            initial="discard")`` per record) or :class:`Lion` ``(gain=..., stepper=...,
            theta0=..., tolerance=...)`` (equals ``lion(..., gain=gain, stepper=stepper)`` per
            record).
        labels: one label per record (default ``"0"``, ``"1"``, …).
        bank: the filter Λ (default :func:`lionjax.default_bank`).
        transient: seconds after a record's start excluded from the LS statistics and from the
            gain's R (default 3·λₙ₋₁/λₙ); records shorter than it are not run.
        max_condition: rows whose condition number reaches this are failures (not excited).
        execution: the performance knobs of :func:`lionjax.lion_batched` (one CPU device
            already uses every core).

    Returns:
        a :class:`BatchIdentification`: row i is ``records[i]``; failures are rows with
        ``result != 0``, NaN estimates and a message (nothing is raised for them).

    Raises:
        InputError: for a bad argument (naming it); never for a record that merely fails.
    """
    given = bank
    bank = default_bank() if bank is None else bank
    method = LeastSquares() if method is None else method
    records, labels = _check(model, records, method, labels, bank)
    if given is None:  # sampling-aware: one filter within the speed bound for every record
        bank = default_bank(max(float(r.dt) for r in records))
    B = len(records)
    p = len(model.names)
    if not (max_condition > 1):
        raise InputError(f"identify_batch: max_condition must be > 1, got {max_condition!r}.")
    tr = float(default_transient(bank)) if transient is None else float(transient)
    if not (np.isfinite(tr) and tr >= 0):
        raise InputError(f"identify_batch: transient must be ≥ 0 seconds, got {transient!r}.")

    n = np.array([r.n_samples for r in records])
    dt = np.array([float(r.dt) for r in records])
    check_filter_speed(bank, dt, "identify_batch")
    full = lambda *shape: np.full((B,) + shape, np.nan)
    theta, theta_ls, condition = full(p), full(p), full()
    result = np.full(B, NOT_RUN, int)
    messages = [""] * B
    nonfinite = result_codes(RESULTS.nonfinite).item()
    # The validity layer per record: bad data (non-finite, out of range) is a failed row, not
    # an error for the batch; the units/spike warnings name the record.
    bad_data = np.zeros(B, bool)
    for i, r in enumerate(records):
        try:
            check_record(r, f"identify_batch: record {labels[i]!r}")
        except InputError as e:
            bad_data[i] = True
            result[i] = nonfinite
            messages[i] = str(e)
    # The same rule as check_duration for one record: the record must outlast the transient.
    run = np.flatnonzero((dt * (n - 1) >= tr) & ~bad_data)
    why = (
        f"3·λₙ₋₁/λₙ of Λ with coefficients {np.asarray(bank.coeffs).tolist()}"
        if transient is None
        else "the transient argument"
    )
    for i in np.flatnonzero((dt * (n - 1) < tr) & ~bad_data):
        messages[i] = (
            f"not run: the record lasts {dt[i] * (n[i] - 1):.4g} s ({n[i]} samples), shorter "
            f"than the filter transient {tr:.4g} s ({why}). "
            + duration_fix(dt[i] * (n[i] - 1), dt[i])
        )
    optional: dict[str, np.ndarray | None] = {
        key: (full(p) if key == "std" else full()) if key in method.columns else None
        for key in ("std", "rms", "final_J", "convergence_time")
    }
    if run.size:
        batch, lengths = stack_records([records[i] for i in run])
        lengths = None if np.all(n[run] == n[run[0]]) else lengths  # nothing padded
        rows = method.run(
            model,
            batch,
            run,
            bank=bank,
            lengths=lengths,
            transient=transient,
            max_condition=max_condition,
            execution=execution,
        )
        theta[run] = np.asarray(rows.theta)
        theta_ls[run] = np.asarray(rows.theta_ls)
        condition[run] = np.asarray(rows.condition)
        for key, column in optional.items():
            if column is not None:
                column[run] = np.asarray(getattr(rows, key))
        codes = np.asarray(rows.result).astype(int)
        # A condition number is ≥ 1; below that (0 from an all-zero ΦᵀΦ, or NaN) the
        # regressors are degenerate: singular, so infinite.
        cond = condition[run]
        cond[~(cond >= 1)] = np.inf
        condition[run] = cond
        # Unexcited is the cause whatever else followed (e.g. a NaN solve); Lion with a
        # FixedGain runs on any record, so an unexcited one is a failure here too.
        unidentifiable = result_codes(RESULTS.unidentifiable).item()
        codes[~(cond < max_condition)] = unidentifiable
        result[run] = codes
        mask = None if rows.unexcited is None else np.asarray(rows.unexcited)
        for j, (i, code) in enumerate(zip(run, codes, strict=True)):
            if code != 0:
                messages[i] = result_message(int(code))
            if code == unidentifiable:
                messages[i] += f" (condition number {condition[i]:.3g}, bound {max_condition:.3g})"
                names = [] if mask is None else unexcited_names(model.names, mask[j])
                if names:
                    messages[i] += f" Not identified: {', '.join(names)}."
    failed = result != 0
    theta[failed] = np.nan
    theta_ls[failed] = np.nan
    for key in ("std", "convergence_time"):
        if optional[key] is not None:
            optional[key][failed] = np.nan
    settings = {
        "filter": {
            "coeffs": np.asarray(bank.coeffs).tolist(),
            "unit_dc_gain": bank.unit_dc_gain,
            "transient_s": tr,
        },
        "regions": list(model.bounds) if isinstance(model, Piecewise) else [],
        **method.settings(),
    }
    return BatchIdentification(
        method=method.name,
        model=type(model).__name__,
        names=tuple(model.names),
        labels=labels,
        settings=settings,
        theta=theta,
        std=optional["std"],
        theta_ls=theta_ls,
        condition=condition,
        rms=optional["rms"],
        final_J=optional["final_J"],
        convergence_time=optional["convergence_time"],
        n_samples=n,
        dt=dt,
        result=result,
        messages=tuple(messages),
        tolerance=getattr(method, "tolerance", 0.02),
        equals=method.equals,
    )


def _gain_fields(gain: AbstractGain) -> dict[str, Any]:
    """The gain Module's fields as plain data (e.g. {"rate": 1.0, "max_condition": 1e12})."""
    out = {}
    for f in dataclasses.fields(gain):
        a = np.asarray(getattr(gain, f.name))
        out[f.name] = a.tolist() if a.ndim else a.item()
    return out
