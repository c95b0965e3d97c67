"""Where a batch of records lives: host devices, the device mesh, and the records laid out over
it by their batch axis (as views of their memory on CPU host devices, copied elsewhere).

:func:`lionjax.lion_batched` shards records that are already laid out, or that can be laid out
without a copy (:func:`shard_here`); others run on one device, the batch split into loops over
its cores (:mod:`lionjax._batched.kernel`).
"""

from __future__ import annotations

import os

import jax
import numpy as np
from jax.sharding import Mesh, PartitionSpec

from .._errors import InputError
from .._record import Record


def host_devices(n: int | None = None) -> int:
    """Ask XLA for ``n`` host (CPU) devices (default: the number of cores), before JAX starts.

    Not needed for speed on one machine: :func:`lion_batched` already uses every core of one
    CPU device (``split``). Host devices are for sharding records placed once with
    :func:`shard_records` (measured faster for data estimated many times) and for testing the
    sharded path. This only edits ``XLA_FLAGS`` and has no effect once JAX's backend is
    initialised. Returns the count asked.
    """
    n = (os.cpu_count() or 1) if n is None else int(n)
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={n}".strip()
    return n


def shard_records(records: Record) -> Record:
    """Place a batch of records in the layout :func:`lion_batched` shards it into: the batch axis
    of ``x``, ``F`` (and of ``(B,)`` ``dt``/``t0``) split over ``jax.local_devices()``.

    On CPU host devices share the memory, so each device's rows are a view of the batch where
    the rows start on 64-byte boundaries (no copy: 0.2 ms for a 131 MB signal, against
    0.07–0.3 s copied); :func:`lion_batched` places unplaced records this way itself. Elsewhere
    the records are copied onto the devices: do it once for data that is estimated several
    times. With one device, or a batch that is not a multiple of the device count, the records
    come back unchanged.
    """
    if not isinstance(records, Record) or records.x.ndim != 2:
        raise InputError(
            "shard_records: expected a batch Record with x of shape (B, T), got "
            f"{type(records).__name__}"
            + (f" with x of shape {records.x.shape}" if isinstance(records, Record) else "")
            + ". Stack records with lionjax.stack_records."
        )
    placed = _place_views(records)
    if placed is not None:
        return placed
    mesh = device_mesh()
    if mesh is None or records.x.shape[0] % mesh.size:
        return records
    from jax.sharding import NamedSharding

    return _by_batch(
        records,
        lambda a, spec: jax.device_put(a, NamedSharding(mesh, spec)),
    )


def _by_batch(records: Record, place) -> Record:
    """``place(leaf, spec)`` on the leaves with the batch axis first ((B, T) and (B,))."""
    B = records.x.shape[0]
    row = PartitionSpec("batch", None)
    return jax.tree.map(
        lambda a: (
            place(a, row)
            if a.ndim == 2 and a.shape[0] == B
            else place(a, PartitionSpec("batch"))
            if a.ndim == 1 and a.shape[0] == B
            else a
        ),
        records,
    )


def _place_views(records: Record) -> Record | None:
    """``records`` over the host devices as views of their memory (CPU), or None where that is
    not possible without a copy: not CPU, fewer than two devices, a batch that is not a multiple
    of the device count, arrays that are traced, already spread over devices, or whose
    per-device rows would not start on 64-byte boundaries (the host buffer's alignment, below
    which the runtime copies). Each device's rows are checked to alias the batch's memory."""
    mesh = device_mesh()
    if mesh is None or jax.default_backend() != "cpu":
        return None
    B = records.x.shape[0]
    n = mesh.size
    if B % n:
        return None
    big = [a for a in jax.tree.leaves(records) if getattr(a, "ndim", 0) == 2 and a.shape[0] == B]
    for a in big:
        if isinstance(a, jax.core.Tracer) or not isinstance(a, jax.Array | np.ndarray):
            return None
        if isinstance(a, jax.Array) and len(a.sharding.device_set) > 1:
            return None
    from jax.sharding import NamedSharding

    devs = list(mesh.devices.flat)
    aliased = True

    def place(a, spec):
        nonlocal aliased
        if a.ndim == 1:  # (B,) per-record scalars: a copy costs nothing
            return jax.device_put(a, NamedSharding(mesh, spec))
        h = np.asarray(a)
        m = h.shape[0] // n
        if not h.flags.c_contiguous or h.ctypes.data % 64 or h[:m].nbytes % 64:
            aliased = False  # the runtime would copy a device's rows: no view possible
            return a
        parts = [jax.device_put(h[i * m : (i + 1) * m], d) for i, d in enumerate(devs)]
        aliased &= all(
            p.unsafe_buffer_pointer() == h[i * m :].ctypes.data for i, p in enumerate(parts)
        )
        return jax.make_array_from_single_device_arrays(h.shape, NamedSharding(mesh, spec), parts)

    placed = _by_batch(records, place)
    return placed if aliased else None


def shard_here(records: Record, shard: bool) -> tuple[Record, bool]:
    """(records, shard) for this call. On CPU records already laid out over the devices
    (:func:`shard_records`) are sharded, and so are records that can be laid out as views of
    their memory (:func:`_place_views`: no copy); others run on one device, the batch split into
    loops over its cores (copying them over the devices costs about as much as it saves). On
    accelerators always (one device would leave the others idle)."""
    if not shard or device_mesh() is None or jax.default_backend() != "cpu":
        return records, shard
    x = records.x
    if isinstance(x, jax.core.Tracer) or not isinstance(x, jax.Array):
        return records, True  # traced (inside an outer jit): the layout is the caller's
    if len(x.sharding.device_set) > 1:
        return records, True
    placed = _place_views(records)
    return (records, False) if placed is None else (placed, True)


def device_mesh() -> Mesh | None:
    devs = jax.local_devices()
    if len(devs) < 2:
        return None
    return Mesh(np.array(devs), ("batch",))
