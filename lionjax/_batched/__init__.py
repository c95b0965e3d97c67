"""The fast batched estimator: a streaming, fused filter + Lion kernel over many records.

Layer 1 (core). :func:`lion_batched` runs Lion's law θ̇ = −G Wᵀε / (1 + μ‖W‖²) (a per-sample
stepper of :mod:`lionjax._estimators`, the exact step by default) over a batch of B records in
one jitted call, without ever storing the regressors: every record's filter states z (n per raw
signal) and θ are carried from sample to sample, so memory is O(B) whatever the record length T.
Everything else it reports is accumulated in the same stream by the output accumulators of
:mod:`lionjax._outputs` (least-squares statistics, convergence time, tail statistics, a
decimated trajectory), passed as ``outputs=(...)``; :func:`least_squares_batched` is the
statistics pass alone (no estimate, no gain).

The call is made of strategy Modules, as diffrax's ``diffeqsolve`` is: the filter
(:class:`lionjax.FilterBank`, one per record when its ``coeffs`` are ``(B, n)``), the gain
(:class:`lionjax.AbstractGain`, one per record when its value is ``(B,)``), the stepper
(:class:`lionjax.extend.AbstractSampleStepper`, which owns the normalisation μ), the outputs and the
performance knobs (:class:`Execution`).

The exact step (:mod:`lionjax._phi`). With S = W G Wᵀ (2×2 symmetric PSD), over one interval h
with frozen W: θ ← θ − h·G Wᵀ E(hS) (Wθ + W₀), E(Z) = (I − e^{−Z}) Z⁻¹, the same function
(:func:`lionjax.extend.phi_sym2`) as in :func:`lionjax.lion`.

One module per concern:

- :mod:`.estimator`: :func:`lion_batched` (the statistics pass, the gain, the estimation pass
  and its closed-form fallback);
- :mod:`.least_squares`: :func:`least_squares_batched`, the statistics pass alone;
- :mod:`.parallel`: :func:`lion_parallel`, Lion's exact step parallel in time;
- :mod:`.stack`: :func:`stack_records`, records of any lengths as one padded batch;
- :mod:`.devices`: where the records live (:func:`host_devices`, :func:`shard_records`, views
  of host memory, the device mesh);
- :mod:`.execution`: the performance knobs (:class:`Execution`) and the kernel they choose;
- :mod:`.stream`: a batch prepared for the kernel (plan, filter maps, initial states) and the
  sharded call;
- :mod:`.kernel`: the fused XLA loop over one shard (and why it is shaped as it is);
- :mod:`.solution`: what the estimators return.
"""

from .devices import host_devices as host_devices, shard_records as shard_records
from .estimator import lion_batched as lion_batched
from .execution import (
    DEFAULT_EXECUTION as DEFAULT_EXECUTION,
    KERNELS as KERNELS,
    Execution as Execution,
)
from .least_squares import least_squares_batched as least_squares_batched
from .parallel import lion_parallel as lion_parallel
from .solution import (
    BatchedSolution as BatchedSolution,
    LSBatchedSolution as LSBatchedSolution,
    ParallelSolution as ParallelSolution,
)
from .stack import stack_records as stack_records
