"""``lionjax reproduce``: files and their documented schema (quick sizes, in process).

The in-process run shares JAX's compilation cache with tests/test_experiments.py (same quick
configuration and seed), so it costs only the run time once the other file has compiled.
"""

import csv
import json

import jax
import numpy as np
import pytest

import lionjax as lj
from lionjax.cli import main

ROW_KEYS = {
    "region",
    "operating_point_mm",
    "settings",
    "input",
    "repetition",
    "a",
    "b",
    "var_mm2",
    "a_err_pct",
    "b_err_pct",
    "a_true",
    "b_true",
}
EFFECT_KEYS = {
    "name",
    "description",
    "a",
    "b",
    "a_err_pct",
    "b_err_pct",
    "nrmse",
    "nrmse_baseline",
    "growth",
}


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    d = tmp_path_factory.mktemp("reproduce")
    assert main(["reproduce", "--quick", "--out", str(d), "--seed", "0"]) == 0
    return d


def test_files_written(out):
    for name in ("table.json", "table.csv", "effects.json", "summary.json", "report.md"):
        assert (out / name).stat().st_size > 100, name
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert pngs == sorted(
        [
            "fig3_calibration.png",
            "fig4_convergence.png",
            "fig5_tracking_error.png",
            "fig6_verification.png",
            "table3_errors.png",
            "effects_nrmse.png",
        ]
    )
    for p in out.glob("*.png"):
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_table_schema_and_numbers(out):
    rows = json.loads((out / "table.json").read_text())
    cfg = lj.paper.PaperConfig.quick()
    R, I, K = cfg.shape
    assert len(rows) == 2 * R * (I * K + 1)
    for r in rows:
        assert set(r) == ROW_KEYS
        assert r["region"] in (1, 2, 3)
        assert r["settings"] in ("paper", "recommended")
        assert r["input"] in (*range(1, I + 1), "all")
        assert (r["input"] == "all") == (r["repetition"] == "all")
        assert r["a_err_pct"] == pytest.approx(100 * (r["a"] / r["a_true"] - 1))
        assert r["b_err_pct"] == pytest.approx(100 * (r["b"] / r["b_true"] - 1))
    summary = [r for r in rows if r["input"] == "all"]
    assert len(summary) == 6
    for r in summary:
        # the median of the region's per-record rows
        per = [
            q["a"]
            for q in rows
            if q["settings"] == r["settings"] and q["region"] == r["region"] and q["input"] != "all"
        ]
        assert r["a"] == pytest.approx(float(np.median(per)), rel=1e-12)
        if r["settings"] == "recommended":
            assert abs(r["a_err_pct"]) < 1 and abs(r["b_err_pct"]) < 1
    with open(out / "table.csv") as f:
        csv_rows = list(csv.DictReader(f))
    assert len(csv_rows) == len(rows)
    assert float(csv_rows[0]["a"]) == pytest.approx(rows[0]["a"], rel=1e-12)


def test_table_row_vs_direct_least_squares(out):
    """One record re-simulated through the public API: Lion's row ≈ lj.least_squares (2 %)."""
    rows = json.loads((out / "table.json").read_text())
    cfg = lj.paper.PaperConfig.quick()
    summary = json.loads((out / "summary.json").read_text())
    _, k_run = jax.random.split(jax.random.key(0))
    recs = lj.paper.paper_records(cfg, key=k_run, calibration_gain=summary["calibration"]["gain"])
    rec = jax.tree.map(lambda z: z[1, 2, 0], recs)
    ls = lj.least_squares(lj.MassDamper(), rec)
    row = next(
        q for q in rows if q["settings"] == "recommended" and q["region"] == 2 and q["input"] == 3
    )
    np.testing.assert_allclose([row["a"], row["b"]], np.asarray(ls.theta), rtol=2e-2)


def test_effects_and_report(out):
    effects = json.loads((out / "effects.json").read_text())
    assert [e["name"] for e in effects] == [c.name for c in lj.paper.realistic_effects()]
    for e in effects:
        assert set(e) == EFFECT_KEYS
        assert len(e["a_err_pct"]) == 3
        assert e["nrmse"] > 0 and e["growth"] == pytest.approx(e["nrmse"] / e["nrmse_baseline"])
    report = (out / "report.md").read_text()
    for heading in (
        "## Force calibration",
        "## Identification",
        "## Verification",
        "## One unmodelled effect",
    ):
        assert heading in report
    for e in effects:
        assert f"| {e['name']} |" in report
    summary = json.loads((out / "summary.json").read_text())
    assert abs(summary["calibration"]["gain"] / 1.75 - 1) < 0.01
    assert summary["verification"]["recommended"]["nrmse"] < 0.01


def test_bad_out_is_an_error(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["reproduce", "--quick", "--out", str(f)]) == 2
    assert "--out" in capsys.readouterr().err
