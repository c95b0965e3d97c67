"""Smoke test of the blind diagnosis benchmark (benchmarks/_blind_sim.py, diagnosis_blind.py).

The independent simulator against closed forms (clean mass–damper, offset, saturation, delay,
dead zone, stick, quadratic drag) and one two-case run of ``diagnosis_blind.run``. That run uses
a stub in place of ``lj.diagnose``: compiling the real diagnosis for a new length bucket takes
~5–15 s, beyond this file's budget; tests/test_diagnose.py runs the benchmark with the real one.
The newer classes (dominant spring and stiction, triples, quadratic drag, force-sensor line and
drift): each makes a case from both sources, the sensor artefacts reach the log only, and the
accepted-answer rules (triple, extra candidates) and the ``--candidates`` plumbing hold.
"""

import dataclasses
import math

import _blind_sim as bs  # benchmarks/ (tests/conftest.py)
import diagnosis_blind as blind  # benchmarks/ (tests/conftest.py)
import numpy as np
import pytest

# the slow tier (.ci/run's second step): the blind benchmark's generator and diagnoses
pytestmark = pytest.mark.slow


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


def test_quadratic_drag_reaches_its_terminal_velocity():
    a, b, c2, F0, fs = 10.0, 2.0, 3.0, 1.5, 800.0
    r = bs.simulate(bs.Axis(a, b, (bs.QuadraticDrag(c2),)), np.full(int(3 * fs), F0), fs)
    v_end = (-a + math.sqrt(a * a + 4 * b * c2 * b * F0)) / (2 * b * c2)  # a·v + b·c₂·v² = b·F0
    assert r.v_true[-1] == pytest.approx(v_end, rel=1e-9)


def test_quadratic_drag_twin_and_scipy_agree():
    """The drag written twice (a twin effect class, the numba kernel) on one open-loop setup."""
    rng = np.random.default_rng(3)
    st = blind.draw_setup(rng, "twin", (500.0, 500.0), (2.0, 2.0), closed=False)
    st = dataclasses.replace(st, noise=0.0)
    x0, F0, _, v0 = blind.simulate(st, [], 1)
    d = blind.draw_effect("quadratic_drag", rng, st, blind._stats(x0, F0, v0))
    d.strength = 1.0
    v_twin = blind.simulate(st, [d], 1)[3]
    v_scipy = blind.simulate(dataclasses.replace(st, source="scipy"), [d], 1)[3]
    assert 0.02 <= blind._change(v_scipy, v0) <= 0.8  # felt
    assert np.max(np.abs(v_twin - v_scipy)) <= 1e-6 * np.max(np.abs(v_scipy))


@pytest.mark.parametrize("source", blind.SOURCES)
@pytest.mark.parametrize("cls", blind.ARTEFACTS)
def test_sensor_artefact_reaches_the_log_only(cls, source):
    """Closed loop: the measured position, the true motion and the command equal the clean
    run's exactly (the device never feels the artefact, the loop never reads it); the logged
    force is the command plus the artefact (the line's amplitudes at f₀, 2f₀, 3f₀)."""
    rng = np.random.default_rng(8)  # the line: 60 Hz with its 2nd and 3rd harmonic
    st = blind.draw_setup(rng, source, (400.0, 400.0), (2.0, 2.0), closed=True)
    x0, F0, xt0, v0 = blind.simulate(st, [], 1)
    d = blind.draw_effect(cls, rng, st, blind._stats(x0, F0, v0))
    d.strength = 0.5
    x, F, xt, v = blind.simulate(st, [d], 1)
    for got, clean in ((x, x0), (xt, xt0), (v, v0)):
        assert np.array_equal(got, clean)
    p, t = d.params(d.strength), np.arange(st.n) * st.dt
    art = F - F0
    if cls == "force_sensor_line":
        w = 2 * np.pi * p["frequency"] * t
        cols = np.stack([f(h * w) for h in (1, 2, 3) for f in (np.sin, np.cos)], 1)
        sc = np.linalg.lstsq(cols, art, rcond=None)[0].reshape(3, 2)
        amp = np.hypot(sc[:, 0], sc[:, 1])
        assert d.shape == "60Hz+harmonics" and p["a2"] > 0 and p["a3"] > 0
        np.testing.assert_allclose(amp, [p["amplitude"], p["a2"], p["a3"]], atol=1e-9)
        assert p["amplitude"] == pytest.approx(0.5 * blind._stats(x0, F0, v0)["F_rms"])
        assert p["frequency"] in (50.0, 60.0)
        if 3 * p["frequency"] >= st.fs / 2:  # no room for the 3rd harmonic: 50 Hz alone
            assert p["frequency"] == 50.0 and p["a2"] == p["a3"] == 0.0
    else:
        np.testing.assert_allclose(art, p["rate"] * t, atol=1e-12)
        assert art[-1] == pytest.approx(p["amplitude"])  # A reached at the record's end


