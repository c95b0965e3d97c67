"""Identify many records in one batched call: one labelled row per record.

:func:`identify_batch` stacks records of any lengths and sampling intervals
(:func:`lionjax.stack_records`: shorter records are padded with their last sample and a
``lengths`` mask makes the padding contribute nothing; each record keeps its own ``dt`` and its
own filter discretisation) and identifies them all in one streamed, jitted call:

- ``method="ls"``: :func:`lionjax.least_squares_batched`, the LS answer θ = −(ΦᵀΦ)⁻¹Φᵀy from
  sufficient statistics streamed over the samples after the filter transient. Per record this
  is ``lionjax.least_squares(model, record, initial="discard")``: no initial-state nuisance
  columns. (The single-record default ``initial="estimate"`` fits them and uses every sample —
  a different estimator, within noise of this one once the record is much longer than the
  transient.) With it the nominal standard deviations √diag(σ²(ΦᵀΦ)⁻¹), σ² = RSS/(N − p), as
  that call reports them.
- ``method="lion"``: :func:`lionjax.lion_batched`, per record Lion's law with the exact step
  (``lionjax.lion(model, record, stepper=ExactStep())``, θ at the end of the record), with the
  streamed LS answer, its condition number and the convergence time to within ``tolerance`` of
  it computed in the same call.

Nothing is dropped or reordered: row i is ``records[i]``. A record shorter than the filter
transient is not run (``result = -1``); a record whose regressors are not excited (condition
number of the column-normalised Φ at or above ``max_condition``, for either method; a
degenerate all-zero Φ counts as infinite) or whose
answer is not finite is a row with ``result > 0`` (a :class:`lionjax.RESULTS` code) and the
reason in ``messages``; the estimates of every failed row are NaN, never a silent number.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from ._batched import least_squares_batched, lion_batched, stack_records
from ._errors import RESULTS, InputError, result_codes
from ._estimators import AbstractGain, AutoGain, default_bank
from ._filters import FilterBank
from ._models import AbstractModel, Piecewise
from ._record import Record
from ._solution import default_transient
from ._tables import write_csv, write_json

#: ``result`` of a record that was not run (shorter than the filter transient).
NOT_RUN = -1

_EQUALS = {
    "ls": "lionjax.least_squares(model, record, initial='discard') per record (streamed "
    "statistics over the samples after the filter transient)",
    "lion": "lionjax.lion(model, record, stepper=ExactStep()) per record (theta at the end of "
    "the record); *_ls columns: least_squares(initial='discard')",
}


class BatchIdentification(eqx.Module):
    """Results of :func:`identify_batch`: one row per record (B records, p parameters).

    Attributes:
        method: ``"ls"`` or ``"lion"``; model: the model's class name; names: the p parameter
            names (``a``, ``b``; per region ``a_1``, ``b_1``, … for ``Piecewise``).
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

    @property
    def ok(self) -> np.ndarray:
        """True where the row succeeded, ``(B,)``."""
        return self.result == 0

    def params(self) -> dict[str, np.ndarray]:
        """Estimates by name, each ``(B,)``."""
        return {n: self.theta[:, i] for i, n in enumerate(self.names)}

    def failures(self) -> list[tuple[str, str]]:
        """``(label, reason)`` of every failed row, in order."""
        rows = zip(self.labels, self.messages, self.result, strict=True)
        return [(label, m) for label, m, r in rows if r != 0]

    def to_records(self) -> list[dict[str, Any]]:
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

    def to_json(self, path: str | Path) -> Path:
        """Write ``{"method", "model", "names", "equals", "settings", "tolerance", "n_records",
        "n_failed", "rows": to_records()}``; non-finite numbers (NaN of a failed row, ``inf``
        not converged) are written as null."""
        payload = {
            "method": self.method,
            "model": self.model,
            "names": list(self.names),
            "equals": _EQUALS[self.method],
            "settings": self.settings,
            "tolerance": self.tolerance,
            "n_records": len(self.labels),
            "n_failed": int(np.sum(self.result != 0)),
            "rows": self.to_records(),
        }
        return write_json(path, payload)

    def to_csv(self, path: str | Path) -> Path:
        """Write :meth:`to_records` as CSV, one row per record (NaN and inf written as such)."""
        return write_csv(path, self.to_records())


