"""The paper's experiments (lionjax.paper) against independent references.

One quick reproduction (``PaperConfig.quick()``, seed 0, all effects) is computed once per
test run and checked piece by piece:

- calibration gain vs ``numpy.polyfit`` on the same readings (1e-9 relative);
- every table entry vs a direct ``lj.lion`` call on the same record (1e-9 relative), and the
  per-region summaries vs the median of direct ``lj.least_squares`` estimates (0.5 %) and the
  twin's truth (1 %, recommended settings);
- var_mm2 vs its definition recomputed with numpy from the filter bank's outputs;
- NRMSE vs numpy; the verification of the *true* model at the quantisation level;
- the batched effect simulation (neutral padding) vs the same device simulated alone;
- ``lionjax reproduce``: the files it writes and their documented schema. The command runs in
  process on the test run's reproduction (the same quick configuration and seed, checked when
  the command asks for it), so the experiments are computed once for both.
"""

import csv
import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lionjax as lj
from lionjax import twin
from lionjax.cli import main

SEED = 0


@functools.cache
def quick_config():
    return lj.paper.PaperConfig.quick()


@pytest.fixture(scope="session")
def result():
    return lj.paper.reproduce_paper(quick_config(), key=jax.random.key(SEED))


@pytest.fixture(scope="session")
def records(result):
    cfg = quick_config()
    _, k_run = jax.random.split(jax.random.key(SEED))
    return lj.paper.paper_records(cfg, key=k_run, calibration_gain=result.calibration.gain)


@pytest.mark.slow  # the paper's reproduction (the shared fixtures' records and run)
def test_calibration_matches_polyfit(result):
    cal = result.calibration
    slope, intercept = np.polyfit(np.asarray(cal.measured_force), np.asarray(cal.set_force), 1)
    assert float(cal.gain) == pytest.approx(slope, rel=1e-9)
    assert float(cal.intercept) == pytest.approx(intercept, rel=1e-6, abs=1e-9)
    assert np.asarray(cal.x).size == 5 * len(lj.paper.PaperConfig().calibration_levels)
    assert sorted(set(np.round(np.asarray(cal.x) * 1e3, 6))) == [-30, -15, 0, 15, 30]
    assert abs(float(cal.gain) / 1.75 - 1) < 0.01


@pytest.mark.slow  # the paper's reproduction (the shared fixtures' records and run)
def test_records_stay_in_their_region(result, records):
    cfg = quick_config()
    assert records.x.shape == (3, 4, 1, cfg.n_samples)
    x = np.asarray(records.x)
    assert x[0].max() < -0.010 and x[2].min() > 0.010
    assert np.abs(x[1]).max() < 0.010


# the paper's law runs on x in mm (its convention), which the units check warns about
@pytest.mark.slow  # the paper's reproduction (the shared fixtures' records and run)
@pytest.mark.filterwarnings("ignore:.*millimetres:lionjax.solutions.DataWarning")
def test_table_matches_direct_lion(result, records):
    table = result.table
    s = table.settings.index("recommended")
    p = table.settings.index("paper")
    for r, i in ((0, 0), (1, 2), (2, 3)):
        rec = jax.tree.map(lambda z: z[r, i, 0], records)
        sol = lj.lion(lj.MassDamper(), rec, gain=lj.AutoGain(1.0))
        np.testing.assert_allclose(
            np.asarray(sol.theta_final), [table.a[s, r, i, 0], table.b[s, r, i, 0]], rtol=1e-9
        )
        # the paper's law on x in mm and F in mN, b converted back to 1/kg
        rec_mm = lj.Record(rec.x * 1e3, rec.F * 1e3, rec.dt)
        solp = lj.lion(lj.MassDamper(), rec_mm, bank=lj.FilterBank.paper(), gain=lj.FixedGain(1e4))
        np.testing.assert_allclose(
            np.asarray(solp.theta_final), [table.a[p, r, i, 0], table.b[p, r, i, 0]], rtol=1e-9
        )


