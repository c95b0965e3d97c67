"""Study grids: Lion's estimator over datasets × gains × filter poles × initial guesses.

:func:`study` flattens the grid (per filter pole set) into the batch axis of the batched
estimator (:func:`lionjax.lion_batched` with ``batched_gain``), runs it in chunks with a progress
bar, and reshapes the answers into a labelled :class:`StudyResult` (dims, coords, arrays of shape
``(*grid, p)``). :func:`study_records` simulates a small seeded set of twin records for it.
"""

from __future__ import annotations

import csv
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from ._batched import lion_batched, stack_records
from ._errors import InputError
from ._estimators import AutoGain, FixedGain, default_bank
from ._filters import FilterBank
from ._models import AbstractModel
from ._record import Record
from ._tables import jsonable as _jsonable


class StudyResult(eqx.Module):
    """Labelled results of :func:`study` over a grid (shape ``len(coords[d]) for d in dims``).

    Attributes:
        dims: axis names, a subset (in this order) of ``("dataset", "gain", "poles", "theta0")``.
        coords: name → list of coordinate values (dataset names; gains [G = g·I] or AutoGain
            rates [1/s]; pole triples [rad/s]; initial guesses).
        names: parameter names (p of them).
        theta_final: θ(T) at the end of each record, ``(*grid, p)``.
        theta_ls: the least-squares answer of each record (streamed, samples after the filter
            transient; equals ``least_squares(..., initial="discard")``), ``(*grid, p)``.
        convergence_time: seconds after which every |θᵢ − θ_LS,ᵢ| ≤ tolerance·|θ_LS,ᵢ| until the
            end; ``inf`` if not settled, NaN for grid points not computed (interrupted).
        final_J: the cost ½εᵀε at the last sample, ``grid``.
        result: :class:`lionjax.RESULTS` code per grid point as an int (0 = success, −1 = not run).
        tolerance: the relative band of ``convergence_time``.
        complete: False if the run was interrupted (NaN where not computed).
    """

    dims: tuple[str, ...] = eqx.field(static=True)
    coords: dict[str, list] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)
    theta_final: np.ndarray
    theta_ls: np.ndarray
    convergence_time: np.ndarray
    final_J: np.ndarray
    result: np.ndarray
    tolerance: float = eqx.field(static=True, default=0.02)
    complete: bool = eqx.field(static=True, default=True)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(self.coords[d]) for d in self.dims)

    @property
    def bias(self) -> np.ndarray:
        """max over parameters of |θ_final − θ_LS| / |θ_LS|, shape ``grid`` (final bias vs LS)."""
        return np.max(np.abs(self.theta_final - self.theta_ls) / np.abs(self.theta_ls), axis=-1)

    def to_records(self) -> list[dict[str, Any]]:
        """One dict per grid point (C order): its coordinates, then the values by name."""
        rows = []
        bias = self.bias
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
            row["final_J"] = float(self.final_J[idx])
            row["result"] = int(self.result[idx])
            rows.append(row)
        return rows

    def to_json(self, path: str | Path) -> Path:
        """Write ``{"dims", "coords", "tolerance", "complete", "rows": to_records()}``.

        Non-finite numbers (``inf`` not settled, NaN not computed) are written as null.
        """
        payload = {
            "dims": list(self.dims),
            "coords": {d: self.coords[d] for d in self.dims},
            "tolerance": self.tolerance,
            "complete": self.complete,
            "rows": self.to_records(),
        }
        path = Path(path)
        path.write_text(json.dumps(_jsonable(payload), indent=2) + "\n")
        return path

    def to_csv(self, path: str | Path) -> Path:
        """Write :meth:`to_records` as CSV (pole triples and θ₀ joined with ';')."""
        rows = self.to_records()
        path = Path(path)
        with path.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            for r in rows:
                w.writerow(
                    {
                        k: ";".join(f"{x:g}" for x in v) if isinstance(v, list | tuple) else v
                        for k, v in r.items()
                    }
                )
        return path


def _as_batch(records) -> tuple[Record, np.ndarray, bool]:
    """(batch with dt/t0 (D,), lengths (D,), had_a_dataset_axis)."""
    if isinstance(records, Record):
        if records.x.ndim == 1:
            batch, lengths = stack_records([records])
            return batch, np.asarray(lengths), False
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
        return batch, np.full(D, T), True
    records = list(records)
    if not records or not all(isinstance(r, Record) for r in records):
        raise InputError(
            "study: records must be a Record (one or a batch) or a non-empty list of Records, "
            f"got {type(records).__name__}."
        )
    batch, lengths = stack_records(records)
    return batch, np.asarray(lengths), True


