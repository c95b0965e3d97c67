"""Careless inputs, round 2 (issue 66): each input a tired user really produces, with the answer
it must get. Beside ``test_fuzz_cli.py`` (the first round), on the same kind of record: ẍ + aẋ
= bF (a = 20 1/s, b = 2 1/kg, four-tone multisines, 1 kHz, noise-free, from the independent
simulator of ``_reference_sim``).

- broken data (a glitch in x or F, a pair in different units) is refused by the diagnosis before
  any fit, naming the record, the sample and the time — never an effect name;
- a user's mistaken candidate is refused with its name, the rule of docs/effects.md and the
  fix — never "internal error";
- ``Record`` fixes dtypes; float16 is identified the same way by every estimator;
- the command line's messages: the gain's direction, an empty pole set, the repeated candidate,
  the encoder origin far away, one prefix, warnings on stderr;
- a force that changes every sample at 1 Hz: least squares warns with both holds' answers, and
  the truth lies between them;
- the streamed least squares refuses what ``least_squares(initial="discard")`` refuses.
"""

from __future__ import annotations

import re
import sys
import textwrap
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _reference_sim import multisine, simulate, stick_slip_axis

import lionjax as lj
from lionjax import _data_checks, _progress
from lionjax.cli import describe, main

A, B, DT, T = 20.0, 2.0, 1e-3, 3000


def _pair(seed: int, n: int = T):
    t = np.arange(n) * DT
    r = np.random.default_rng(seed)
    F = multisine(t, [0.7, 2.3, 5.1, 9.7], r.uniform(0.15, 0.3, 4), r.uniform(0, 2 * np.pi, 4))
    return t, simulate(F, DT, a=(A,), b=(B,), bounds=()), F


def _csv(path: Path, t, x, F) -> Path:
    np.savetxt(path, np.c_[t, x, F], delimiter=",", header="t,x,F", comments="", fmt="%.17g")
    return path


def _run(args, capsys):
    try:
        code = main([str(a) for a in args])
    except SystemExit as e:  # argparse
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


def _error(err: str, command: str) -> str:
    """The single error line (no traceback, no internal error, no doubled prefix)."""
    assert "Traceback" not in err and "internal error" not in err, err
    lines = [ln for ln in err.splitlines() if f"lionjax {command}: error: " in ln]
    assert len(lines) == 1, err
    assert f"error: {command}: " not in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("careless")
    t, xt, Ft = _pair(1)
    _, xv, Fv = _pair(2)
    out = {"train": _csv(d / "train.csv", t, xt, Ft), "valid": _csv(d / "valid.csv", t, xv, Fv)}
    F1 = Ft.copy()
    F1[1500] = 1000.0  # a logging glitch: 1000 N among forces of 1 N
    out["F_spike"] = _csv(d / "F_spike.csv", t, xt, F1)
    out["valid_mN"] = _csv(d / "valid_mN.csv", t, xv, 1e3 * Fv)
    out["valid_mm"] = _csv(d / "valid_mm.csv", t, 1e3 * xv, Fv)
    x1 = xt.copy()
    x1[2000] += 1.0  # an encoder glitch: one position 1 m off
    out["x_spike"] = _csv(d / "x_spike.csv", t, x1, Ft)
    x2 = xv.copy()
    x2[2000:] += 1.0  # the encoder lost counts: a jump that stays
    out["x_jump"] = _csv(d / "x_jump.csv", t, x2, Fv)
    F3 = Fv.copy()
    F3[100:102] = -50.0  # two wrong samples
    out["F_burst"] = _csv(d / "F_burst.csv", t, xv, F3)
    out["far_origin"] = _csv(d / "far_origin.csv", t, 1000.0 + 1e-3 * xt, Ft)  # µm motion
    return out


# --------------------------------------------------------------------------- broken data

