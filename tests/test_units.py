"""Rotary axes: a record in rad and N·m (``units="rotary"``, ``--units rotary``) is diagnosed and
identified with the same numbers as the linear reading of the same samples, and every unit the
reports state is the rotary one (JSON, text, plot labels); the millimetre check stays silent."""

from __future__ import annotations

import json
import re
import warnings

import numpy as np
import pytest
import scipy.signal

import lionjax as lj
from lionjax import InputError
from lionjax._units import convert_units, unit
from lionjax._validity import sanity_messages
from lionjax.cli import main

#: A rotor J = 2e-3 kg·m², viscous B = 2e-3 N·m·s/rad, driven by a torque with a mean (so that it
#: turns through ~190 rad in 10 s, inside the 110–4000 that reads as millimetres on a linear
#: axis) and two tones; 200 Hz, exact zero-order-hold samples (scipy).
J, B, FS, T_END = 2e-3, 2e-3, 200.0, 10.0


def _rotor(seed: int = 0):
    t = np.arange(int(T_END * FS)) / FS
    tau = 0.04 + 0.05 * np.sin(2 * np.pi * 1.3 * t) + 0.03 * np.sin(2 * np.pi * 4.1 * t + 1.0)
    A, Bm = np.array([[0, 1], [0, -B / J]]), np.array([[0], [1 / J]])
    Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete((A, Bm, np.eye(1, 2), np.zeros((1, 1))), 1 / FS)
    _, y, _ = scipy.signal.dlsim((Ad, Bd, Cd, Dd, 1 / FS), tau)
    theta = y[:, 0] + 1e-5 * np.random.default_rng(seed).standard_normal(t.size)
    return t, theta, tau


def _write(path, t, x, F):
    np.savez(path, t=t, x=x, F=F)
    return path


@pytest.mark.parametrize(
    ("linear", "rotary"),
    [
        ("m", "rad"),
        ("N", "N·m"),
        ("1/kg", "1/(kg·m²)"),
        ("N/m", "N·m/rad"),
        ("N·s/m", "N·m·s/rad"),
        ("m/s²", "rad/s²"),
        ("N/s", "N·m/s"),
        ("1/s", "1/s"),
        ("Hz", "Hz"),
        ("", ""),
        ("x < 0.3 m", "x < 0.3 rad"),
        ("|v| < 2 m/s (near zero, reversals)", "|v| < 2 rad/s (near zero, reversals)"),
    ],
)
def test_unit_names(linear, rotary):
    # the work τ·dθ replaces F·dx: each linear base unit has one rotary counterpart
    assert unit(linear, "rotary") == rotary
    assert unit(linear, "linear") == linear


def test_units_argument_is_checked(tmp_path):
    t, x, F = _rotor()
    with pytest.raises(InputError, match=r"units.*'linear', 'rotary'.*got 'degrees'"):
        lj.Record(x, F, 1 / FS, units="degrees")
    with pytest.raises(InputError, match="units"):
        lj.load_record(_write(tmp_path / "r.npz", t, x, F), units="rad")
    assert convert_units({"units": {"b": "1/kg"}, "gap_units": "m"}, "rotary") == {
        "units": {"b": "1/(kg·m²)"},
        "gap_units": "rad",
    }


def test_millimetre_check_is_for_linear_axes(tmp_path):
    t, x, F = _rotor()
    assert 110 < np.max(np.abs(x)) < 4000  # the range the linear check reads as millimetres
    path = _write(tmp_path / "rotor.npz", t, x, F)
    linear = lj.load_record(path)
    rotary = lj.load_record(path, units="rotary")
    assert (linear.units, rotary.units) == ("linear", "rotary")
    assert rotary.decimate(2).units == "rotary"
    assert any("millimetres" in m for m in sanity_messages(linear))
    assert not any("millimetres" in m for m in sanity_messages(rotary))


def _labels(monkeypatch):
    """The y labels of the figure plot_diagnosis draws (its save captured, nothing written)."""
    import lionjax.diagnosis._plot as plot

    seen = []

    def capture(fig, path, **kw):
        seen.extend(a.get_ylabel() for a in fig.axes)
        return path

    monkeypatch.setattr(plot, "save_figure", capture)
    return seen


def test_rotary_diagnosis_and_identification(tmp_path, monkeypatch, capsys):
    t, x, F = _rotor()
    tv, xv, Fv = _rotor(seed=1)
    xv = xv - xv[0] + 50.0  # the validation run starts elsewhere on the shaft
    train = _write(tmp_path / "train.npz", t, x, F)
    valid = _write(tmp_path / "valid.npz", tv, xv, Fv)

    # the linear reading of the same samples: the numbers, and the millimetre warning
    with pytest.warns(lj.solutions.DataWarning, match="millimetres"):
        lin = lj.diagnose(lj.load_record(train), lj.load_record(valid))
    assert lin.units == "linear" and lin.baseline["units"]["b"] == "1/kg"

    labels = _labels(monkeypatch)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "x in mm?" (nor any other) warning
        code = main(
            [
                "diagnose",
                str(train),
                "--validate",
                str(valid),
                "--units",
                "rotary",
                "--json",
                str(tmp_path / "d.json"),
                "--plot",
                str(tmp_path / "d.png"),
            ]
        )
    assert code == 0
    text = capsys.readouterr().out
    out = json.loads((tmp_path / "d.json").read_text())
    ref = lin.to_json()
    assert out["units"] == "rotary"
    base = out["baseline"]
    assert (base["units"]["b"], base["gap_units"], base["equation_gap_units"]) == (
        "1/(kg·m²)",
        "rad",
        "rad/s²",
    )
    # the same numbers, every unit the rotary one of the linear report's
    assert out["verdict"] == ref["verdict"] and out["stack"] == ref["stack"]
    for k, v in ref["baseline"]["params"].items():
        assert base["params"][k] == pytest.approx(v, rel=1e-9)
    assert out["final"]["units"] == {k: unit(u, "rotary") for k, u in ref["final"]["units"].items()}
    assert not any(
        re.search(r"(?<![A-Za-z·])m(?![A-Za-z])", u) for u in out["final"]["units"].values()
    )
    assert "1/(kg·m²)" in text and re.search(r"gap \S+ rad", text) and " 1/kg" not in text
    assert {"x [rad]", "sim. error [mrad]", "ε₁ [rad/s²]"} <= set(labels)
    assert 1 / base["params"]["b"] == pytest.approx(J, rel=0.05)  # b = 1/J of the rotor
    # the searched regions: the same bounds, stated in rad, rad/s, N·m (t in s)
    bounds = [(r["variable"], r["low"], r["high"]) for r in out["regions"]]
    assert bounds == [(r["variable"], r["low"], r["high"]) for r in ref["regions"]]
    assert [r["units"] for r in out["regions"]] == [
        unit(r["units"], "rotary") for r in ref["regions"]
    ]

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code = main(
            ["identify", str(train), "--units", "rotary", "--json", str(tmp_path / "i.json")]
        )
    assert code == 0
    ident = json.loads((tmp_path / "i.json").read_text())
    assert ident["units"] == "rotary"
    assert ident["param_units"] == {"a": "1/s", "b": "1/(kg·m²)"}
    assert "1/(kg·m²)" in capsys.readouterr().out