@pytest.mark.slow  # the paper's reproduction (the shared fixtures' records and run)
def test_summary_vs_least_squares_and_truth(result, records):
    table = result.table
    flat = jax.tree.map(lambda z: z.reshape(-1, *z.shape[3:]), records)
    ls = jax.vmap(lambda r: lj.least_squares(lj.MassDamper(), r, throw=False))(flat)
    lj.raise_if_failed(ls)
    theta = np.asarray(ls.theta).reshape(3, -1, 2)
    ls_med = np.median(theta, axis=1)
    s = table.settings.index("recommended")
    summ = np.stack([np.asarray(table.summary_a[s]), np.asarray(table.summary_b[s])], axis=-1)
    np.testing.assert_allclose(summ, ls_med, rtol=5e-3)
    truth = np.stack([[16.2, 22.0, 37.1], [2.02, 1.916, 1.289]], axis=-1)
    np.testing.assert_allclose(summ, truth, rtol=1e-2)
    np.testing.assert_allclose(ls_med, truth, rtol=1e-2)
    # rows(): the summary rows hold the same numbers
    rows = [q for q in table.to_rows() if q["settings"] == "recommended" and q["input"] == "all"]
    assert [q["region"] for q in rows] == [1, 2, 3]
    np.testing.assert_allclose([q["a"] for q in rows], summ[:, 0], rtol=1e-12)
    np.testing.assert_allclose(
        [q["b_err_pct"] for q in rows], 100 * (summ[:, 1] / truth[:, 1] - 1), rtol=1e-9
    )


@pytest.mark.slow  # the paper's reproduction (the shared fixtures' records and run)
def test_var_mm2_definition(result, records):
    from scipy.signal import cont2discrete

    table = result.table
    s = table.settings.index("recommended")
    r, i = 1, 2
    rec = jax.tree.map(lambda z: z[r, i, 0], records)
    a, b = float(table.a[s, r, i, 0]), float(table.b[s, r, i, 0])
    x = np.asarray(rec.x) * 1e3
    F = np.asarray(rec.F) * 1e3
    dt = 1e-3
    # Λ = (s+4)³ in controllable canonical form; x: first-order hold, F: zero-order hold
    A = np.array([[0, 1, 0], [0, 0, 1], [-64.0, -48.0, -12.0]])
    B = np.array([[0.0], [0.0], [1.0]])
    C = np.eye(3)
    D = np.zeros((3, 1))

    def filt(u, method):
        Ad, Bd, *_ = cont2discrete((A, B, C, D), dt, method=method)
        z = np.zeros(3)
        z[0] = u[0] / 64.0
        out = np.empty((u.size, 3))
        if method == "zoh":
            for k in range(u.size):
                out[k] = z
                z = Ad @ z + Bd[:, 0] * u[k]
        else:  # scipy's foh state is shifted: z̃ = z − Bd₁·u; use Γ-form instead
            from scipy.linalg import expm

            M = np.zeros((5, 5))
            M[:3, :3] = A * dt
            M[:3, 3] = B[:, 0] * dt
            M[3, 4] = 1.0
            E = expm(M)
            Phi, G0, G1 = E[:3, :3], E[:3, 3], E[:3, 4]
            un = np.append(u[1:], u[-1])
            for k in range(u.size):
                out[k] = z
                z = Phi @ z + G0 * u[k] + G1 * (un[k] - u[k])
        return out  # columns: 1/Λ, s/Λ, s²/Λ

    X = filt(x, "foh")
    Q = filt(F, "zoh")
    eps1 = X[:, 2] + a * X[:, 1] - b * Q[:, 0]
    t = dt * np.arange(x.size)
    var = np.var(eps1[t >= 2.25], ddof=1)
    assert float(table.var_mm2[s, r, i, 0]) == pytest.approx(var, rel=1e-6)


@pytest.mark.slow  # the paper's reproduction (the shared fixtures' records and run)
def test_verification(result):
    v = result.verifications[result.table.settings.index("recommended")]
    xd, xm = np.asarray(v.x_device), np.asarray(v.x_model)
    ref = np.linalg.norm(xm - xd) / np.linalg.norm(xd - xd.mean())
    assert float(v.nrmse) == pytest.approx(ref, rel=1e-12)
    assert xd.shape == (1601,)
    assert float(v.nrmse) < 0.01
    # the logged desired force: the verification input plus force-sensor noise (0.01 N / k̂)
    t = np.arange(1601) * 1e-3
    F = 3 * np.cos(40 * t + 400) + 0.5 * t
    np.testing.assert_allclose(np.asarray(v.force), F, atol=0.05)
    # the true model (b seen through the fitted calibration k̂/1.75) against the same record:
    # only quantisation, force-noise and integration error remain
    ver_rec = lj.Record(v.x_device, v.force, 1e-3)
    scale = float(result.calibration.gain) / 1.75
    true = lj.paper.verify(
        jnp.array([16.2, 22.0, 37.1]), scale * jnp.array([2.02, 1.916, 1.289]), ver_rec
    )
    assert float(true.nrmse) < 2e-3
    # within 1.5 encoder counts (±½ count rounding plus a drift driven by the force noise)
    assert np.abs(np.asarray(true.x_model) - xd).max() < 1.5 * twin.FALCON_ENCODER_RESOLUTION


