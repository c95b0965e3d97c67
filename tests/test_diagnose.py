"""lionjax.diagnose: the JSON contract, EMPS against the published table, the CLI, bad input,
a small blind evaluation on twin records (benchmarks/diagnosis_blind.py), and the record
statistics it starts from (encoder lattice, loop detection, hold correction, noise floor).

The cases of held-out records are in test_diagnose_floor.py (the noise floor and the loop),
test_diagnose_stacking.py (friction, stacking, stand-ins) and test_diagnose_modes.py (the flexible
mode); test_diagnose_rates.py runs the CLI across sample rates. (Several files: CI runs them on
two workers, one file each.)"""

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


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("q", [1e-6, 2.3e-6, 2e-5])
def test_lattice_step_of_a_quantised_record(q, dtype):
    """An encoder's count q is recovered from a quantised, slowly drifting position (to 10⁻⁴ in
    float32, where the smallest step alone is off by more); noise on top leaves no lattice."""
    from lionjax.diagnosis._statistics import _lattice_step

    rng = np.random.default_rng(0)
    t = np.arange(20000) / 3000.0
    x = 0.05 * np.sin(2 * np.pi * 0.3 * t) + 0.01 * t + 0.003
    xq = (q * np.round(x / q)).astype(dtype)
    assert _lattice_step(xq) == pytest.approx(q, rel=1e-4)
    assert _lattice_step(xq + rng.normal(0, 0.3 * q, xq.shape).astype(dtype)) == 0.0


def test_feedback_share_tells_closed_from_open_loop():
    """A PD on the measured position puts the position noise into F's third difference (share
    near 1); an open-loop force, smooth at the sample scale, shares nothing with it."""
    from lionjax.diagnosis._statistics import _feedback

    rng = np.random.default_rng(1)
    dt = 1 / 2000.0
    t = np.arange(20000) * dt
    x = 0.01 * np.sin(2 * np.pi * 1.3 * t)
    xm = x + rng.normal(0, 2e-6, t.size)
    exc = np.sin(2 * np.pi * 3.1 * t) + 0.5 * np.sin(2 * np.pi * 7.7 * t)
    # a digital PD: backward difference of the measured position
    F_closed = exc - 800.0 * xm - 20.0 * np.diff(xm, prepend=xm[0]) / dt
    share, F_ref = _feedback(xm, F_closed)
    assert share > 0.95
    assert _feedback(xm, exc)[0] < 0.05
    # F less the controller's answer is the excitation, up to a slow drift (a quadratic in t:
    # the third difference leaves it free), removed by a least-squares fit
    e = F_ref - exc
    P = np.vander(t, 3)
    e = e - P @ np.linalg.lstsq(P, e, rcond=None)[0]
    assert np.sqrt(np.mean(e**2)) < 0.02 * np.sqrt(np.mean(exc**2))


def test_feedback_share_reads_a_low_rate_open_loop_as_open():
    """At 117 Hz a rough excitation is partly predicted from the plant's response to it: the R²
    of Δ³F on Δ³x alone read these open loops as 0.84–0.97 (closed). The share of F's
    innovation that the position just measured explains is ≈ 0 in open loop and ≈ 1 under a PD
    on that position. Plant x'' = −a x' + b F discretised exactly (zoh) by scipy; 20 µm
    encoder and 20 µm white position noise; twelve sines up to 47 Hz in open loop, six up to
    5 Hz as the closed loop's feed-forward."""
    import scipy.signal as sg

    from lionjax.diagnosis._statistics import _feedback

    fs, n, a, b, q = 117.0, 1200, 3.0, 50.0, 2e-5
    dt = 1 / fs
    Ad, Bd, *_ = sg.cont2discrete(
        (np.array([[0, 1], [0, -a]]), np.array([[0], [b]]), np.eye(2), np.zeros((2, 1))), dt, "zoh"
    )
    t = np.arange(n) * dt
    for seed in range(3):
        rng = np.random.default_rng(seed)
        sines = lambda hi, m: sum(
            np.sin(2 * np.pi * f * t + rng.uniform(0, 6.3)) for f in rng.uniform(0.2, hi, m)
        )
        rough, smooth = sines(47.0, 12), sines(5.0, 6)
        noise = rng.normal(0, 2e-5, n)

        def run(exc, kp, kd):
            s, xm, F = np.zeros(2), np.zeros(n), np.zeros(n)
            for k in range(n):
                xm[k] = q * np.round(s[0] / q) + noise[k]
                F[k] = exc[k] - kp * xm[k] - kd * (xm[k] - xm[max(k - 1, 0)]) / dt
                s = Ad @ s + Bd[:, 0] * F[k]
            return xm, F

        assert _feedback(*run(rough, 0.0, 0.0))[0] < 0.05
        assert _feedback(*run(smooth, 100.0, 1.0))[0] > max(
            0.9, lj.diagnosis.Criteria().feedback_share
        )


