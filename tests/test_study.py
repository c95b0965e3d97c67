"""lionjax.study: a grid of batched runs equals per-element lj.lion / lj.least_squares calls."""

import csv
import json

import jax
import numpy as np
import pytest

import lionjax as lj
from lionjax.cli import main

POLES = [(-8.0, -8.0, -8.0), (-12.0, -12.0, -12.0)]


@pytest.fixture(scope="module")
def records():
    return lj.studies.study_records(2, n_samples=3000, seed=0)


@pytest.fixture(scope="module")
def result(records):
    return lj.study(
        lj.MassDamper(),
        records,
        gains=[3.0, 10.0],
        gain=lj.AutoGain,
        poles=POLES,
        chunk_size=3,
        progress=False,
    )


def test_study_matches_per_element_calls(records, result):
    model = lj.MassDamper()
    assert result.dims == ("dataset", "gain", "poles")
    assert result.shape == (2, 2, 2)
    assert result.theta_final.shape == (2, 2, 2, 2)
    assert result.complete and np.all(result.result == 0)
    for d, rec in enumerate(records):
        for gi, g in enumerate(result.coords["gain"]):
            for pi, P in enumerate(result.coords["poles"]):
                bank = lj.FilterBank.from_poles(np.array(P), True)
                sol = lj.lion(model, rec, bank=bank, gain=lj.AutoGain(g), stepper=lj.ExactStep())
                ls = lj.least_squares(model, rec, bank=bank, initial="discard")
                # float64: same law and exact step, different summation order
                np.testing.assert_allclose(
                    result.theta_final[d, gi, pi], np.asarray(sol.theta[-1]), rtol=1e-9
                )
                np.testing.assert_allclose(
                    result.theta_ls[d, gi, pi], np.asarray(ls.theta), rtol=1e-9
                )
                # convergence time: numpy reference from the per-sample trajectory
                th = np.asarray(sol.theta)
                off = np.any(np.abs(th - ls.theta) > 0.02 * np.abs(ls.theta), axis=1)
                last = np.flatnonzero(off)
                t_ref = (
                    np.inf
                    if last.size and last[-1] >= th.shape[0] - 1
                    else ((last[-1] + 1) * 1e-3 if last.size else 0.0)
                )
                assert result.convergence_time[d, gi, pi] == pytest.approx(t_ref, abs=1.5e-3)


def test_study_theta0_and_fixed_gain_axes(records):
    model = lj.MassDamper()
    th0 = [(0.0, 0.0), (20.0, 2.0)]
    res = lj.study(model, records[0], gains=[1e4], theta0s=th0, progress=False)
    assert res.dims == ("gain", "theta0") and res.shape == (1, 2)
    for i, t0 in enumerate(th0):
        sol = lj.lion(
            model, records[0], gain=lj.FixedGain(1e4), theta0=np.array(t0), stepper=lj.ExactStep()
        )
        np.testing.assert_allclose(res.theta_final[0, i], np.asarray(sol.theta[-1]), rtol=1e-9)


def test_study_outputs(result, tmp_path):
    rows = result.to_rows()
    assert len(rows) == 8
    assert set(rows[0]) >= {"dataset", "gain", "poles", "a", "b", "a_ls", "convergence_time"}
    assert rows[3]["poles"] == list(POLES[1]) and rows[3]["gain"] == 10.0
    assert rows[3]["a"] == pytest.approx(result.theta_final[0, 1, 1, 0])
    result.to_csv(tmp_path / "s.csv")
    with (tmp_path / "s.csv").open() as f:
        got = list(csv.DictReader(f))
    assert len(got) == 8 and got[1]["poles"] == "-12;-12;-12"
    result.to_json(tmp_path / "s.json")
    payload = json.loads((tmp_path / "s.json").read_text())
    assert payload["dims"] == ["dataset", "gain", "poles"] and len(payload["rows"]) == 8


