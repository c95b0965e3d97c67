"""``lionjax diagnose`` across sample rates: 100 Hz to 10 kHz with non-round dt.

Records from the twin (region-2 plant of the paper, closed loop, encoder quantisation), clean and
with Coulomb friction, at each rate; the CLI must run without error and name the effect (or
``none`` for the clean record). Every record-derived setting is checked finite in the JSON.
"""

import json
import math

import jax
import numpy as np
import pytest
from _reference_sim import sampled_force_axis

import lionjax as lj
from lionjax import twin as tw
from lionjax.cli import main

# the slow tier (.ci/run's second step): whole diagnoses at several sampling rates
pytestmark = pytest.mark.slow

RATES = (97.3, 2011.7, 4987.3, 10103.9)  # Hz, deliberately non-round


def _record(fs, effects, seed, duration=5.0, max_samples=8000):
    # at most 8 000 samples: the 2, 5 and 10 kHz records share one length bucket of the
    # diagnosis, 2¹³ (one set of compiled programs; the 2 kHz record is then 4.0 s long, the
    # 5 kHz one 1.6 s, the 10 kHz one 0.79 s). At 16 000 the verdicts were the same and the
    # sweep took 1.7× as long once compiled (9.7 against 16.8 s, measured when written).
    duration = min(duration, max_samples / fs)
    plant = tw.Plant(22.0, 1.916, (), [tw.EncoderQuantisation(2e-6)]).with_effects(*effects)
    exc = tw.multisine(
        np.array([0.4, 0.9, 1.7, 3.1, 5.3]) + 0.1 * seed, 1.2, key=jax.random.key(seed)
    )
    r = tw.simulate(
        plant,
        exc,
        dt=1 / fs,
        n_samples=int(duration * fs),
        key=jax.random.key(seed + 10),
        closed_loop=tw.CentringPD(kp=60 / 1.916, kd=1 / 1.916),
    )
    return lj.Record(r.x, r.F, r.dt)


@pytest.mark.parametrize("fs", RATES)
def test_cli_diagnose_any_rate(fs, tmp_path, capsys):
    for name, effects in (("none", []), ("coulomb_friction", [tw.CoulombFriction(0.25)])):
        paths = []
        for seed in (1, 2):
            p = tmp_path / f"{name}_{seed}.npz"
            lj.save_record(p, _record(fs, effects, seed))
            paths.append(str(p))
        out = tmp_path / f"{name}.json"
        assert main(["diagnose", paths[0], "--validate", paths[1], "--json", str(out)]) == 0
        j = json.loads(out.read_text())
        assert j["verdict"] == name, (fs, name, j["verdict"], j["stack"])
        st = j["settings"]
        for k in ("dt", "filter_hz", "velocity_filter_hz", "v_eps", "window_s"):
            assert st[k] is not None and math.isfinite(st[k]) and st[k] > 0, (k, st[k])
        assert st["filter_hz"] < 0.5 / st["dt"]
        assert 0.0 <= j["confidence"] <= 1.0
        assert "near-tie" in capsys.readouterr().out or not j["ambiguous"]


def test_cli_diagnose_decimated(tmp_path):
    """``--decimate auto`` takes the least factor that fits ``--max-memory-gb`` (0.1 GB: the
    shortest bucket, 2¹², holds 16 000/4 samples, 2¹³ does not fit) and names the effect of the
    10 kHz records at 2.5 kHz, with the Coulomb level within 1 % of the truth."""
    fs = RATES[-1]
    paths = []
    for seed in (1, 2):
        p = tmp_path / f"c{seed}.npz"
        lj.save_record(p, _record(fs, [tw.CoulombFriction(0.25)], seed, max_samples=16000))
        paths.append(str(p))
    out = tmp_path / "d.json"
    args = ["diagnose", paths[0], "--validate", paths[1], "--json", str(out)]
    assert main([*args, "--decimate", "auto", "--max-memory-gb", "0.1"]) == 0
    j = json.loads(out.read_text())
    assert j["decimate"]["factor"] == 4 and j["decimate"]["dt_recorded"] == pytest.approx(1 / fs)
    assert j["settings"]["dt"] == pytest.approx(4 / fs)
    assert j["verdict"] == "coulomb_friction", (j["verdict"], j["stack"])
    assert j["final"]["params"]["Fc"] == pytest.approx(0.25, rel=0.01)
    for bad in ("0", "x", "1.5"):
        with pytest.raises(SystemExit):
            main([*args, "--decimate", bad])


