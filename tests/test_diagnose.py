"""lionjax.diagnose: the JSON contract, EMPS against the published table, the CLI, bad input and
a small blind evaluation on twin records (benchmarks/diagnosis_blind.py).

The cases of held-out records are in test_diagnose_floor.py (the noise floor and the loop),
test_diagnose_stacking.py (friction, stacking, stand-ins) and test_diagnose_modes.py (the flexible
mode); test_diagnose_rates.py runs the CLI across sample rates, test_diagnose_streamed.py reads
records in chunks. The statistics and kernels a diagnosis is built from (encoder lattice, loop
detection, hold correction, noise floor, filters, least squares, searches) are tested against
independent references in test_diagnose_kernels.py. (Several files: CI runs them on two workers,
one file each.)"""

import json

import diagnosis_blind as blind  # benchmarks/ (tests/conftest.py)
import numpy as np
import pytest

import lionjax as lj
from lionjax.cli import main

FIXED = ("coulomb_friction", "offset", "spring", "delay", "saturation", "position_dependent")


@pytest.fixture(scope="module")
def emps():
    tr = lj.datasets.emps("estimation")
    va = lj.datasets.emps("validation")
    return lj.diagnose(tr, va)


@pytest.mark.slow  # whole diagnoses (EMPS, a figure)
def test_emps_against_published(emps):
    R = lj.datasets.EMPS_REFERENCE
    j = emps.to_json()
    assert j["verdict"] == "coulomb_friction"
    assert j["stack"][0] == "coulomb_friction" and "offset" in j["stack"]
    p = j["final"]["params"]
    M = 1 / p["b"]
    assert M == pytest.approx(R.M, rel=0.02)
    assert p["a"] * M == pytest.approx(R.Fv, rel=0.02)
    assert p["Fc"] == pytest.approx(R.Fc, rel=0.02)
    assert p["F0"] == pytest.approx(R.F0, rel=0.02)  # F0 = −offset = +3.1648 N
    assert j["final"]["gap"] < j["baseline"]["gap"]


@pytest.mark.slow  # whole diagnoses (EMPS, a figure)
def test_json_contract(emps):
    j = json.loads(json.dumps(emps.to_json()))
    assert set(j["baseline"]) >= {"model", "params", "gap"}
    assert isinstance(j["where"], list) and all("kind" in w for w in j["where"])
    assert {e["name"] for e in j["effects"]} == {
        *FIXED,
        "asymmetric_friction",
        "flexible_mode",
        "force_sensor_line",
        "force_sensor_drift",
    }
    scores = [e["score"] for e in j["effects"]]
    assert scores == sorted(scores, reverse=True)
    for e in j["effects"]:
        assert set(e) >= {"name", "params", "gap", "shrink", "significant"}
        assert e["shrink"] == pytest.approx(1 - e["gap"] / j["baseline"]["gap"])
    assert j["verdict"] in (*j["stack"][:1], "none", "unexplained")
    assert "gap" in j["final"] and "Fc" in j["final"]
    kinds = {w["kind"] for w in j["where"]}
    assert kinds >= {"position", "velocity", "force", "frequency", "time", "whiteness"}
    # where the gap lies: the searched regions, strongest first, each at the family-wise level
    assert isinstance(j["regions"], list) and j["regions"]
    assert j["settings"]["alpha"] == 0.05
    for r in j["regions"]:
        assert r["variable"] in ("x", "v", "|v|", "F", "|F|", "t")
        assert r["low"] is not None or r["high"] is not None
        assert 0 < r["p_value"] <= 0.05 and 0 < r["sample_share"] < 1
        assert 0 <= r["gap_share"] <= 1 and r["stack_removes"] <= 1
    # the regions are recomputed from the validation signals alone (a pure function, seeded)
    again = lj.diagnosis.find_regions(
        {**emps.series}, alpha=0.05, filter_hz=j["settings"]["filter_hz"]
    )
    assert [r.to_json() for r in again] == emps.to_json()["regions"]