BROKEN = {
    # name: (train, valid, what the one error line must say)
    "F_spike_in_train": (
        "F_spike",
        "valid",
        r"F_spike\.csv.*force F has a glitch: a spike F\[1500\] = 1000 N \(t = 1\.5 s\)",
    ),
    "valid_in_mN": (
        "train",
        "valid_mN",
        r"different units: its force F is [\d.]+ times the training record's.*mN",
    ),
    "valid_in_mm": (
        "train",
        "valid_mm",
        r"different units: its position x spreads [\d.]+ times.*mm",
    ),
    "x_spike_in_train": (
        "x_spike",
        "valid",
        r"x_spike\.csv.*position x has a glitch: a spike x\[2000\] = .* \(t = 2 s\)",
    ),
    "x_jump_in_valid": ("train", "x_jump", r"x_jump\.csv.*a jump of 1 m between x\[1999\]"),
    "F_burst_in_valid": ("train", "F_burst", r"F_burst\.csv.*a spike F\[100…101\] = -50 N"),
}


@pytest.mark.parametrize("case", BROKEN)
def test_broken_data_refused_before_any_fit(files, case, capsys):
    """Refused (exit 2, one line naming the file, the sample and the time): never a verdict, so
    never an effect at confidence ≥ 0.9."""
    train, valid, said = BROKEN[case]
    code, out, err = _run(["diagnose", files[train], "--validate", files[valid]], capsys)
    assert code == 2, out + err
    assert re.search(said, _error(err, "diagnose")), err
    assert "verdict" not in out


def test_glitches_named_by_the_estimators(files, capsys):
    """identify answers with a warning naming the glitch (least squares is not refused)."""
    code, out, err = _run(["identify", files["F_spike"]], capsys)
    assert code == 0, err
    assert re.search(r"lionjax identify: warning: .*glitch: a spike F\[1500\] = 1000 N", err), err


