"""Many pairs in one process: ``lj.diagnosis.diagnose_many`` against separate ``lj.diagnose``
calls, error rows, shared compilation; ``lionjax diagnose --pairs DIR|FILE.csv``, its argument
errors, and the command line's persistent compilation cache."""

import dataclasses
import json
import logging
import os
import pathlib
import platform
import subprocess
import sys

import diagnosis_blind as blind  # benchmarks/ (tests/conftest.py)
import jax
import numpy as np
import pytest
from test_cli_errors import _one_error, _run

import lionjax as lj
from lionjax.cli import build_parser
from lionjax.cli._compile_cache import cache_dir

#: (name, class, seed) of the pairs: 2.5 s at 1 kHz, one length bucket (as test_diagnose.py).
CASES = (("p_offset", "offset", 11), ("p_none", "none", 12))


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    """Records, the folder of NAME_train/NAME_valid files, and the reference rows."""
    d = tmp_path_factory.mktemp("pairs")
    recs, ref = {}, {}
    for (name, cls, seed), ext in zip(CASES, (".csv", ".npz"), strict=True):
        tr, va, _ = blind.make_case(cls, seed, duration=2.5, rate=(1000.0, 1000.0))
        lj.save_record(d / f"{name}_train{ext}", tr)
        lj.save_record(d / f"{name}_valid{ext}", va)
        # the independent reference: one diagnose call per pair, on the records as read back
        read = [lj.load_record(d / f"{name}_{role}{ext}") for role in ("train", "valid")]
        recs[name] = read
        ref[name] = lj.diagnose(*read).to_json()
    return {"dir": d, "records": recs, "ref": ref}


def _same(row: dict, ref: dict) -> None:
    assert row["verdict"] == ref["verdict"] and row["stack"] == ref["stack"]
    assert row["confidence"] == pytest.approx(ref["confidence"], rel=1e-9, abs=1e-12)
    assert row["shrink"] == pytest.approx(ref["final"]["shrink"], rel=1e-9)
    assert row["detection_limit"] == pytest.approx(ref["noise"]["detection_limit"], rel=1e-9)
    assert row["error"] is None


@pytest.mark.slow  # diagnoses of pairs, processes
def test_rows_equal_single_calls_and_bad_pairs_are_rows(pairs, tmp_path):
    recs, ref = pairs["records"], pairs["ref"]
    dead = lj.Record(recs["p_none"][0].x, 0.0 * recs["p_none"][0].F, recs["p_none"][0].dt)
    got = lj.diagnosis.diagnose_many(
        [
            ("p_offset", *recs["p_offset"]),
            ("missing", tmp_path / "nope_train.csv", recs["p_none"][1]),
            ("dead", dead, recs["p_none"][1]),
            ("p_none", pairs["dir"] / "p_none_train.npz", pairs["dir"] / "p_none_valid.npz"),
        ]
    )
    assert isinstance(got, lj.diagnosis.ManyDiagnoses) and got.complete
    rows = got.payload()["rows"]
    assert [r["name"] for r in rows] == ["p_offset", "missing", "dead", "p_none"]
    assert ref["p_offset"]["verdict"] == "offset"  # the pairs differ: the rows are not copies
    assert ref["p_none"]["verdict"] != "offset"
    _same(rows[0], ref["p_offset"])
    _same(rows[3], ref["p_none"])
    for r, why in ((rows[1], "nope_train.csv: no such file"), (rows[2], "constant force")):
        assert r["verdict"] is None and r["confidence"] is None and r["stack"] == []
        assert why in r["error"]
    assert [n for n, _ in got.failures] == ["missing", "dead"]
    with pytest.raises(dataclasses.FrozenInstanceError):  # the result is immutable
        got.rows = ()


@pytest.mark.slow  # diagnoses of pairs, processes
def test_other_errors_propagate_and_bad_pairs_are_refused(pairs):
    recs = pairs["records"]["p_none"]
    with pytest.raises(lj.InputError, match=r"pairs\[0\] must be \(name, train, valid\)"):
        lj.diagnosis.diagnose_many([recs])
    with pytest.raises(lj.InputError, match="given to two pairs"):
        lj.diagnosis.diagnose_many([("a", *recs), ("a", *recs)])
    with pytest.raises(lj.InputError, match="no pairs"):
        lj.diagnosis.diagnose_many([])

    # a diagnosis that fails otherwise than on its records (here: called with an argument it
    # does not take) is a bug of the caller's or of lionjax: it propagates, not a row
    with pytest.raises(TypeError, match="bogus"):
        lj.diagnosis.diagnose_many([("a", *recs)], bogus=1)


