"""A batch of records prepared for the kernel: the plan of the model's signals and columns,
the filter maps (shared, or one compact filter per record), the initial filter states, the
accumulators' :class:`lionjax._outputs.Context`, and the call of the kernel over the batch —
split into loops per device and sharded over the device mesh. Also the argument checks the
batched entry points share."""

from __future__ import annotations

import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec

from .._errors import InputError
from .._filters import FilterBank
from .._kernel_core import (
    _filter,
    _Inputs,
    _maps,
    _midpoint_basis,
    _Out,
    _Plan,
)
from .._linalg import matvec
from .._models import AbstractModel
from .._outputs import (
    Accumulated,
    Context,
)
from .._record import Record
from .devices import device_mesh
from .execution import Execution


def plan_for(
    model: AbstractModel, record0: Record, bank: FilterBank, align: bool = False, **flags
) -> _Plan:
    """The :class:`_Plan` of ``model``'s signals and columns; ``align``: carry the filter states
    in the midpoint basis (:func:`_midpoint_basis`) when the pass estimates θ with midpoint
    regressors (shared filter maps only: the compact per-record filter stays in z)."""
    sigs = model.signals(record0)
    if "x" not in sigs:
        raise InputError(f"{type(model).__name__}.signals must provide 'x' (for W₀).")
    names = list(sigs)
    cols = tuple((names.index(c.signal), c.order, float(c.sign)) for c in model.columns())
    for _, order, _ in cols:
        if order + 2 > 4 or order < 0:
            raise InputError("lion_batched: column orders must be 0…2 (outputs V₁…V₄).")
    if bank.order < 3:
        raise InputError(
            f"lion_batched: the filter must have order n ≥ 3 (V₄ = s³/Λ·x must be proper), "
            f"got n = {bank.order}."
        )
    aligned = align and flags.get("estimate", False) and flags.get("midpoint", True)
    return _Plan(
        signals=tuple((k, sigs[k][1]) for k in names),
        columns=cols,
        x_index=names.index("x"),
        n=bank.order,
        aligned=aligned,
        **flags,
    )


