"""Parallel in time (lion_parallel, lionjax._scan) against the sequential paths, and the
float32 precision of every matrix product the estimators trace (issue 11: TF32 on a GPU made
lion_parallel's θ differ from lion_batched's by 16 %)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _reference_sim import multisine, simulate

import lionjax as lj
from lionjax._scan import filter_states

DT = 1e-3
T = 10_000
B = 3
G = 1e4


@pytest.fixture(scope="module")
def signals():
    xs, Fs = [], []
    for i in range(B):
        t = np.arange(T) * DT
        F = multisine(t, [0.7, 2.3, 5.1], [0.2 + 0.05 * i, 0.15, 0.1])
        xs.append(simulate(F, DT, a=(22.0,), b=(1.916,), bounds=()))
        Fs.append(F)
    return np.stack(xs), np.stack(Fs)


def _close(a, b, tol):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    assert a.shape == b.shape and np.all(np.isfinite(b))
    np.testing.assert_allclose(a, b, rtol=tol, atol=tol * np.max(np.abs(b)))


# ----------------------------------------------------------------------------------------------
# the filter bank as an associative scan


@pytest.mark.parametrize(
    "dtype, tol, hold", [(np.float64, 1e-10, "foh"), (np.float32, 1e-4, "zoh")]
)
def test_filter_scan_equals_sequential(signals, dtype, tol, hold):
    """filter_states (associative scan) against FilterBank.__call__ (lax.scan), T = 10⁴; the
    sequential reference in float64, tolerances relative to the largest output."""
    bank = lj.FilterBank.from_poles([-4.0, -4.0, -4.0], unit_dc_gain=True)
    u = signals[1][0]
    ref = np.asarray(eqx.filter_jit(bank)(jnp.asarray(u, jnp.float64), DT, hold=hold))
    z = eqx.filter_jit(filter_states)(bank, jnp.asarray(u, dtype), DT, hold)
    assert z.dtype == dtype and z.shape == (T, 3)
    _, _, C, D = (np.asarray(a, np.float64) for a in bank.state_space())
    got = np.asarray(z, np.float64) @ C.T + np.asarray(u, dtype)[:, None] * D
    _close(got, ref, tol)


# ----------------------------------------------------------------------------------------------
# lion_parallel against the sequential lion_batched, B > 1 (vmap), T = 10⁴


@pytest.mark.parametrize(
    "dtype, tol", [pytest.param(np.float64, 1e-9, marks=pytest.mark.slow), (np.float32, 1e-4)]
)  # the float64 run in the slow tier
def test_lion_parallel_equals_lion_batched(signals, dtype, tol):
    """θ at every 100th sample and θ(T) of vmap(lion_parallel) against lion_batched (the fused
    sequential loop, tested against lj.lion) for B = 3 records of 10⁴ samples, relative to the
    largest |θ|. float32: 1e-4 (measured 2e-6 between the two float32 paths, each within 4e-6
    of float64; TF32 products were ~1e-1)."""
    x, F = (jnp.asarray(a, dtype) for a in signals)
    batch = lj.Record(x, F, jnp.asarray(DT, dtype), jnp.asarray(0.0, dtype))
    seq = lj.lion_batched(
        lj.MassDamper(),
        batch,
        gain=lj.FixedGain(G),
        outputs=(lj.Trajectory(100),),
        execution=lj.Execution(shard=False),
    )
    Gm = jnp.eye(2, dtype=dtype) * G
    par = jax.vmap(
        lambda xx, ff: lj.lion_parallel(lj.MassDamper(), lj.Record(xx, ff, batch.dt, batch.t0), Gm)
    )(x, F)
    assert par.theta.dtype == dtype and par.theta.shape == (B, T, 2)
    _close(par.theta_final, seq.theta, tol)
    traj = np.moveaxis(np.asarray(par.theta[:, 100::100]), 0, 1)  # (K, B, p)
    _close(traj[: seq.trajectory.shape[0]], seq.trajectory, tol)


# ----------------------------------------------------------------------------------------------
# every float32 matrix product at full precision


def _dot_precisions(jaxpr, out):
    """The precision of every dot_general in a jaxpr and all its sub-jaxprs (jit, scan, cond,
    shard_map, pallas_call, custom derivatives)."""
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "dot_general":
            out.append(eqn.params["precision"])
        for v in eqn.params.values():
            for sub in v if isinstance(v, list | tuple) else [v]:
                if hasattr(sub, "eqns"):
                    _dot_precisions(sub, out)
                elif hasattr(getattr(sub, "jaxpr", None), "eqns"):
                    _dot_precisions(sub.jaxpr, out)
    return out


def _assert_highest(fn, *args):
    precs = _dot_precisions(jax.make_jaxpr(fn)(*args).jaxpr, [])
    highest = (jax.lax.Precision.HIGHEST, jax.lax.Precision.HIGHEST)
    bad = [p for p in precs if p != highest]
    assert not bad, f"{len(bad)} of {len(precs)} dot_generals below HIGHEST: {bad[:3]}"
    return precs


def test_walker_catches_default_precision():
    a = jnp.ones((4, 2, 2), jnp.float32)
    with pytest.raises(AssertionError, match="below HIGHEST"):
        _assert_highest(lambda m: jnp.einsum("tij,tjk->tik", m, m), a)
    _assert_highest(lambda m: jnp.einsum("tij,tjk->tik", m, m, precision="highest"), a)


@pytest.fixture(scope="module")
def small32(signals):
    x, F = (jnp.asarray(a[:, :200], jnp.float32) for a in signals)
    return lj.Record(x, F, jnp.float32(DT), jnp.float32(0.0))


def test_lion_parallel_products_full_precision(small32):
    rec = jax.tree.map(lambda a: a[0] if a.ndim == 2 else a, small32)
    precs = _assert_highest(
        lambda r: lj.lion_parallel(lj.MassDamper(), r, jnp.eye(2, dtype=jnp.float32) * G).theta,
        rec,
    )
    # none at all: every product, the filter's matrix exponential included, is elementwise
    # (lionjax._linalg); test_walker_catches_default_precision shows the walker finds dots
    assert precs == []


@pytest.mark.parametrize("kernel", ["xla", "pallas"])
def test_lion_batched_products_full_precision(small32, kernel):
    _assert_highest(
        lambda r: (
            lj.lion_batched(
                lj.MassDamper(),
                r,
                gain=lj.AutoGain(),
                outputs=(lj.LSStatistics(transient=0.03),),
                execution=lj.Execution(kernel=kernel, shard=False),
                throw=False,
            ).theta
        ),
        small32,
    )