@pytest.mark.parametrize("source", blind.SOURCES)
@pytest.mark.parametrize("cls", blind.NEW)
def test_new_class_makes_a_case(cls, source):
    """Each new class, from both sources, at 400 Hz for 2 s: finite records, sized as its
    class says (or flagged), and the class' own draws (rates, loop, triple, stuck share)."""
    seed = 10000 * blind.CLASSES.index(cls) + 1000 * blind.SOURCES.index(source)
    tr, va, info = blind.make_case(cls, seed, 2.0, source=source, rate=(400.0, 400.0))
    fs = info["fs"]  # 400 Hz to rounding
    assert all(np.all(np.isfinite(r.x)) and np.all(np.isfinite(r.F)) for r in (tr, va))
    eff = info["effects"]
    band = {"spring_dominant": blind.SPRING_BAND, "stiction_dominant": blind.DOMINANT_BAND}.get(
        cls, blind.BAND
    )
    assert info["size_band"] == [list(band)] * len(eff)
    if cls not in blind.ARTEFACTS:
        changes = [e["change_alone"] for e in eff]
        assert info["size_in_band"] == all(band[0] <= c <= band[1] for c in changes)
    if cls == "spring_dominant":
        p, fh = eff[0]["params"], blind.filter_corner(fs)
        assert eff[0]["name"] == "spring" and p["filter_hz"] == fh
        assert 1.2 * fh <= p["f_n"] <= min(3 * fh, fs / 8)
        assert p["k"] == pytest.approx((2 * math.pi * p["f_n"]) ** 2 / info["b"])
        # driven so that the stiffest spring of its sizing still moves the axis
        k_hi = (2 * math.pi * min(3 * fh, fs / 8)) ** 2 / info["b"]
        sway = blind.SPRING_MOTION * max(info["q"], info["noise_std"])
        assert info["excitation_rms"] / k_hi >= sway * (1 - 1e-9)
        assert np.ptp(np.asarray(va.x)) >= 4 * info["q"]
    elif cls == "stiction_dominant":
        p = eff[0]["params"]
        assert eff[0]["name"] == "coulomb_friction" and not info["closed_loop"]
        assert 1.5 <= p["fs"] / p["fc"] <= 2.5
        assert all(e["kind"] != "steps" and e["f_hi"] <= 4.0 for e in info["excitation"])
        assert 0.0 <= info["stick_share"] <= 1.0
        lo, hi = blind.STICK_AIM
        assert info["stick_share_in_aim"] == (lo <= info["stick_share"] <= hi)
        # the stuck share (the larger of the two records') held at 30–80 %, or the case is
        # flagged after its setups were redrawn
        stuck = max(info["stick_share"], info["stick_share_train"])
        assert lo <= stuck <= hi or not info["size_in_band"]
        assert 1 <= info["setup_draws"] <= blind.SETUP_DRAWS
    elif cls in ("triple", "saturation_triple"):
        names = info["truth"]
        assert len(set(names)) == 3 and "+".join(names) in blind.TRIPLES
        if cls == "saturation_triple":  # the triple drawn before its redraw, kept whole
            assert names == ["saturation", "coulomb_friction", "offset"]
        if "+".join(names) in blind.OPEN_LOOP_TRIPLES:
            assert not info["closed_loop"]
        if "saturation" in names:  # the command leaves saturation on each record, or flagged
            f_max = next(e for e in eff if e["name"] == "saturation")["params"]["f_max"]
            F = [np.asarray(r.F) for r in (tr, va)]
            share = [max(np.mean(f > f_max), np.mean(f < -f_max)) for f in F]
            assert info["saturated_share"] == pytest.approx(share)
            held = max(share) <= blind.SATURATED_MOST
            assert held or info["setup_draws"] == blind.SETUP_DRAWS or cls == "saturation_triple"
    elif cls == "quadratic_drag":
        assert eff[0]["params"]["c2"] > 0
    else:  # artefacts: sized by A/F_rms; the device is the clean run
        lo, hi = (0.05, 1.0) if cls == "force_sensor_line" else (0.1, 1.0)
        assert lo <= info["artefact_size"] <= hi and info["size_in_band"]
        assert info["response_change"] == 0.0 and info["device_unchanged"]


