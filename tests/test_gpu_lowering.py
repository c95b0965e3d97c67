"""The GPU lowering of the Pallas kernel, proven without a GPU: ``jax.export`` to ``cuda`` runs
Pallas' Triton lowering on any machine where JAX's CUDA plugin is installed (``.ci/gpu-lowering``
builds such an environment). Skipped where the plugin is not importable (the normal CI venv);
with ``LIONJAX_REQUIRE_GPU_LOWERING=1`` in the environment a missing plugin fails instead.

At the benchmark's sizes (B = 4096 records × T = 8000 samples), in float32 and float64:

- the benchmark's configuration (one filter, one dt, a scalar FixedGain, no outputs, the default
  series evaluation of E): 2 Triton kernels, the estimation and its closed-form re-run;
- every option at once (one filter and one dt per record, AutoGain with a rate per record, the
  normalised law, θ₀, ``lengths``, LSStatistics, ConvergenceTime, TailStatistics, Trajectory):
  3 Triton kernels, the statistics pass (for the gain and LSStatistics) and the two above;
- the Euler stepper with the closed form of E throughout: 1 kernel;
- ``least_squares_batched`` (the statistics pass alone): 1 kernel;
- ``lion_parallel`` on one record of 10⁶ samples: plain XLA (associative scans), no kernel.

Every Triton kernel carries the pinned launch parameters (``num_warps = 4``, ``num_stages = 1``,
:data:`lionjax._pallas.TRITON_PARAMS`), no export contains a Mosaic call, and the outputs have the
records' dtype. Where ``ptxas`` is on the PATH, the Triton modules are also compiled for sm_90a
(H100) through the plugin's Triton compiler, and must not spill registers.
"""

import io
import os
import re
import shutil
import subprocess

import jax
import jax.numpy as jnp
import pytest

import lionjax as lj
from lionjax import _pallas


def _plugin():
    """The CUDA plugin, or a skip (a failure under LIONJAX_REQUIRE_GPU_LOWERING=1)."""
    try:
        import jax_plugins.xla_cuda12 as plugin
    except ImportError as e:
        reason = f"JAX's CUDA plugin is not importable ({e}); run .ci/gpu-lowering"
        if os.environ.get("LIONJAX_REQUIRE_GPU_LOWERING") == "1":
            pytest.fail(reason)
        pytest.skip(reason)
    return plugin


B, T = 4096, 8000  # the benchmark's sizes
TRITON = "__gpu$xla.gpu.triton"


def _export(f, *args):
    _plugin()
    exp = jax.export.export(
        jax.jit(f),
        platforms=["cuda"],
        disabled_checks=[jax.export.DisabledSafetyCheck.custom_call(TRITON)],
    )(*args)
    return exp, exp.mlir_module()


def _sds(shape, dtype):
    return jax.ShapeDtypeStruct(shape, dtype)


def _shared(x, F):
    rec = lj.Record(x, F, jnp.asarray(1e-3, x.dtype))
    return lj.lion_batched(
        lj.MassDamper(),
        rec,
        gain=lj.FixedGain(100.0),
        execution=lj.Execution(kernel="pallas", shard=False),
        throw=False,
    ).theta


def _everything(x, F, dt, coeffs, lengths, rate):
    rec = lj.Record(x, F, dt, jnp.zeros_like(dt))
    sol = lj.lion_batched(
        lj.MassDamper(),
        rec,
        bank=lj.FilterBank(coeffs, unit_dc_gain=True),
        gain=lj.AutoGain(rate),
        stepper=lj.ExactStep(normalisation=0.5),
        theta0=jnp.array([20.0, 2.0], x.dtype),
        lengths=lengths,
        outputs=(
            lj.LSStatistics(transient=0.03),
            lj.ConvergenceTime(tolerance=0.3),
            lj.TailStatistics(),
            lj.Trajectory(500),
        ),
        execution=lj.Execution(kernel="pallas", shard=False),
        throw=False,
    )
    return sol.theta, sol.J, sol.result, sol.outputs


def _euler(x, F):
    rec = lj.Record(x, F, jnp.asarray(1e-3, x.dtype))
    return lj.lion_batched(
        lj.MassDamper(),
        rec,
        gain=lj.FixedGain(10.0),
        stepper=lj.EulerStep(),
        execution=lj.Execution(kernel="pallas", shard=False, phi="closed"),
        throw=False,
    ).theta


def _ls(x, F, lengths):
    rec = lj.Record(x, F, jnp.asarray(1e-3, x.dtype))
    return lj.least_squares_batched(
        lj.MassDamper(),
        rec,
        lengths=lengths,
        execution=lj.Execution(kernel="pallas", shard=False),
        throw=False,
    ).theta


def _args(name, dtype):
    X = _sds((B, T), dtype)
    if name == "shared" or name == "euler":
        return (X, X)
    if name == "least_squares":
        return (X, X, _sds((B,), jnp.int32))
    return (X, X, _sds((B,), dtype), _sds((B, 3), dtype), _sds((B,), jnp.int32), _sds((B,), dtype))


