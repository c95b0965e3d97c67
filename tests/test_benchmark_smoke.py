"""Smoke run of benchmarks/throughput.py at a tiny size (the study module is not written yet; numba skipped when not installed)."""

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_throughput_smoke(tmp_path):
    out = tmp_path / "out.json"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
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
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    data = json.loads(out.read_text())
    assert data["lionjax"]["law"] == "exact" and data["lionjax"]["msps"] > 0
    if "numba" in data:
        assert data["numba"]["agrees"]


def test_gpu_check_dry_run(tmp_path):
    """benchmarks/gpu_check.py --dry-run: the GPU check's code paths on the CPU at tiny sizes
    (Pallas in interpret mode, no CuPy, pytest collects only)."""
    out = tmp_path / "gpu_check.json"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [
        sys.executable,
        str(ROOT / "benchmarks" / "gpu_check.py"),
        "--dry-run",
        "--out",
        str(out),
    ]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
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
