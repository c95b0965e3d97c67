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