VARIANTS = {"shared": (_shared, 2), "everything": (_everything, 3), "euler": (_euler, 1)}
VARIANTS["least_squares"] = (_ls, 1)


def _check_triton(text, n):
    assert text.count(TRITON) == n
    assert "mosaic" not in text.lower()
    # the pinned launch parameters, on every kernel (lionjax._pallas.TRITON_PARAMS)
    warps = re.findall(r"num_warps = (\d+)", text)
    stages = re.findall(r"num_stages = (\d+)", text)
    assert warps == [str(_pallas.TRITON_PARAMS.num_warps)] * n
    assert stages == [str(_pallas.TRITON_PARAMS.num_stages)] * n
    assert _pallas.TRITON_PARAMS.num_warps * 32 == _pallas.ROWS_GPU  # one record per thread


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64], ids=["float32", "float64"])
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_pallas_kernel_lowers_to_triton(variant, dtype):
    f, n = VARIANTS[variant]
    exp, text = _export(f, *_args(variant, dtype))
    _check_triton(text, n)
    floats = [a for a in exp.out_avals if jnp.issubdtype(a.dtype, jnp.floating)]
    assert floats and all(a.dtype == dtype for a in floats)
    assert exp.out_avals[0].shape == (B, 2)  # θ of every record


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64], ids=["float32", "float64"])
def test_lion_parallel_lowers(dtype):
    Tl = 10**6

    def f(x, F, G):
        rec = lj.Record(x, F, jnp.asarray(1e-3, dtype))
        sol = lj.lion_parallel(lj.MassDamper(), rec, G)
        return sol.theta, sol.theta_final

    exp, text = _export(f, _sds((Tl,), dtype), _sds((Tl,), dtype), _sds((2, 2), dtype))
    assert TRITON not in text and "mosaic" not in text.lower()
    assert "custom_call" not in text  # associative scans and elementwise algebra only
    assert [a.shape for a in exp.out_avals] == [(Tl, 2), (2,)]
    assert all(a.dtype == dtype for a in exp.out_avals)


def test_xla_kernel_has_no_triton_call():
    """The counter-check: the same call with the fused XLA loop holds no Triton kernel (so the
    counts above are the Pallas kernel's)."""

    def f(x, F):
        rec = lj.Record(x, F, jnp.asarray(1e-3, x.dtype))
        return lj.lion_batched(
            lj.MassDamper(),
            rec,
            gain=lj.FixedGain(100.0),
            execution=lj.Execution(kernel="xla", shard=False),
            throw=False,
        ).theta

    _, text = _export(f, *_args("shared", jnp.float32))
    assert TRITON not in text


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64], ids=["float32", "float64"])
def test_triton_compiles_for_h100_without_spills(dtype, monkeypatch, tmp_path):
    """Triton → PTX through the plugin's compiler, PTX → SASS for sm_90a with ptxas: registers
    per thread and no spills (speed still needs a GPU: benchmarks/gpu_check.py)."""
    _plugin()
    if shutil.which("ptxas") is None:
        pytest.skip("ptxas not on the PATH (CUDA toolkit); the lowering tests above still ran")
    from jax._src.lib import triton
    from jax._src.pallas.triton import pallas_call_registration as registration

    jax.devices()  # the plugin registers its Triton compiler when JAX initialises its backends
    if not triton.has_compilation_handler("CUDA"):
        pytest.fail("JAX's CUDA plugin registered no Triton compiler")

    modules = []
    lower = registration.lowering.lower_jaxpr_to_triton_module

    def capture(*args, **kwargs):
        result = lower(*args, **kwargs)
        buf = io.BytesIO()
        result.module.operation.write_bytecode(buf)
        modules.append(buf.getvalue())
        return result

    monkeypatch.setattr(registration.lowering, "lower_jaxpr_to_triton_module", capture)
    jax.clear_caches()  # lower again (the export above may be cached)
    _export(_everything, *_args("everything", dtype))
    assert len(modules) == 3
    params = _pallas.TRITON_PARAMS
    for i, m in enumerate(modules):
        ptx = triton.compile(
            "CUDA",
            m,
            "9.0",
            num_warps=params.num_warps,
            num_ctas=1,
            num_stages=params.num_stages,
        )
        assert ptx.smem_bytes == 0  # rows come from global memory, nothing staged
        path = tmp_path / f"kernel{i}.ptx"
        path.write_text(ptx.asm)
        res = subprocess.run(
            ["ptxas", "-v", "--gpu-name", "sm_90a", "-o", os.devnull, str(path)],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert res.returncode == 0, res.stderr[-2000:]
        info = res.stderr
        regs = int(re.search(r"Used (\d+) registers", info).group(1))
        assert re.search(r"0 bytes spill stores, 0 bytes spill loads", info), info
        assert regs <= 255
        print(f"kernel {i} ({jnp.dtype(dtype).name}): {regs} registers per thread, no spills")
