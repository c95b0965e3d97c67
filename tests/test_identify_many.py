"""`lionjax identify FOLDER` / many files: one batched call, one row per file (float64).

Records: ẍ + aẋ = bF simulated exactly (zero-order-hold force, closed-form step of (x, v)) with
a, b drawn ±20 % around the paper's region 2 (22.0 1/s, 1.916 1/kg), random-phase multisines,
three lengths (1500, 2250, 3000 samples) and two sampling intervals (2 ms, 2.5 ms), half CSV and
half NPZ. Every row is checked against the per-file reference of the SAME estimator:

- ``--method ls`` against ``lj.least_squares(model, record, initial="discard")`` (the streamed
  batched LS is that estimator), relative 1e-8;
- ``--method lion`` against ``lj.lion(model, record, stepper=lj.ExactStep())``, relative 1e-9
  (tests/test_batched.py: 1e-10 on unpadded batches).

Only three distinct lengths keep the per-file references to three compilations each.
"""

import csv
import json
import time

import numpy as np
import pytest

import lionjax as lj
import lionjax._identify_many as identify_many
from lionjax.cli import main

N_FILES = 100
LENGTHS = (1500, 2250, 3000)
DTS = (2e-3, 2.5e-3)
FREQS = (0.7, 2.3, 5.1, 9.7)
LS_RTOL = 1e-8
LION_RTOL = 1e-9


def simulate(a, b, F, dt):
    """Positions at the samples for the held force F: exact step of v̇ = −av + bF."""
    e = np.exp(-a * dt)
    x = np.empty_like(F)
    xk = vk = 0.0
    for k, u in enumerate(F):
        x[k] = xk
        vinf = b * u / a
        dv = vk - vinf
        xk, vk = xk + vinf * dt + dv * (1 - e) / a, vinf + dv * e
    return x


def make_records(n, seed=0):
    rng = np.random.default_rng(seed)
    a = 22.0 * (1 + 0.2 * rng.uniform(-1, 1, n))
    b = 1.916 * (1 + 0.2 * rng.uniform(-1, 1, n))
    T = rng.choice(LENGTHS, n)
    dt = rng.choice(DTS, n)
    out = []
    for i in range(n):
        t = np.arange(T[i]) * dt[i]
        ph = rng.uniform(0, 2 * np.pi, len(FREQS))
        F = sum(0.3 / (1 + j) * np.sin(2 * np.pi * f * t + ph[j]) for j, f in enumerate(FREQS))
        out.append(lj.Record(simulate(a[i], b[i], F, dt[i]), F, dt[i]))
    return out, np.c_[a, b]


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("many")
    records, truth = make_records(N_FILES)
    paths = []
    for i, r in enumerate(records):
        paths.append(lj.save_record(d / f"rec{i:03d}.{'csv' if i % 2 else 'npz'}", r))
    return d, paths, truth


@pytest.fixture
def calls(monkeypatch):
    """Count the batched calls identify_batch makes."""
    n = {"ls": 0, "lion": 0}

    def counted(key, f):
        def g(*args, **kw):
            n[key] += 1
            return f(*args, **kw)

        return g

    monkeypatch.setattr(
        identify_many, "least_squares_batched", counted("ls", identify_many.least_squares_batched)
    )
    monkeypatch.setattr(identify_many, "lion_batched", counted("lion", identify_many.lion_batched))
    return n


def _run(args, capsys):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def _max_rel(got, want):
    return float(np.max(np.abs(np.asarray(got) - want) / np.abs(want)))


def test_fixture_has_mixed_lengths_and_dt(folder):
    _, paths, _ = folder
    recs = [lj.load_record(p) for p in paths]
    assert {r.n_samples for r in recs} == set(LENGTHS)
    assert {round(float(r.dt), 6) for r in recs} == set(DTS)


