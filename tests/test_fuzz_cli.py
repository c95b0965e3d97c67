"""Fuzz the command line with what a careless user feeds it: every answer right or refused.

A good record of ẍ + aẋ = bF (a = 20 1/s, b = 2 1/kg, a four-tone multisine force, 3 000
noise-free samples at 1 kHz, from the independent simulator of ``_reference_sim``) is spoiled
in the ways of issue 39 and of everyday mistakes (empty, truncated and corrupt files, missing or
swapped columns, wrong units, NaN, duplicate or reversed time, bad sampling, constant signals,
spikes, booleans, text in a cell, …): ``VARIANTS`` holds each with the answer it must get.

Each variant runs through ``lionjax identify``, ``identify --method lion``, ``study`` and
``diagnose`` in this process (:func:`lionjax.cli.main`, so the compiled programs are shared)
and must be **right or refused**:

- refused: exit status 2, exactly one line ``lionjax CMD: error: …`` naming the file, no
  traceback, no "internal error";
- right: exit status 0, the JSON strict (no NaN token), ``nan`` nowhere in the printed output,
  and the numbers equal to the known truth of the data as given (the good record's a, b mapped
  through the variant's unit change) within a stated tolerance: least squares 1e-3, Lion and
  the study's θ(T) (AutoGain rate 20 1/s: settled within 1 s on the good record) 1e-2 — or,
  where Lion did not settle within 2 % of least squares, the output saying so —, the
  diagnosis' baseline 1e-2 (noise-free data: every estimator is within 1e-4 on the good
  record);
- ``"refuse"`` variants must be refused, ``"right"`` variants answered right, ``"either"``
  variants one of the two, and ``"warn"`` variants refused or answered with a warning line
  (``lionjax CMD: warning: …``) — a spike or a swapped pair of columns the data cannot prove
  wrong must at least be flagged, never reported as a plain success.

The diagnosis of a valid record costs seconds, so it runs on ``DIAGNOSE_VALID`` only (every other
variant is refused before any fitting, in milliseconds); ``test_count`` states the number of
(variant, subcommand) pairs executed.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import numpy as np
import pytest
from _reference_sim import multisine, simulate

from lionjax.cli import main

A, B, DT, T = 20.0, 2.0, 1e-3, 3000
COMMANDS = ("identify", "lion", "study", "diagnose")
#: Relative tolerance of the right answer per command (see the module docstring).
RTOL = {"identify": 1e-3, "lion": 1e-2, "study": 1e-2, "diagnose": 1e-2}


def _good():
    t = np.arange(T) * DT
    F = multisine(t, [0.7, 2.3, 5.1, 9.7], [0.2, 0.15, 0.1, 0.1])
    x = simulate(F, DT, a=(A,), b=(B,), bounds=())
    return t, x, F


def _csv(path: Path, header: str, *cols, fmt="%.17g") -> None:
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=header, comments="", fmt=fmt)


def _text(path: Path, text: str, newline: str = "\n") -> None:
    path.write_bytes(text.replace("\n", newline).encode("utf-8"))


def _csv_text(t, x, F, header="t,x,F") -> str:
    return header + "\n" + "".join(f"{a:.17g},{b:.17g},{c:.17g}\n" for a, b, c in zip(t, x, F))


def _edit_line(text: str, k: int, new: str) -> str:
    lines = text.split("\n")
    lines[k + 1] = new  # sample k is on line k + 2 (1-based)
    return "\n".join(lines)


def _mat(path: Path, **arrays) -> None:
    import scipy.io

    scipy.io.savemat(path, {k: np.asarray(v)[:, None] for k, v in arrays.items()})


# --------------------------------------------------------------------------- the variants
# name -> (writer(folder, t, x, F) -> file name, expectation, (a, b) of the data as given or None)

VARIANTS: dict = {}


def variant(name, expect, truth=None):
    def deco(fn):
        VARIANTS[name] = (fn, expect, truth)
        return fn

    return deco


@variant("good", "right", (A, B))
def _(d, t, x, F):
    _csv(d / "good.csv", "t,x,F", t, x, F)
    return "good.csv"


@variant("good_npz", "right", (A, B))
def _(d, t, x, F):
    np.savez(d / "good.npz", t=t, x=x, F=F)
    return "good.npz"


@variant("good_mat", "right", (A, B))
def _(d, t, x, F):
    _mat(d / "good.mat", t=t, x=x, F=F)
    return "good.mat"


@variant("columns_reordered", "right", (A, B))
def _(d, t, x, F):
    _csv(d / "reordered.csv", "F,t,x", F, t, x)
    return "reordered.csv"


@variant("extra_columns", "right", (A, B))
def _(d, t, x, F):
    text = "t,x,F,xref,note\n" + "".join(
        f"{a:.17g},{b:.17g},{c:.17g},0.0,run{k % 3}\n" for k, (a, b, c) in enumerate(zip(t, x, F))
    )
    _text(d / "extra.csv", text)
    return "extra.csv"


@variant("x_in_mm", "right", (A, 1e3 * B))
def _(d, t, x, F):
    _csv(d / "x_mm.csv", "t,x,F", t, 1e3 * x, F)
    return "x_mm.csv"


@variant("F_in_mN", "right", (A, 1e-3 * B))
def _(d, t, x, F):
    _csv(d / "F_mN.csv", "t,x,F", t, x, 1e3 * F)
    return "F_mN.csv"


@variant("t_in_ms", "either", (A / 1e3, B / 1e6))
def _(d, t, x, F):
    _csv(d / "t_ms.csv", "t,x,F", 1e3 * t, x, F)
    return "t_ms.csv"


@variant("t_as_sample_index", "either", (A / 1e3, B / 1e6))
def _(d, t, x, F):
    _csv(d / "t_index.csv", "t,x,F", np.arange(T), x, F)
    return "t_index.csv"


@variant("F_sign_flipped", "right", (A, -B))
def _(d, t, x, F):
    _csv(d / "F_neg.csv", "t,x,F", t, x, -F)
    return "F_neg.csv"


@variant("t_offset", "right", (A, B))
def _(d, t, x, F):
    _csv(d / "t_offset.csv", "t,x,F", t + 1234.5, x, F)
    return "t_offset.csv"


@variant("crlf_line_endings", "right", (A, B))
def _(d, t, x, F):
    _text(d / "crlf.csv", _csv_text(t, x, F), newline="\r\n")
    return "crlf.csv"


@variant("utf8_bom", "right", (A, B))
def _(d, t, x, F):
    (d / "bom.csv").write_bytes(b"\xef\xbb\xbf" + _csv_text(t, x, F).encode())
    return "bom.csv"


@variant("trailing_blank_lines", "right", (A, B))
def _(d, t, x, F):
    _text(d / "trailing.csv", _csv_text(t, x, F) + "\n\n\n")
    return "trailing.csv"


@variant("spaces_around_cells", "right", (A, B))
def _(d, t, x, F):
    rows = "".join(f" {a:.17g} , {b:.17g} , {c:.17g} \n" for a, b, c in zip(t, x, F))
    text = " t , x , F \n" + rows
    _text(d / "spaces.csv", text)
    return "spaces.csv"


@variant("float32_npz", "right", (A, B))
def _(d, t, x, F):
    np.savez(d / "f32.npz", t=t, x=x.astype(np.float32), F=F.astype(np.float32))
    return "f32.npz"


@variant("x_in_mm_npz_with_dt", "right", (A, 1e3 * B))
def _(d, t, x, F):
    np.savez(d / "x_mm.npz", t=t, x=1e3 * x, F=F, dt=DT)
    return "x_mm.npz"


@variant("single_spike_in_F", "warn")
def _(d, t, x, F):
    F = F.copy()
    F[1500] = 1e6
    _csv(d / "spike.csv", "t,x,F", t, x, F)
    return "spike.csv"


@variant("columns_swapped", "warn")
def _(d, t, x, F):
    _csv(d / "swapped.csv", "t,x,F", t, F, x)  # the header says x, F; the data hold F, x
    return "swapped.csv"


@variant("force_logged_constant", "warn")
def _(d, t, x, F):
    _csv(d / "F_const_logged.csv", "t,x,F", t, x, np.full(T, 0.3))
    return "F_const_logged.csv"


# --- refused: the file


@variant("empty_csv", "refuse")
def _(d, t, x, F):
    (d / "empty.csv").write_bytes(b"")
    return "empty.csv"


@variant("blank_lines_only", "refuse")
def _(d, t, x, F):
    _text(d / "blank.csv", "\n\n\n")
    return "blank.csv"


@variant("header_only", "refuse")
def _(d, t, x, F):
    _text(d / "header_only.csv", "t,x,F\n")
    return "header_only.csv"


@variant("no_header_row", "refuse")
def _(d, t, x, F):
    np.savetxt(d / "no_header.csv", np.c_[t, x, F], delimiter=",")
    return "no_header.csv"


@variant("missing_column", "refuse")
def _(d, t, x, F):
    _csv(d / "missing.csv", "t,x", t, x)
    return "missing.csv"


@variant("misnamed_column", "refuse")
def _(d, t, x, F):
    _csv(d / "misnamed.csv", "time,pos,force", t, x, F)
    return "misnamed.csv"


@variant("duplicate_column_names", "refuse")
def _(d, t, x, F):
    _csv(d / "dup_cols.csv", "t,x,x,F", t, x, x, F)
    return "dup_cols.csv"


@variant("semicolon_separated", "refuse")
def _(d, t, x, F):
    np.savetxt(d / "semicolon.csv", np.c_[t, x, F], delimiter=";", header="t;x;F", comments="")
    return "semicolon.csv"


@variant("nan_in_the_middle", "refuse")
def _(d, t, x, F):
    x = x.copy()
    x[1500] = np.nan
    _csv(d / "nan.csv", "t,x,F", t, x, F)
    return "nan.csv"


@variant("inf_in_F", "refuse")
def _(d, t, x, F):
    F = F.copy()
    F[10] = np.inf
    _csv(d / "inf.csv", "t,x,F", t, x, F)
    return "inf.csv"


@variant("string_in_a_cell", "refuse")
def _(d, t, x, F):
    row = f"{t[700]:.17g},oops,{F[700]:.17g}"
    _text(d / "string.csv", _edit_line(_csv_text(t, x, F), 700, row))
    return "string.csv"


@variant("empty_cell", "refuse")
def _(d, t, x, F):
    _text(d / "empty_cell.csv", _edit_line(_csv_text(t, x, F), 42, f"{t[42]:.17g},,{F[42]:.17g}"))
    return "empty_cell.csv"


@variant("ragged_row", "refuse")
def _(d, t, x, F):
    _text(d / "ragged.csv", _edit_line(_csv_text(t, x, F), 99, f"{t[99]:.17g},{x[99]:.17g}"))
    return "ragged.csv"


@variant("truncated_csv", "refuse")
def _(d, t, x, F):
    text = _csv_text(t, x, F)
    _text(d / "truncated.csv", text[: len(text) // 2 - 7])  # cut inside a row
    return "truncated.csv"


@variant("blank_line_in_the_middle", "refuse")
def _(d, t, x, F):
    _text(d / "blank_mid.csv", _edit_line(_csv_text(t, x, F), 1000, ""))
    return "blank_mid.csv"


@variant("bool_strings_in_F", "refuse")
def _(d, t, x, F):
    text = "t,x,F\n" + "".join(f"{a:.17g},{b:.17g},{c > 0}\n" for a, b, c in zip(t, x, F))
    _text(d / "bool_text.csv", text)
    return "bool_text.csv"


@variant("binary_file_as_csv", "refuse")
def _(d, t, x, F):
    (d / "binary.csv").write_bytes(bytes(range(256)) * 10)
    return "binary.csv"


@variant("wrong_extension", "refuse")
def _(d, t, x, F):
    _csv(d / "record.txt", "t,x,F", t, x, F)
    return "record.txt"


@variant("no_such_file", "refuse")
def _(d, t, x, F):
    return "does_not_exist.csv"


@variant("empty_mat", "refuse")
def _(d, t, x, F):
    (d / "empty.mat").write_bytes(b"")
    return "empty.mat"


@variant("truncated_mat", "refuse")
def _(d, t, x, F):
    _mat(d / "full.mat", t=t, x=x, F=F)
    raw = (d / "full.mat").read_bytes()
    (d / "truncated.mat").write_bytes(raw[: len(raw) // 2])
    return "truncated.mat"


@variant("all_zero_mat", "refuse")
def _(d, t, x, F):
    (d / "zeros.mat").write_bytes(bytes(4096))
    return "zeros.mat"


@variant("csv_renamed_mat", "refuse")
def _(d, t, x, F):
    _text(d / "renamed.mat", _csv_text(t[:50], x[:50], F[:50]))
    return "renamed.mat"


@variant("empty_npz", "refuse")
def _(d, t, x, F):
    (d / "empty.npz").write_bytes(b"")
    return "empty.npz"


@variant("truncated_npz", "refuse")
def _(d, t, x, F):
    np.savez(d / "full.npz", t=t, x=x, F=F)
    raw = (d / "full.npz").read_bytes()
    (d / "truncated.npz").write_bytes(raw[: len(raw) // 2])
    return "truncated.npz"


@variant("npz_missing_array", "refuse")
def _(d, t, x, F):
    np.savez(d / "no_F.npz", t=t, x=x, force=F)
    return "no_F.npz"


@variant("float16_time", "refuse")
def _(d, t, x, F):
    np.savez(d / "f16.npz", t=t.astype(np.float16), x=x, F=F)
    return "f16.npz"


@variant("bool_force_npz", "refuse")
def _(d, t, x, F):
    np.savez(d / "bool.npz", t=t, x=x, F=F > 0)
    return "bool.npz"


@variant("complex_x_npz", "refuse")
def _(d, t, x, F):
    np.savez(d / "complex.npz", t=t, x=x + 0j, F=F)
    return "complex.npz"


@variant("npz_stored_dt_wrong", "refuse")
def _(d, t, x, F):
    np.savez(d / "bad_dt.npz", t=t, x=x, F=F, dt=10 * DT)
    return "bad_dt.npz"


# --- refused: the time column


@variant("duplicate_times", "refuse")
def _(d, t, x, F):
    t = t.copy()
    t[1001] = t[1000]
    _csv(d / "dup_t.csv", "t,x,F", t, x, F)
    return "dup_t.csv"


@variant("reversed_time", "refuse")
def _(d, t, x, F):
    _csv(d / "reversed.csv", "t,x,F", t[::-1], x[::-1], F[::-1])
    return "reversed.csv"


@variant("negative_dt", "refuse")
def _(d, t, x, F):
    _csv(d / "neg_dt.csv", "t,x,F", -t, x, F)
    return "neg_dt.csv"


@variant("time_all_zero", "refuse")
def _(d, t, x, F):
    _csv(d / "t_zero.csv", "t,x,F", 0 * t, x, F)
    return "t_zero.csv"


@variant("jittered_sampling", "refuse")
def _(d, t, x, F):
    rng = np.random.default_rng(0)
    _csv(d / "jitter.csv", "t,x,F", t + rng.uniform(-0.2, 0.2, T) * DT, x, F)
    return "jitter.csv"


@variant("sampling_rate_changes", "refuse")
def _(d, t, x, F):
    t = t.copy()
    t[1500:] = t[1500] + 2 * (t[1500:] - t[1500])
    _csv(d / "two_rates.csv", "t,x,F", t, x, F)
    return "two_rates.csv"


@variant("one_sample", "refuse")
def _(d, t, x, F):
    _csv(d / "one.csv", "t,x,F", t[:1], x[:1], F[:1])
    return "one.csv"


@variant("twenty_samples", "refuse")
def _(d, t, x, F):
    _csv(d / "twenty.csv", "t,x,F", t[:20], x[:20], F[:20])
    return "twenty.csv"


# --- refused: the record does not identify the model


@variant("force_all_zero", "refuse")
def _(d, t, x, F):
    _csv(d / "F_zero.csv", "t,x,F", t, x, 0 * F)
    return "F_zero.csv"


@variant("position_all_zero", "refuse")
def _(d, t, x, F):
    _csv(d / "x_zero.csv", "t,x,F", t, 0 * x, F)
    return "x_zero.csv"


@variant("position_constant_3mm", "refuse")
def _(d, t, x, F):
    _csv(d / "x_const.csv", "t,x,F", t, np.full(T, 3e-3), F)
    return "x_const.csv"


@variant("constant_force_response", "either", (A, B))  # a step response identifies a, b
def _(d, t, x, F):
    Fc = np.full(T, 0.2)
    _csv(d / "F_const.csv", "t,x,F", t, simulate(Fc, DT, a=(A,), b=(B,), bounds=()), Fc)
    return "F_const.csv"


@variant("everything_zero", "refuse")
def _(d, t, x, F):
    _csv(d / "zeros.csv", "t,x,F", t, 0 * x, 0 * F)
    return "zeros.csv"


@variant("huge_values", "refuse")
def _(d, t, x, F):
    _csv(d / "huge.csv", "t,x,F", t, 1e200 * x, 1e200 * F)
    return "huge.csv"


#: Valid variants the (costly) diagnosis runs on; every other variant must be refused by it.
DIAGNOSE_VALID = {"good", "columns_reordered"}


def _pairs():
    for name, (_, expect, _) in VARIANTS.items():
        for cmd in COMMANDS:
            if cmd == "diagnose" and expect != "refuse" and name not in DIAGNOSE_VALID:
                continue
            yield name, cmd


PAIRS = list(_pairs())


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz")
    t, x, F = _good()
    files = {name: d / fn(d, t, x, F) for name, (fn, _, _) in VARIANTS.items()}
    return d, files


def _run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as e:  # argparse
            code = e.code
    return code, out.getvalue(), err.getvalue()


def _argv(cmd: str, path: Path, out: Path) -> list[str]:
    if cmd == "identify":
        return ["identify", str(path), "--json", str(out)]
    if cmd == "lion":
        return ["identify", str(path), "--method", "lion", "--rate", "20", "--json", str(out)]
    if cmd == "study":
        return [
            "study", str(path), "--gains", "20", "--gain-type", "auto", "--poles", "-4",
            "--json", str(out),
        ]  # fmt: skip
    return ["diagnose", str(path), "--json", str(out)]


def _strict(text: str):
    def refuse(token):
        raise AssertionError(f"JSON holds the non-standard token {token}")

    return json.loads(text, parse_constant=refuse)


def _estimates(cmd: str, doc) -> list[tuple[str, float]]:
    """The numbers that must be right. Lion's θ(T) only where it settled within 2 % of least
    squares (else the output says it did not, which is the right answer about θ(T))."""
    if cmd in ("identify", "lion"):
        settled = cmd == "identify" or doc["convergence_time"] is not None
        got = [(k, v) for k, v in doc["params"].items()] if settled else []
        return got + [(f"{k} (LS)", v) for k, v in doc.get("params_ls", {}).items()]
    if cmd == "study":
        (row,) = doc["rows"]
        keys = ("a", "b") if row["convergence_time"] is not None else ()
        return [(k, row[k]) for k in (*keys, "a_ls", "b_ls")]
    return [(k, doc["baseline"]["params"][k]) for k in ("a", "b")]


@pytest.mark.parametrize(("name", "cmd"), PAIRS)
def test_right_or_refused(folder, tmp_path, name, cmd):
    _, expect, truth = VARIANTS[name]
    path = folder[1][name]
    out = tmp_path / "out.json"
    code, stdout, stderr = _run(_argv(cmd, path, out))
    text = stdout + stderr
    assert "Traceback" not in text and "internal error" not in text, text[-2000:]
    assert code in (0, 2), (code, text[-2000:])
    label = "identify" if cmd == "lion" else cmd
    if code == 2:
        errors = [ln for ln in stderr.splitlines() if ln.startswith(f"lionjax {label}: error: ")]
        assert len(errors) == 1, stderr
        assert path.name in errors[0], errors[0]  # names the file
        rest = [ln for ln in stderr.splitlines() if ": error: " in ln and ln not in errors]
        assert not rest, stderr
        assert expect != "right", f"{name} refused by {cmd}: {errors[0]}"
        return
    assert expect != "refuse", f"{name} not refused by {cmd}:\n{text[-2000:]}"
    if expect == "warn":
        assert re.search(rf"^lionjax {label}: warning: ", stderr, re.M), (
            f"{name} answered by {cmd} without a warning:\n{text[-1500:]}"
        )
        return
    assert not re.search(r"\bnan\b", stdout, re.I), stdout
    doc = _strict(out.read_text())
    if cmd == "lion" and doc["convergence_time"] is None:
        assert "did not settle within 2 % of least squares" in stdout, stdout
    for key, value in _estimates(cmd, doc):
        want = truth[0] if key.startswith("a") else truth[1]
        assert value == pytest.approx(want, rel=RTOL[cmd]), (name, cmd, key, value, want)


def test_count():
    """At least 40 variants × 4 subcommands are fuzzed and ≥ 160 pairs executed."""
    assert len(VARIANTS) >= 40
    assert len(PAIRS) >= 160
    assert {c for _, c in PAIRS} == set(COMMANDS)