def study_records(
    n: int = 3, n_samples: int = 3000, dt: float = 1e-3, force_noise: float = 0.01, seed: int = 0
) -> list[Record]:
    """``n`` seeded twin records of the paper's region 2 (a = 22.0 1/s, b = 1.916 1/kg).

    Closed loop (:class:`lionjax.twin.CentringPD`, K_p = 200 N/m, K_d = 1 N·s/m), a random-phase
    multisine (0.7, 2.3, 5.1, 9.7 Hz, 1 N each; phases from ``seed + i``) and white force-sensor
    noise of ``force_noise`` N; ``n_samples`` samples at ``dt`` s.
    """
    from . import twin

    fp = twin.FALCON_PAPER
    plant = twin.Plant(a=(fp.a[1],), b=(fp.b[1],), bounds=())
    if force_noise > 0:
        plant = plant.with_effects(twin.ForceNoise(force_noise))
    out = []
    for i in range(n):
        exc = twin.multisine(jnp.array([0.7, 2.3, 5.1, 9.7]), 1.0, key=jax.random.PRNGKey(seed + i))
        out.append(
            twin.simulate(
                plant,
                exc,
                n_samples=n_samples,
                dt=dt,
                key=jax.random.PRNGKey(1000 + seed + i),
                closed_loop=twin.CentringPD(),
            )
        )
    return out


def _progress(done: int, total: int, width: int = 30) -> None:
    n = int(round(width * done / total))
    sys.stderr.write(f"\rstudy [{'#' * n}{'.' * (width - n)}] {done}/{total} chunks")
    if done == total:
        sys.stderr.write("\n")
    sys.stderr.flush()