def test_cli_diagnose_a_force_sampled_at_instants(tmp_path, capsys):
    """A force read at the instants acts half a sample before lionjax reads it as held: the
    plain diagnosis of a mass–damper without effects names a delay of about −½ sample and says
    how to read F instead (measured τ = −0.49 samples, confidence 1.00); ``--F-hold foh``
    (Record.hold_force) diagnoses it as ``none`` and records the reading in the JSON; with
    ``--pairs`` the flag is refused."""
    paths = []
    for seed in (1, 2):
        p = tmp_path / f"m{seed}.npz"
        lj.save_record(p, lj.Record(*sampled_force_axis(seed, noise=2e-7), 1e-3))
        paths.append(str(p))
    out = tmp_path / "d.json"
    args = ["diagnose", paths[0], "--validate", paths[1], "--json", str(out)]
    assert main(args) == 0
    j = json.loads(out.read_text())
    assert j["verdict"] == "delay" and j["F_hold"] == "zoh", (j["verdict"], j["stack"])
    assert -0.6 < j["final"]["params"]["tau_samples"] < -0.4
    assert "--F-hold foh reads it so" in capsys.readouterr().out
    assert main([*args, "--F-hold", "foh"]) == 0
    j = json.loads(out.read_text())
    assert j["verdict"] == "none" and j["F_hold"] == "foh", (j["verdict"], j["stack"])
    assert "diagnosed as the held force" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["diagnose", "--pairs", str(tmp_path), "--F-hold", "foh"])
    assert "--F-hold is not allowed with --pairs" in capsys.readouterr().err


def test_no_motion_is_a_clear_input_error():
    t = np.arange(2000) * 1e-3
    still = lj.Record(np.zeros_like(t), np.sin(t), 1e-3)
    with pytest.raises(lj.InputError, match=r"training record.*constant position"):
        lj.diagnose(still, still)


def test_records_too_long_for_the_memory_are_refused_before_computing(tmp_path, capsys):
    """The diagnosis' peak host memory in one chunk grows with the padded length (measured: 6.5 kB
    per padded sample of each record, its filtered signals and designs kept): records
    that would need more than ``max_memory_gb`` (default: the machine's memory) get an
    InputError naming the need, the limit, the least decimation that fits (``decimation_for``)
    and the longest records that fit, before anything is computed. A 10-minute record at
    10 kHz, padded to 2²³, would need 109 GB in one chunk; it is streamed by default, estimated by
    its raw samples (the estimate's formulas: test_diagnose_kernels.py)."""
    t = np.arange(20_000) / 1000.0
    rec = lj.Record(0.01 * np.sin(2 * np.pi * 0.7 * t), np.cos(2 * np.pi * 0.7 * t), 1e-3)
    # 0.3 GB: the longest padded length that fits is 2¹⁴ (6500·2·2¹⁴ = 0.21 GB; 2¹⁵: 0.43 GB),
    # which holds 2¹⁴ − 20 samples (padded_length pads n + 20)
    with pytest.raises(
        lj.InputError,
        match=r"0\.426 GB .* max_memory_gb \(0\.3 GB\)\. Decimate both records by 2 .* 16364 ",
    ):
        lj.diagnose(rec, rec, max_memory_gb=0.3)
    # by 2: 10 000 samples each, padded to 2¹⁴ (0.21 GB)
    assert lj.diagnosis.decimation_for(rec, rec, max_memory_gb=0.3) == 2
    assert lj.diagnosis.decimation_for(rec, max_memory_gb=0.5) == 1
    assert lj.diagnosis.decimation_for(rec, rec, max_memory_gb=0.01) == 0
    # 0.01 GB: not even one bucket of 2¹² (6500·2·2¹² = 0.05 GB)
    with pytest.raises(lj.InputError, match="Even the shortest records do not fit"):
        lj.diagnose(rec, rec, max_memory_gb=0.01)
    for bad in (-1.0, 0, "8", True, float("nan")):
        with pytest.raises(lj.InputError, match="max_memory_gb must be a number > 0"):
            lj.diagnose(rec, rec, max_memory_gb=bad)
    with pytest.raises(lj.InputError, match=r"max_memory_gb \(0\.3 GB\)"):  # numpy scalars
        lj.diagnose(rec, rec, max_memory_gb=np.float32(0.3))
    # the command line: a clear message and exit status 2
    path = tmp_path / "rec.npz"
    lj.save_record(path, rec)
    assert main(["diagnose", str(path), "--max-memory-gb", "0.3"]) == 2
    assert "need about 0.426 GB" in capsys.readouterr().err