def _check(model, records, method, labels, bank, gain) -> tuple[list[Record], tuple[str, ...]]:
    if not isinstance(model, AbstractModel):
        raise InputError(
            f"identify_batch: model must be a lionjax model (e.g. MassDamper()), got "
            f"{type(model).__name__}."
        )
    if method not in ("ls", "lion"):
        raise InputError(f"identify_batch: method must be 'ls' or 'lion', got {method!r}.")
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
    if not isinstance(gain, AbstractGain):
        raise InputError(
            f"identify_batch: gain must be a FixedGain or AutoGain, got {type(gain).__name__}."
        )
    return records, labels


def identify_batch(
    model: AbstractModel,
    records: Sequence[Record],
    *,
    method: Literal["ls", "lion"] = "ls",
    labels: Sequence[str] | None = None,
    bank: FilterBank | None = None,
    gain: AbstractGain | None = None,
    normalisation: float | None = None,
    theta0: ArrayLike | None = None,
    transient: float | None = None,
    max_condition: float = 1e7,
    tolerance: float = 0.02,
    shard: bool = True,
) -> BatchIdentification:
    """Identify every record of a list in one batched call; one labelled row per record.

    Arguments:
        model: the model structure, the same for every record (``MassDamper()``,
            ``Piecewise(bounds)``).
        records: records of shape ``(T,)`` each, any lengths T and sampling intervals dt
            (padded and masked; each record keeps its own dt and filter discretisation).
        method: ``"ls"`` (default; equals ``least_squares(..., initial="discard")`` per record)
            or ``"lion"`` (equals ``lion(..., stepper=ExactStep())`` per record).
        labels: one label per record (default ``"0"``, ``"1"``, …).
        bank: the filter Λ (default :func:`lionjax.default_bank`).
        gain: Lion's gain (``"lion"`` only; default ``AutoGain(1.0)``); normalisation: μ of the
            normalised law (None or 0: the plain law); theta0: Lion's initial estimate ``(p,)``
            or ``(B, p)`` (default zeros).
        transient: seconds after a record's start excluded from the LS statistics and from the
            gain's R (default 3·λₙ₋₁/λₙ); records shorter than it are not run.
        max_condition: rows whose condition number reaches this are failures (not excited).
        tolerance: relative band of Lion's ``convergence_time`` (default 2 %).
        shard: as :func:`lionjax.lion_batched` (one CPU device already uses every core).

    Returns:
        a :class:`BatchIdentification`: row i is ``records[i]``; failures are rows with
        ``result != 0``, NaN estimates and a message (nothing is raised for them).

    Raises:
        InputError: for a bad argument (naming it); never for a record that merely fails.
    """
    bank = default_bank() if bank is None else bank
    gain = AutoGain() if gain is None else gain
    records, labels = _check(model, records, method, labels, bank, gain)
    B = len(records)
    p = len(model.names)
    if theta0 is not None:
        th0 = np.asarray(theta0, float)
        if th0.shape not in ((p,), (B, p)):
            raise InputError(
                f"identify_batch: theta0 must have shape ({p},) or ({B}, {p}) for parameters "
                f"{model.names}, got {th0.shape}."
            )
        theta0 = np.broadcast_to(th0, (B, p))
    if not (max_condition > 1):
        raise InputError(f"identify_batch: max_condition must be > 1, got {max_condition!r}.")
    tr = float(default_transient(bank)) if transient is None else float(transient)
    if not (np.isfinite(tr) and tr >= 0):
        raise InputError(f"identify_batch: transient must be ≥ 0 seconds, got {transient!r}.")

    mu = None if normalisation is None or normalisation == 0 else float(normalisation)
    n = np.array([r.n_samples for r in records])
    dt = np.array([float(r.dt) for r in records])
    theta = np.full((B, p), np.nan)
    theta_ls = np.full((B, p), np.nan)
    condition = np.full(B, np.nan)
    rms = np.full(B, np.nan) if method == "ls" else None
    final_J = np.full(B, np.nan) if method == "lion" else None
    t_conv = np.full(B, np.nan) if method == "lion" else None
    std = np.full((B, p), np.nan) if method == "ls" else None
    result = np.full(B, NOT_RUN, int)
    messages = [""] * B
    # The same rule as check_duration for one record: the record must outlast the transient.
    run = np.flatnonzero(dt * (n - 1) >= tr)
    why = (
        f"3·λₙ₋₁/λₙ of Λ with coefficients {np.asarray(bank.coeffs).tolist()}"
        if transient is None
        else "the transient argument"
    )
    for i in np.flatnonzero(dt * (n - 1) < tr):
        messages[i] = (
            f"not run: the record lasts {dt[i] * (n[i] - 1):.4g} s ({n[i]} samples), shorter "
            f"than the filter transient {tr:.4g} s ({why}); use a longer record or faster "
            "filter poles."
        )

    if run.size:
        batch, lengths = stack_records([records[i] for i in run])
        lengths = None if np.all(n[run] == n[run[0]]) else lengths  # nothing padded
        if method == "ls":
            sol = least_squares_batched(
                model,
                batch,
                bank=bank,
                lengths=lengths,
                transient=transient,
                max_condition=max_condition,
                shard=shard,
                throw=False,
            )
            theta[run] = np.asarray(sol.theta)
            theta_ls[run] = theta[run]
            std[run] = np.asarray(sol.std)
            condition[run] = np.asarray(sol.condition)
            rms[run] = np.asarray(sol.rms)
        else:
            sol = lion_batched(
                model,
                batch,
                bank=bank,
                gain=gain,
                normalisation=mu,
                theta0=None if theta0 is None else jnp.asarray(theta0[run], batch.x.dtype),
                lengths=lengths,
                ls=True,
                convergence=True,
                tolerance=tolerance,
                transient=transient,
                shard=shard,
                throw=False,
            )
            theta[run] = np.asarray(sol.theta)
            theta_ls[run] = np.asarray(sol.theta_ls)
            condition[run] = np.asarray(sol.ls_condition)
            final_J[run] = np.asarray(sol.J)
            t_conv[run] = np.asarray(sol.t_converged)
        codes = result_codes(sol.result).astype(int)
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
        for i, code in zip(run, codes, strict=True):
            if code != 0:
                messages[i] = RESULTS._index_to_message[int(code)]
            if code == unidentifiable:
                messages[i] += f" (condition number {condition[i]:.3g}, bound {max_condition:.3g})"
    failed = result != 0
    theta[failed] = np.nan
    if std is not None:
        std[failed] = np.nan
    if method == "lion":
        theta_ls[failed] = np.nan
        t_conv[failed] = np.nan
    settings = {
        "filter": {
            "coeffs": np.asarray(bank.coeffs).tolist(),
            "unit_dc_gain": bank.unit_dc_gain,
            "transient_s": tr,
        },
        "regions": list(model.bounds) if isinstance(model, Piecewise) else [],
    }
    if method == "lion":
        settings["gain"] = {type(gain).__name__: _gain_fields(gain)}
        settings["normalisation"] = 0.0 if mu is None else float(mu)
    return BatchIdentification(
        method=method,
        model=type(model).__name__,
        names=tuple(model.names),
        labels=labels,
        settings=settings,
        theta=theta,
        std=std,
        theta_ls=theta_ls,
        condition=condition,
        rms=rms,
        final_J=final_J,
        convergence_time=t_conv,
        n_samples=n,
        dt=dt,
        result=result,
        messages=tuple(messages),
        tolerance=tolerance,
    )


def _gain_fields(gain: AbstractGain) -> dict[str, Any]:
    """The gain Module's fields as plain data (e.g. {"rate": 1.0, "max_condition": 1e12})."""
    out = {}
    for f in dataclasses.fields(gain):
        a = np.asarray(getattr(gain, f.name))
        out[f.name] = a.tolist() if a.ndim else a.item()
    return out