def test_verdict_right_counts_the_verdict_not_the_stack():
    """A wrong verdict at confidence ≥ 0.9 is a wrong name: with several effects at once, a
    verdict naming one of them is right even where the stack misses another."""
    vr = blind.verdict_right
    cdo = ["coulomb_friction", "delay", "offset"]
    assert vr("triple", "offset", False, cdo)  # right name, incomplete stack
    assert not vr("triple", "force_sensor_drift", False, cdo)
    assert not vr("triple", "spring", True, ["saturation", "coulomb_friction", "offset"])
    assert vr("triple", "offset", False, ["spring", "delay", "coulomb_friction"])  # equilibrium
    assert vr("triple", "asymmetric_friction", False, cdo)
    assert not vr("triple", "unexplained", False, cdo) and not vr("triple", None, False, cdo)
    assert vr("spring+delay", "delay", False, ["spring", "delay"])
    # one effect: the accepted answer, as is_correct says
    assert vr("coulomb_friction", "offset", True, ["coulomb_friction"])
    assert not vr("force_sensor_line", "none", False, ["force_sensor_line"])


def test_is_correct_new_rules():
    ic = blind.is_correct
    cso = ["coulomb_friction", "spring", "offset"]
    assert ic("triple", "spring", [], ["coulomb_friction", "spring"], cso)  # offset in the spring
    assert ic("triple", "spring", [], ["spring", "offset", "coulomb_friction"], cso)
    assert not ic("triple", "spring", [], ["coulomb_friction", "offset"], cso)
    assert not ic("triple", None, [], ["coulomb_friction", "spring"], cso)  # crash
    cdo = ["coulomb_friction", "delay", "offset"]
    assert ic("triple", "delay", [], ["delay", "coulomb_friction", "offset"], cdo)
    assert ic("triple", "delay", [], ["delay", "coulomb_friction", "spring"], cdo)
    assert not ic("triple", "delay", ["offset"], ["delay", "coulomb_friction"], cdo)  # stack only
    with pytest.raises(ValueError):
        ic("triple", "delay", [], ["delay"], [])
    for cls in ("quadratic_drag", "cogging"):
        assert ic(cls, "unexplained", []) and not ic(cls, cls, [])
        assert ic(cls, cls, [], extra=(cls,)) and not ic(cls, "unexplained", [], extra=(cls,))
    assert ic("cogging", "unexplained", [], extra=("quadratic_drag",))
    for cls in blind.ARTEFACTS:
        assert ic(cls, cls, []) and ic(cls, "unexplained", [])
        assert not any(ic(cls, v, []) for v in ("none", "offset", "coulomb_friction", "spring"))
    assert ic("spring_dominant", "spring", []) and not ic("spring_dominant", "unexplained", [])
    for v, ok in (("coulomb_friction", True), ("asymmetric_friction", True), ("spring", False)):
        assert ic("stiction_dominant", v, []) == ok
    assert blind.CLASSES[: len(blind.CLASSES) - len(blind.NEW)][-1] == "backlash"  # appended


def _stub_extra(train, valid, candidates=None):
    """A stand-in for lj.diagnose that records the candidates and names quadratic drag."""
    from types import SimpleNamespace

    _stub_extra.seen.append(candidates)
    return SimpleNamespace(
        verdict="quadratic_drag",
        stack=["quadratic_drag"],
        effects=[],
        final={"shrink": 0.0},
        confidence=0.95,
        ambiguous=[],
    )


_stub_extra.seen = []


