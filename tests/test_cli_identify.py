"""`lionjax identify` end to end on CSV/NPZ files from the independent reference simulator."""

import json
import subprocess
import sys

import numpy as np
import pytest
from _reference_sim import PAPER_A, PAPER_B, multisine, simulate

from lionjax.cli import main

DT = 1e-3


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("records")
    t = np.arange(30000) * DT
    F1 = multisine(t, [0.7, 2.3, 5.1, 9.7], [0.2, 0.15, 0.1, 0.1])
    x1 = simulate(F1, DT, a=(22.0,), b=(1.916,), bounds=())
    np.savetxt(d / "single.csv", np.c_[t, x1, F1], delimiter=",", header="t,x,F", comments="")
    F3 = multisine(t, [0.5, 1.7, 3.9], [1.0, 0.4, 0.3], [np.pi / 2, 1.0, 2.0])
    x3 = simulate(F3, DT)
    np.savez(d / "cross.npz", t=t, x=x3, F=F3)
    np.savetxt(
        d / "renamed.csv", np.c_[t, x1, F1], delimiter=",", header="time,pos,force", comments=""
    )
    return d


def _run(args, capsys):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_identify_ls_single_region(files, tmp_path, capsys):
    out = tmp_path / "o.json"
    code, text, _ = _run(["identify", files / "single.csv", "--json", out], capsys)
    assert code == 0
    assert "a " in text and "b " in text and "1/kg" in text
    p = json.loads(out.read_text())["params"]
    assert set(p) == {"a", "b"}
    assert abs(p["a"] / 22.0 - 1) < 1e-3 and abs(p["b"] / 1.916 - 1) < 1e-3


def test_identify_lion_single_region(files, tmp_path, capsys):
    out = tmp_path / "o.json"
    code, text, _ = _run(
        ["identify", files / "single.csv", "--method", "lion", "--json", out], capsys
    )
    assert code == 0
    p = json.loads(out.read_text())["params"]
    assert abs(p["a"] / 22.0 - 1) < 1e-2 and abs(p["b"] / 1.916 - 1) < 1e-2


def test_identify_regions(files, tmp_path, capsys):
    out = tmp_path / "o.json"
    code, _, _ = _run(
        ["identify", files / "cross.npz", "--regions", "-0.01,0.01", "--json", out], capsys
    )
    assert code == 0
    p = json.loads(out.read_text())["params"]
    assert list(p) == ["a_1", "b_1", "a_2", "b_2", "a_3", "b_3"]
    truth = [v for ab in zip(PAPER_A, PAPER_B) for v in ab]
    np.testing.assert_allclose(list(p.values()), truth, rtol=1e-2)


def test_identify_columns_and_options(files, capsys):
    code, _, err = _run(["identify", files / "renamed.csv"], capsys)
    assert code == 2 and "renamed.csv" in err and "--columns" in err
    code, text, _ = _run(
        [
            "identify",
            files / "renamed.csv",
            "--columns",
            "t=time,x=pos,F=force",
            "--poles",
            "-5,-6,-7",
            "--x-hold",
            "foh",
        ],
        capsys,
    )
    assert code == 0 and "MassDamper by ls" in text


@pytest.mark.parametrize(
    "args, match",
    [
        (["--regions", "0.01,-0.01"], "strictly increasing"),
        (["--regions", "a,b"], "--regions"),
        (["--poles", "1,-4,-4"], "negative real part"),
        (["--coeffs", "12,48,-64"], "Hurwitz"),
        (["--method", "lion", "--gain", "fast"], "--gain"),
        (["--method", "lion", "--gain", "-1"], "positive"),
        (["--regions", "-0.5,-0.4"], "does not excite"),
    ],
)
def test_identify_bad_options(files, capsys, args, match):
    code, _, err = _run(["identify", files / "single.csv", *args], capsys)
    assert code == 2
    assert match in err


def test_console_script_runs(files):
    # The installed entry point, in a subprocess, as a user would call it.
    r = subprocess.run(
        [sys.executable, "-m", "lionjax.cli", "identify", str(files / "single.csv")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert "MassDamper by ls" in r.stdout
