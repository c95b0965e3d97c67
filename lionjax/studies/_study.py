"""Study grids: Lion's estimator over records × gains × filter poles × initial guesses.

:func:`study` flattens the whole grid — datasets (or twin records labelled by excitation,
operating point and noise seed), gains, filter pole sets and initial guesses — into the batch
axis of the batched estimator (:func:`lionjax.lion_batched` with one gain and one filter per batch
element: a gain Module whose value has shape ``(B,)`` and a :class:`~lionjax.FilterBank` whose
coefficients have shape ``(B, n)``), runs it in chunks (one jitted call per
chunk, every chunk the same size so it compiles once) with a progress bar, and reshapes the
answers into a labelled :class:`StudyResult` (dims, coords, arrays of shape ``(*grid, p)``).
Memory per grid point does not grow with the record length: the estimator streams the records
and keeps θ(T), the cost, the LS statistics, the convergence time and the tail statistics (plus
an optional decimated trajectory).

:func:`study_records` simulates seeded twin records for it, optionally as a labelled grid over
excitations × operating points × noise seeds (:class:`StudyRecords`), whose labels become the
leading dims of the :class:`StudyResult`.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._batched import DEFAULT_EXECUTION, Execution, lion_batched, stack_records
from .._errors import InputError, result_codes
from .._estimators import AbstractGain, AbstractSampleStepper, AutoGain, FixedGain, default_bank
from .._filters import FilterBank
from .._least_squares import check_identified
from .._models import AbstractModel
from .._outputs import ConvergenceTime, LSStatistics, TailStatistics, Trajectory
from .._progress import run_chunks
from .._record import Record
from .._tables import Table
from .._validity import MAX_POLE_DT, check_duration, check_filter_speed, check_record, pole_dt

#: Names a record axis of a study may have (``dataset`` for plain lists of records).
RECORD_DIMS = ("dataset", "excitation", "operating_point", "noise_seed")
#: Quantities :meth:`StudyResult.map` pools (each of shape ``grid``).
MAP_QUANTITIES = (
    "convergence_time",
    "bias",
    "noise_amplification",
    "time_outside",
    "final_J",
)


class StudyRecords(eqx.Module):
    """Records labelled by a grid of record axes (the leading dims of a :func:`study`).

    A sequence of :class:`~lionjax.Record` (``len``, indexing and iteration give the records
    in C order over ``dims``), e.g. from :func:`study_records`.

    Attributes:
        records: the records, ``prod(shape)`` of them, C order over ``dims``.
        dims: record axis names, from :data:`RECORD_DIMS` (``"dataset"``, ``"excitation"``,
            ``"operating_point"``, ``"noise_seed"``), each at most once.
        coords: axis name → list of labels (excitation names; operating points x_ref [m];
            noise seeds; dataset names).
    """

    records: tuple[Record, ...]
    dims: tuple[str, ...] = eqx.field(static=True)
    coords: dict[str, list] = eqx.field(static=True)

    def __check_init__(self):
        if len(set(self.dims)) != len(self.dims) or any(d not in RECORD_DIMS for d in self.dims):
            raise InputError(
                f"StudyRecords: dims must be distinct names from {RECORD_DIMS}, got {self.dims}."
            )
        if set(self.coords) != set(self.dims):
            raise InputError(
                f"StudyRecords: coords must have one list per dim {self.dims}, got keys "
                f"{tuple(self.coords)}."
            )
        n = int(np.prod([len(self.coords[d]) for d in self.dims]))
        if len(self.records) != n or n == 0:
            raise InputError(
                f"StudyRecords: {len(self.records)} records for a grid of shape {self.shape} "
                f"({n} records expected, at least one)."
            )

    @property
    def shape(self) -> tuple[int, ...]:
        """Grid shape, ``len(coords[d])`` for d in ``dims``."""
        return tuple(len(self.coords[d]) for d in self.dims)

    def __len__(self) -> int:
        return len(self.records)

    def __getitem__(self, i: int) -> Record:
        return self.records[i]

    def __iter__(self) -> Iterator[Record]:
        return iter(self.records)

    def labels(self) -> list[dict[str, Any]]:
        """One ``{dim: label}`` dict per record, in the order of ``records``."""
        return [
            {d: self.coords[d][i] for d, i in zip(self.dims, idx, strict=True)}
            for idx in np.ndindex(*self.shape)
        ]


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


def _as_batch(records) -> tuple[Record, np.ndarray, tuple[str, ...], dict[str, list] | None]:
    """(batch with dt/t0 (D,), lengths (D,), record dims, their coords or None for defaults)."""
    if isinstance(records, StudyRecords):
        batch, lengths = stack_records(list(records.records))
        return batch, np.asarray(lengths), records.dims, dict(records.coords)
    if isinstance(records, Record):
        if records.x.ndim == 1:
            batch, lengths = stack_records([records])
            return batch, np.asarray(lengths), (), None
        if records.x.ndim != 2:
            raise InputError(
                f"study: records must be one record (T,) or a batch (D, T), got x of shape "
                f"{records.x.shape}."
            )
        D, T = records.x.shape
        batch = Record(
            records.x,
            records.F,
            jnp.broadcast_to(records.dt, (D,)),
            jnp.broadcast_to(records.t0, (D,)),
        )
        return batch, np.full(D, T), ("dataset",), None
    records = list(records)
    if not records or not all(isinstance(r, Record) for r in records):
        raise InputError(
            "study: records must be a Record (one or a batch), a non-empty list of Records or a "
            f"StudyRecords, got {type(records).__name__}."
        )
    batch, lengths = stack_records(records)
    return batch, np.asarray(lengths), ("dataset",), None


def _labels(values, dim: str) -> tuple[list, list]:
    """(labels, items) of one record axis given as a list or a {label: item} mapping."""
    if isinstance(values, Mapping):
        return [str(k) for k in values], list(values.values())
    items = list(values)
    if not items:
        raise InputError(f"study_records: {dim} must be a non-empty list, got {values!r}.")
    return None, items


def study_records(
    n: int | None = None,
    n_samples: int = 3000,
    dt: float = 1e-3,
    force_noise: float = 0.01,
    seed: int = 0,
    *,
    excitations: Sequence[Any] | Mapping[str, Any] | str | None = None,
    operating_points: Sequence[float] | str | None = None,
    noise_seeds: Sequence[int] | None = None,
    plant: Any | None = None,
) -> StudyRecords:
    """Seeded closed-loop twin records for :func:`study`, labelled (a :class:`StudyRecords`).

    Two forms:

    - ``study_records(n, ...)`` (no grid axes): ``n`` records (default 3, dims ``("dataset",)``,
      labels "0", "1", …) of the paper's region 2 alone (a = 22.0 1/s, b = 1.916 1/kg, one
      region, so records never cross a region bound) under :class:`lionjax.twin.CentringPD`
      (K_p = 200 N/m, K_d = 1 N·s/m, x_ref = 0) with a random-phase multisine (0.7, 2.3, 5.1,
      9.7 Hz, 1 N each; phases from key ``seed + i``) and force-sensor noise from key
      ``1000 + seed + i``.
    - a grid over any of ``excitations`` × ``operating_points`` × ``noise_seeds`` (dims in this
      order, only those given): one record per combination, on ``plant`` (default the paper's
      piecewise device :data:`lionjax.twin.FALCON_PAPER`, eq. (13)) under
      ``CentringPD(x_ref=operating point)``. Defaults for an axis not given: the paper's input 4
      (``twin.PAPER_SINE_SETS[3]``, ±5 mm around the operating point: one region), x_ref = 0,
      noise key ``seed``. The noise seed only changes the noise (key
      ``jax.random.PRNGKey(noise_seed)``), never the excitation.

    Arguments:
        n: number of records of the first form (leave None with grid axes).
        n_samples: samples per record; dt: sample interval [s].
        force_noise: σ [N] of white force-sensor noise (:class:`lionjax.twin.ForceNoise`) added
            to the plant (0: none).
        seed: base seed (first form; default noise key of the grid form).
        excitations: force inputs [N], a list of twin excitations (labels "0", "1", …), a
            ``{label: excitation}`` mapping, or ``"paper"`` (the four
            ``twin.PAPER_SINE_SETS``, labels "input1" … "input4").
        operating_points: x_ref [m] of the centring loop, or ``"paper"`` (−20, 0, +20 mm).
        noise_seeds: integer seeds of the noise (one record per seed).
        plant: a :class:`lionjax.twin.Plant` for the grid form (its effects are kept;
            ``force_noise`` adds a ForceNoise on top).

    Returns:
        a :class:`StudyRecords` (a sequence of :class:`~lionjax.Record`).
    """
    from .. import twin

    grid = excitations is not None or operating_points is not None or noise_seeds is not None
    if not grid:
        if plant is not None:
            raise InputError(
                "study_records: plant is for the grid form; pass excitations=, "
                "operating_points= or noise_seeds= with it (the first form uses region 2)."
            )
        n = 3 if n is None else int(n)
        if n < 1:
            raise InputError(f"study_records: n must be a positive int, got {n!r}.")
        fp = twin.FALCON_PAPER
        base = twin.Plant(a=(fp.a[1],), b=(fp.b[1],), bounds=())
        if force_noise > 0:
            base = base.with_effects(twin.ForceNoise(force_noise))
        out = []
        for i in range(n):
            exc = twin.multisine(
                jnp.array([0.7, 2.3, 5.1, 9.7]), 1.0, key=jax.random.PRNGKey(seed + i)
            )
            out.append(
                twin.simulate(
                    base,
                    exc,
                    n_samples=n_samples,
                    dt=dt,
                    key=jax.random.PRNGKey(1000 + seed + i),
                    closed_loop=twin.CentringPD(),
                )
            )
        return StudyRecords(tuple(out), ("dataset",), {"dataset": [str(i) for i in range(n)]})

    if n is not None:
        raise InputError(
            f"study_records: n={n!r} is for the plain form; with excitations=, "
            "operating_points= or noise_seeds= the grid sets the number of records. Drop n."
        )
    base = twin.FALCON_PAPER if plant is None else plant
    if not isinstance(base, twin.Plant):
        raise InputError(
            f"study_records: plant must be a lionjax.twin.Plant, got {type(base).__name__}."
        )
    if force_noise > 0:
        base = base.with_effects(twin.ForceNoise(force_noise))
    dims: list[str] = []
    coords: dict[str, list] = {}
    axes: list[list] = []
    if excitations is not None:
        if isinstance(excitations, str):
            if excitations != "paper":
                raise InputError(
                    f"study_records: excitations must be a list, a mapping or 'paper', got "
                    f"{excitations!r}."
                )
            excitations = {f"input{i + 1}": e for i, e in enumerate(twin.PAPER_SINE_SETS)}
        labels, items = _labels(excitations, "excitations")
        for e in items:
            if not isinstance(e, twin.AbstractExcitation):
                raise InputError(
                    "study_records: every excitation must be a lionjax.twin excitation "
                    f"(SineSum, multisine(...), Chirp, PRBS …), got {type(e).__name__}."
                )
        dims.append("excitation")
        coords["excitation"] = labels or [str(i) for i in range(len(items))]
        axes.append(items)
    if operating_points is not None:
        if isinstance(operating_points, str):
            if operating_points != "paper":
                raise InputError(
                    "study_records: operating_points must be a list of x_ref [m] or 'paper', "
                    f"got {operating_points!r}."
                )
            operating_points = twin.PAPER_OPERATING_POINTS
        ops = np.atleast_1d(np.asarray(operating_points, float))
        if ops.ndim != 1 or ops.size == 0 or not np.all(np.isfinite(ops)):
            raise InputError(
                "study_records: operating_points must be a non-empty list of finite x_ref [m], "
                f"got {operating_points!r}."
            )
        dims.append("operating_point")
        coords["operating_point"] = ops.tolist()
        axes.append(ops.tolist())
    if noise_seeds is not None:
        seeds = list(noise_seeds)
        if not seeds or not all(isinstance(s, int | np.integer) for s in seeds):
            raise InputError(
                f"study_records: noise_seeds must be a non-empty list of ints, got {noise_seeds!r}."
            )
        dims.append("noise_seed")
        coords["noise_seed"] = [int(s) for s in seeds]
        axes.append([int(s) for s in seeds])
    default = {
        "excitation": twin.PAPER_SINE_SETS[3],
        "operating_point": 0.0,
        "noise_seed": int(seed),
    }
    out = []
    for idx in np.ndindex(*[len(a) for a in axes]):
        pick = dict(default)
        pick.update({d: axes[k][i] for k, (d, i) in enumerate(zip(dims, idx, strict=True))})
        out.append(
            twin.simulate(
                base,
                pick["excitation"],
                n_samples=n_samples,
                dt=dt,
                key=jax.random.PRNGKey(pick["noise_seed"]),
                closed_loop=twin.CentringPD(x_ref=pick["operating_point"]),
                x0=pick["operating_point"],
            )
        )
    return StudyRecords(tuple(out), tuple(dims), coords)


def stack_banks(pole_sets: ArrayLike, unit_dc_gain: bool = True) -> FilterBank:
    """A batched :class:`FilterBank` (``coeffs`` of shape ``(K, n)``) from K pole sets.

    Each set is checked (Hurwitz, conjugate pairs) by :meth:`FilterBank.from_poles`; with one
    set per record it is what :func:`lionjax.lion_batched` takes as one filter per record
    (index it with ``jax.tree.map(lambda c: c[idx], bank)`` to give every batch element its
    filter).
    """
    banks = [FilterBank.from_poles(np.asarray(P), unit_dc_gain) for P in pole_sets]
    return FilterBank(jnp.stack([b.coeffs for b in banks]), unit_dc_gain)


def gain_class(gain, what: str) -> type[AbstractGain] | AbstractGain | None:
    """Check a ``gain`` argument of :func:`study` / :func:`lionjax.studies.tune`: a gain Module
    class (called with each grid value) or, for :func:`study`, one gain Module. The old strings
    ``"fixed"``/``"auto"`` are refused with their replacement."""
    if isinstance(gain, str):
        repl = {"fixed": "lionjax.FixedGain", "auto": "lionjax.AutoGain"}.get(gain)
        raise InputError(
            f"{what}: gain={gain!r}: gains are given as Module classes, not strings: "
            + (f"use gain={repl}." if repl else "gain=lionjax.FixedGain or lionjax.AutoGain.")
        )
    if gain is None or isinstance(gain, AbstractGain):
        return gain
    if isinstance(gain, type) and issubclass(gain, AbstractGain):
        return gain
    raise InputError(
        f"{what}: gain must be a gain Module class (lionjax.FixedGain: G = g·I, "
        f"lionjax.AutoGain: G = rate·R⁻¹) or a gain Module, got {gain!r}."
    )


def refuse_gain_type(gain_type, what: str) -> None:
    """The removed ``gain_type=`` argument: an error naming its replacement."""
    if gain_type is not None:
        repl = {"fixed": "lionjax.FixedGain", "auto": "lionjax.AutoGain"}.get(gain_type)
        raise InputError(
            f"{what}: gain_type={gain_type!r} was replaced by the gain Module class: "
            + (f"pass gain={repl}." if repl else "gain=lionjax.FixedGain or lionjax.AutoGain.")
        )


def study(
    model: AbstractModel,
    records: Record | Sequence[Record] | StudyRecords,
    *,
    gains: Sequence[float] | None = None,
    gain: type[AbstractGain] | AbstractGain | None = None,
    poles: Sequence[Sequence[float]] | None = None,
    unit_dc_gain: bool = True,
    theta0s: Sequence[ArrayLike] | None = None,
    dataset_names: Sequence[str] | None = None,
    stepper: AbstractSampleStepper | None = None,
    tolerance: float = 0.02,
    softness: float = 0.25,
    transient: float | None = None,
    save_every: int | None = None,
    chunk_size: int | None = None,
    progress: bool = True,
    execution: Execution = DEFAULT_EXECUTION,
    gain_type: None = None,
) -> StudyResult:
    """Lion's estimator over a grid of records × gains × filter poles × initial guesses.

    The whole grid is flattened into the batch axis of :func:`lionjax.lion_batched` — one
    gain and one filter per batch element (a gain value ``(B,)``, filter coefficients
    ``(B, n)``) — and run in
    chunks of ``chunk_size`` elements, one jitted call per chunk (every chunk the same size, so
    it compiles once). The LS answer, the convergence time to within ``tolerance`` of it, its
    smooth surrogate and the tail statistics are streamed in the same pass: memory per grid
    point is independent of the record length (plus ``(T/save_every, p)`` for a trajectory).

    Arguments:
        model: the model structure (``MassDamper()`` …).
        records: one :class:`Record` (no record axis), a batch ``(D, T)`` or a list of records
            (dim ``"dataset"``; different lengths are padded and masked), or a
            :class:`StudyRecords` (its dims, e.g. excitation × operating point × noise seed).
        gains: a grid of scalar gain values, each passed to the ``gain`` class: G = g·I
            (``gain=lionjax.FixedGain``, the default with a grid; paper: 1e4) or AutoGain rates
            [1/s] (``gain=lionjax.AutoGain``, G = rate·R⁻¹). None: no gain axis.
        gain: the gain Module class of the ``gains`` grid (default :class:`lionjax.FixedGain`),
            or, without ``gains``, one gain Module for every grid point (default
            ``AutoGain(1.0)``).
        poles: a grid of filter pole sets [rad/s], e.g. ``[(-4, -4, -4), (-8, -8, -8)]``
            (all of the same length, real, negative). None: :func:`default_bank`, no pole axis.
        unit_dc_gain: filter normalisation for ``poles`` (λₙ/Λ, as the default bank).
        theta0s: a grid of initial estimates, each ``(p,)``. None: zeros, no θ₀ axis.
        dataset_names: labels of the datasets (default "0", "1", …; dim ``"dataset"`` only).
        stepper: Lion's per-sample stepper (default ``ExactStep()``; its ``normalisation`` μ
            selects the normalised law).
        tolerance, softness: of the convergence time (:class:`lionjax.ConvergenceTime`: the
            band, default 2 %, and the width of its smooth surrogate).
        transient: [s] the start of the LS window and of AutoGain's R (None: 3·λₙ₋₁/λₙ of each
            filter; :class:`lionjax.LSStatistics`).
        execution: the performance knobs of :func:`lionjax.lion_batched`.
        gain_type: removed (an error naming the replacement): pass ``gain=lionjax.FixedGain``
            or ``gain=lionjax.AutoGain``.
        save_every: also keep θ every ``save_every`` samples (``trajectory``; records of one
            common ``dt``).
        chunk_size: grid points per batched call (default: all in one call).
        progress: print a progress bar to stderr, one step per chunk.

    Returns:
        a :class:`StudyResult`. On KeyboardInterrupt the chunks already done are returned
        (NaN elsewhere, ``complete=False``) and a warning is printed to stderr.
    """
    if not isinstance(model, AbstractModel):
        raise InputError(f"study: model must be an AbstractModel, got {type(model).__name__}.")
    refuse_gain_type(gain_type, "study")
    gain = gain_class(gain, "study")
    if gains is not None and isinstance(gain, AbstractGain):
        raise InputError(
            f"study: gains= is a grid of values for a gain class, but gain is the Module "
            f"{gain!r}; pass gain={type(gain).__name__} (the class) with gains=[...], or drop "
            "gains."
        )
    if gains is None:
        gain = AutoGain() if gain is None or isinstance(gain, type) else gain
        if gain.batch_shape:
            raise InputError(
                f"study: gain must be one gain for every grid point, got a batch of "
                f"{gain.batch_shape[0]}; give the values as gains=[...]."
            )
    else:
        gain = FixedGain if gain is None else gain
    batch, lengths, rec_dims, rec_coords = _as_batch(records)
    D = batch.x.shape[0]
    p = len(model.names)
    dtype = batch.x.dtype
    dims: list[str] = list(rec_dims)
    coords: dict[str, list] = dict(rec_coords or {})
    if dataset_names is not None:
        if rec_dims != ("dataset",):
            raise InputError(
                f"study: dataset_names labels a plain list of records (dim 'dataset'); these "
                f"records have dims {rec_dims}. Drop dataset_names."
            )
        coords["dataset"] = [str(s) for s in dataset_names]
        if len(coords["dataset"]) != D:
            raise InputError(
                f"study: dataset_names has {len(coords['dataset'])} names for {D} datasets."
            )
    elif rec_dims == ("dataset",) and rec_coords is None:
        coords["dataset"] = [str(i) for i in range(D)]
    if gains is not None:
        g = np.atleast_1d(np.asarray(gains, float))
        if g.ndim != 1 or g.size == 0 or not np.all(g > 0):
            raise InputError(
                f"study: gains must be a non-empty list of positive numbers, got {gains!r}."
            )
        dims.append("gain")
        coords["gain"] = g.tolist()
    if poles is not None:
        P = np.asarray(poles, float)
        if P.ndim != 2 or P.shape[1] < 3 or np.any(P >= 0):
            raise InputError(
                "study: poles must be a list of pole sets of equal length ≥ 3, all negative "
                f"(rad/s), e.g. [(-4, -4, -4), (-8, -8, -8)]; got {poles!r}."
            )
        dims.append("poles")
        coords["poles"] = P.tolist()
    if theta0s is not None:
        Th = np.asarray(theta0s, float)
        if Th.ndim != 2 or Th.shape[1] != p:
            raise InputError(
                f"study: theta0s must be a list of initial estimates of length p={p} "
                f"({', '.join(model.names)}), got shape {Th.shape}."
            )
        dims.append("theta0")
        coords["theta0"] = Th.tolist()
    if not (isinstance(softness, int | float) and softness > 0):
        raise InputError(f"study: softness must be a positive number, got {softness!r}.")
    dt_all = np.asarray(batch.dt)
    common_dt = bool(np.all(dt_all == dt_all[0]))
    if save_every is not None and not common_dt:
        raise InputError(
            "study: save_every needs records of one sampling interval (the trajectory has one "
            f"time axis); got dt from {dt_all.min():g} to {dt_all.max():g} s. Resample the "
            "records (lionjax.resample) or drop save_every."
        )
    shape = tuple(len(coords[d]) for d in dims)
    N = int(np.prod(shape)) if shape else 1
    grid_idx = np.indices(shape).reshape(len(shape), N) if shape else np.zeros((0, 1), int)
    idx = {d: grid_idx[i] for i, d in enumerate(dims)}
    n_rec = len(rec_dims)
    if n_rec:
        di = np.ravel_multi_index(tuple(grid_idx[:n_rec]), shape[:n_rec])
    else:
        di = np.zeros(N, int)

    # every record outlasts every filter's transient (the rule of lion/least_squares for one
    # record, checked per record: padding must not lengthen a short record)
    rec_names = (
        [", ".join(str(v) for v in lab.values()) for lab in records.labels()]
        if isinstance(records, StudyRecords)
        else coords.get("dataset", [str(i) for i in range(D)])
    )
    check_banks = (
        [FilterBank.from_poles(np.asarray(P), unit_dc_gain) for P in coords["poles"]]
        if "poles" in coords
        else [default_bank(batch.dt)]
    )
    for i in range(D):
        one = Record(batch.x[i, : lengths[i]], batch.F[i, : lengths[i]], batch.dt[i], batch.t0[i])
        what = f"study: record {rec_names[i]!r}"
        check_record(one, what)
        for bk in check_banks:
            rho = pole_dt(bk, one.dt)
            if rho is not None and np.any(rho > MAX_POLE_DT):  # refused: name the record
                check_filter_speed(bk, one.dt, what, "poles")
            check_duration(one, bk, what, transient)
        # the record identifies the model from its samples after the transient (what a_LS and
        # Lion's law use), and the model explains more than a trace of it
        check_identified(model, one, check_banks[0], transient, what)

    outputs = (
        LSStatistics(transient),
        ConvergenceTime(tolerance=tolerance, softness=softness),
        TailStatistics(),
    ) + (() if save_every is None else (Trajectory(save_every),))
    # The whole grid in one batch axis (pole sets included: one filter per element, a bank
    # with coeffs (chunk, n), tested equal to one call per pole set), run in equal chunks.
    chunk = N if chunk_size is None else int(chunk_size)
    if chunk < 1:
        raise InputError(f"study: chunk_size must be a positive int, got {chunk_size!r}.")
    chunk = min(chunk, N)
    jobs = [np.arange(s, min(s + chunk, N)) for s in range(0, N, chunk)]
    n_chunks = len(jobs)
    banks = stack_banks(coords["poles"], unit_dc_gain) if "poles" in idx else None

    theta = np.full((N, p), np.nan)
    theta_ls = np.full((N, p), np.nan)
    t_conv = np.full(N, np.nan)
    surr = np.full(N, np.nan)
    tstd = np.full((N, p), np.nan)
    J = np.full(N, np.nan)
    res = np.full(N, -1, int)
    traj = None
    t_saved = None

    def run_chunk(sel: np.ndarray):
        d = di[sel]
        if common_dt:  # one dt: the filter is discretised once per pole set
            sub = Record(batch.x[d], batch.F[d], batch.dt[0], batch.t0[0])
        else:
            sub = Record(batch.x[d], batch.F[d], batch.dt[d], batch.t0[d])
        kw: dict[str, Any] = {}
        if banks is not None:
            kw["bank"] = jax.tree.map(lambda c: c[idx["poles"][sel]], banks)  # (chunk, n)
        else:
            kw["bank"] = default_bank(batch.dt)
        if "gain" in idx:  # one gain per element: the class called with a (chunk,) value
            kw["gain"] = gain(jnp.asarray(np.asarray(coords["gain"])[idx["gain"][sel]], dtype))
        else:
            kw["gain"] = gain
        if "theta0" in idx:
            kw["theta0"] = jnp.asarray(np.asarray(coords["theta0"])[idx["theta0"][sel]], dtype)
        ln = lengths[d]
        return lion_batched(
            model,
            sub,
            stepper=stepper,
            lengths=None if np.all(ln == batch.x.shape[1]) else jnp.asarray(ln, jnp.int32),
            outputs=outputs,
            execution=execution,
            throw=False,
            **kw,
        )

    def run_job(sel: np.ndarray) -> None:
        nonlocal traj, t_saved
        n = sel.size
        # pad a short chunk to the chunk size (repeat its last point): one compilation
        padded = np.concatenate([sel, np.repeat(sel[-1:], chunk - n)])
        sol = run_chunk(padded)
        theta[sel] = np.asarray(sol.theta)[:n]
        theta_ls[sel] = np.asarray(sol.theta_ls)[:n]
        t_conv[sel] = np.asarray(sol.t_converged)[:n]
        surr[sel] = np.asarray(sol.time_outside)[:n]
        tstd[sel] = np.asarray(sol.tail_std)[:n]
        J[sel] = np.asarray(sol.J)[:n]
        res[sel] = result_codes(sol.result)[:n]
        if save_every is not None:
            tr = np.moveaxis(np.asarray(sol.trajectory), 1, 0)  # (B, K, p)
            if traj is None:
                traj = np.full((N,) + tr.shape[1:], np.nan)
                t_saved = float(dt_all[0]) * save_every * np.arange(1, tr.shape[1] + 1)
            traj[sel] = tr[:n]

    complete = run_chunks(jobs, run_job, label="study", total=n_chunks, progress=progress)

    return StudyResult(
        dims=tuple(dims),
        coords=coords,
        names=tuple(model.names),
        theta_final=theta.reshape(shape + (p,)),
        theta_ls=theta_ls.reshape(shape + (p,)),
        convergence_time=t_conv.reshape(shape),
        final_J=J.reshape(shape),
        result=res.reshape(shape),
        time_outside=surr.reshape(shape),
        tail_std=tstd.reshape(shape + (p,)),
        t_saved=t_saved,
        trajectory=None if traj is None else traj.reshape(shape + traj.shape[1:]),
        tolerance=tolerance,
        softness=float(softness),
        transient=None if transient is None else float(transient),
        complete=complete,
        gain_class=gain.__name__ if isinstance(gain, type) else type(gain).__name__,
    )