def study(
    model: AbstractModel,
    records: Record | Sequence[Record],
    *,
    gains: Sequence[float] | None = None,
    gain_type: Literal["fixed", "auto"] = "fixed",
    poles: Sequence[Sequence[float]] | None = None,
    unit_dc_gain: bool = True,
    theta0s: Sequence[ArrayLike] | None = None,
    dataset_names: Sequence[str] | None = None,
    normalisation: float | None = None,
    tolerance: float = 0.02,
    transient: float | None = None,
    chunk_size: int | None = None,
    progress: bool = True,
    shard: bool = True,
) -> StudyResult:
    """Lion's estimator over a grid of datasets × gains × filter poles × initial guesses.

    For each pole set, the grid of datasets × gains × θ₀ is flattened into the batch axis of
    :func:`lionjax.lion_batched` (one gain per batch element via ``batched_gain``) and run in
    chunks of ``chunk_size`` elements (every chunk the same size, so it compiles once); the LS
    answer and the convergence time to within ``tolerance`` of it are streamed in the same pass.

    Arguments:
        model: the model structure (``MassDamper()`` …).
        records: one :class:`Record` (no dataset axis), a batch ``(D, T)`` or a list of records
            (dataset axis; different lengths are padded and masked).
        gains: a grid of scalar gains: G = g·I (``gain_type="fixed"``, paper: 1e4) or AutoGain
            rates [1/s] (``gain_type="auto"``). None: AutoGain(1.0), no gain axis.
        poles: a grid of filter pole sets [rad/s], e.g. ``[(-4, -4, -4), (-8, -8, -8)]``
            (all of the same length). None: :func:`default_bank`, no pole axis.
        unit_dc_gain: filter normalisation for ``poles`` (λₙ/Λ, as the default bank).
        theta0s: a grid of initial estimates, each ``(p,)``. None: zeros, no θ₀ axis.
        dataset_names: labels of the datasets (default "0", "1", …).
        normalisation, tolerance, transient, shard: as :func:`lionjax.lion_batched`.
        chunk_size: grid points per batched call (default: all in one call).
        progress: print a progress bar to stderr, one step per chunk.

    Returns:
        a :class:`StudyResult`. On KeyboardInterrupt the chunks already done are returned
        (NaN elsewhere, ``complete=False``) and a warning is printed to stderr.
    """
    if not isinstance(model, AbstractModel):
        raise InputError(f"study: model must be an AbstractModel, got {type(model).__name__}.")
    if gain_type not in ("fixed", "auto"):
        raise InputError(f"study: gain_type must be 'fixed' or 'auto', got {gain_type!r}.")
    batch, lengths, has_data = _as_batch(records)
    D = batch.x.shape[0]
    p = len(model.names)
    dtype = batch.x.dtype
    dims: list[str] = []
    coords: dict[str, list] = {}
    if has_data:
        names = [str(i) for i in range(D)] if dataset_names is None else list(dataset_names)
        if len(names) != D:
            raise InputError(f"study: dataset_names has {len(names)} names for {D} datasets.")
        dims.append("dataset")
        coords["dataset"] = names
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
    shape = tuple(len(coords[d]) for d in dims)
    N = int(np.prod(shape)) if shape else 1
    grid_idx = np.indices(shape).reshape(len(shape), N) if shape else np.zeros((0, 1), int)
    idx = {d: grid_idx[i] for i, d in enumerate(dims)}
    di = idx.get("dataset", np.zeros(N, int))

    # One batched call per pole set (batch = datasets × gains × θ₀), in chunks. lion_batched's
    # batched_bank=True path is not used: it takes the filter order from coeffs.shape[0] (= B
    # for a batched bank) and its default transient from a row of coeffs, so it is only right
    # when B equals the filter order.
    pole_idx = idx.get("poles", np.zeros(N, int))
    groups = [np.flatnonzero(pole_idx == k) for k in range(len(coords.get("poles", [None])))]
    M = groups[0].size
    chunk = M if chunk_size is None else int(chunk_size)
    if chunk < 1:
        raise InputError(f"study: chunk_size must be a positive int, got {chunk_size!r}.")
    chunk = min(chunk, M)
    jobs = [(k, g[s : s + chunk]) for k, g in enumerate(groups) for s in range(0, M, chunk)]
    n_chunks = len(jobs)

    theta = np.full((N, p), np.nan)
    theta_ls = np.full((N, p), np.nan)
    t_conv = np.full(N, np.nan)
    J = np.full(N, np.nan)
    res = np.full(N, -1, int)

    def run_chunk(k: int, sel: np.ndarray):
        sub = Record(batch.x[di[sel]], batch.F[di[sel]], batch.dt[di[sel]], batch.t0[di[sel]])
        kw: dict[str, Any] = {}
        if "poles" in idx:
            kw["bank"] = FilterBank.from_poles(np.asarray(coords["poles"][k]), unit_dc_gain)
        else:
            kw["bank"] = default_bank()
        if "gain" in idx:
            gv = jnp.asarray(np.asarray(coords["gain"])[idx["gain"][sel]], dtype)
            kw["gain"] = jax.vmap(FixedGain if gain_type == "fixed" else AutoGain)(gv)
            kw["batched_gain"] = True
        if "theta0" in idx:
            kw["theta0"] = jnp.asarray(np.asarray(coords["theta0"])[idx["theta0"][sel]], dtype)
        return lion_batched(
            model,
            sub,
            lengths=jnp.asarray(lengths[di[sel]], jnp.int32),
            normalisation=normalisation,
            ls=True,
            convergence=True,
            tolerance=tolerance,
            transient=transient,
            shard=shard,
            throw=False,
            **kw,
        )

    complete = True
    done = 0
    try:
        for k, sel in jobs:
            n = sel.size
            # pad a short chunk to the chunk size (repeat its last point): one compilation
            padded = np.concatenate([sel, np.repeat(sel[-1:], chunk - n)])
            sol = run_chunk(k, padded)
            theta[sel] = np.asarray(sol.theta)[:n]
            theta_ls[sel] = np.asarray(sol.theta_ls)[:n]
            t_conv[sel] = np.asarray(sol.t_converged)[:n]
            J[sel] = np.asarray(sol.J)[:n]
            res[sel] = np.asarray(sol.result._value)[:n]
            done += 1
            if progress:
                _progress(done, n_chunks)
    except KeyboardInterrupt:
        complete = False
        if progress:
            sys.stderr.write("\n")
        sys.stderr.write(
            f"warning: study interrupted after {done}/{n_chunks} chunks; returning the grid "
            "points done (NaN elsewhere, complete=False).\n"
        )
        sys.stderr.flush()

    return StudyResult(
        dims=tuple(dims),
        coords=coords,
        names=tuple(model.names),
        theta_final=theta.reshape(shape + (p,)),
        theta_ls=theta_ls.reshape(shape + (p,)),
        convergence_time=t_conv.reshape(shape),
        final_J=J.reshape(shape),
        result=res.reshape(shape),
        tolerance=tolerance,
        complete=complete,
    )