def _parts(split: int | None, rows: int, sharded: bool) -> int:
    """Independent loops per device (:func:`split_kernel`): ``split``, or by default on CPU the
    cores per device (at least 64 records per loop), elsewhere 1."""
    if split is not None:
        return max(1, min(int(split), rows))
    if jax.default_backend() != "cpu":
        return 1
    ndev = len(jax.local_devices()) if sharded else 1
    cores = max(1, (os.cpu_count() or 1) // ndev)
    return max(1, min(cores, rows // 64))


def _kernel_view(tree, dtype):
    """A strategy Module as the kernel sees it: scalar leaves as arrays of the records' dtype
    (runtime values, replicated over shards), per-record arrays dropped (they reach the kernel
    through the accumulators' ``prepare``, sliced with the batch)."""

    def leaf(v):
        if isinstance(v, bool | np.bool_):
            return v
        if isinstance(v, int | float) or (isinstance(v, jax.Array | np.ndarray) and v.ndim == 0):
            return jnp.asarray(v, dtype)
        return None

    return jax.tree.map(leaf, tree)


class Stream:
    """A batch of records prepared for the kernel (trace-time): the raw signals in their
    ``(B, T)`` layout, the filter maps (shared or one per record), initial filter states, the
    :class:`Context` of the accumulators."""

    def __init__(self, model, records, bank, lengths, execution, one):
        B, T = records.x.shape
        dtype = records.x.dtype
        rec0 = jax.tree.map(lambda a: a[0] if a.ndim >= 1 else a, records)
        full = Record(
            records.x,
            records.F,
            jnp.broadcast_to(records.dt, (B,)),
            jnp.broadcast_to(records.t0, (B,)),
            records.extras,
        )
        sigs0 = model.signals(rec0)
        order = list(sigs0)  # the plan's signal order (a dict out of vmap is sorted)
        sig_vals = jax.vmap(lambda r: {k: v[0] for k, v in model.signals(r).items()})(full)
        self.X = tuple(sig_vals[k].astype(dtype) for k in order)  # (B, T), never transposed
        self.masked = lengths is not None
        dt = jnp.broadcast_to(jnp.asarray(records.dt, dtype), (B,))
        length = (
            jnp.full((B,), T, jnp.int32) if lengths is None else jnp.asarray(lengths, jnp.int32)
        )
        # filter maps: shared (one dt, one filter) or one per record
        holds = [sigs0[k][1] == "foh" for k in order]
        per_bank = bool(bank.batch_shape)
        shared_coeffs = not per_bank and jnp.ndim(records.dt) == 0
        if shared_coeffs:  # scalars in the kernel: the composed maps cost nothing to read
            maps = tuple(_maps(bank, jnp.asarray(records.dt, dtype), f) for f in holds)
        else:  # per-record arrays: the compact form, a quarter of the values read per sample
            maps = jax.vmap(_filter, in_axes=(0 if per_bank else None, 0))(bank, dt)
        maps = jax.tree.map(lambda a: jnp.asarray(a, dtype), maps)
        z0 = jnp.stack(
            [
                jax.vmap(lambda b, u0: b.steady_state(u0), in_axes=(0 if per_bank else None, 0))(
                    bank, sig_vals[k][:, 0]
                )
                for k in order
            ],
            axis=1,
        ).astype(dtype)  # (B, S, n)
        # the same in the midpoint basis w = A z (shared maps only; passes that estimate θ with
        # midpoint regressors, :func:`plan_for`)
        self.aligned = None
        if shared_coeffs:
            lam_rev = bank.coeffs[::-1].astype(dtype)
            basis = [_midpoint_basis(m, lam_rev) for m in maps]
            w0 = jnp.stack([matvec(A, z0[:, s]) for s, (_, A) in enumerate(basis)], 1)
            self.aligned = (tuple(m for m, _ in basis), w0)
        self.per = _Inputs(
            maps=None if shared_coeffs else maps,
            h=None if shared_coeffs else dt,
            length=length,
            z0=z0,
        )
        self.shared = _Inputs(
            maps=maps if shared_coeffs else None,
            h=jnp.asarray(records.dt, dtype) if shared_coeffs else None,
            one=one,
        )
        self.ctx = Context(
            dtype=dtype,
            p=len(model.names),
            names=tuple(model.names),
            dt=dt,
            t0=jnp.broadcast_to(jnp.asarray(records.t0, dtype), (B,)),
            length=length,
            bank=bank,
        )
        self.plan = lambda **kw: plan_for(
            model, rec0, bank, align=shared_coeffs, masked=self.masked, **kw
        )
        self.execution = execution

    def run(
        self, plan, outputs, inputs, *, theta0=None, G=None, G_shared=None, stepper=None, idx=None
    ) -> _Out:
        """The kernel over the batch (or over the records ``idx`` of it), batch-first outputs.

        ``outputs``: the accumulators of this pass; ``inputs``: their prepared per-record
        inputs (batch first); ``G``: per-record gains ``(B, p, p)`` or ``G_shared`` ``(p, p)``."""
        dtype = self.ctx.dtype
        per = dataclasses.replace(self.per, G=G, theta0=theta0, outputs=tuple(inputs))
        maps = self.shared.maps
        if plan.aligned:  # the states carried in the midpoint basis w = A z
            maps, w0 = self.aligned
            per = dataclasses.replace(per, z0=w0)
        shared = dataclasses.replace(
            self.shared,
            maps=maps,
            G=G_shared,
            outputs=tuple(_kernel_view(o, dtype) for o in outputs),
            stepper=None if stepper is None else _kernel_view(stepper, dtype),
        )
        xs = self.X
        if idx is not None:
            per = jax.tree.map(lambda a: a[idx], per)
            xs = tuple(a[idx] for a in xs)
        perT = jax.tree.map(lambda a: jnp.moveaxis(a, 0, -1), per)  # batch axis last
        ex = self.execution
        mesh = device_mesh() if ex.shard else None
        sharded = mesh is not None and xs[0].shape[0] % mesh.size == 0
        parts = _parts(ex.split, xs[0].shape[0] // (mesh.size if sharded else 1), sharded)
        kernel = ex.kernel_function()
        f = lambda xs, pe, sh: kernel(plan, xs, sh, pe, parts)
        if sharded:
            spec_last = lambda a: PartitionSpec(*([None] * (a.ndim - 1) + ["batch"]))
            in_specs = (
                tuple(PartitionSpec("batch", None) for _ in xs),
                jax.tree.map(spec_last, perT),
                jax.tree.map(lambda a: PartitionSpec(), shared),
            )
            out_shape = jax.eval_shape(f, xs, perT, shared)
            out_specs = jax.tree.map(
                lambda a: spec_last(a) if a.ndim else PartitionSpec(), out_shape
            )
            f = jax.shard_map(f, mesh=mesh, in_specs=in_specs, out_specs=out_specs, check_vma=False)
        out = f(xs, perT, shared)
        return jax.tree.map(lambda a: jnp.moveaxis(a, -1, 0) if a.ndim else a, out)

    def statistics(self, outputs) -> tuple[Accumulated, ...]:
        """The statistics pass (no estimate): the final states of ``outputs``, batch first."""
        inputs = tuple(o.prepare(self.ctx) for o in outputs)
        plan = self.plan(estimate=False, block=self.execution.chunk)
        return self.run(plan, outputs, inputs).outputs


def check_batch(what, model, records, bank, lengths, execution) -> None:
    """Argument checks shared by :func:`lion_batched` and :func:`least_squares_batched`."""
    for arg, val, typ in (
        ("model", model, AbstractModel),
        ("records", records, Record),
        ("bank", bank, FilterBank),
        ("execution", execution, Execution),
    ):
        if not isinstance(val, typ):
            raise InputError(f"{what}: {arg} must be a {typ.__name__}, got {type(val).__name__}.")
    if records.x.ndim != 2:
        raise InputError(
            f"{what}: records must be a batch with x of shape (B, T), got {records.x.shape}."
            " Stack single records with lionjax.stack_records([...])."
        )
    B = records.x.shape[0]
    if bank.batch_shape not in ((), (B,)):
        raise InputError(
            f"{what}: bank must be one filter (coeffs (n,)) or one per record (coeffs ({B}, n)) "
            f"for {B} records, got coeffs of shape {bank.coeffs.shape}."
        )
    if lengths is not None and jnp.shape(lengths) != (B,):
        raise InputError(
            f"{what}: lengths must have shape ({B},) (valid samples per record), got "
            f"{jnp.shape(lengths)}. lionjax.stack_records returns them."
        )
