"""What :func:`lionjax.studies.study` returns: :class:`StudyResult`, the labelled grid of
answers (dims, coords, arrays of shape ``(*grid, p)``), its pooled maps and its tables."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import equinox as eqx
import numpy as np

from .._errors import InputError
from .._tables import Table

#: Quantities :meth:`StudyResult.map` pools (each of shape ``grid``).
MAP_QUANTITIES = (
    "convergence_time",
    "bias",
    "noise_amplification",
    "time_outside",
    "final_J",
)


class StudyResult(Table, eqx.Module):
    """Labelled results of :func:`study` over a grid (shape ``len(coords[d]) for d in dims``).

    Attributes:
        dims: axis names, in this order: the record axes (``"dataset"``, or any of
            ``"excitation"``, ``"operating_point"``, ``"noise_seed"`` from :class:`StudyRecords`),
            then those of ``("gain", "poles", "theta0")`` that were given.
        coords: name → list of coordinate values (dataset / excitation names; operating points
            x_ref [m]; noise seeds; gains [G = g·I] or AutoGain rates [1/s]; pole sets [rad/s];
            initial guesses).
        names: parameter names (p of them).
        theta_final: θ(T) at the end of each record, ``(*grid, p)``.
        theta_ls: the least-squares answer of each record (streamed, samples after the
            transient; equals ``least_squares(..., initial="discard")``), ``(*grid, p)``.
        convergence_time: seconds after which every |θᵢ − θ_LS,ᵢ| ≤ tolerance·|θ_LS,ᵢ| until the
            end; ``inf`` if not settled ("n.c."), NaN for grid points not computed (interrupted).
        time_outside: smooth surrogate of ``convergence_time`` [s]: Σₖ h·σ((log rₖ − log tol)/s)
            with rₖ the smooth max over parameters of |θᵢ − θ_LS,ᵢ|/|θ_LS,ᵢ| and s = ``softness``
            (see :func:`lionjax.lion_batched`), ``grid``.
        tail_std: standard deviation of θᵢ(t) over the last quarter of each record,
            ``(*grid, p)`` (in the units of θ).
        final_J: the cost ½εᵀε at the last sample, ``grid``.
        result: :class:`lionjax.RESULTS` code per grid point as an int (0 = success, −1 = not run).
        t_saved: times [s from the record start] of the decimated trajectory, ``(K,)``, or None.
        trajectory: θ every ``save_every`` samples, ``(*grid, K, p)``, or None.
        tolerance: the relative band of ``convergence_time``; softness: that of ``time_outside``.
        transient: the LS window's start [s] (None: 3·λₙ₋₁/λₙ of each filter).
        complete: False if the run was interrupted (NaN where not computed).
        gain_class: the name of the gain Module class of the ``gain`` axis (``"FixedGain"``:
            coordinates g of G = g·I; ``"AutoGain"``: rates [1/s]), or of the one gain used.
    """

    dims: tuple[str, ...] = eqx.field(static=True)
    coords: dict[str, list] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)
    theta_final: np.ndarray
    theta_ls: np.ndarray
    convergence_time: np.ndarray
    final_J: np.ndarray
    result: np.ndarray
    time_outside: np.ndarray | None = None
    tail_std: np.ndarray | None = None
    t_saved: np.ndarray | None = None
    trajectory: np.ndarray | None = None
    tolerance: float = eqx.field(static=True, default=0.02)
    softness: float = eqx.field(static=True, default=0.25)
    transient: float | None = eqx.field(static=True, default=None)
    complete: bool = eqx.field(static=True, default=True)
    gain_class: str | None = eqx.field(static=True, default=None)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(self.coords[d]) for d in self.dims)

    @property
    def bias(self) -> np.ndarray:
        """max over parameters of |θ_final − θ_LS| / |θ_LS|, shape ``grid`` (final bias vs LS)."""
        # NaN where θ_LS is 0 or NaN (a grid point that failed or was not run): no ratio exists
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.abs(self.theta_final - self.theta_ls) / np.abs(self.theta_ls)
        return np.max(np.where(self.theta_ls != 0, r, np.nan), axis=-1)

    @property
    def noise_amplification(self) -> np.ndarray:
        """maxᵢ σᵢ / |θ_LS,ᵢ|, shape ``grid`` (dimensionless).

        σᵢ is the standard deviation of θᵢ(t) over the last quarter of the record
        (``tail_std``): how much of the measurement noise the estimator passes into its
        estimate once it has converged (for a gain too low to converge it also holds the
        remaining drift). 0.01 means the estimate still wanders by 1 % (one σ).
        """
        if self.tail_std is None:
            return np.full(self.shape, np.nan)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = self.tail_std / np.abs(self.theta_ls)
        return np.max(np.where(self.theta_ls != 0, r, np.nan), axis=-1)

    def map(
        self,
        quantity: str | np.ndarray,
        keep: Sequence[str] = ("gain", "poles"),
        reduce: Literal["median", "mean", "max", "min"] = "median",
    ) -> np.ndarray:
        """``quantity`` pooled over every dim not in ``keep``: an array of shape
        ``(len(coords[keep[0]]), len(coords[keep[1]]), …)``.

        Arguments:
            quantity: a name from :data:`MAP_QUANTITIES` (``"convergence_time"`` [s], ``"bias"``,
                ``"noise_amplification"``, ``"time_outside"`` [s], ``"final_J"``) or an array of
                shape ``grid``.
            keep: the dims kept, in this order (default: the designer's (gain, pole) map).
            reduce: how the other dims are pooled (median by default: a never-settled record
                makes the median ``inf`` only if it is the majority).
        """
        if isinstance(quantity, str):
            if quantity not in MAP_QUANTITIES:
                raise InputError(
                    f"StudyResult.map: quantity must be one of {MAP_QUANTITIES} or an array of "
                    f"shape {self.shape}, got {quantity!r}."
                )
            values = np.asarray(getattr(self, quantity))
        else:
            values = np.asarray(quantity)
        if values.shape != self.shape:
            raise InputError(
                f"StudyResult.map: expected values of the grid's shape {self.shape}, got "
                f"{values.shape}."
            )
        missing = [d for d in keep if d not in self.dims]
        if missing:
            raise InputError(
                f"StudyResult.map: keep={tuple(keep)} names dims {missing} that this study does "
                f"not have (dims {self.dims})."
            )
        axes = [self.dims.index(d) for d in keep]
        moved = np.moveaxis(values, axes, range(-len(axes), 0))
        pooled = moved.reshape((-1,) + moved.shape[moved.ndim - len(axes) :])
        fn = {"median": np.median, "mean": np.mean, "max": np.max, "min": np.min}.get(reduce)
        if fn is None:
            raise InputError(
                f"StudyResult.map: reduce must be 'median', 'mean', 'max' or 'min', got {reduce!r}."
            )
        return fn(pooled, axis=0)

    def to_rows(self) -> list[dict[str, Any]]:
        """One dict per grid point (C order): its coordinates, then the values by name.

        Keys: the dims; each parameter (θ_final) and ``<name>_ls``; ``convergence_time`` [s]
        (inf: not converged); ``bias``; ``noise_amplification``; ``time_outside`` [s];
        ``final_J``; ``result``.
        """
        rows = []
        bias = self.bias
        noise = self.noise_amplification
        surr = self.time_outside if self.time_outside is not None else np.full(self.shape, np.nan)
        for idx in np.ndindex(*self.shape):
            row: dict[str, Any] = {
                d: self.coords[d][i] for d, i in zip(self.dims, idx, strict=True)
            }
            for j, n in enumerate(self.names):
                row[n] = float(self.theta_final[idx + (j,)])
            for j, n in enumerate(self.names):
                row[f"{n}_ls"] = float(self.theta_ls[idx + (j,)])
            row["convergence_time"] = float(self.convergence_time[idx])
            row["bias"] = float(bias[idx])
            row["noise_amplification"] = float(noise[idx])
            row["time_outside"] = float(surr[idx])
            row["final_J"] = float(self.final_J[idx])
            row["result"] = int(self.result[idx])
            rows.append(row)
        return rows

    def payload(self) -> dict[str, Any]:
        """The JSON document of :meth:`to_json`: ``{"dims", "coords", "names", "tolerance",
        "softness", "transient", "complete", "rows": to_rows()}``, plus
        ``"trajectory": {"t", "theta"}`` (``theta`` nested ``(*grid, K, p)``) when the study saved
        one. Non-finite numbers (``inf`` not settled, NaN not computed) are written as null;
        :meth:`to_csv` writes :meth:`to_rows` (pole sets and θ₀ joined with ';')."""
        payload: dict[str, Any] = {
            "dims": list(self.dims),
            "coords": {d: self.coords[d] for d in self.dims},
            "names": list(self.names),
            "tolerance": self.tolerance,
            "softness": self.softness,
            "transient": self.transient,
            "complete": self.complete,
            "rows": self.to_rows(),
        }
        if self.trajectory is not None:
            payload["trajectory"] = {
                "t": np.asarray(self.t_saved).tolist(),
                "theta": np.asarray(self.trajectory).tolist(),
            }
        return payload
