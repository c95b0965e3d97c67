"""Smoke test of the blind diagnosis benchmark (benchmarks/_blind_sim.py, diagnosis_blind.py).

The independent simulator against closed forms (clean mass–damper, offset, saturation, delay,
dead zone, stick) and one two-case run of ``diagnosis_blind.run``. That run uses a stub in place
of ``lj.diagnose``: compiling the real diagnosis for a new length bucket takes ~5–15 s, beyond
this file's budget; tests/test_diagnose.py runs the benchmark with the real one.
"""

import math

import _blind_sim as bs  # benchmarks/ (tests/conftest.py)
import diagnosis_blind as blind  # benchmarks/ (tests/conftest.py)
import numpy as np
import pytest


def test_self_test_closed_form():
    worst = bs.self_test(1e-6)
    assert worst["x"] <= 1e-6 and worst["v"] <= 1e-6


def test_offset_gives_the_constant_force_response():
    a, b, F0, fs = 12.0, 2.0, 0.7, 777.7
    r = bs.simulate(bs.Axis(a, b, (bs.ForceOffset(F0),)), np.zeros(int(2 * fs)), fs)
    t = np.arange(r.x.size) / fs
    v = b * F0 / a * (1 - np.exp(-a * t))  # ẍ + aẋ = b·F0 from rest
    x = b * F0 / a * (t - (1 - np.exp(-a * t)) / a)
    assert np.max(np.abs(r.v_true - v)) <= 1e-6 * np.max(np.abs(v))
    assert np.max(np.abs(r.x_true - x)) <= 1e-6 * np.max(np.abs(x))
    assert r.v_true[-1] == pytest.approx(b * F0 / a, rel=1e-6)  # steady velocity b·F0/a


def test_hard_saturation_clips_and_dead_zone_removes():
    fs, a, b = 500.0, 20.0, 1.0
    F = 3.0 * np.sin(2 * np.pi * 2.0 * np.arange(1000) / fs)
    r = bs.simulate(bs.Axis(a, b, (bs.HardSaturation(1.2),)), F, fs)
    assert np.max(np.abs(r.u)) == pytest.approx(1.2)
    np.testing.assert_allclose(r.u, np.clip(F, -1.2, 1.2), atol=1e-15)
    X, _ = bs.exact_mass_damper(a, b, np.clip(F, -1.2, 1.2), 1 / fs)
    assert np.max(np.abs(r.x_true - X)) <= 1e-6 * np.max(np.abs(X))
    r = bs.simulate(bs.Axis(a, b, (bs.DeadZone(0.5),)), F, fs)
    np.testing.assert_allclose(r.u, np.sign(F) * np.maximum(np.abs(F) - 0.5, 0), atol=1e-15)


def test_fractional_delay_shifts_a_sine_by_its_phase():
    fs, f0, a, b = 1234.56, 3.0, 15.0, 1.0
    tau = 4.37 / fs  # 4.37 samples
    n = int(6 * fs)
    t = np.arange(n) / fs
    F = np.sin(2 * np.pi * f0 * t)

    def phase(v):
        sel = t > 3.0  # steady state
        A = np.stack([np.sin(2 * np.pi * f0 * t[sel]), np.cos(2 * np.pi * f0 * t[sel])], 1)
        s, c = np.linalg.lstsq(A, v[sel], rcond=None)[0]
        return math.atan2(c, s)

    v0 = bs.simulate(bs.Axis(a, b), F, fs).v_true
    v1 = bs.simulate(bs.Axis(a, b, (bs.InputDelay(tau),)), F, fs).v_true
    lag = (phase(v0) - phase(v1)) % (2 * np.pi)
    assert lag == pytest.approx(2 * np.pi * f0 * tau, abs=1e-3)


def test_coulomb_sticks_below_breakaway_and_slides_above():
    fs, a, b = 1000.0, 10.0, 1.0
    fr = bs.StribeckFriction(0.4, 0.6, 1e-3)
    r = bs.simulate(bs.Axis(a, b, (fr,)), np.full(500, 0.55), fs)
    assert np.all(r.x_true == 0) and np.all(r.v_true == 0)
    r = bs.simulate(bs.Axis(a, b, (fr,)), np.full(2000, 0.8), fs)
    assert r.v_true[-1] == pytest.approx(b * (0.8 - 0.4) / a, rel=1e-4)  # kinetic level F_c


def _stub(train, valid):
    """A stand-in for lj.diagnose: answers "none", and raises on its second call."""
    from types import SimpleNamespace

    if _stub.calls == 1:
        _stub.calls += 1
        raise RuntimeError("stub crash")
    _stub.calls += 1
    e = SimpleNamespace(name="offset", shrink=0.1, significant=False)
    return SimpleNamespace(
        verdict="none", stack=[], effects=[e], final={"shrink": 0.0}, confidence=0.5, ambiguous=[]
    )


_stub.calls = 0


def test_two_case_run_records_answers_and_crashes():
    out = blind.run(
        1,
        0,
        ("none", "cogging"),
        sources=("scipy",),
        rate=(300.0, 300.0),
        durations=(2.0, 2.0),
        diagnose=_stub,
        progress=False,
    )
    rows = out["records"]
    assert [r["class"] for r in rows] == ["none", "cogging"]
    assert rows[0]["correct"] and rows[0]["verdict"] == "none"
    assert not rows[1]["correct"] and rows[1]["crash"].startswith("RuntimeError")
    assert out["crashes"][0]["class"] == "cogging" and out["false_alarm_clean"] == 0.0
    assert 0.02 <= rows[1]["response_change"] <= 0.8 and rows[1]["size_in_band"]
    assert rows[0]["fs"] == pytest.approx(300.0) and rows[0]["n_samples"] == 601
    assert rows[0]["confidence"] == 0.5  # read from the diagnosis