def test_study_interrupt_returns_partial(records, capsys):
    calls = []

    class Interrupting(lj.AbstractGain):
        """AutoGain, interrupted (Ctrl-C) when the study builds the second chunk's gains."""

        rate: jax.Array
        uses_data = True

        def __check_init__(self):
            calls.append(1)
            if len(calls) == 2:
                raise KeyboardInterrupt

        @property
        def batch_shape(self):
            return tuple(self.rate.shape)

        def __call__(self, R, names):
            return lj.AutoGain(self.rate)(R, names)

    # the grid and chunk of the module's `result`: 8 elements in chunks of 3, interrupted in the
    # second
    res = lj.study(
        lj.MassDamper(), records, gains=[3.0, 10.0], gain=Interrupting, poles=POLES, chunk_size=3
    )
    err = capsys.readouterr().err
    assert "interrupted after 1/3 chunks" in err
    assert not res.complete and res.gain_class == "Interrupting"
    done = np.isfinite(res.theta_final).all(axis=-1).ravel()
    np.testing.assert_array_equal(done, [True] * 3 + [False] * 5)
    np.testing.assert_array_equal(res.result.ravel()[3:], -1)


def test_study_bad_input(records):
    with pytest.raises(lj.InputError, match="poles"):
        lj.study(lj.MassDamper(), records, poles=[(-4.0, 4.0, -4.0)])
    with pytest.raises(lj.InputError, match="theta0s"):
        lj.study(lj.MassDamper(), records, theta0s=[(1.0, 2.0, 3.0)])
    # the gain is a Module class now; the old strings name their replacement
    with pytest.raises(lj.InputError, match=r"gain=lionjax\.AutoGain"):
        lj.study(lj.MassDamper(), records, gains=[1.0], gain_type="auto")
    with pytest.raises(lj.InputError, match=r"gain=lionjax\.FixedGain"):
        lj.study(lj.MassDamper(), records, gains=[1.0], gain="fixed")
    with pytest.raises(lj.InputError, match="gains="):
        lj.study(lj.MassDamper(), records, gains=[1.0], gain=lj.AutoGain(2.0))


def test_cli_study(records, result, tmp_path, capsys):
    for i, r in enumerate(records):
        lj.save_record(tmp_path / f"r{i}.npz", r)
    out = tmp_path / "o"
    code = main(
        [
            "study",
            str(tmp_path),
            "--gains",
            "3,10",
            "--gain-type",
            "auto",
            "--poles",
            "-8,-8,-8;-12,-12,-12",
            "--json",
            f"{out}.json",
            "--csv",
            f"{out}.csv",
            "--plot",
            f"{out}.png",
            "--chunk-size",
            "3",  # the chunk of the module's `result`: the compiled call is shared
        ]
    )
    text = capsys.readouterr().out
    assert code == 0 and "r1.npz" in text and "t_conv [s]" in text
    rows = json.loads((tmp_path / "o.json").read_text())["rows"]
    assert len(rows) == 8 and (tmp_path / "o.png").stat().st_size > 1000
    # the CLI equals the API on the same grid (the module's `result`; files round-trip in float64)
    api = result
    np.testing.assert_allclose([r["a"] for r in rows], api.theta_final[..., 0].ravel(), rtol=1e-9)


def test_one_batched_call_over_pole_sets(records, result):
    """The study runs every pole set in one lion_batched call (one filter per batch element: a
    FilterBank with coeffs (B, n)): with a batch size (12) different from the filter order (3), and the
    default per-filter transient 3·λ₂/λ₃, it equals the per-pole-set run (chunks of 3) and
    per-element lj.lion."""
    poles = POLES + [(-5.0, -6.0, -7.0)]
    res = lj.study(
        lj.MassDamper(), records, gains=[3.0, 10.0], gain=lj.AutoGain, poles=poles, progress=False
    )
    assert res.shape == (2, 2, 3)
    np.testing.assert_allclose(res.theta_final[:, :, :2], result.theta_final, rtol=1e-12)
    np.testing.assert_allclose(res.theta_ls[:, :, :2], result.theta_ls, rtol=1e-12)
    np.testing.assert_array_equal(res.convergence_time[:, :, :2], result.convergence_time)
    bank = lj.FilterBank.from_poles(np.array(poles[2]), True)
    for d, rec in enumerate(records):
        sol = lj.lion(lj.MassDamper(), rec, bank=bank, gain=lj.AutoGain(10.0))
        np.testing.assert_allclose(res.theta_final[d, 1, 2], np.asarray(sol.theta[-1]), rtol=1e-9)