def test_glitch_rule():
    """The rule on what it must catch and what it must leave: a quantised encoder, random force
    steps (one changing level at an end sample), a clipped force, a PD's pulses at encoder
    counts, a stuck axis, EMPS (real, closed loop) have none; a spike of 10 common steps in x,
    a persistent jump, a 3-sample burst in F are found with their index and run length."""
    t, x, F = _pair(3)
    rng = np.random.default_rng(0)
    q = 10e-6
    levels = np.repeat(rng.uniform(-1, 1, T // 50), 50)  # random steps held 50 samples
    xs = simulate(levels, DT, a=(A,), b=(B,), bounds=())
    xq = q * np.round(xs / q)
    Fpd = levels - 200.0 * (np.round(xq / q) - np.round(np.roll(xq, 1) / q)) * q / DT / 1e3
    clean = {
        "quantised_steps": (xq, levels),
        "clipped": (x, np.clip(F, -0.2, 0.2)),
        "pd_pulses": (xq, Fpd),
        "stick_slip": (stick_slip_axis(3 * F, DT, a=A, b=B, Fc=0.3, Fs=0.5, vs=1e-3), 3 * F),
    }
    for name, (xx, FF) in clean.items():
        assert _data_checks.find_glitches(lj.Record(xx, FF, DT)) == [], name
    for split in ("estimation", "validation"):  # the validation split's 5 N force pulses too
        assert _data_checks.find_glitches(lj.datasets.emps(split)) == [], split
    Qx = _data_checks.common_step(x)
    bad = x.copy()
    bad[700] += 12 * Qx
    (g,) = _data_checks.find_glitches(lj.Record(bad, F, DT))
    assert (g.column, g.kind, g.index, g.length) == ("x", "spike", 700, 1)
    bad = x.copy()
    bad[900:] += 0.05
    (g,) = _data_checks.find_glitches(lj.Record(bad, F, DT))
    assert (g.column, g.kind, g.index) == ("x", "jump", 900)
    FF = F.copy()
    FF[1200:1203] = 30.0
    (g,) = _data_checks.find_glitches(lj.Record(x, FF, DT))
    assert (g.column, g.kind, g.index, g.length) == ("F", "spike", 1200, 3)
    # seven long force steps, mostly at two close levels (a spread of 0.015 N, no common step),
    # whose level changes by 0.2 N at the last sample (or the first), within the force's range:
    # a step, not a spike (whether it comes back cannot be seen)
    held = np.repeat([1.25, 1.23, 1.25, -0.6, 1.23, 1.25, 1.25, 1.23], -(-T // 8))[:T]
    for k, j in ((T - 1, T - 2), (0, 1)):
        steps = held.copy()
        steps[k] = steps[j] - 0.2
        assert _data_checks.find_glitches(lj.Record(xq, steps, DT)) == [], k
    for k in (0, T - 1):  # the first and the last sample
        FF, xx = F.copy(), x.copy()
        FF[k], xx[k] = 1000.0, 1.0
        glitches = _data_checks.find_glitches(lj.Record(xx, FF, DT))
        assert [(g.column, g.index) for g in glitches] == [("F", k), ("x", k)], glitches
        assert (
            "the first sample" in _data_checks.glitch_message(lj.Record(xx, FF, DT), glitches) or k
        )


@pytest.mark.slow
def test_no_glitch_on_clean_benchmark_records():
    """Every class of the blind benchmark's independent simulator (one pair each: encoders,
    saturation, closed loop, stiction, backlash, sensor lines …): no glitch, no unit mismatch
    (benchmarks/results/2026-11-29_data_checks.md: 0 of 440 records)."""
    import diagnosis_blind as blind  # benchmarks/ (tests/conftest.py)

    for c, cls in enumerate(blind.CLASSES):
        train, valid, _ = blind.make_case(cls, 600000 + 10000 * c + 1000, source="scipy")
        for rec in (train, valid):
            assert _data_checks.find_glitches(rec) == [], cls
        assert _data_checks.unit_mismatch(train, valid) == "", cls


def test_far_encoder_origin_is_not_millimetres(files, capsys):
    """µm of motion 1 km from the origin: no "millimetres" advice, and the answer is right."""
    code, out, err = _run(
        ["identify", files["far_origin"], "--json", files["train"].parent / "o.json"], capsys
    )
    assert code == 0 and "millimetres" not in err, err
    import json

    doc = json.loads((files["train"].parent / "o.json").read_text())
    assert doc["params"]["a"] == pytest.approx(A, rel=1e-3)
    assert doc["params"]["b"] == pytest.approx(B * 1e-3, rel=1e-3)


# --------------------------------------------------------------------------- a user's candidate

CANDIDATES = textwrap.dedent(
    """
    from typing import ClassVar
    import jax.numpy as jnp
    import numpy as np
    import lionjax as lj

    FE = lj.diagnosis.ForceEffect


    def one(name, pars, body, **extra):
        ns = {"name": name, "parameters": pars, "units": {p: "N" for p in pars}}
        ns["__annotations__"] = {"name": ClassVar[str], "parameters": ClassVar[tuple], "units": ClassVar[dict]}
        ns.update(extra)
        ns["basis"] = body
        return type(name.title().replace("_", ""), (FE,), ns)


    NanBasis = one("nan_basis", ("c_nan",), lambda self, x, v, F, t: (jnp.sqrt(x),))
    Inverse = one("inverse", ("c_inv",), lambda self, x, v, F, t: (1.0 / (x - x),))
    TwoRows = one("two_rows", ("c_tr",), lambda self, x, v, F, t: (jnp.stack([x, v]),))
    BareArray = one("bare_array", ("c_ba",), lambda self, x, v, F, t: jnp.tanh(v / 1e-3))
    TwoForOne = one("two_for_one", ("c_two",), lambda self, x, v, F, t: (x, v))
    NumpyBasis = one("numpy_basis", ("c_np",), lambda self, x, v, F, t: (np.sin(1e3 * x),))


    def _if(self, x, v, F, t):
        if v > 0:
            return (x,)
        return (-x,)


    PythonIf = one("python_if", ("c_if",), _if)
    # implausible answering a bool (True would read as the reason "True")
    BoolImplausible = one(
        "bool_implausible",
        ("c_bi",),
        lambda self, x, v, F, t: (jnp.tanh(v / 1e-3),),
        implausible=lambda self, phys, limits: phys["c_bi"] < 0,
    )
    ZeroBasis = one("zero_basis", ("c_zero",), lambda self, x, v, F, t: (jnp.zeros_like(x),))
    # a force on a part of the rail the training record never reaches (x is a few mm here)
    Unvisited = one("unvisited", ("c_un",), lambda self, x, v, F, t: (jnp.where(x > 10.0, 1.0, 0.0),))


    class EmptyGrid(FE):
        name: ClassVar[str] = "empty_grid"
        parameters: ClassVar[tuple] = ("c_eg",)
        nonlinear: ClassVar[tuple] = ("period",)
        units: ClassVar[dict] = {"c_eg": "N", "period": "m"}
        period: float = 1e-3

        def basis(self, x, v, F, t):
            return (jnp.sin(2 * jnp.pi * x / self.period),)

        def grid(self, limits):
            return []


    class FloatGrid(EmptyGrid):
        name: ClassVar[str] = "float_grid"
        parameters: ClassVar[tuple] = ("c_fg",)
        units: ClassVar[dict] = {"c_fg": "N", "period": "m"}

        def grid(self, limits):
            return [1e-3, 2e-3, 4e-3]


    class Raises(EmptyGrid):
        name: ClassVar[str] = "raises"
        parameters: ClassVar[tuple] = ("c_r",)
        units: ClassVar[dict] = {"c_r": "N", "period": "m"}

        def grid(self, limits):
            return [Raises(p) for p in limits.no_such_field]
    """
)

#: class → what its one error line must say (the rule's words and the mistake). Refused when
#: loaded (traced once as the simulation calls it), except where the record is needed.
MISTAKES = {
    "TwoRows": r"'two_rows' \(TwoRows\): basis function 0 \(c_tr\) has shape \(2, 4\).*Rule \(docs/effects\.md\): Return exactly one array per name",
    "BareArray": r"'bare_array' \(BareArray\): basis returned an array of shape \(4,\).*not a tuple",
    "TwoForOne": r"'two_for_one' \(TwoForOne\): basis returned 2 array\(s\).*for the 1 parameter",
    "NumpyBasis": r"'numpy_basis' \(NumpyBasis\): basis converts a traced argument to NumPy.*Rule \(docs/effects\.md\): jax\.numpy, elementwise",
    "PythonIf": r"'python_if' \(PythonIf\): basis branches in Python.*jnp\.where",
}
#: ... refused on the first evaluation (after the baseline is fitted).
MISTAKES_ON_RECORD = {
    "NanBasis": r"'nan_basis' \(NanBasis\): basis function 0 \(c_nan\) is not finite at \d+ of the record's 3000 samples.*Rule \(docs/effects\.md\): Finite everywhere",
    "Inverse": r"'inverse' \(Inverse\): basis function 0 \(c_inv\) is not finite at 3000 of",
    "ZeroBasis": r"'zero_basis' \(ZeroBasis\): basis function 0 \(c_zero\) is zero at every one of the training record's 3000 samples.*Rule \(docs/effects\.md\): Nonzero where it is fitted",
    "Unvisited": r"'unvisited' \(Unvisited\): basis function 0 \(c_un\) is zero at every one of the training record's 3000 samples \(x from .* m\), so c_un cannot be fitted",
    "BoolImplausible": r"'bool_implausible' \(BoolImplausible\): implausible returned (True|False) \(a bool\), not a reason\. Rule \(docs/effects\.md\): Physics in implausible",
    "EmptyGrid": r"'empty_grid' \(EmptyGrid\): grid returned no Module to search.*Rule",
    "FloatGrid": r"'float_grid' \(FloatGrid\): grid returned a float \(0\.001\) among its 3 points, not a FloatGrid",
    "Raises": r"the candidate file .*bad_candidates\.py failed \(line \d+, in grid\): AttributeError",
}


@pytest.fixture(scope="module")
def candidate_file(files):
    path = files["train"].parent / "bad_candidates.py"
    path.write_text(CANDIDATES)
    return path


@pytest.mark.parametrize("cls", MISTAKES)
def test_user_candidate_refused_when_loaded(files, candidate_file, cls, capsys):
    argv = ["diagnose", files["train"], "--validate", files["valid"]]
    code, out, err = _run([*argv, "--candidates", f"{candidate_file}:{cls}"], capsys)
    assert code == 2, out + err
    assert re.search(MISTAKES[cls], _error(err, "diagnose")), err


@pytest.mark.slow
def test_user_candidate_refused_on_first_evaluation(files, candidate_file, capsys):
    """The mistakes only a record shows, each refused on the first evaluation (one diagnosis
    each, up to the candidates' fits; the compiled programs shared)."""
    argv = ["diagnose", files["train"], "--validate", files["valid"]]
    for cls, said in MISTAKES_ON_RECORD.items():
        code, out, err = _run([*argv, "--candidates", f"{candidate_file}:{cls}"], capsys)
        assert code == 2, (cls, out + err)
        assert re.search(said, _error(err, "diagnose")), (cls, err)


def test_user_frame_named():
    """An exception raised inside a candidate file is the file's, with its line."""
    from lionjax.diagnosis._load import USER_MODULE

    ns = {"__name__": f"{USER_MODULE}test"}
    exec(compile("def grid():\n    return 1 / 0\n", "my_effects.py", "exec"), ns)
    try:
        ns["grid"]()
    except ZeroDivisionError as e:
        text = describe(e, "diagnose")
    assert "the candidate file my_effects.py failed (line 2, in grid)" in text
    assert "internal error" not in text


def test_repeated_candidate_named():
    lib = lj.diagnosis.DEFAULT_CANDIDATES
    t, x, F = _pair(1)
    rec = lj.Record(x, F, DT)
    with pytest.raises(
        lj.InputError, match=r"the name\(s\) \['offset'\] are used by more than one"
    ):
        lj.diagnose(rec, rec, candidates=lib + (lib[0],))


# --------------------------------------------------------------------------- records


def test_record_dtypes():
    t, x, F = _pair(1)
    rec = lj.Record(np.round(x * 1e6).astype(np.int64), F, 0.001)  # an encoder's integer counts
    assert rec.dt.dtype == jnp.float64 and float(rec.dt) == 0.001
    assert rec.x.dtype == jnp.float64 and rec.t.dtype == jnp.float64
    f32 = lj.Record(x.astype(np.float32), F.astype(np.float32), DT, 1234.5)
    assert f32.x.dtype == jnp.float32 and f32.dt.dtype == jnp.float64
    assert float(f32.t[-1]) == pytest.approx(1234.5 + (T - 1) * DT, abs=1e-9)
    with pytest.raises(lj.InputError, match="F is boolean"):
        lj.Record(x, F > 0, DT)
    with pytest.raises(lj.InputError, match="x is complex"):
        lj.Record(x + 0j, F, DT)
    with pytest.raises(lj.InputError, match=r"shape \(3000, 1\).*x\.ravel\(\)"):
        lj.Record(x[:, None], F[:, None], DT)


def test_float16_same_in_every_estimator():
    """A float16 record is identified as its float32 copy is, by every estimator."""
    t, x, F = _pair(1, 2600)
    h = lj.Record(x.astype(np.float16), F.astype(np.float16), DT)
    s = lj.Record(
        x.astype(np.float16).astype(np.float32), F.astype(np.float16).astype(np.float32), DT
    )
    MD = lj.MassDamper()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", lj.solutions.DataWarning)  # float16's rounding
        for fn in (
            lambda r: lj.least_squares(MD, r).theta,
            lambda r: lj.lion(MD, r, gain=lj.AutoGain(20.0)).theta[-1],
            lambda r: lj.lion_batched(MD, jax.tree.map(lambda a: a[None], r), throw=False).theta[0],
            lambda r: lj.least_squares_batched(
                MD, jax.tree.map(lambda a: a[None], r), throw=False
            ).theta[0],
            lambda r: np.array([lj.identify_batch(MD, [r]).to_rows()[0][k] for k in "ab"]),
        ):
            np.testing.assert_array_equal(np.asarray(fn(h)), np.asarray(fn(s)))


# --------------------------------------------------------------------------- messages


def test_huge_fixed_gain_told_to_lower(files, capsys):
    code, out, err = _run(
        ["identify", files["train"], "--method", "lion", "--gain", "1e12"], capsys
    )
    assert code == 0, err
    assert "lower --gain" in out and "raise --gain" not in out, out
    code, out, err = _run(["identify", files["train"], "--method", "lion", "--gain", "1"], capsys)
    assert "raise --gain" in out, out


def test_empty_pole_set_refused(files, capsys):
    code, out, err = _run(["study", files["train"], "--poles", "-4;;-8"], capsys)
    assert code == 2
    assert "pole set 2 of 3 in '-4;;-8' is empty" in _error(err, "study")


def test_progress_status_line(capsys, monkeypatch):
    """The status line: drawn once the task has run QUIET_FOR seconds, the stage and its count;
    a profile's grid points counted; nothing when not enabled."""
    monkeypatch.setattr(_progress, "QUIET_FOR", 0.0)
    monkeypatch.setattr(_progress, "REDRAW_EVERY", 0.0)
    with _progress.status("diagnose") as st:
        st.stage("fitting")
        assert [g for g in _progress.counted(range(3), "profiling cogging", "grid points")] == [
            0,
            1,
            2,
        ]
        assert st.what == "fitting"  # the enclosing step restored
    err = capsys.readouterr().err
    assert "diagnose: profiling cogging 3/3 grid points" in err and err.endswith("\n")
    with _progress.status("diagnose", enabled=False) as st:
        st.stage("fitting")
        list(_progress.counted(range(3), "profiling"))
    assert capsys.readouterr().err == ""
    assert _progress.wanted(quiet=True) is False


# --------------------------------------------------------------------------- coarse sampling


@pytest.mark.parametrize("truth", ["zoh", "foh"])
def test_force_changing_every_sample_at_1hz(truth):
    """A slow axis (a = 0.2 1/s, b = 0.02 1/kg) at 1 Hz under a force drawn anew every sample:
    least squares warns naming both holds' answers, and the truth lies between them (held F:
    the held answer is the truth; a force linear between samples: the linear one is)."""
    a, b, n, sub = 0.2, 0.02, 1800, 128  # the linear force to 1e-3 with 128 held steps
    F = np.random.default_rng(0).standard_normal(n)
    if truth == "zoh":
        x = simulate(F, 1.0, a=(a,), b=(b,), bounds=())
    else:  # the drive moved F linearly between samples: exact per held sub-step
        Ff = np.interp(np.arange(n * sub) / sub, np.arange(n), F)
        x = simulate(Ff, 1.0 / sub, a=(a,), b=(b,), bounds=())[::sub]
    with pytest.warns(lj.solutions.DataWarning, match=r"Nyquist") as caught:
        sol = lj.least_squares(lj.MassDamper(), lj.Record(x, F, 1.0))
    (msg,) = [str(w.message) for w in caught if "Nyquist" in str(w.message)]
    got = {
        k: [float(v) for v in m]
        for k, *m in re.findall(r"(\w) = ([\d.e-]+) \(zoh\) or ([\d.e-]+) \(foh\)", msg)
    }
    assert set(got) == {"a", "b"}, msg
    for k, true in (("a", a), ("b", b)):
        lo, hi = sorted(got[k])
        assert lo * (1 - 2e-3) <= true <= hi * (1 + 2e-3), (k, got[k], true)
        assert got[k][0 if truth == "zoh" else 1] == pytest.approx(true, rel=2e-3)
    assert float(sol.params()["a"]) == pytest.approx(got["a"][0], rel=1e-5)  # printed to 6 digits


def test_slow_excitation_at_1hz_no_warning():
    """The same axis excited far below Nyquist: no intersample warning."""
    t = np.arange(1800.0)
    F = np.sin(2 * np.pi * 0.005 * t) + 0.5 * np.sin(2 * np.pi * 0.013 * t + 1)
    x = simulate(F, 1.0, a=(0.2,), b=(0.02,), bounds=())
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*Nyquist")
        sol = lj.least_squares(lj.MassDamper(), lj.Record(x, F, 1.0))
    assert float(sol.params()["a"]) == pytest.approx(0.2, rel=1e-3)


# --------------------------------------------------------------------------- streamed LS


def test_streamed_least_squares_refuses_what_single_refuses(files, tmp_path, capsys):
    """A noise-free step response after the filter transient identifies only b/a:
    least_squares(initial="discard") refuses it, and so do least_squares_batched and
    `identify DIR` (a = 3.14 "ok" before); a good record beside it is answered as the single
    least squares answers it."""
    n = 3000
    t = np.arange(n) * DT
    Fs = np.full(n, 0.2)
    xs = simulate(Fs, DT, a=(A,), b=(B,), bounds=())
    step = lj.Record(xs, Fs, DT)
    with pytest.raises(lj.IdentificationError, match="Not identified from this record: a, b"):
        lj.least_squares(lj.MassDamper(), step, initial="discard")
    sol = lj.least_squares_batched(
        lj.MassDamper(), jax.tree.map(lambda a: a[None], step), throw=False
    )
    assert lj.solutions.result_codes(sol.result).tolist() == [1]
    assert np.asarray(sol.unexcited).tolist() == [[True, True]]
    d = tmp_path / "dir"
    d.mkdir()
    _csv(d / "a_step.csv", t, xs, Fs)
    tg, xg, Fg = _pair(1)
    _csv(d / "b_good.csv", tg, xg, Fg)
    code, out, err = _run(["identify", d, "--csv", tmp_path / "rows.csv"], capsys)
    assert code == 1, out + err
    rows = (tmp_path / "rows.csv").read_text().splitlines()
    assert ",failed," in rows[1] and ",ok," in rows[2], rows
    good = lj.least_squares(lj.MassDamper(), lj.Record(xg, Fg, DT), initial="discard")
    a_row = float(rows[2].split(",")[rows[0].split(",").index("a")])
    assert a_row == pytest.approx(float(good.params()["a"]), rel=1e-9)


def test_streamed_free_response_condition_matches_single():
    """The streamed [Φ, N] condition number equals the single least squares' own (a record cut
    from a longer run: the axis moves at its first sample)."""
    from lionjax import _least_squares as L
    from lionjax._solution_tools import transient_mask

    t, x, F = _pair(4, 7500)
    rec = lj.Record(x[5000:], F[5000:], DT)
    bank = lj.default_bank(rec.dt)
    regs = lj.MassDamper().regressors(rec, bank)
    n = regs.W.shape[0]
    w = transient_mask(rec, bank, None)
    Phi = (regs.W * w[:, None, None]).reshape(2 * n, -1)
    N = L.nuisance_columns(bank, rec.dt, n, (0, 1)) * w[:, None, None]
    aug = L.linear_lstsq(
        jnp.concatenate([Phi, N.reshape(2 * n, -1)], -1), (regs.W0 * w[:, None]).reshape(-1)
    )
    out = lj.lion_batched(
        lj.MassDamper(),
        jax.tree.map(lambda a: a[None], rec),
        outputs=(lj.LSStatistics(free_response=True),),
        throw=False,
    ).output(lj.LSStatistics)
    assert float(out.free_condition[0]) == pytest.approx(float(aug.condition), rel=1e-4)
    assert np.abs(np.asarray(out.free_weakest[0])) == pytest.approx(
        np.abs(np.asarray(aug.weakest)), abs=1e-4
    )


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))
