"""lionjax.study: a grid of batched runs equals per-element lj.lion / lj.least_squares calls."""

import csv
import json

import numpy as np
import pytest

import lionjax as lj
import lionjax._study as study_mod
from lionjax.cli import main

POLES = [(-8.0, -8.0, -8.0), (-12.0, -12.0, -12.0)]


@pytest.fixture(scope="module")
def records():
    return lj.study_records(2, n_samples=3000, seed=0)


@pytest.fixture(scope="module")
def result(records):
    return lj.study(
        lj.MassDamper(),
        records,
        gains=[3.0, 10.0],
        gain_type="auto",
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
    rows = result.to_records()
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


def test_study_interrupt_returns_partial(records, monkeypatch, capsys):
    real = study_mod.lion_batched
    calls = []

    def flaky(*a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(study_mod, "lion_batched", flaky)
    res = lj.study(lj.MassDamper(), records, gains=[3.0, 10.0], gain_type="auto", chunk_size=2)
    err = capsys.readouterr().err
    assert "interrupted after 1/2 chunks" in err and "1/2 chunks" in err
    assert not res.complete
    assert np.all(np.isfinite(res.theta_final[0])) and np.all(np.isnan(res.theta_final[1]))
    assert np.all(res.result[1] == -1)


def test_study_bad_input(records):
    with pytest.raises(lj.InputError, match="poles"):
        lj.study(lj.MassDamper(), records, poles=[(-4.0, 4.0, -4.0)])
    with pytest.raises(lj.InputError, match="theta0s"):
        lj.study(lj.MassDamper(), records, theta0s=[(1.0, 2.0, 3.0)])


def test_cli_study(records, tmp_path, capsys):
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
        ]
    )
    text = capsys.readouterr().out
    assert code == 0 and "r1.npz" in text and "t_conv [s]" in text
    rows = json.loads((tmp_path / "o.json").read_text())["rows"]
    assert len(rows) == 8 and (tmp_path / "o.png").stat().st_size > 1000
    # the CLI equals the API on the same grid (files round-trip in float64)
    api = lj.study(
        lj.MassDamper(), records, gains=[3.0, 10.0], gain_type="auto", poles=POLES, progress=False
    )
    np.testing.assert_allclose([r["a"] for r in rows], api.theta_final[..., 0].ravel(), rtol=1e-9)