def test_folder_ls_one_call_matches_per_file(folder, tmp_path, capsys, calls):
    d, paths, truth = folder
    out_json, out_csv = tmp_path / "o.json", tmp_path / "o.csv"
    t0 = time.perf_counter()
    code, text, err = _run(["identify", d, "--json", out_json, "--csv", out_csv], capsys)
    elapsed = time.perf_counter() - t0
    assert code == 0, err
    assert calls == {"ls": 1, "lion": 0}  # one batched call for the whole folder
    assert f"{N_FILES} records" in text and "rec099.csv" in text
    payload = json.loads(out_json.read_text())
    assert payload["method"] == "ls" and payload["model"] == "MassDamper"
    assert payload["names"] == ["a", "b"] and "initial='discard'" in payload["equals"]
    rows = payload["rows"]
    assert [r["record"] for r in rows] == [str(p) for p in paths]  # sorted by name, none lost
    assert all(r["status"] == "ok" and r["result"] == 0 for r in rows)
    got = np.array([[r["a"], r["b"]] for r in rows])
    ref, ref_std = [], []
    for p, r in zip(paths, rows):
        rec = lj.load_record(p)
        sol = lj.least_squares(lj.MassDamper(), rec, initial="discard")
        ref.append(np.asarray(sol.theta))
        ref_std.append(np.asarray(sol.std))
        assert r["n_samples"] == rec.n_samples and r["dt"] == pytest.approx(float(rec.dt))
        assert r["condition"] == pytest.approx(float(sol.condition), rel=1e-6)
    ref = np.array(ref)
    rel = _max_rel(got, ref)
    print(f"\nls: {N_FILES} files in one call, {elapsed:.2f} s; max rel diff vs per-file {rel:.3g}")
    assert rel < LS_RTOL
    # against the simulated truth, loosely (short records: 0.75–5.25 s after the transient)
    err_true = np.abs(got - truth) / truth
    assert np.median(err_true) < 0.01 and np.max(err_true) < 0.05
    # the library entry point on the same records: same numbers, and the nominal std of the
    # per-file LS (σ²(ΦᵀΦ)⁻¹ from the streamed statistics vs the stored-regressor QR)
    res = lj.identify_batch(lj.MassDamper(), [lj.load_record(p) for p in paths])
    np.testing.assert_array_equal(res.theta, got)
    np.testing.assert_allclose(res.std, np.array(ref_std), rtol=1e-6)
    assert res.failures() == [] and res.labels[0] == "0"
    with out_csv.open() as f:
        table = list(csv.DictReader(f))
    assert len(table) == N_FILES
    np.testing.assert_allclose([[float(r["a"]), float(r["b"])] for r in table], got, rtol=1e-15)
    assert table[0]["record"] == str(paths[0]) and table[0]["status"] == "ok"


