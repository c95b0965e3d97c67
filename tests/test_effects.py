"""Candidate regressor effects (lionjax._effects) against independent references.

References: the analytic derivative of a sine (zero-phase velocity), and scipy ``solve_ivp`` of
the augmented model written from the docstring equations, identified by ``numpy.linalg.lstsq`` on
the columns the effects produce.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import lionjax as lj
from lionjax._effects import zero_phase_velocity

DT = 1e-3
T = 1201


def _sim(rhs, F, x0=0.0):
    t = np.arange(T) * DT
    xs = [np.array([x0, 0.0])]
    for k in range(T - 1):  # held force, restart each interval
        s = solve_ivp(rhs, (0, DT), xs[-1], args=(F[k],), rtol=1e-10, atol=1e-12, method="DOP853")
        xs.append(s.y[:, -1])
    return t, np.array(xs)[:, 0]


def _force(seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(T) * DT
    f = rng.uniform(0.5, 6, 5)
    return sum(np.sin(2 * np.pi * fi * t + rng.uniform(0, 6)) for fi in f)


@eqx.filter_jit
def _regressors(model, rec, bank):
    return model.regressors(rec, bank)


def _lstsq_fit(model, rec, bank):
    regs = _regressors(model, rec, bank)
    N = np.asarray(bank.free_response(rec.dt, rec.n_samples))[:, :, 0]
    W = np.concatenate([np.asarray(regs.W[:, 0, :]), N], axis=1)
    th = np.linalg.lstsq(W, -np.asarray(regs.W0[:, 0]), rcond=None)[0][: len(model.names)]
    return {k: float(v) for k, v in model.physical(jnp.asarray(th)).items()}


BANK = lj.FilterBank.from_poles(np.full(3, -2 * np.pi * 40.0), unit_dc_gain=True)


def test_zero_phase_velocity_matches_derivative():
    t = np.arange(T) * DT
    x = 0.01 * np.sin(2 * np.pi * 2.0 * t)
    v = np.asarray(zero_phase_velocity(jnp.asarray(x), DT, 2 * np.pi * 100))
    ref = 0.01 * 2 * np.pi * 2.0 * np.cos(2 * np.pi * 2.0 * t)
    inner = slice(200, -200)  # ends: the backward pass starts from a held value
    # gain (ω²/(ω² + w²))³ = 1 − 1.2e-3 at w = 2π·2 Hz, ω = 2π·100 Hz; no phase error
    np.testing.assert_allclose(v[inner], ref[inner], atol=1.5e-3 * np.max(np.abs(ref)))


def test_spring_and_offset_recovered():
    a, b, k, x0, F0 = 15.0, 2.0, 40.0, 0.003, 0.4
    rhs = lambda t, y, F: [y[1], -a * y[1] + b * (F + F0 - k * (y[0] - x0))]
    F = _force(1)
    _, x = _sim(rhs, F)
    rec = lj.Record(x, F, DT)
    p = _lstsq_fit(lj.Augmented(lj.MassDamper(), [lj.Spring(), lj.Offset()]), rec, BANK)
    assert p["a"] == pytest.approx(a, rel=1e-3)
    assert p["b"] == pytest.approx(b, rel=1e-3)
    assert p["k"] == pytest.approx(k, rel=2e-3)
    assert p["F0"] == pytest.approx(F0 + k * x0, rel=2e-3)  # the constant F0 + k·x0


def test_linear_position_exact():
    a, b, a1, b1, xc, ell = 15.0, 2.0, 3.0, -0.3, 0.0, 0.01

    def rhs(t, y, F):
        xi = (y[0] - xc) / ell
        return [y[1], -(a + a1 * xi) * y[1] + (b + b1 * xi) * F]

    F = 3 * _force(2)
    _, x = _sim(rhs, F)
    rec = lj.Record(x, F, DT)
    p = _lstsq_fit(lj.Augmented(lj.MassDamper(), [lj.LinearPosition(xc, ell)]), rec, BANK)
    # exact in a₁ (ξẋ = d/dt ℓξ²/2); ξ·F is held per sample (O(dt) error): 1 % / 5 %
    assert p["a"] == pytest.approx(a, rel=1e-2)
    assert p["b"] == pytest.approx(b, rel=1e-2)
    assert p["da_dx"] == pytest.approx(a1 / ell, rel=5e-2)
    assert p["db_dx"] == pytest.approx(b1 / ell, rel=5e-2)


def test_coulomb_recovered_smooth_friction():
    a, b, Fc, eps = 15.0, 2.0, 0.5, 2e-3  # a smooth (tanh) friction, so solve_ivp is exact
    rhs = lambda t, y, F: [y[1], -a * y[1] + b * (F - Fc * np.tanh(y[1] / eps))]
    F = 3 * _force(3)
    _, x = _sim(rhs, F)
    rec = lj.Record(x, F, DT)
    p = _lstsq_fit(lj.Augmented(lj.MassDamper(), [lj.Coulomb(2 * np.pi * 100, eps)]), rec, BANK)
    assert p["Fc"] == pytest.approx(Fc, rel=0.03)
    assert p["a"] == pytest.approx(a, rel=0.02)


def test_bad_arguments():
    with pytest.raises(lj.InputError, match="omega"):
        lj.Coulomb(-1.0, 1e-3)
    with pytest.raises(lj.InputError, match="scale"):
        lj.LinearPosition(0.0, 0.0)
