import os
import pathlib
import re
import sys
from importlib import metadata

# One JAX compilation cache for the whole run, shared by the pytest-xdist workers and the
# notebook kernels they start (set before jax is imported, so child processes inherit it): the
# suite is compile-bound, and the workers compile many of the same programs. Results do not
# depend on it (a cache hit is the same executable).
_ROOT = pathlib.Path(__file__).resolve().parents[1]
_CACHE = _ROOT / ".jax_cache"
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(_CACHE))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.2")
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
# One BLAS thread per process: the suite runs two pytest-xdist workers on two cores, and each
# worker's JAX already keeps both busy; OpenBLAS's own threads then spin against them, and the
# diagnosis' host-side float64 Gram products (numpy) slow many times over (test_diagnose_modes
# and test_diagnose_stacking, 24 tests, on a loaded 2-core machine: 125 s with one thread; with
# two, 13 tests done when stopped at 500 s). Set before the workers start, which inherit it
# (this process may have imported numpy already, through a plugin; the workers run the tests).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
# XLA's CPU fusion emitters (its default) take about twice as long to compile this package's
# programs as the elemental emitters (measured on the 2-core CI machine: a first lion_batched
# call 9.5 → 5.3 s, a first lion call 4.4 → 2.2 s, the tune compile 25 → 15 s). At the suite's
# sizes (a few records of a few thousand samples) the run time is the same, and the suite is
# compile-bound, so the tests use the elemental emitters; children (notebook kernels,
# subprocess tests) inherit the flag. Not for real work: at benchmark sizes the fusion
# emitters' kernels run 2.6-3.6x faster (benchmarks/README.md, "Compile time and the XLA:CPU
# emitters").
# (Gated on the jaxlib it was measured with: XLA aborts on a flag it does not know. Not set where
# a GPU plugin is installed: on an H200 with jax 0.11.2 and jax-cuda13-pjrt, pytest on the GPU
# test files ended with status 1 and no output while the flag was set, and ran (45 passed)
# with this line disabled, nothing else changed.)
_FLAG = "--xla_cpu_use_fusion_emitters=false"
_JAXLIB = tuple(int(p) for p in re.findall(r"\d+", metadata.version("jaxlib"))[:2])
_GPU_PLUGIN = any(
    re.fullmatch(r"jax[-_](cuda|rocm)\d*[-_](pjrt|plugin)", (d.metadata["Name"] or "").lower())
    for d in metadata.distributions()
)
if (
    _JAXLIB >= (0, 10)
    and not _GPU_PLUGIN
    and "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", "")
):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + _FLAG).strip()

import jax  # noqa: E402

# The blind benchmark's generators (benchmarks/diagnosis_blind.py, _blind_sim.py) serve the
# diagnosis tests as independent references: importable as top-level modules.
sys.path.insert(0, str(_ROOT / "benchmarks"))

jax.config.update("jax_enable_x64", True)
# (also through the config, in case a plugin imported jax before this file)
jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
jax.config.update(
    "jax_persistent_cache_min_compile_time_secs",
    float(os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"]),
)
jax.config.update(
    "jax_persistent_cache_min_entry_size_bytes",
    int(os.environ["JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES"]),
)


# pytest.approx reads the numpy protocol of what it is handed (`.flat` since pytest 9.2), which
# JAX arrays do not implement in full: a JAX array on either side of an approx comparison works
# with one pytest and raises with the next. Every test hands approx Python or numpy numbers
# (float(...), np.asarray(...)); this guard makes a JAX array there fail the same way on every
# pytest version, with the fix in the message, instead of only on the newest.
import pytest  # noqa: E402

_APPROX = pytest.approx
_GUARDED: dict[type, type] = {}


def _refuse_jax(value, side: str) -> None:
    leaves = jax.tree.leaves(value) if isinstance(value, list | tuple | dict) else [value]
    if any(isinstance(v, jax.Array) for v in leaves):
        raise TypeError(
            f"pytest.approx: the {side} value is a JAX array; pass float(...) for a scalar or "
            "np.asarray(...) for an array (approx reads the numpy protocol, which JAX arrays "
            "do not implement in full)"
        )


def _guarded_class(cls: type) -> type:
    if cls not in _GUARDED:

        def __eq__(self, actual):
            _refuse_jax(actual, "compared")
            return cls.__eq__(self, actual)

        _GUARDED[cls] = type(cls.__name__, (cls,), {"__eq__": __eq__, "__hash__": None})
    return _GUARDED[cls]


def _approx(expected, *args, **kwargs):
    __tracebackhide__ = True
    _refuse_jax(expected, "expected")
    result = _APPROX(expected, *args, **kwargs)
    result.__class__ = _guarded_class(type(result))
    return result


pytest.approx = _approx


#: LLVM's optimisation level for the README's test command (``-m "not slow"``) alone. That tier is
#: compile-bound (small records, many distinct programs): at level 0 it ran in 269 s against
#: 314 s at XLA's default with an empty compilation cache on the 2-core machine (646 tests, all
#: passing either way). The slow tier keeps the default: its diagnoses are run-bound (at level 0
#: it took 1066 s, not about 760 s) and two of its tests compare two programs bit for bit
#: (tests/test_batched.py::test_split_loops_equal_one_loop, tests/test_pallas.py), which holds
#: at the default level only. Not for real work, like the emitter flag above.
_FAST_TIER_FLAG = "--xla_backend_optimization_level=0"


def _level_zero(env) -> str | None:
    """``env``'s XLA_FLAGS with LLVM at level 0, where the emitter flag above is set (a CPU run)
    and no level is; None otherwise."""
    flags = env.get("XLA_FLAGS", "")
    if _FLAG in flags and "xla_backend_optimization_level" not in flags:
        return f"{flags} {_FAST_TIER_FLAG}"
    return None


def pytest_configure(config):
    """Level 0 for the README's test command, set before any backend starts: XLA reads
    XLA_FLAGS when the first computation starts its backend, and the pytest-xdist workers,
    started after this hook, inherit it."""
    flags = _level_zero(os.environ)
    if (config.option.markexpr or "").strip() == "not slow" and flags:
        os.environ["XLA_FLAGS"] = flags


@pytest.fixture
def smoke_env() -> dict[str, str]:
    """The environment of a subprocess that runs lionjax at tiny sizes (a benchmark script's
    smoke run, the two-device sharding check): this run's, with the repository on PYTHONPATH
    and, where the emitter flag above is set (a CPU run), LLVM at level 0. Such a child is
    compile-bound like the README's test command: level 0 took throughput.py's smoke run from
    34.9 to 24.4 s of CPU on the 2-core machine. Its comparisons are of programs compiled alike
    (sharded against unsharded, Pallas against the XLA loop at its tolerance), not bit for bit
    against the slow tier's own level. (Not the notebooks: their kernels share the compilation
    cache that the slow tier's own tests fill at the default level, and at level 0 they ran
    slower in .ci/run, 01_paper 23.6 → 33.0 s.)"""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(_ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    env["XLA_FLAGS"] = _level_zero(env) or env.get("XLA_FLAGS", "")
    return env


def pytest_collection_modifyitems(config, items):
    """The notebooks (nbmake's items) belong to the slow tier: the README's test command
    (``-m "not slow"``) leaves them out, ``.ci/run``'s second step (``-m slow``) runs them."""
    notebooks = _ROOT / "notebooks"
    for item in items:
        if pathlib.Path(str(item.path)).is_relative_to(notebooks):
            item.add_marker(pytest.mark.slow)