def test_map_pools_the_record_dims(result):
    tc = result.map("convergence_time")
    assert tc.shape == (2, 2)
    np.testing.assert_array_equal(tc, np.median(result.convergence_time, axis=0))
    np.testing.assert_array_equal(
        result.map("noise_amplification", keep=("poles",), reduce="max"),
        np.max(result.noise_amplification, axis=(0, 1)),
    )
    with pytest.raises(lj.InputError, match="keep"):
        result.map("bias", keep=("theta0",))
    with pytest.raises(lj.InputError, match="quantity"):
        result.map("speed")


@pytest.fixture(scope="module")
def grid_records():
    from lionjax import twin

    return lj.studies.study_records(
        excitations={"in1": twin.PAPER_SINE_SETS[0], "in4": twin.PAPER_SINE_SETS[3]},
        operating_points=[-0.02, 0.02],
        noise_seeds=[3],
        n_samples=2000,
    )


def test_study_records_grid(grid_records):
    from lionjax import twin

    assert grid_records.dims == ("excitation", "operating_point", "noise_seed")
    assert grid_records.shape == (2, 2, 1) and len(grid_records) == 4
    assert grid_records.coords["operating_point"] == [-0.02, 0.02]
    assert grid_records.labels()[2] == {
        "excitation": "in4",
        "operating_point": -0.02,
        "noise_seed": 3,
    }
    # independent reference: the same twin call by hand
    plant = twin.FALCON_PAPER.with_effects(twin.ForceNoise(0.01))
    ref = twin.simulate(
        plant,
        twin.PAPER_SINE_SETS[3],
        n_samples=2000,
        key=jax.random.PRNGKey(3),
        closed_loop=twin.CentringPD(x_ref=-0.02),
        x0=-0.02,
    )
    np.testing.assert_array_equal(np.asarray(grid_records[2].x), np.asarray(ref.x))
    # each record stays in the region of its operating point (eq. 13 bounds ±10 mm)
    for lab, rec in zip(grid_records.labels(), grid_records, strict=True):
        x = np.asarray(rec.x)
        assert np.all(np.sign(x) == np.sign(lab["operating_point"])) and np.all(np.abs(x) > 0.01)
    with pytest.raises(lj.InputError, match="n=2"):
        lj.studies.study_records(2, noise_seeds=[1])
    with pytest.raises(lj.InputError, match="operating_points"):
        lj.studies.study_records(operating_points="centre")


