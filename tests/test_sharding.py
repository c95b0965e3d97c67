"""Sharded over two forced host devices == unsharded (run in a subprocess: the device count
must be fixed before JAX starts, and the rest of the suite keeps one device)."""

import subprocess
import sys
import textwrap

import pytest

# the slow tier (.ci/run's second step): a subprocess with two host devices
pytestmark = pytest.mark.slow

SCRIPT = textwrap.dedent(
    """
    import jax, numpy as np
    jax.config.update("jax_enable_x64", True)
    import lionjax as lj
    assert len(jax.local_devices()) == 2, jax.local_devices()
    rng = np.random.default_rng(0)
    B, T = 6, 2600
    t = np.arange(T) * 1e-3
    F = np.sin(2 * np.pi * 1.3 * t)[None] + 0.3 * rng.normal(size=(B, T))
    x = np.cumsum(np.cumsum(F, 1), 1) * 1e-6
    rec = lj.Record(x, F, 1e-3)
    outputs = (lj.LSStatistics(), lj.ConvergenceTime(), lj.TailStatistics())
    kw = dict(gain=lj.AutoGain(2.0), outputs=outputs, throw=False)
    placed = lj.shard_records(rec)
    assert len(placed.x.sharding.device_set) == 2, placed.x.sharding
    a = lj.lion_batched(lj.MassDamper(), placed, execution=lj.Execution(shard=True), **kw)
    assert len(a.theta.sharding.device_set) == 2, a.theta.sharding  # it did run sharded
    b = lj.lion_batched(lj.MassDamper(), rec, execution=lj.Execution(shard=False), **kw)
    for name in ("theta", "J", "theta_ls", "t_converged"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-10, atol=0)
    # std = sqrt(E[θ²] − E[θ]²) amplifies last-bit differences of the (differently fused) kernel
    np.testing.assert_allclose(a.tail_std, b.tail_std, rtol=1e-5)
    # one filter per record on placed records (the per-record discretisation over both
    # devices, which stopped XLA:CPU at B = 4000-4096 with jax's expm; benchmarks/README.md)
    banks = lj.studies.stack_banks([[-40.0 - i, -40.0, -40.0] for i in range(B)])
    kw2 = dict(gain=lj.FixedGain(1e3), bank=banks, throw=False)
    c = lj.lion_batched(lj.MassDamper(), placed, **kw2)
    d = lj.lion_batched(lj.MassDamper(), rec, **kw2)
    np.testing.assert_allclose(c.theta, d.theta, rtol=1e-10)
    # unplaced records: laid out over the devices as views of their memory (no copy), the
    # default call sharded; rows that would not start on 64 bytes are not viewed
    xj = jax.numpy.asarray(x)
    recj = lj.Record(xj, jax.numpy.asarray(F), 1e-3)
    viewed = lj.shard_records(recj)
    base = np.asarray(xj).ctypes.data
    ptrs = [s.data.unsafe_buffer_pointer() for s in viewed.x.addressable_shards]
    assert sorted(ptrs) == [base, base + (B // 2) * T * 8], (ptrs, base)
    e = lj.lion_batched(lj.MassDamper(), recj, **kw)
    assert len(e.theta.sharding.device_set) == 2, e.theta.sharding
    for name in ("theta", "J", "theta_ls", "t_converged"):
        np.testing.assert_allclose(getattr(e, name), getattr(b, name), rtol=1e-10, atol=0)
    odd = lj.Record(jax.numpy.asarray(x[:, :2599]), jax.numpy.asarray(F[:, :2599]), 1e-3)
    f = lj.lion_batched(lj.MassDamper(), odd, **kw)  # 3·2599·8 bytes: not on 64 bytes
    assert len(f.theta.sharding.device_set) == 1, f.theta.sharding
    g = lj.lion_batched(lj.MassDamper(), lj.shard_records(odd), **kw)  # copied over
    assert len(g.theta.sharding.device_set) == 2, g.theta.sharding
    np.testing.assert_allclose(f.theta, g.theta, rtol=1e-10)
    print("OK", a.theta.sharding)
    """
)


def test_sharded_equals_unsharded_on_two_host_devices(smoke_env):
    env = dict(smoke_env)
    env["XLA_FLAGS"] = env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert "OK" in out.stdout
