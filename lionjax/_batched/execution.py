"""The performance knobs of the batched estimators (:class:`Execution`) and the kernel
implementation they choose; results do not depend on them beyond rounding."""

from __future__ import annotations

from typing import Literal

import equinox as eqx

from .._errors import InputError
from .._pallas import pallas_kernel
from .kernel import split_kernel

#: Kernel implementations :class:`Execution` accepts (``"auto"``: the best for the backend).
KERNELS = ("auto", "xla", "pallas")
_BLOCK = 128  # samples per slab read from the (B, T) records (transposed in cache, per block)


class Execution(eqx.Module):
    """How :func:`lion_batched` and :func:`least_squares_batched` run: the performance knobs
    (results are the same, to rounding, whatever they are).

    Attributes:
        chunk: samples per slab read from the ``(B, T)`` records per inner loop (default 128;
            each slab is transposed in cache, the batch never is as a whole).
        split: independent loops per device, each over its own rows of the batch (XLA:CPU runs
            them concurrently: this is how one CPU device uses every core without copying the
            records). None (default): on CPU the cores per device (≥ 64 records per loop),
            else 1.
        shard: shard the batch over ``jax.local_devices()`` (default True; the batch size must
            be a multiple of the device count, else it runs unsharded). On CPU host devices
            records are sharded when already placed by :func:`shard_records` or when they can
            be laid out over the devices as views of their memory (rows starting on 64 bytes:
            no copy); others run on one device, whose ``split`` loops use the cores.
        kernel: the kernel implementation, one of :data:`KERNELS`: ``"auto"`` (default:
            ``"xla"`` everywhere), ``"xla"`` (the fused XLA loop) or ``"pallas"`` (the whole
            time loop in one Pallas kernel, one record per lane: :mod:`lionjax._pallas`; off a
            GPU it runs in Pallas' interpret mode — slow, for testing). On an H200 the Pallas
            kernel agrees with the XLA loop bitwise and runs 1.65–23× faster on batches, 46× on
            one long record (``benchmarks/results/2026-11-27_gpu_h200.md``): pass ``"pallas"``
            on a GPU. ``"auto"`` does not choose it there until that choice has run on one.
        phi: how E(hS) = (I − e^{−hS})(hS)⁻¹ is evaluated: ``"series"`` (default: its series
            alone, 8 terms in float32, 14 in float64, while tr(hS) ≤ 1/2 — truncation below the
            unit roundoff — and the records where some sample exceeds the bound, or θ is not
            finite, re-run with the closed form, gathered B/16 at a time: one closed-form
            program, compiled once; a loop, so forward-mode differentiable only) or
            ``"closed"`` (the closed form throughout; also for reverse-mode gradients).
    """

    chunk: int = eqx.field(static=True, default=_BLOCK)
    split: int | None = eqx.field(static=True, default=None)
    shard: bool = eqx.field(static=True, default=True)
    kernel: str = eqx.field(static=True, default="auto")
    phi: Literal["series", "closed"] = eqx.field(static=True, default="series")

    def __check_init__(self):
        if self.kernel not in KERNELS:
            raise InputError(
                f"Execution: kernel must be one of {KERNELS}, got {self.kernel!r}. Use "
                "kernel='auto' (the best kernel for the backend)."
            )
        if not (isinstance(self.chunk, int) and self.chunk >= 1):
            raise InputError(
                f"Execution: chunk must be a positive int (samples per slab), got {self.chunk!r}."
            )
        if self.split is not None and not (isinstance(self.split, int) and self.split >= 1):
            raise InputError(
                f"Execution: split must be a positive int (loops per device) or None, got "
                f"{self.split!r}."
            )
        if not isinstance(self.shard, bool):
            raise InputError(f"Execution: shard must be True or False, got {self.shard!r}.")
        if self.phi not in ("series", "closed"):
            raise InputError(
                f"Execution: phi must be 'series' (fast, with a closed-form fallback) or "
                f"'closed', got {self.phi!r}."
            )

    def kernel_function(self):
        """The kernel implementation this resolves to (``"auto"``: ``"xla"``; see ``kernel``)."""
        kernel = "xla" if self.kernel == "auto" else self.kernel
        if kernel == "pallas":
            return pallas_kernel
        return split_kernel


#: The default :class:`Execution` (every knob at its default).
DEFAULT_EXECUTION = Execution()