@pytest.mark.slow  # the paper's reproduction (the shared fixtures' records and run)
def test_effect_rows(result):
    names = [e.name for e in result.effects]
    assert names == [c.name for c in lj.paper.realistic_effects()]
    assert len(names) == 8
    base = float(result.verifications[result.table.settings.index("recommended")].nrmse)
    for e in result.effects:
        assert float(e.nrmse_baseline) == pytest.approx(base, rel=1e-12)
        assert float(e.growth) == pytest.approx(float(e.nrmse) / base, rel=1e-12)
        assert np.all(np.isfinite(np.asarray(e.a)))
        d = e.to_row()
        assert set(d) >= {"name", "a_err_pct", "b_err_pct", "nrmse", "growth"}
    by = {e.name: e for e in result.effects}
    # effects that must visibly hurt the validation
    for name in ("coulomb_friction", "offset", "delay", "saturation"):
        assert float(by[name].growth) > 3, name
    # a calibration drift is absorbed by b (validated on the same device): b drops by ≈ 1/1.1
    np.testing.assert_allclose(np.asarray(by["calibration_error"].b_err_pct), -9.1, atol=1.0)


@pytest.mark.slow  # the paper's reproduction (the shared fixtures' records and run)
def test_batched_effects_equal_single_device(result):
    cfg = quick_config()
    _, k_run = jax.random.split(jax.random.key(SEED))
    cases = [
        c
        for c in lj.paper.realistic_effects()
        if c.name
        in ("offset", "spring", "delay", "saturation", "calibration_error", "position_dependent")
    ]
    gain = result.calibration.gain
    batched, vb = lj.paper.twin_runs(
        cfg, key=k_run, calibration_gain=gain, effects=[(c.effect,) for c in cases]
    )
    alone, va = lj.paper.twin_runs(
        cfg, key=k_run, calibration_gain=gain, effects=[(cases[0].effect,)]
    )
    np.testing.assert_allclose(np.asarray(batched.x[0]), np.asarray(alone.x[0]), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(vb.x[0]), np.asarray(va.x[0]), rtol=0, atol=1e-12)


def test_bad_arguments():
    with pytest.raises(lj.InputError, match="repetitions"):
        lj.paper.PaperConfig(repetitions=0)
    with pytest.raises(lj.InputError, match="operating_points"):
        lj.paper.PaperConfig(operating_points=(0.0,))
    with pytest.raises(lj.InputError, match="position_scale"):
        lj.paper.LionSettings.paper(position_scale=-1.0)
    rec = lj.Record(jnp.zeros(5000), jnp.zeros(5000), 1e-3)
    with pytest.raises(lj.InputError, match="settings"):
        lj.paper.identify_records(rec, settings="paper")
    with pytest.raises(lj.InputError, match="single record"):
        lj.paper.verify(
            jnp.ones(3), jnp.ones(3), lj.Record(jnp.zeros((2, 50)), jnp.zeros((2, 50)), 1e-3)
        )


@pytest.mark.slow  # the paper's reproduction (the shared fixtures' records and run)
def test_figures(result, tmp_path):
    figs = lj.paper.paper_figures(result)
    assert set(figs) == {
        "fig3_calibration",
        "fig4_convergence",
        "fig5_tracking_error",
        "fig6_verification",
        "table3_errors",
        "effects_nrmse",
    }
    for name, fig in figs.items():
        assert any(ax.get_xlabel() for ax in fig.axes), name
        assert any(ax.get_ylabel() for ax in fig.axes), name
        assert fig.axes[0].get_title() or fig.get_suptitle(), name
        fig.savefig(tmp_path / f"{name}.png", dpi=40)
        assert (tmp_path / f"{name}.png").stat().st_size > 1000


# ---------------------------------------------------------------------------------------------
# lionjax reproduce

ROW_KEYS = {
    "region",
    "operating_point_mm",
    "settings",
    "input",
    "repetition",
    "a",
    "b",
    "var_mm2",
    "a_err_pct",
    "b_err_pct",
    "a_true",
    "b_true",
}
EFFECT_KEYS = {
    "name",
    "description",
    "a",
    "b",
    "a_err_pct",
    "b_err_pct",
    "nrmse",
    "nrmse_baseline",
    "growth",
}


@pytest.fixture(scope="module")
def out(result, tmp_path_factory):
    """``lionjax reproduce --quick --seed 0`` in process, its computation answered by this
    test run's ``result`` once the command's own arguments are checked."""
    asked = []

    def reproduce_paper(config, *, key, effects, progress):
        assert config == quick_config() and effects
        np.testing.assert_array_equal(
            jax.random.key_data(key), jax.random.key_data(jax.random.key(SEED))
        )
        progress("(the test run's reproduction)")
        asked.append(config)
        return result

    d = tmp_path_factory.mktemp("reproduce")
    with pytest.MonkeyPatch.context() as m:
        m.setattr(lj.paper, "reproduce_paper", reproduce_paper)
        assert main(["reproduce", "--quick", "--out", str(d), "--seed", str(SEED)]) == 0
    assert len(asked) == 1
    return d