@pytest.mark.slow  # studies against per-record runs, tuning
def test_study_over_labelled_records_vs_lion(grid_records, tmp_path):
    """Record dims become study dims; tail std (noise amplification), the smooth surrogate and
    the decimated trajectory equal numpy references computed from lj.lion's full θ(t)."""
    model = lj.MassDamper()
    P = (-20.0, -20.0, -20.0)
    res = lj.study(
        model,
        grid_records,
        gains=[5.0],
        gain=lj.AutoGain,
        poles=[P],
        softness=0.5,
        transient=0.5,
        save_every=100,
        progress=False,
    )
    assert res.dims == ("excitation", "operating_point", "noise_seed", "gain", "poles")
    assert res.shape == (2, 2, 1, 1, 1) and res.trajectory.shape == (2, 2, 1, 1, 1, 19, 2)
    np.testing.assert_allclose(res.t_saved, 0.1 * np.arange(1, 20))
    # region 1 (x_ref = −20 mm): a = 16.2, b = 2.02; region 3: a = 37.1, b = 1.289 (eq. 13)
    truth = {-0.02: (16.2, 2.02), 0.02: (37.1, 1.289)}
    bank = lj.FilterBank.from_poles(np.array(P), True)
    tol, soft = 0.02, 0.5
    for k, (lab, rec) in enumerate(zip(grid_records.labels(), grid_records, strict=True)):
        idx = np.unravel_index(k, grid_records.shape) + (0, 0)
        # (2-s records, one sine of input 1: within 10 %; the regions differ by a factor 2.3)
        np.testing.assert_allclose(res.theta_ls[idx], truth[lab["operating_point"]], rtol=0.1)
        sol = lj.lion(model, rec, bank=bank, gain=lj.AutoGain(5.0), transient=0.5)
        ls = lj.least_squares(model, rec, bank=bank, initial="discard", transient=0.5)
        th = np.asarray(sol.theta)  # (T, p), θ after each sample
        ref = np.asarray(ls.theta)
        T = th.shape[0]
        np.testing.assert_allclose(res.theta_final[idx], th[-1], rtol=1e-9)
        # tail: samples 3T/4 … T−1; population std
        std = np.std(th[(3 * T) // 4 :], axis=0)
        np.testing.assert_allclose(res.tail_std[idx], std, rtol=1e-6)
        np.testing.assert_allclose(
            res.noise_amplification[idx], np.max(std / np.abs(ref)), rtol=1e-6
        )
        # surrogate: Σ_k h·σ((log r_k − log tol)/s), r_k² = Σ r⁴ / Σ r² over θ after each step
        r = (th[1:] - ref) / np.abs(ref)
        rr = np.sum(r**4, axis=1) / np.sum(r**2, axis=1)
        surr = 1e-3 * np.sum(1.0 / (1.0 + np.exp(-(0.5 * np.log(rr) - np.log(tol)) / soft)))
        np.testing.assert_allclose(res.time_outside[idx], surr, rtol=1e-8)
        np.testing.assert_allclose(res.trajectory[idx], th[100::100][:19], rtol=1e-9)
    rows = res.to_rows()
    assert rows[0]["excitation"] == "in1" and "noise_amplification" in rows[0]
    res.to_json(tmp_path / "g.json")
    payload = json.loads((tmp_path / "g.json").read_text())
    assert len(payload["trajectory"]["t"]) == 19 and payload["softness"] == 0.5
    with pytest.raises(lj.InputError, match="dataset_names"):
        lj.study(model, grid_records, dataset_names=["a", "b", "c", "d"], progress=False)


@pytest.mark.slow  # studies against per-record runs, tuning
def test_cli_study_tune_and_map(monkeypatch, tmp_path, capsys):
    """--noise-seeds simulates labelled twin records; --tune calls lj.studies.tune from the grid's
    centre with the objective whose map is drawn (lj.studies.tune itself: tests/test_tune.py)."""
    calls = {}

    def fake_tune(model, records, **kw):
        calls.update(kw, n_records=len(records))
        return lj.studies.TuneSolution(
            gain_class=kw["gain"],
            gain=12.0,
            pole=25.0,
            filter_order=3,
            unit_dc_gain=True,
            init_gain=kw["init_gain"],
            init_pole=kw["init_pole"],
            objective=0.5,
            gradient=np.zeros(2),
            n_steps=7,
            success=True,
            message="",
            labels=("noise_seed=1", "noise_seed=2"),
            names=("a", "b"),
            theta=np.ones((2, 2)),
            theta_ls=np.ones((2, 2)),
            convergence_time=np.array([0.4, np.inf]),
            time_outside=np.array([0.4, 0.5]),
            tail_std=np.zeros((2, 2)),
            spec=kw["objective"],
        )

    monkeypatch.setattr(lj.studies, "tune", fake_tune)
    out = tmp_path / "t"
    code = main(
        [
            "study",
            "--noise-seeds",
            "1,2",
            "--samples",
            "1500",
            "--gains",
            "4,16,64",
            "--gain-type",
            "auto",
            "--poles",
            "-10;-40",
            "--tune",
            "--kappa",
            "2",
            "--json",
            f"{out}.json",
            "--plot",
            f"{out}.png",
        ]
    )
    text = capsys.readouterr().out
    assert code == 0 and "noise [%]" in text and "noise_seed" in text
    assert "tuned" in text and "gain 12 [1/s]" in text and "grid minimum of J" in text
    assert calls["init_gain"] == pytest.approx(16.0) and calls["init_pole"] == pytest.approx(20.0)
    assert calls["objective"].kappa == 2.0 and calls["n_records"] == 2
    payload = json.loads((tmp_path / "t.json").read_text())
    assert payload["dims"] == ["noise_seed", "gain", "poles"] and payload["softness"] == 0.5
    assert (
        payload["tune"]["gain"] == 12.0
        and payload["tune"]["records"][1]["convergence_time"] is None
    )
    assert len(payload["rows"]) == 12 and "noise_amplification" in payload["rows"][0]
    assert (tmp_path / "t.png").stat().st_size > 1000
