"""The Pallas kernel (interpret mode on CPU) against the fused XLA loop of lion_batched, which
test_batched.py checks against the independent references.

Two configurations, each compiled once for each kernel (module fixtures):

- float64, everything per record: one filter and one dt per record, AutoGain with a rate per
  record, the normalised law (μ = 0.5), θ₀, ``lengths`` (padded records), LS statistics, convergence time, tail statistics and a
  decimated trajectory; B = 6 over programs of 4 records (two programs, two padded lanes);
- float32, everything shared: one filter, one scalar dt, a scalar FixedGain (values read as
  scalars in the kernel), LS statistics, convergence time and a trajectory.

Tolerances: float64 1e-9, float32 1e-4, relative to each output's largest magnitude (θ's
first parameter is near 0 on these short records, so an entry-wise relative bound would test
rounding of a cancellation, not the kernel)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _reference_sim import multisine, simulate

import lionjax as lj

# the slow tier (.ci/run's second step): the Pallas kernel in interpret mode
pytestmark = pytest.mark.slow

DT = 1e-3
T = 300
B = 6


def _signals(dtype):
    xs, Fs = [], []
    for i in range(B):
        t = np.arange(T) * DT
        F = multisine(t, [0.7, 2.3, 5.1, 11.0], [0.2 + 0.05 * i, 0.15, 0.1, 0.05])
        xs.append(simulate(F, DT, a=(22.0,), b=(1.916,), bounds=()))
        Fs.append(F)
    return np.stack(xs).astype(dtype), np.stack(Fs).astype(dtype)


def _close(a, b, tol):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    assert a.shape == b.shape
    fin = np.isfinite(b)
    np.testing.assert_array_equal(np.isfinite(a), fin)
    scale = np.max(np.abs(b[fin])) if fin.any() else 1.0
    np.testing.assert_allclose(a[fin], b[fin], rtol=tol, atol=tol * scale)


def _run_per_record(kernel):
    x, F = _signals(np.float64)
    dts = DT * np.array([1.0, 1.0, 0.8, 1.2, 1.0, 0.9])
    batch = lj.Record(jnp.asarray(x), jnp.asarray(F), jnp.asarray(dts), jnp.zeros(B))
    lengths = jnp.array([300, 250, 300, 280, 220, 300], jnp.int32)
    poles = [[-4.0 - 0.5 * i, -4.0, -5.0 + 0.2 * i] for i in range(B)]
    bank = lj.studies.stack_banks(poles)
    return lj.lion_batched(
        lj.MassDamper(),
        batch,
        bank=bank,
        gain=lj.AutoGain(jnp.linspace(20.0, 60.0, B)),
        stepper=lj.ExactStep(normalisation=0.5),
        theta0=jnp.array([0.8 * 22.0, 1.2 * 1.916]),  # inside the band: t_converged finite
        lengths=lengths,
        outputs=(
            lj.LSStatistics(transient=0.03),
            lj.ConvergenceTime(tolerance=0.3),
            lj.TailStatistics(),
            lj.Trajectory(50),
        ),
        # the closed form of E throughout (one estimation kernel; the float32 case runs the
        # default series with its closed-form re-run)
        execution=lj.Execution(kernel=kernel, shard=False, chunk=16, phi="closed"),
        throw=False,
    )


def _run_shared(kernel):
    x, F = _signals(np.float32)
    batch = lj.Record(jnp.asarray(x), jnp.asarray(F), jnp.float32(DT), jnp.float32(0.0))
    return lj.lion_batched(
        lj.MassDamper(),
        batch,
        bank=lj.FilterBank.from_poles([-4.0, -4.0, -4.0], unit_dc_gain=True),
        gain=lj.FixedGain(3e3),
        outputs=(
            lj.LSStatistics(transient=0.03),
            lj.ConvergenceTime(tolerance=0.3),
            lj.Trajectory(40),
        ),
        execution=lj.Execution(kernel=kernel, shard=False),
        throw=False,
    )


@pytest.fixture(scope="module")
def per_record():
    return _run_per_record("xla"), _run_per_record("pallas")


@pytest.fixture(scope="module")
def shared():
    return _run_shared("xla"), _run_shared("pallas")


def _compare(ref, got, tol):
    assert got.theta.dtype == ref.theta.dtype
    _close(got.theta, ref.theta, tol)
    _close(got.J, ref.J, tol)
    _close(got.gain, ref.gain, tol)
    np.testing.assert_array_equal(
        lj.solutions.result_codes(got.result), lj.solutions.result_codes(ref.result)
    )
    assert got.kinds == ref.kinds
    for a, b in zip(got.outputs, ref.outputs, strict=True):
        for la, lb in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
            _close(la, lb, tol)


def test_pallas_equals_xla_float64_per_record(per_record):
    ref, got = per_record
    assert ref.theta.dtype == jnp.float64
    assert np.all(np.isfinite(np.asarray(ref.theta)))
    _compare(ref, got, 1e-9)
    # the options did something: a trajectory, a settled band, per-record gains
    assert got.trajectory.shape == (5, B, 2)
    assert np.isfinite(np.asarray(got.t_converged)).any()
    assert len(np.unique(np.asarray(got.gain[:, 0, 0]))) == B


def test_pallas_equals_xla_float32_shared(shared):
    ref, got = shared
    assert ref.theta.dtype == jnp.float32
    assert np.all(np.isfinite(np.asarray(ref.theta)))
    _compare(ref, got, 1e-4)
    assert got.trajectory.shape == (7, B, 2)


def test_kernel_choice():
    assert lj.Execution(kernel="pallas").kernel == "pallas"
    xla = lj.Execution(kernel="xla").kernel_function()
    auto = lj.Execution().kernel_function()
    assert auto is xla  # "auto" stays on XLA until Pallas is validated on a GPU
    pallas = lj.Execution(kernel="pallas").kernel_function()
    assert pallas is not xla and pallas.__name__ == "pallas_kernel"
    with pytest.raises(lj.InputError, match="kernel must be one of"):
        lj.Execution(kernel="cuda")
