"""Smoke runs of the benchmarks at tiny sizes (throughput.py with its numba arm; gpu_check.py --dry-run; the records of diagnosis_speed.py --lengths against scipy)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

# the slow tier (.ci/run's second step): the benchmark scripts in subprocesses
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]


def test_throughput_smoke(tmp_path, smoke_env):
    out = tmp_path / "out.json"
    cmd = [
        sys.executable,
        str(ROOT / "benchmarks" / "throughput.py"),
        "--batch",
        "8",
        "--samples",
        "200",
        "--repeats",
        "1",
        "--skip",
        "diffrax,scipy,numpy",
        "--json",
        str(out),
    ]
    res = subprocess.run(cmd, env=smoke_env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    data = json.loads(out.read_text())
    assert data["lionjax"]["law"] == "exact" and data["lionjax"]["msps"] > 0
    if "numba" in data:
        assert data["numba"]["agrees"]


def test_gpu_check_dry_run(tmp_path, smoke_env):
    """benchmarks/gpu_check.py --dry-run: the GPU check's code paths on the CPU at tiny sizes
    (Pallas in interpret mode, no CuPy, pytest collects only)."""
    out = tmp_path / "gpu_check.json"
    cmd = [
        sys.executable,
        str(ROOT / "benchmarks" / "gpu_check.py"),
        "--dry-run",
        "--out",
        str(out),
    ]
    res = subprocess.run(cmd, env=smoke_env, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    data = json.loads(out.read_text())
    assert data["dry_run"] is True
    for key in ("environment", "config", "agreement", "throughput", "parallel_in_time"):
        assert key in data, key
    assert {"pytest", "criteria", "stage_s"} <= set(data)
    for dtype in ("float32", "float64"):
        agree = data["agreement"][dtype]
        assert agree["pass"] and agree["dtype"] == dtype, agree
    row = data["throughput"][0]
    assert row["pallas"]["gsps"] > 0 and row["xla"]["gsps"] > 0
    assert "skipped" in row["cupy"]  # no CuPy in a dry run, with the reason
    assert data["parallel_in_time"]["agrees"]
    assert data["pytest"]["status"] == "collected"
    assert {c["status"] for c in data["criteria"].values()} == {"not measured"}
    assert "PASS" in res.stdout and "ACCEPTANCE" in res.stdout


def test_long_record_against_scipy():
    """diagnosis_speed.py --lengths' records: the mass–damper ẍ + aẋ = b(F + F₀) sampled under
    a zero-order hold, against scipy's exact discretisation (cont2discrete, zoh) driven by the
    same input, before the encoder steps and noise (agreement within 2 µm: one step plus 3σ of
    the 0.3 µm noise)."""
    import numpy as np
    from scipy.signal import cont2discrete, dlsim

    sys.path.insert(0, str(ROOT / "benchmarks"))
    import diagnosis_speed

    x, F, dt = diagnosis_speed._long_record(5000, 1000.0, seed=3)
    a, b, F0 = 8.0, 2.0, 0.3
    A, B = np.array([[0.0, 1.0], [0.0, -a]]), np.array([[0.0], [b]])
    sysd = cont2discrete((A, B, np.array([[1.0, 0.0]]), np.zeros((1, 1))), dt, method="zoh")
    _, y, _ = dlsim(sysd, F + F0)
    assert dt == 1e-3 and np.max(np.abs(x - y[:, 0])) < 2e-6
    assert np.ptp(x) > 100e-6  # the input moves the axis well beyond the encoder step