@pytest.mark.slow  # diagnoses of pairs, processes
def test_a_second_pair_of_the_same_bucket_compiles_nothing(pairs, caplog):
    recs = pairs["records"]
    lj.diagnosis.diagnose_many([("p_offset", *recs["p_offset"])])
    with jax.log_compiles(True), caplog.at_level(logging.DEBUG, logger="jax"):
        caplog.clear()
        lj.diagnosis.diagnose_many([("p_none", *recs["p_none"])])
    compiled = [r.getMessage() for r in caplog.records if "ompil" in r.getMessage()]
    assert compiled == []
    with jax.log_compiles(True), caplog.at_level(logging.DEBUG, logger="jax"):  # the probe works
        caplog.clear()
        jax.jit(lambda v: v * 3.0 + 1.0)(np.ones(7))
    assert any("ompil" in r.getMessage() for r in caplog.records)


@pytest.mark.slow  # diagnoses of pairs, processes
def test_cli_pairs_folder_and_manifest(pairs, tmp_path, capsys, monkeypatch):
    d, ref = pairs["dir"], pairs["ref"]
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)  # the bar: on a terminal only
    folder = tmp_path / "in"
    folder.mkdir()
    for q in d.iterdir():
        (folder / q.name).write_bytes(q.read_bytes())
    (folder / "lonely_train.csv").write_bytes((d / "p_offset_train.csv").read_bytes())
    js, cs = tmp_path / "rows.json", tmp_path / "rows.csv"
    code, out, err = _run(["diagnose", "--pairs", folder, "--json", js, "--csv", cs], capsys)
    assert code == 1, err  # a pair failed: the others ran
    rows = {r["name"]: r for r in json.loads(js.read_text())["rows"]}
    assert sorted(rows) == ["lonely", "p_none", "p_offset"]
    _same(rows["p_offset"], ref["p_offset"])
    _same(rows["p_none"], ref["p_none"])
    assert rows["lonely"]["verdict"] is None and "lonely_train.csv" in rows["lonely"]["error"]
    assert "no lonely_valid" in rows["lonely"]["error"]
    lines = cs.read_text().splitlines()
    assert lines[0] == "name,verdict,confidence,stack,shrink,detection_limit,error"
    assert len(lines) == 4 and lines[2].startswith("p_none,") and ",offset," in lines[3]
    table = out.splitlines()
    assert table[0].split()[:3] == ["name", "verdict", "confidence"]
    assert "diagnose [" in err and "3/3 pairs" not in err and "2/2 pairs" in err  # the bar
    # the manifest: paths relative to its folder, the same rows
    sub = tmp_path / "m"
    sub.mkdir()
    (sub / "man.csv").write_text(
        "name,train,valid\n"
        + "".join(
            f"{n},../in/{n}_train{e},../in/{n}_valid{e}\n"
            for (n, _, _), e in zip(CASES, (".csv", ".npz"), strict=True)
        )
    )
    code, out, err = _run(["diagnose", "--pairs", sub / "man.csv", "--json", js, "--quiet"], capsys)
    assert code == 0 and "diagnose [" not in err  # --quiet: no bar
    listed = json.loads(js.read_text())["rows"]
    assert [r["name"] for r in listed] == ["p_offset", "p_none"]  # the manifest's order
    _same(listed[0], ref["p_offset"])


@pytest.mark.slow  # diagnoses of pairs, processes
def test_cli_pairs_argument_errors(pairs, tmp_path, capsys):
    d = pairs["dir"]
    empty = tmp_path / "nopairs"
    empty.mkdir()
    (empty / "run1.csv").write_bytes((d / "p_offset_train.csv").read_bytes())
    (tmp_path / "bad.csv").write_text("name,train\na,x.csv\n")
    (tmp_path / "dup.csv").write_text("name,train,valid\na,x.csv,y.csv\na,z.csv,w.csv\n")
    cases = (
        (["diagnose", d / "p_offset_train.csv", "--pairs", d], "TRAIN", "not allowed with --pairs"),
        (["diagnose"], "TRAIN or --pairs", "required"),
        (["diagnose", "--pairs", d, "--plot", tmp_path / "a.png"], "--plot", "not allowed"),
        (["diagnose", "--pairs", d, "--validate", d / "x.csv"], "--validate", "not allowed"),
        (["diagnose", "--pairs", empty], "nopairs", "no pairs of records named NAME_train"),
        (["diagnose", "--pairs", tmp_path / "bad.csv"], "bad.csv", "lacks the column(s) valid"),
        (["diagnose", "--pairs", tmp_path / "nothere"], "nothere", "no such file or folder"),
        (["diagnose", "--pairs", tmp_path / "dup.csv"], "lines 2 and 3", "both name the pair"),
        (["diagnose", d / "p_offset_train.csv", "--csv", tmp_path / "o.csv"], "--csv", "--pairs"),
    )
    for argv, name, why in cases:
        code, out, err = _run(argv, capsys)
        line = _one_error(err, "diagnose")
        assert code == 2 and name in line and why in line, line
        assert "verdict" not in out


