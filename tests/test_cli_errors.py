"""The command line's errors (issue 39, cases 5–9 and the weak items) and its output without
``nan`` (issue 38, item 4): every error is one line ``lionjax CMD: error: …`` naming the file or
option, exit status 2, never a traceback; outputs are checked before the work and written
atomically."""

import json
import os
import re

import numpy as np
import pytest
from _reference_sim import multisine, simulate

import lionjax as lj
from lionjax._tables import write_json
from lionjax.cli import main

A, B, DT, T = 20.0, 2.0, 1e-3, 3000


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    d = tmp_path_factory.mktemp("records")
    t = np.arange(T) * DT
    F = multisine(t, [0.7, 2.3, 5.1, 9.7], [0.2, 0.15, 0.1, 0.1])
    x = simulate(F, DT, a=(A,), b=(B,), bounds=())

    def csv(name, *cols, header="t,x,F"):
        np.savetxt(d / name, np.c_[cols], delimiter=",", header=header, comments="")
        return d / name

    return {
        "dir": d,
        "good": csv("good.csv", t, x, F),
        "dead_F": csv("dead_F.csv", t, x, 0 * F),
        "still": csv("still.csv", t, np.full(T, 3e-3), F),
        "short": csv("short.csv", t[:20], x[:20], F[:20]),
        "arrays": (t, x, F),
    }


def _run(args, capsys):
    try:
        code = main([str(a) for a in args])
    except SystemExit as e:
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


def _one_error(err: str, command: str) -> str:
    """The single error line of stderr (and no traceback)."""
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if f"lionjax {command}: error: " in ln]
    assert len(lines) == 1, err
    return lines[0]


# --------------------------------------------------------------------------- numbered cases


def test_case5_dead_validation_record_is_refused(rec, capsys):
    code, out, err = _run(["diagnose", rec["good"], "--validate", rec["dead_F"]], capsys)
    line = _one_error(err, "diagnose")
    assert code == 2 and "verdict" not in out
    assert "dead_F.csv" in line and "--validate" in line and "constant force" in line
    t, x, F = rec["arrays"]
    with pytest.raises(lj.InputError, match="validation record.*constant force: F ≡ 0"):
        lj.diagnose(lj.Record.from_samples(t, x, F), lj.Record.from_samples(t, x, 0 * F))


def test_case6_study_refuses_a_record_identify_refuses(rec, capsys):
    code_i, _, err_i = _run(["identify", rec["short"]], capsys)
    code_s, out_s, err_s = _run(["study", rec["short"], "--gains", "100"], capsys)
    assert code_i == code_s == 2 and "a_LS" not in out_s
    line = _one_error(err_s, "study")
    assert "short.csv" in line and "shorter than the filter transient" in line
    assert "shorter than the filter transient" in _one_error(err_i, "identify")
    t, x, F = rec["arrays"]
    with pytest.raises(lj.InputError, match="shorter than the filter transient"):
        lj.study(lj.MassDamper(), [lj.Record.from_samples(t[:20], x[:20], F[:20])], gains=[1e2])