def test_lion_files_and_failed_rows(folder, tmp_path, capsys, calls):
    d, paths, _ = folder
    # two lengths (padding in the batch), both dts; 2 + 2 failures = 10 files
    lengths = {p: lj.load_record(p).n_samples for p in paths[:20]}
    good = [p for p in paths[:20] if lengths[p] == LENGTHS[0]][:4]
    good += [p for p in paths[:20] if lengths[p] == LENGTHS[-1]][:4]
    flat = lj.save_record(tmp_path / "flat.npz", lj.Record(np.zeros(2000), np.zeros(2000), 2e-3))
    first = lj.load_record(good[0])
    short = lj.save_record(
        tmp_path / "short.csv", lj.Record(first.x[:600], first.F[:600], first.dt)
    )
    out_json = tmp_path / "o.json"
    code, text, err = _run(
        ["identify", *good, flat, short, "--method", "lion", "--json", out_json], capsys
    )
    assert code == 1  # rows written, some failed
    assert calls == {"ls": 0, "lion": 1}
    assert "flat.npz" in err and "short.csv" in err and "2 of 10" in err
    assert "does not excite" in err and "filter transient" in err
    rows = json.loads(out_json.read_text())["rows"]
    assert [r["record"] for r in rows] == [str(p) for p in [*good, flat, short]]
    assert {round(float(lj.load_record(p).dt), 6) for p in good} == set(DTS)
    assert rows[-2]["status"] == "failed" and rows[-2]["a"] is None
    assert rows[-1]["status"] == "not run" and rows[-1]["result"] == -1
    got = np.array([[r["a"], r["b"]] for r in rows[:8]])
    got_ls = np.array([[r["a_ls"], r["b_ls"]] for r in rows[:8]])
    ref, ref_ls = [], []
    for p in good:
        rec = lj.load_record(p)
        ref.append(np.asarray(lj.lion(lj.MassDamper(), rec, stepper=lj.ExactStep()).theta_final))
        ref_ls.append(np.asarray(lj.least_squares(lj.MassDamper(), rec, initial="discard").theta))
    rel, rel_ls = _max_rel(got, np.array(ref)), _max_rel(got_ls, np.array(ref_ls))
    print(f"\nlion: max rel diff vs per-file lion {rel:.3g}, LS columns {rel_ls:.3g}")
    assert rel < LION_RTOL and rel_ls < LS_RTOL


def test_empty_folder_is_an_error(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    code, _, err = _run(["identify", empty], capsys)
    assert code == 2 and str(empty) in err and "empty" in err
    (empty / "notes.txt").write_text("no records here")
    code, _, err = _run(["identify", empty], capsys)
    assert code == 2 and "notes.txt" in err


def test_bad_files_named_before_computing(folder, tmp_path, capsys, calls):
    _, paths, _ = folder
    bad1 = tmp_path / "corrupt.csv"
    bad1.write_text("t,x,F\n0,0,0\n0.002,oops,0\n")
    bad2 = tmp_path / "broken.npz"
    bad2.write_bytes(b"not a zip")
    out = tmp_path / "o.json"
    code, text, err = _run(["identify", *paths[:3], bad1, bad2, "--json", out], capsys)
    assert code == 2
    assert "2 of 5 files" in err and "nothing was identified" in err
    assert "corrupt.csv" in err and "line 3" in err and "broken.npz" in err
    assert calls == {"ls": 0, "lion": 0} and not out.exists() and text == ""


@pytest.mark.parametrize(
    "extra, match",
    [
        (["--csv", "o.csv"], "--csv writes the table of several records"),
        (["{other}", "--json", "missing/o.json"], "missing"),
        (["{self}"], "named twice"),
    ],
)
def test_bad_arguments(folder, tmp_path, capsys, extra, match):
    _, paths, _ = folder
    extra = [
        e.format(self=paths[0], other=paths[1]).replace("missing/", f"{tmp_path}/missing/")
        for e in extra
    ]
    code, _, err = _run(["identify", paths[0], *extra], capsys)
    assert code == 2 and match in err


def test_identify_batch_bad_arguments(folder):
    rec = lj.load_record(folder[1][0])
    with pytest.raises(lj.InputError, match="one Record"):
        lj.identify_batch(lj.MassDamper(), rec)
    with pytest.raises(lj.InputError, match="2 labels for 1 records"):
        lj.identify_batch(lj.MassDamper(), [rec], labels=["a", "b"])
    with pytest.raises(lj.InputError, match="method"):
        lj.identify_batch(lj.MassDamper(), [rec], method="euler")
    with pytest.raises(lj.InputError, match=r"method=lionjax\.LeastSquares\(\)"):
        lj.identify_batch(lj.MassDamper(), [rec], method="ls")
    with pytest.raises(lj.InputError, match="theta0"):
        lj.identify_batch(lj.MassDamper(), [rec], method=lj.Lion(theta0=[1.0, 2.0, 3.0]))
    with pytest.raises(lj.InputError, match="no records"):
        lj.identify_batch(lj.MassDamper(), [])