def test_compile_cache_folder():
    parse = build_parser().parse_args
    assert parse(["--no-compile-cache", "identify", "a.csv"]).no_compile_cache
    assert parse(["identify", "a.csv", "--no-compile-cache"]).no_compile_cache  # after it too
    assert not parse(["identify", "a.csv"]).no_compile_cache
    assert cache_dir({}) == pathlib.Path.home() / ".cache" / "lionjax" / "jax"
    assert str(cache_dir({"XDG_CACHE_HOME": "/x"})) == "/x/lionjax/jax"
    assert str(cache_dir({"XDG_CACHE_HOME": "/x", "LIONJAX_CACHE_DIR": "/y"})) == "/y"
    assert cache_dir({"LIONJAX_CACHE_DIR": "/y", "LIONJAX_NO_COMPILE_CACHE": "1"}) is None


@pytest.mark.slow  # diagnoses of pairs, processes
def test_compile_cache_is_kept_unless_turned_off(pairs, tmp_path):
    base = {k: v for k, v in os.environ.items() if not k.startswith("JAX_PERSISTENT_CACHE")}
    base.pop("JAX_COMPILATION_CACHE_DIR", None)  # the test suite's own cache
    data = str(pairs["dir"] / "p_offset_train.csv")
    missing = str(tmp_path / "missing.csv")  # fails after the cache is set up, compiling nothing
    runs = (
        ("on", {}, [], data, 0),
        ("env_off", {"LIONJAX_NO_COMPILE_CACHE": "1"}, [], missing, 2),
        ("flag_off", {}, ["--no-compile-cache"], missing, 2),
    )
    for name, extra, flag, path, code in runs:
        env = {**base, "LIONJAX_CACHE_DIR": str(tmp_path / name), **extra}
        cmd = [sys.executable, "-m", "lionjax.cli", *flag, "identify", path]
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
        assert p.returncode == code, p.stderr
    kept = list((tmp_path / "on").iterdir())
    assert len(kept) > 3  # the identification's programs, each a file
    for name in ("env_off", "flag_off"):
        assert not (tmp_path / name).exists(), name


@pytest.mark.slow  # diagnoses of pairs, processes
@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's mallopt only")
def test_the_command_line_keeps_freed_memory_for_reuse():
    # arrays of 8 MiB and growing, allocated and freed 20 times: with glibc's default each
    # takes fresh pages (and faults them in); with the command line's heap they reuse freed
    # memory. In a subprocess: the setting is the process' own
    code = (
        "import resource, sys, numpy as np\n"
        # 4-KiB pages: numpy asks for transparent huge pages for large arrays, whose faults
        # count 512 pages as one whenever the kernel has huge pages free (glibc's default gave
        # 4686 or 11841 faults for this loop, as the machine's memory allowed)
        "getattr(np._core.multiarray, '_set_madvise_hugepage', lambda on: None)(False)\n"
        "from lionjax.cli._heap import keep_freed_memory\n"
        "def faults():\n"
        "    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
        "    for k in range(20):\n"
        "        a = np.ones((1 << 20) + 4096 * k); del a\n"
        "    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0\n"
        "on = sys.argv[1] == 'on' and keep_freed_memory()\n"
        "print(on, faults(), keep_freed_memory({'MALLOC_TOP_PAD_': '0'}))\n"
    )
    out = {}
    for arm in ("off", "on"):
        p = subprocess.run([sys.executable, "-c", code, arm], capture_output=True, text=True)
        assert p.returncode == 0, p.stderr
        out[arm] = p.stdout.split()
    assert out["off"][0] == "False" and out["on"][0] == "True"
    assert out["on"][2] == "False"  # the user's own tunable wins
    # fresh pages for every one of the 20 arrays of 2048 pages and more (42500 faults on the
    # development machine) against about the first array's (2160)
    off, on = int(out["off"][1]), int(out["on"][1])
    assert off > 10 * 2048 and on < 3_500 and off > 4 * on, out
