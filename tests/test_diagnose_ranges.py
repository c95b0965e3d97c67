"""The diagnosis' searches follow the record (issue 64): a resonance anywhere in the excited band
is found, a record that cannot decide is called ``inconclusive`` with what to record instead."""

import math

import numpy as np
import pytest

import lionjax as lj
from lionjax import twin


def _multisine(rng, n: int, dt: float, f_lo: float, f_hi: float, rms: float) -> np.ndarray:
    """A random-phase multisine over [f_lo, f_hi] (lines 1/(n·dt) apart), of RMS ``rms`` [N]."""
    t = dt * np.arange(n)
    fs = np.arange(f_lo, f_hi, 1.0 / (n * dt) * 4)
    ph = rng.uniform(0, 2 * math.pi, fs.size)
    u = np.sum(np.cos(2 * math.pi * fs[:, None] * t[None] + ph[:, None]), 0)
    return rms * u / np.std(u)


@pytest.mark.slow
def test_a_resonance_above_the_filter_corner_band_is_found():
    """A flexible mode at 300 Hz on a record at 2 kHz excited up to 400 Hz: above 4× the filter
    corner (40 Hz), where the mode search used to stop, and inside the excited band, where it
    now reaches (1.25 × the band's top). Named, within 10 % of its frequency."""
    dt, n = 1 / 2000.0, 12000
    plant = twin.Plant(20.0, 2.0, (), [twin.EncoderQuantisation(1e-7)])
    plant = plant.with_effects(twin.FlexibleMode(0.15, 300.0, 0.03))
    recs = []
    for seed in (1, 2):
        F = _multisine(np.random.default_rng(seed), n, dt, 2.0, 400.0, 2.0)
        recs.append(twin.simulate(plant, F, dt=dt))
    d = lj.diagnose(*recs)
    assert d.verdict == "flexible_mode", (d.verdict, d.stack)
    assert d.final["params"]["f_mode"] == pytest.approx(300.0, rel=0.1)


def test_a_record_that_cannot_decide_is_inconclusive():
    """A slow record whose validation residual holds few effective samples (a sine of 0.3 Hz
    over 5 s, one effect hidden in it): too few to tell an effect from none — ``inconclusive``,
    with the reason and the advice in the JSON, never ``none`` or ``unexplained``."""
    dt, n = 1e-3, 5000
    plant = twin.Plant(5.0, 1.0, (), [twin.EncoderQuantisation(1e-6)])
    plant = plant.with_effects(twin.SmoothCoulombFriction(0.05, 1e-3))
    t = dt * np.arange(n)
    recs = [twin.simulate(plant, 0.5 * np.sin(2 * math.pi * 0.3 * t + p), dt=dt) for p in (0, 1)]
    d = lj.diagnose(*recs)
    j = d.to_json()
    if not d.stack:
        assert d.verdict == "inconclusive", (d.verdict, d.noise["n_effective"])
        assert j["inconclusive"]["reason"] and j["inconclusive"]["advice"]
    else:  # a record that does decide names what it holds
        assert d.verdict == "coulomb_friction"
        assert j["inconclusive"] is None