def test_case7_bad_mat_files_are_named(rec, tmp_path, capsys):
    scipy_io = pytest.importorskip("scipy.io")
    t, x, F = rec["arrays"]
    scipy_io.savemat(tmp_path / "full.mat", {"t": t[:, None], "x": x[:, None], "F": F[:, None]})
    raw = (tmp_path / "full.mat").read_bytes()
    bad = {"empty.mat": b"", "truncated.mat": raw[: len(raw) // 2], "zeros.mat": bytes(4096)}
    for name, content in bad.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(lj.InputError, match=re.escape(name)):
            lj.load_record(tmp_path / name)
        code, _, err = _run(["identify", tmp_path / name], capsys)
        assert code == 2 and name in _one_error(err, "identify")
    # in a folder: every bad file named, nothing identified
    code, out, err = _run(["identify", tmp_path], capsys)
    assert code == 2 and "Traceback" not in err and "full.mat" not in out
    assert all(name in err for name in bad) and "3 of 4 files cannot be used" in err


def test_case8_diagnose_train_without_motion_is_an_input_error(rec, capsys):
    code, _, err = _run(["diagnose", rec["still"], "--validate", rec["good"]], capsys)
    line = _one_error(err, "diagnose")
    assert code == 2 and "still.csv" in line and "constant position" in line
    t, x, F = rec["arrays"]
    with pytest.raises(lj.InputError, match="training record.*constant position"):
        lj.diagnose(lj.Record.from_samples(t, np.full(T, 3e-3), F), lj.Record.from_samples(t, x, F))


def test_case9_bad_output_paths_fail_before_the_work(rec, tmp_path, capsys):
    code, out, err = _run(["identify", rec["good"], "--json", tmp_path], capsys)
    assert code == 2 and out == ""  # nothing printed as if it had worked
    assert "--json" in _one_error(err, "identify") and "is a folder" in err
    code, out, err = _run(["reproduce", "--quick", "--out", "/proc/nope"], capsys)
    assert code == 2 and "--out" in _one_error(err, "reproduce")
    code, out, err = _run(["study", rec["good"], "--csv", tmp_path / "no" / "o.csv"], capsys)
    assert code == 2 and "does not exist" in _one_error(err, "study") and out == ""
    code, out, err = _run(["diagnose", rec["good"], "--plot", tmp_path], capsys)
    assert code == 2 and "--plot" in _one_error(err, "diagnose")
    code, out, err = _run(["diagnose", rec["good"], "--plot", tmp_path / "fig"], capsys)
    assert code == 2 and "extension" in _one_error(err, "diagnose")


def test_case9_writes_are_atomic(tmp_path):
    path = tmp_path / "out.json"
    write_json(path, {"a": 1.0, "b": float("nan")})
    assert json.loads(path.read_text()) == {"a": 1.0, "b": None}
    before = path.read_text()
    with pytest.raises(TypeError):
        write_json(path, {"a": object()})  # fails while serialising
    assert path.read_text() == before  # the old file is untouched
    assert os.listdir(tmp_path) == ["out.json"]  # and no temporary file is left


def test_case9_one_handler_for_every_error(rec, monkeypatch, capsys):
    import lionjax.cli._identify as ident

    def boom(args):
        raise RuntimeError("something unforeseen")

    monkeypatch.setattr(ident, "run", boom)
    code, _, err = _run(["identify", rec["good"]], capsys)
    line = _one_error(err, "identify")
    assert code == 2 and "internal error" in line and "something unforeseen" in line
    monkeypatch.undo()
    code, _, err = _run(["identify", rec["good"], "--method", "nope"], capsys)
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    code, _, err = _run(["identify", rec["good"], "--method", "lion", "--theta0", "nan,1"], capsys)
    assert code == 2 and "--theta0" in _one_error(err, "identify")


# --------------------------------------------------------------------------- weak items


def test_weak_items_of_the_readers(rec, tmp_path, capsys):
    t, x, F = rec["arrays"]
    np.savetxt(tmp_path / "nohead.csv", np.c_[np.zeros(T), np.zeros(T), F], delimiter=",")
    code, _, err = _run(["identify", tmp_path / "nohead.csv"], capsys)
    line = _one_error(err, "identify")
    assert "no header row" in line and "t,x,F" in line and "more than once" not in line
    tj = t + np.random.default_rng(0).uniform(-0.2, 0.2, T) * DT
    np.savetxt(tmp_path / "jit.csv", np.c_[tj, x, F], delimiter=",", header="t,x,F", comments="")
    code, _, err = _run(["identify", tmp_path / "jit.csv"], capsys)
    line = _one_error(err, "identify")
    assert "--resample" in line and "resample=True" not in line
    with pytest.raises(lj.InputError, match="resample=True"):
        lj.load_record(tmp_path / "jit.csv")  # the API names its argument
    np.savez(tmp_path / "f16.npz", t=t.astype(np.float16), x=x, F=F)
    with pytest.raises(lj.InputError, match="float16.*precision is too low"):
        lj.load_record(tmp_path / "f16.npz")
    np.savez(tmp_path / "bool.npz", t=t, x=x, F=F > 0)
    with pytest.raises(lj.InputError, match="'F' holds booleans.*expected numbers"):
        lj.load_record(tmp_path / "bool.npz")


def test_lion_output_has_an_uncertainty_and_plain_english(rec, tmp_path, capsys):
    out = tmp_path / "o.json"
    code, text, _ = _run(
        ["identify", rec["good"], "--method", "lion", "--rate", "20", "--json", out], capsys
    )
    assert code == 0 and not re.search(r"\bnan\b", text)
    assert re.search(r"Lion's estimate settles within 2 % of least squares after [\d.]+ s\.", text)
    assert "* std: least-squares covariance" in text
    doc = json.loads(out.read_text(), parse_constant=lambda c: pytest.fail(f"JSON has {c}"))
    assert all(np.isfinite(v) and v > 0 for v in doc["std"].values())
    # the std: σ²(θ)(ΦᵀΦ)⁻¹ over the samples after the transient, σ²(θ) = RSS(θ)/(2N − p) at
    # Lion's estimate θ, from the regressors with numpy
    r = lj.load_record(rec["good"])
    regs = lj.MassDamper().regressors(r, lj.default_bank())
    k0 = int(np.ceil(2.25 / DT - 1e-9))  # 3·λ₂/λ₃ of (s + 4)³
    Phi = np.asarray(regs.W)[k0:].reshape(-1, 2)
    y = np.asarray(regs.W0)[k0:].reshape(-1)
    theta = np.array([doc["params"]["a"], doc["params"]["b"]])
    s2 = np.sum((Phi @ theta + y) ** 2) / (Phi.shape[0] - 2)
    want = np.sqrt(np.diagonal(s2 * np.linalg.inv(Phi.T @ Phi)))
    np.testing.assert_allclose(list(doc["std"].values()), want, rtol=1e-3)
    code, text, _ = _run(["identify", rec["good"], "--method", "lion"], capsys)  # rate 1: slow
    assert code == 0 and not re.search(r"\bnan\b", text)
    assert "did not settle within 2 % of least squares by the end of the record (3 s)" in text


def test_study_and_batch_tables_print_no_nan(rec, tmp_path, capsys):
    code, text, _ = _run(
        ["study", rec["good"], "--gains", "1,1e5", "--poles", "-8", "--csv", tmp_path / "s.csv"],
        capsys,
    )
    assert code == 0 and not re.search(r"\bnan\b", text) and "not settled" in text
    code, text, _ = _run(
        ["identify", rec["good"], rec["dead_F"], "--method", "lion", "--json", tmp_path / "b.json"],
        capsys,
    )
    assert code == 1 and "failed" in text  # the dead record's row: failed, its values —
    assert not re.search(r"\bnan\b", text)
    json.loads((tmp_path / "b.json").read_text(), parse_constant=lambda c: pytest.fail(c))
