"""The diagnosis' searches follow the record (issue 64): a resonance anywhere in the excited band
is found, a record that cannot decide is called ``inconclusive`` with what to record instead."""

import math

import jax
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
    """A flexible mode at 300 Hz on a record at 2 kHz excited up to 400 Hz: far above the filter
    corner (40 Hz) and inside the excited band, which the mode search covers (to 1.25 × the
    band's top); F is noise-free, so its noise comes from the top of its spectrum, not from
    the multisine's third differences. Named, within 10 % of its frequency."""
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


@pytest.mark.slow
@pytest.mark.parametrize(("f_mode", "mu", "f_top"), [(120.0, 0.05, 200.0), (150.0, 0.03, 300.0)])
def test_a_resonance_at_an_eighth_of_the_sample_rate_inside_the_excited_band(f_mode, mu, f_top):
    """A light mode at 120 or 150 Hz on an open-loop axis sampled at 1 kHz, driven by a
    multisine up to 200 or 300 Hz: inside the excited band, where a mode answers with its
    resonance, not with the sampling's hold error (μ/ω² = h²/12, the look-alike of a mode above
    the excitation: 3× it exceeds μ here). Named, within 5 % of its frequency (the simulator's)."""
    dt, n = 1e-3, 8000
    plant = twin.Plant(20.0, 2.0, (), [twin.EncoderQuantisation(1e-6)])
    plant = plant.with_effects(twin.FlexibleMode(mu, f_mode, 0.02))
    assert mu < 3 * (2 * math.pi * f_mode * dt) ** 2 / 12
    recs = []
    for seed in (1, 2):
        F = _multisine(np.random.default_rng(seed), n, dt, 1.0, f_top, 2.0)
        recs.append(twin.simulate(plant, F, dt=dt))
    d = lj.diagnose(*recs)
    assert d.verdict == "flexible_mode", (d.verdict, d.stack)
    assert d.final["params"]["f_mode"] == pytest.approx(f_mode, rel=0.05)


@pytest.mark.parametrize("path", ["one way", "back and forth"])
def test_a_spring_on_an_axis_moving_one_way_is_inconclusive(path):
    """A spring (k = 20 N/m) driven by a ramp of force, the axis moving one way at 0.05 m/s with
    a small multisine on top that never moves it back: x is a monotone function of time, so the
    spring's column is one of time too (a force of time shaped as x(t) fits it exactly; a
    drift's ramp fits all but the start's transient and the multisine's small share of x).
    Nothing is named: ``inconclusive``, the reason the share of samples where the axis passes
    twice, the advice to move back and forth. The same axis driven back and forth over its range
    names the spring."""
    dt, n = 1e-3, 6000
    t = dt * np.arange(n)
    plant = twin.Plant(5.0, 1.0, (), [twin.EncoderQuantisation(1e-6)])
    plant = plant.with_effects(twin.LinearSpring(20.0))
    recs = []
    for seed in (1, 2):
        wiggle = _multisine(np.random.default_rng(seed), n, dt, 5.0, 50.0, 0.1)
        if path == "one way":  # F = k·v₀·t + a·v₀/b holds x = v₀·t against the spring
            drive = 20.0 * 0.05 * t + 5.0 * 0.05
        else:
            drive = 4.0 * np.sin(2 * math.pi * 0.25 * t + seed)
        recs.append(twin.simulate(plant, drive + wiggle, dt=dt))
    d = lj.diagnose(*recs)
    spring = next(e for e in d.effects if e.name == "spring")
    if path == "one way":
        assert all(np.all(np.diff(np.asarray(r.x)) >= 0) for r in recs)
        assert d.verdict == "inconclusive", (d.verdict, d.stack)
        assert "passes twice" in spring.reason and not spring.significant
        assert "passes twice" in d.to_json()["inconclusive"]["reason"]
        assert "back and forth" in d.to_json()["inconclusive"]["advice"]
        assert d.noise["passed_twice"] == 0.0
    else:
        assert d.verdict == "spring", (d.verdict, d.stack)
        assert spring.params["k"] == pytest.approx(20.0, rel=0.05)
        assert d.noise["passed_twice"] > 0.9


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


def test_a_record_whose_noise_hides_every_effect_is_inconclusive():
    """Position noise of 0.1 mm rms on 2–3 cm of travel: the detection limit (the size an effect
    needs to be seen, over the input's term b·F) is above one half, so an effect half as large
    as the drive could hide, and a Coulomb friction of 0.1 N (a fifth of the force) is not
    seen. Nothing named is then no evidence of no effect: ``inconclusive``, with that reason and
    the advice to drive harder or measure finer, with or without the friction — never ``none``.
    The same records at 10 µm (limit ≈ 0.03–0.09) decide: the friction, or none."""
    dt, n = 1e-3, 6000
    t = dt * np.arange(n)
    F = [0.5 * np.sin(2 * math.pi * t + p) + 0.3 * np.sin(2 * math.pi * 3.1 * t) for p in (0, 1)]
    for noise, friction, verdict in (
        (1e-4, True, "inconclusive"),
        (1e-4, False, "inconclusive"),
        (1e-5, True, "coulomb_friction"),
    ):
        plant = twin.Plant(5.0, 1.0, (), [twin.PositionNoise(noise)])
        if friction:
            plant = plant.with_effects(twin.CoulombFriction(0.1))
        recs = [twin.simulate(plant, f, dt=dt, key=jax.random.key(k)) for k, f in enumerate(F)]
        d = lj.diagnose(*recs)
        limit = d.noise["detection_limit_worst"]
        assert d.verdict == verdict, (noise, friction, d.verdict, limit)
        assert (limit >= 0.5) == (verdict == "inconclusive"), limit
        j = d.to_json()
        if verdict == "inconclusive":
            assert "detection limit" in j["inconclusive"]["reason"]
            assert "measure its position finer" in j["inconclusive"]["advice"]
        else:
            assert j["inconclusive"] is None