@pytest.mark.slow  # whole diagnoses (EMPS, a figure)
def test_cli_roundtrip_and_plot(tmp_path, capsys):
    tr, va, _ = blind.make_case("offset", 11, duration=2.5, rate=(1000.0, 1000.0))
    for name, r in (("train", tr), ("valid", va)):
        t = np.asarray(r.t)
        data = np.c_[t, np.asarray(r.x), np.asarray(r.F) / 2.0]
        np.savetxt(tmp_path / f"{name}.csv", data, delimiter=",", header="time,pos,u", comments="")
    out, png = tmp_path / "out.json", tmp_path / "out.png"
    rc = main(
        [
            "diagnose",
            str(tmp_path / "train.csv"),
            "--validate",
            str(tmp_path / "valid.csv"),
            "--columns",
            "t=time,x=pos,F=u",
            "--force-scale",
            "2.0",
            "--json",
            str(out),
            "--plot",
            str(png),
        ]
    )
    assert rc == 0
    j = json.loads(out.read_text())
    assert j["verdict"] == "offset" and j["stack"] == ["offset"]
    assert png.stat().st_size > 10_000
    # an offset acts on the whole record: no region of it, and the CLI says so
    assert j["regions"] == []
    assert "where the gap lies: no region is significant at α = 0.05" in capsys.readouterr().out


def test_cli_refuses_nonuniform(tmp_path, capsys):
    t = np.cumsum(np.r_[0, np.full(999, 1e-3)])
    t[500:] += 3e-4
    np.savetxt(
        tmp_path / "a.csv",
        np.c_[t, np.sin(t), np.cos(t)],
        delimiter=",",
        header="t,x,F",
        comments="",
    )
    rc = main(["diagnose", str(tmp_path / "a.csv")])
    assert rc == 2
    assert "not uniform" in capsys.readouterr().err


def test_bad_arguments():
    t = np.arange(1000) * 1e-3  # a moving, forced record: the arguments are what is wrong
    rec = lj.Record(0.01 * np.sin(5 * t), np.cos(5 * t), 1e-3)
    with pytest.raises(lj.InputError, match="valid"):
        lj.diagnose(rec, "nope")
    with pytest.raises(lj.InputError, match="filter_hz"):
        lj.diagnose(rec, filter_hz=900.0)
    other = lj.Record(rec.x, rec.F, 2e-3)
    with pytest.raises(lj.InputError, match="sample interval"):
        lj.diagnose(rec, other)


@pytest.mark.slow  # diagnoses of blind-benchmark records
def test_blind_small():
    """The blind benchmark's harness (``blind.run``) with the real diagnosis, end to end, on one
    twin record per outcome it scores: clean (``none``), two named effects, and one outside the
    library (``unexplained``). The library's other effects are named in the files of
    held-out cases (test_diagnose_stacking.py, test_diagnose_floor.py, test_diagnose_rates.py);
    the full benchmark (benchmarks/diagnosis_blind.py) is the measure."""
    classes = ("none", "offset", "spring", "dead_zone")
    out = blind.run(
        per_class=1,
        seed0=500,
        classes=classes,
        duration=2.5,
        rate=(1000.0, 1000.0),
        sources=("twin",),
        progress=False,
    )
    rows = out["records"]
    assert [r["class"] for r in rows] == list(classes)
    single = [r for r in rows if r["class"] in FIXED]
    assert all(r["verdict"] == r["class"] for r in single)
    clean = [r for r in rows if r["class"] == "none"]
    assert all(r["verdict"] == "none" for r in clean)
    ool = [r for r in rows if r["class"] == "dead_zone"]  # outside the library
    assert all(r["verdict"] == "unexplained" for r in ool)
    # "none" is never a verdict the evidence contradicts (confidence = its BIC weight)
    assert all(r["confidence"] >= 0.05 for r in rows if r["verdict"] == "none")