def test_gram_solve_is_float64_without_x64():
    """The diagnosis' solve (augmented Gram → lj's gram_lstsq) against numpy's lstsq (an
    independent SVD reference) at 1e-9, with jax_enable_x64 switched off by the caller."""
    import jax

    from lionjax.diagnosis._fit import _augmented_gram, solve_grams

    rng = np.random.default_rng(3)
    W = rng.normal(size=(500, 5)) * np.array([1e-3, 1.0, 30.0, 1.0, 5e2])
    y = W @ np.array([2.0, -1.0, 0.5, 0.0, 3e-3]) + 1e-4 * rng.normal(size=500)
    with jax.enable_x64(False):
        coef, rss, gi, cond = solve_grams(_augmented_gram(W, y)[None], 500)
    ref, res, *_ = np.linalg.lstsq(W, -y, rcond=None)
    assert coef.dtype == np.float64
    np.testing.assert_allclose(coef[0], ref, rtol=1e-9, atol=1e-12)
    # RSS = yᵀy − bᵀθ by cancellation in the Gram: its rounding floor is eps·yᵀy/RSS (4.8e-6
    # relative here, so a bound of 1e-6 would test the compiler's rounding, not the solve)
    floor = np.finfo(np.float64).eps * float(y @ y) / float(res[0])
    assert rss[0] == pytest.approx(float(res[0]), rel=4 * floor)
    np.testing.assert_allclose(gi[0], np.linalg.inv(W.T @ W), rtol=1e-8)


@pytest.mark.parametrize("fs", [400.0, 1000.0])
def test_hold_correction_is_fourth_order(fs):
    """A smooth x sampled at fs through h = (s²/D)[·] (the mode filter): the first-order hold of
    the raw samples (scipy's lsim) is off by ≈ (ωh)²/12, that of the hold-corrected samples
    (mode_signals) by O(h⁴). Reference:
    the exact steady-state response |H(jω)|·sin(ωt + ∠H) of each sine (closed form), after the
    transient (ζ = 0.3: decays as e^{−ζω_n t}, < 1e-12 of the signal after 0.5 s)."""
    from scipy import signal

    from lionjax.diagnosis._filtering import mode_signals, padded_length

    w, z = 2 * np.pi * 30.0, 0.3
    freqs, amps = (3.1, 17.0, 37.0), (0.01, 0.004, 0.002)

    def exact(t):
        out = np.zeros_like(t)
        for f, a in zip(freqs, amps, strict=True):
            s = 2j * np.pi * f
            H = s**2 / (s**2 + 2 * z * w * s + w * w)
            out += a * np.abs(H) * np.sin(2 * np.pi * f * t + np.angle(H))
        return out

    errs = {}
    for h in (1 / fs, 0.5 / fs):
        t = np.arange(int(round(2.0 / h))) * h
        x = sum(a * np.sin(2 * np.pi * f * t) for f, a in zip(freqs, amps, strict=True))
        keep = (t > 0.5) & (t < t[-1])  # the last sample: see hold_corrected
        ref = exact(t)[keep]
        ((hx, _),) = mode_signals(x, np.zeros_like(x), h, [(w, z)], padded_length(t.size))
        # the plain first-order hold of the raw samples: scipy's lsim (linear interpolation)
        lti = signal.lti([1.0, 0.0, 0.0], [1.0, 2 * z * w, w * w])
        hraw = signal.lsim(lti, x, t, interp=True)[1]
        scale = np.max(np.abs(ref))
        errs[h] = (
            np.max(np.abs(hx[keep] - ref)) / scale,
            np.max(np.abs(hraw[keep] - ref)) / scale,
        )
    (c1, r1), (c2, r2) = errs[1 / fs], errs[0.5 / fs]
    assert c1 < 0.1 * r1  # the correction removes ≥ 90 % of the hold error
    assert 3.0 < r1 / r2 < 5.0  # the plain hold: second order (ratio 4)
    assert c1 / c2 > 10.0  # the corrected hold: fourth order (ratio 16)


def test_noise_floor_counts_sparse_noise():
    """σ of the noise floor (third differences) against the drawn noise: Gaussian noise within
    5 %; sparse noise (a coarse encoder's steps: nonzero at 10 % of samples) within 20 % of its
    RMS, where the median absolute deviation alone gives less than half."""
    from lionjax.diagnosis._statistics import _robust_diff_std

    rng = np.random.default_rng(11)
    t = np.arange(200_000) * 1e-3
    smooth = 0.01 * np.sin(2 * np.pi * 0.7 * t)
    n = 2e-6 * rng.normal(size=t.size)
    assert _robust_diff_std(smooth + n) == pytest.approx(2e-6, rel=0.05)
    sparse = np.where(rng.random(t.size) < 0.1, 2e-5 * rng.normal(size=t.size), 0.0)
    rms = float(np.sqrt(np.mean(sparse**2)))
    # (the trim drops the largest 1 % of |Δ³|, the spikes' tail: 0.86× the RMS here)
    assert _robust_diff_std(smooth + sparse) == pytest.approx(rms, rel=0.2)
    d = np.diff(smooth + sparse, 3)
    mad = 1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(20)
    assert mad < 0.5 * rms