def test_candidates_option_passes_the_extra_candidates(monkeypatch):
    """``candidates=`` (``--candidates``) loads the spec once per process through
    ``lj.diagnosis.load_candidates`` (stubbed here), passes the default library plus the extra
    ones, scores quadratic_drag by its own name and records the spec; the summary's aggregate
    figures count the confident wrong verdict."""
    from types import SimpleNamespace

    import lionjax as lj

    extra, calls = (SimpleNamespace(name="quadratic_drag"),), []
    monkeypatch.setattr(
        lj.diagnosis, "load_candidates", lambda s: calls.append(s) or extra, raising=False
    )
    monkeypatch.setattr(blind, "_EXTRA", {})
    _stub_extra.seen.clear()
    spec = "drag.py:QuadraticDrag"
    out = blind.run(
        1,
        0,
        ("quadratic_drag", "force_sensor_line"),
        sources=("scipy",),
        rate=(300.0, 300.0),
        durations=(2.0, 2.0),
        diagnose=_stub_extra,
        progress=False,
        candidates=spec,
    )
    assert calls == [spec]
    default = tuple(lj.diagnosis.DEFAULT_CANDIDATES)
    assert len(_stub_extra.seen) == 2
    assert all(
        c[: len(default)] == default and c[len(default) :] == extra for c in _stub_extra.seen
    )
    drag, line = out["records"]
    assert drag["correct"] and drag["extra_candidates"] == ["quadratic_drag"]
    assert not line["correct"]  # a mechanical name for a sensor artefact
    assert out["config"]["candidates"] == spec
    assert out["config"]["extra_candidates"] == ["quadratic_drag"]
    agg = out["aggregate"]
    assert agg["wrong_at_confidence_ge_0.9"] == {"n": 2, "count": 1, "rate": 0.5}
    assert out["confident_wrong"][0]["class"] == "force_sensor_line"
    assert agg["out_of_library_or_artefact_unexplained_or_own_name"]["correct"] == 1
    assert agg["crashes"]["count"] == 0
    assert out["per_class_rate"]["quadratic_drag"]["250-500 Hz"]["n"] == 1


def test_no_candidates_never_needs_load_candidates(monkeypatch):
    import lionjax as lj

    monkeypatch.delattr(lj.diagnosis, "load_candidates", raising=False)
    _stub.calls = 0
    out = blind.run(
        1,
        0,
        ("none",),
        sources=("scipy",),
        rate=(300.0, 300.0),
        durations=(2.0, 2.0),
        diagnose=_stub,
        progress=False,
    )
    assert out["records"][0]["correct"] and out["config"]["candidates"] is None


def test_a_saturation_triple_saturated_throughout_is_drawn_again():
    """Seed 190160006's first setup (closed loop, soft saturation at 1.16 N beside an offset of
    −1.70 N and friction) kept the command beyond F_max, on one side, on 88 % and 96 % of the
    records: the applied force and the offset are then one constant. The case is drawn on a
    second setup, whose command leaves saturation on most samples."""
    tr, va, info = blind.make_case("triple", 190160006, source="twin")
    assert info["truth"] == ["saturation", "coulomb_friction", "offset"]
    assert info["setup_draws"] == 2
    f_max = info["effects"][0]["params"]["f_max"]
    F = [np.asarray(r.F) for r in (tr, va)]
    assert max(max(np.mean(f > f_max), np.mean(f < -f_max)) for f in F) <= blind.SATURATED_MOST


def test_an_open_loop_saturation_triple_swinging_beyond_both_limits_is_kept():
    """Seed 150161019 (open loop, soft saturation at 1.66 N): the command lies beyond ±F_max on
    86 % of the training record, but on one side on 76 %: the applied force swings between
    the limits, and the diagnosis identifies all three effects there. It is kept on its first
    setup."""
    tr, va, info = blind.make_case("triple", 150161019, source="scipy")
    assert info["setup_draws"] == 1 and not info["closed_loop"]
    f_max = info["effects"][0]["params"]["f_max"]
    F = np.asarray(tr.F)
    assert np.mean(np.abs(F) > f_max) > blind.SATURATED_MOST
    assert info["saturated_share"][0] <= blind.SATURATED_MOST
