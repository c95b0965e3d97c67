"""Records of any lengths as one batch: :func:`stack_records` (padded, with their lengths)."""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._errors import InputError
from .._record import Record


def stack_records(records: Sequence[Record], pad_to: int | None = None) -> tuple[Record, Array]:
    """Stack records into one batch, padding shorter ones; returns ``(batch, lengths)``.

    Padding repeats each record's last sample, and ``lengths`` (B,) tells :func:`lion_batched`
    which samples are real: pass it on (``lion_batched(model, batch, lengths=lengths)``). A
    held force under a resting position contradicts the model, so :func:`lion_batched` and
    :func:`least_squares_batched` refuse a batch that ends in such padding without
    ``lengths``. ``dt`` and ``t0`` become ``(B,)``.
    """
    records = list(records)
    if not records:
        raise InputError("stack_records: got no records; pass at least one.")
    lens = [int(r.n_samples) for r in records]
    T = max(lens) if pad_to is None else int(pad_to)
    if T < max(lens):
        raise InputError(
            f"stack_records: pad_to={pad_to} is shorter than the longest record "
            f"({max(lens)} samples)."
        )

    def pad(a, n):
        a = np.asarray(a)
        return np.concatenate([a, np.repeat(a[-1:], T - n)]) if n < T else a

    x = np.stack([pad(r.x, n) for r, n in zip(records, lens, strict=True)])
    F = np.stack([pad(r.F, n) for r, n in zip(records, lens, strict=True)])
    dt = np.array([float(r.dt) for r in records])
    t0 = np.array([float(r.t0) for r in records])
    dtype = records[0].x.dtype
    batch = Record(
        jnp.asarray(x, dtype), jnp.asarray(F, dtype), jnp.asarray(dt, dtype), jnp.asarray(t0, dtype)
    )
    return batch, jnp.asarray(lens, jnp.int32)
