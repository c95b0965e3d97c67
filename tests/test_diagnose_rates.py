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

import lionjax as lj
from lionjax import twin as tw
from lionjax.cli import main

RATES = (97.3, 2011.7, 4987.3, 10103.9)  # Hz, deliberately non-round


def _record(fs, effects, seed, duration=5.0):
    # at most 30 000 samples: the 5 kHz and 10 kHz records share one length bucket of the
    # diagnosis (one set of compiled programs; the 10 kHz record is then 3 s long)
    duration = min(duration, 30000 / fs)
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


def test_no_motion_is_a_clear_input_error():
    t = np.arange(2000) * 1e-3
    still = lj.Record(np.zeros_like(t), np.sin(t), 1e-3)
    with pytest.raises(lj.InputError, match="does not move"):
        lj.diagnose(still, still)