@pytest.mark.slow  # the paper's reproduction (the shared fixtures' records and run)
def test_files_written(out):
    for name in ("table.json", "table.csv", "effects.json", "summary.json", "report.md"):
        assert (out / name).stat().st_size > 100, name
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert pngs == sorted(
        [
            "fig3_calibration.png",
            "fig4_convergence.png",
            "fig5_tracking_error.png",
            "fig6_verification.png",
            "table3_errors.png",
            "effects_nrmse.png",
        ]
    )
    for p in out.glob("*.png"):
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow  # the paper's reproduction (the shared fixtures' records and run)
def test_table_schema_and_numbers(out):
    rows = json.loads((out / "table.json").read_text())
    cfg = lj.paper.PaperConfig.quick()
    R, I, K = cfg.shape
    assert len(rows) == 2 * R * (I * K + 1)
    for r in rows:
        assert set(r) == ROW_KEYS
        assert r["region"] in (1, 2, 3)
        assert r["settings"] in ("paper", "recommended")
        assert r["input"] in (*range(1, I + 1), "all")
        assert (r["input"] == "all") == (r["repetition"] == "all")
        assert r["a_err_pct"] == pytest.approx(100 * (r["a"] / r["a_true"] - 1))
        assert r["b_err_pct"] == pytest.approx(100 * (r["b"] / r["b_true"] - 1))
    summary = [r for r in rows if r["input"] == "all"]
    assert len(summary) == 6
    for r in summary:
        # the median of the region's per-record rows
        per = [
            q["a"]
            for q in rows
            if q["settings"] == r["settings"] and q["region"] == r["region"] and q["input"] != "all"
        ]
        assert r["a"] == pytest.approx(float(np.median(per)), rel=1e-12)
        if r["settings"] == "recommended":
            assert abs(r["a_err_pct"]) < 1 and abs(r["b_err_pct"]) < 1
    with open(out / "table.csv") as f:
        csv_rows = list(csv.DictReader(f))
    assert len(csv_rows) == len(rows)
    assert float(csv_rows[0]["a"]) == pytest.approx(rows[0]["a"], rel=1e-12)


@pytest.mark.slow  # the paper's reproduction (the shared fixtures' records and run)
def test_table_row_vs_direct_least_squares(out):
    """One record re-simulated through the public API: Lion's row ≈ lj.least_squares (2 %)."""
    rows = json.loads((out / "table.json").read_text())
    cfg = lj.paper.PaperConfig.quick()
    summary = json.loads((out / "summary.json").read_text())
    _, k_run = jax.random.split(jax.random.key(0))
    recs = lj.paper.paper_records(cfg, key=k_run, calibration_gain=summary["calibration"]["gain"])
    rec = jax.tree.map(lambda z: z[1, 2, 0], recs)
    ls = lj.least_squares(lj.MassDamper(), rec)
    row = next(
        q for q in rows if q["settings"] == "recommended" and q["region"] == 2 and q["input"] == 3
    )
    np.testing.assert_allclose([row["a"], row["b"]], np.asarray(ls.theta), rtol=2e-2)


@pytest.mark.slow  # the paper's reproduction (the shared fixtures' records and run)
def test_effects_and_report(out):
    effects = json.loads((out / "effects.json").read_text())
    assert [e["name"] for e in effects] == [c.name for c in lj.paper.realistic_effects()]
    for e in effects:
        assert set(e) == EFFECT_KEYS
        assert len(e["a_err_pct"]) == 3
        assert e["nrmse"] > 0 and e["growth"] == pytest.approx(e["nrmse"] / e["nrmse_baseline"])
    report = (out / "report.md").read_text()
    for heading in (
        "## Force calibration",
        "## Identification",
        "## Verification",
        "## One unmodelled effect",
    ):
        assert heading in report
    for e in effects:
        assert f"| {e['name']} |" in report
    summary = json.loads((out / "summary.json").read_text())
    assert abs(summary["calibration"]["gain"] / 1.75 - 1) < 0.01
    assert summary["verification"]["recommended"]["nrmse"] < 0.01


def test_bad_out_is_an_error(tmp_path, capsys):
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["reproduce", "--quick", "--out", str(f)]) == 2
    assert "--out" in capsys.readouterr().err
