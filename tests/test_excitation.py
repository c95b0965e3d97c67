"""Tests of the excitation signals against numpy formulas (float64: agreement to 1e-12 N)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lionjax.twin as lp
from lionjax import InputError
from lionjax.twin import (
    PAPER_OPERATING_POINTS,
    PAPER_SINE_SETS,
    PRBS,
    VERIFICATION_DURATION,
    Chirp,
    SineSum,
    VerificationInput,
    multisine,
)

jax.config.update("jax_enable_x64", True)

TOL = 1e-12  # N, float64 evaluation of the same formula
t = np.linspace(0.0, 3.0, 3001)


def test_sine_sum_formula_and_sample():
    exc = SineSum((1.0, 0.5), (2.0, 7.5), (0.3, -1.0), offset=0.2)
    ref = 0.2 + np.sin(2 * np.pi * 2.0 * t + 0.3) + 0.5 * np.sin(2 * np.pi * 7.5 * t - 1.0)
    np.testing.assert_allclose(exc(t), ref, atol=TOL)
    np.testing.assert_allclose(exc.sample(3001, 1e-3), ref, atol=TOL)
    np.testing.assert_allclose(exc.sample(5, 0.5, t0=1.0), exc(1.0 + 0.5 * np.arange(5)), atol=TOL)
    assert exc(jnp.zeros((2, 3))).shape == (2, 3)


def test_multisine_random_and_schroeder():
    f = np.arange(1, 9) * 0.5
    m1 = multisine(f, 0.3, key=jax.random.key(0))
    m2 = multisine(f, 0.3, key=jax.random.key(0))
    m3 = multisine(f, 0.3, key=jax.random.key(1))
    np.testing.assert_array_equal(m1.phases, m2.phases)
    assert not np.array_equal(m1.phases, m3.phases)
    assert np.all((np.asarray(m1.phases) >= 0) & (np.asarray(m1.phases) < 2 * np.pi))
    s = multisine(f, 0.3, phases="schroeder")
    j = np.arange(1, 9)
    np.testing.assert_allclose(s.phases, -np.pi * j * (j - 1) / 8, atol=0)
    # Schroeder phases: crest factor well below the all-zero-phase multisine (√(2·8) = 4)
    tt = np.linspace(0, 2.0, 20001)
    crest = lambda e: np.max(np.abs(e(tt))) / np.sqrt(np.mean(np.asarray(e(tt)) ** 2))
    assert crest(s) < 2.0 < crest(SineSum(0.3, f))
    # vmappable over keys
    batch = jax.vmap(lambda k: multisine(f, 0.3, key=k)(0.123))(
        jax.random.split(jax.random.key(0), 4)
    )
    assert batch.shape == (4,)


@pytest.mark.parametrize("kind", ["linear", "log"])
def test_chirp_instantaneous_frequency(kind):
    c = Chirp(1.5, 0.5, 8.0, 3.0, kind=kind, phase=0.2, offset=0.1)
    tt = np.linspace(0.01, 2.99, 300)
    h = 1e-6
    f_num = (np.asarray(c.phase_at(tt + h)) - np.asarray(c.phase_at(tt - h))) / (4 * np.pi * h)
    f_ref = 0.5 + 7.5 * tt / 3.0 if kind == "linear" else 0.5 * 16.0 ** (tt / 3.0)
    np.testing.assert_allclose(f_num, f_ref, rtol=1e-6)
    np.testing.assert_allclose(c.phase_at(0.0), 0.0, atol=TOL)
    np.testing.assert_allclose(
        c(tt), 0.1 + 1.5 * np.sin(np.asarray(c.phase_at(tt)) + 0.2), atol=TOL
    )
    np.testing.assert_allclose(c(np.array([-1.0, 3.5])), [0.1, 0.1], atol=TOL)  # off outside


def test_prbs_maximal_length_and_clock():
    for order in (5, 10):
        p = PRBS(0.7, 0.01, jax.random.key(2), order=order)
        bits = np.asarray(p.bits)
        P = 2**order - 1
        assert bits.shape == (P,) and bits.sum() == 2 ** (order - 1)
        # maximal length: the sequence is not periodic with any proper divisor of P …
        for d in range(1, P):
            if P % d == 0:
                assert not np.array_equal(bits, np.roll(bits, d))
        # … and its ±1 circular autocorrelation is −1 at every non-zero lag (m-sequence property)
        pm = 2 * bits - 1
        ac = np.array([np.dot(pm, np.roll(pm, k)) for k in range(1, P)])
        np.testing.assert_array_equal(ac, -1)
    p = PRBS(0.7, 0.01, jax.random.key(2), order=5, offset=-0.1)
    x = np.asarray(p.sample(1000, 1e-3))
    assert set(np.round(x, 12)) <= {0.6, -0.8}
    # held over each clock period of 10 samples, levels follow the bits, period 31 clocks
    np.testing.assert_array_equal(x.reshape(-1, 10), x[::10, None].repeat(10, 1))
    np.testing.assert_allclose(x[::10][:31], -0.1 + 0.7 * (2 * np.asarray(p.bits) - 1), atol=TOL)
    np.testing.assert_array_equal(x[::10][31:62], x[::10][:31])
    q = PRBS(0.7, 0.01, jax.random.key(2), order=5)
    np.testing.assert_array_equal(q.bits, p.bits)  # seeded: same key, same sequence
    r = PRBS(0.7, 0.01, jax.random.key(5), order=5)
    assert not np.array_equal(r.bits, p.bits)


def test_verification_input():
    v = VerificationInput()
    tt = np.linspace(0, VERIFICATION_DURATION, 1601)
    np.testing.assert_allclose(v(tt), 3 * np.cos(40 * tt + 400) + 0.5 * tt, atol=1e-11)
    assert VERIFICATION_DURATION == 1.6


def test_paper_sine_sets_hold_each_operating_point():
    """With the centring PD, every set moves the twin 2–6 mm around each operating point and
    never leaves that point's region of eq. (13)."""
    assert len(PAPER_SINE_SETS) == 4
    freqs = [tuple(np.asarray(s.frequencies)) for s in PAPER_SINE_SETS]
    assert len(set(freqs)) == 4
    n = 6001
    F = jnp.stack([s.sample(n, 1e-3) for s in PAPER_SINE_SETS])
    ops = jnp.asarray(PAPER_OPERATING_POINTS)
    Fb, xb = jnp.tile(F, (3, 1)), jnp.repeat(ops, 4)

    def one(f, x):
        return lp.simulate(lp.FALCON_PAPER, f, x0=x, closed_loop=lp.CentringPD(200.0, 1.0, x))

    rec = eqx.filter_vmap(one)(Fb, xb)
    x = np.asarray(rec.extras["x_true"])
    dev = np.max(np.abs(x - np.asarray(xb)[:, None]), axis=1)
    assert np.all(dev > 2e-3) and np.all(dev < 6e-3), dev
    region = np.asarray(lp.FALCON_PAPER.region_of(x))
    np.testing.assert_array_equal(region, np.repeat([0, 1, 2], 4)[:, None].repeat(n, 1))


def test_excitation_errors():
    with pytest.raises(InputError, match="'frequencies'"):
        SineSum(1.0, -2.0)
    with pytest.raises(InputError, match="'amplitudes'"):
        SineSum((1.0, 2.0, 3.0), (1.0, 2.0))
    with pytest.raises(InputError, match="'key'"):
        multisine((1.0, 2.0), 1.0)
    with pytest.raises(InputError, match="'phases'"):
        multisine((1.0, 2.0), 1.0, phases="zero")
    with pytest.raises(InputError, match="'kind'"):
        Chirp(1.0, 1.0, 2.0, 1.0, kind="cubic")
    with pytest.raises(InputError, match="f0 != f1"):
        Chirp(1.0, 1.0, 1.0, 1.0, kind="log")
    with pytest.raises(InputError, match="'order'"):
        PRBS(1.0, 0.01, jax.random.key(0), order=40)
    with pytest.raises(InputError, match="'clock_period'"):
        PRBS(1.0, 0.0, jax.random.key(0))
    with pytest.raises(InputError, match="'n_samples'"):
        SineSum(1.0, 1.0).sample(0, 1e-3)
    assert math.isfinite(float(SineSum(1.0, 1.0)(0.25)))
