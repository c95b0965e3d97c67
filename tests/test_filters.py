"""Filter bank: exact discretisation against scipy.signal.cont2discrete + dlsim."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal as ss

import lionjax as lj

DT = 1e-3


def _signal(T=3000, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(T) * DT
    u = np.sin(7 * t) + 0.3 * np.cos(31 * t) + 0.1 * rng.normal(size=T)
    u[0] = 0.0  # scipy's foh realisation starts from a shifted state; start both at rest
    return t, u


@pytest.mark.parametrize("hold", ["zoh", "foh"])
@pytest.mark.parametrize(
    "bank",
    [
        lj.FilterBank.paper(),
        lj.FilterBank.from_poles([-4.0, -6 + 2j, -6 - 2j], unit_dc_gain=True),
        lj.FilterBank.from_poles([-3.0, -5.0, -8.0, -20.0]),
    ],
)
def test_filter_matches_scipy(bank, hold):
    t, u = _signal()
    A, B, C, D = (np.asarray(m) for m in bank.state_space())
    Ad, Bd, Cd, Dd, _ = ss.cont2discrete((A, B[:, None], C, D[:, None]), DT, method=hold)
    _, ref, _ = ss.dlsim((Ad, Bd, Cd, Dd, DT), u, t=t)
    ours = np.asarray(bank(jnp.asarray(u), DT, hold, init="zero"))
    # float64: agreement to ~1e-10 of each output's range
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-10 * np.max(np.abs(ref)))


def test_outputs_are_successive_derivatives():
    # V_{j+1} = d/dt V_j: check with the continuous transfer functions via scipy.signal.lsim.
    bank = lj.FilterBank.paper()
    t = np.arange(4000) * DT
    u = np.sin(3 * t) * t
    out = np.asarray(bank(jnp.asarray(u), DT, "foh", init="zero"))
    for j in range(4):
        num = np.zeros(j + 1)
        num[0] = 1.0
        sys = ss.lti(num, np.concatenate([[1.0], np.asarray(bank.coeffs)]))
        _, y, _ = ss.lsim(sys, u, t, interp=True)
        np.testing.assert_allclose(out[:, j], y, atol=1e-7 * np.max(np.abs(y)))


def test_unit_dc_gain_and_steady_init():
    bank = lj.FilterBank.from_poles([-4.0, -4.0, -4.0], unit_dc_gain=True)
    u = jnp.full((500,), 2.5)
    out = bank(u, DT, "zoh")  # steady init: a constant signal is already settled
    np.testing.assert_allclose(out[:, 0], 2.5, rtol=1e-12)
    np.testing.assert_allclose(out[:, 1:], 0.0, atol=1e-12)


def test_from_poles_and_coefficients():
    bank = lj.FilterBank.from_poles([-4.0, -4.0, -4.0])
    np.testing.assert_allclose(bank.coeffs, [12.0, 48.0, 64.0])
    np.testing.assert_allclose(np.sort(np.real(np.asarray(bank.poles))), [-4, -4, -4], atol=1e-4)


def test_free_response_is_zero_input_response():
    bank = lj.FilterBank.paper()
    N = np.asarray(bank.free_response(DT, 200))
    Phi, _, _ = (np.asarray(m) for m in bank.discretise(DT))
    C = np.asarray(bank.state_space()[2])
    z = np.array([0.3, -1.0, 2.0])
    direct = np.stack([C @ np.linalg.matrix_power(Phi, k) @ z for k in range(200)])
    np.testing.assert_allclose(np.einsum("tij,i->tj", N, z), direct, atol=1e-12)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: lj.FilterBank([12.0, 48.0, -64.0]), "Hurwitz"),
        (lambda: lj.FilterBank([1.0, 1.0, 5.0]), "Hurwitz"),  # λ₁λ₂ < λ₃
        (lambda: lj.FilterBank([1.0, 2.0]), "n ≥ 3"),
        (lambda: lj.FilterBank.from_poles([-4.0, 1.0, -4.0]), "negative real part"),
        (lambda: lj.FilterBank.from_poles([-4.0, -1 + 1j, -4.0]), "conjugate pairs"),
        (lambda: lj.FilterBank([12.0, np.nan, 64.0]), "finite"),
    ],
)
def test_bad_filter(make, match):
    with pytest.raises(lj.InputError, match=match):
        make()


def test_bad_hold():
    with pytest.raises(lj.InputError, match="'zoh'.*'foh'"):
        lj.FilterBank.paper()(jnp.zeros(10), DT, "linear")


def test_filter_vmap_and_jit():
    bank = lj.FilterBank.paper()
    us = jnp.asarray(np.stack([_signal(seed=s)[1] for s in range(3)]))
    batched = jax.vmap(lambda u: bank(u, DT, "foh"))(us)
    jitted = jax.jit(lambda u: bank(u, DT, "foh"))
    for i in range(3):
        np.testing.assert_allclose(batched[i], bank(us[i], DT, "foh"), rtol=1e-13, atol=1e-16)
        np.testing.assert_allclose(jitted(us[i]), bank(us[i], DT, "foh"), rtol=1e-13, atol=1e-16)


@pytest.mark.parametrize("hold", ["zoh", "foh"])
@pytest.mark.parametrize(
    ("pole", "dt"), [(-2 * np.pi * 80, 5e-4), (-2 * np.pi * 400, 1e-4), (-2 * np.pi * 1000, 1e-4)]
)
def test_fast_poles_stay_finite_and_match_scipy(pole, dt, hold):
    """Fast filters at high sample rates (the diagnosis' corner f_s/25 at 2–10 kHz): the raw
    companion matrix made jax's expm return NaN; the balanced discretisation matches scipy's
    cont2discrete to ~1e-10 of each output's range."""
    bank = lj.FilterBank.from_poles([pole] * 3, unit_dc_gain=True)
    T = 4000
    t = np.arange(T) * dt
    u = np.sin(2 * np.pi * 7 * t) + 0.3 * np.cos(2 * np.pi * 45 * t)
    u[0] = 0.0
    A, B, C, D = (np.asarray(m) for m in bank.state_space())
    Ad, Bd, Cd, Dd, _ = ss.cont2discrete((A, B[:, None], C, D[:, None]), dt, method=hold)
    _, ref, _ = ss.dlsim((Ad, Bd, Cd, Dd, dt), u, t=t)
    ours = np.asarray(bank(jnp.asarray(u), dt, hold, init="zero"))
    assert np.all(np.isfinite(ours))
    err = np.max(np.abs(ours - ref), axis=0) / np.max(np.abs(ref), axis=0)
    assert np.all(err < 1e-9), err


def test_elementwise_expm_against_scipy():
    """lionjax._linalg.expm (scaling and squaring, Taylor order 18, elementwise products: what
    FilterBank.discretise uses) against scipy.linalg.expm (Padé, an independent reference), from
    ‖M‖ ~ 1e-8 to the squaring regime, float64 and float32, vmapped under jit."""
    from scipy.linalg import expm as scipy_expm

    from lionjax._linalg import expm

    rng = np.random.default_rng(7)
    scales = [0.0, 1e-8, 1e-3, 0.1, 1.0, 5.0, 30.0]
    M = np.stack([s * rng.normal(size=(5, 5)) for s in scales for _ in range(4)])
    ref = np.stack([scipy_expm(m) for m in M])
    got = np.asarray(jax.jit(jax.vmap(expm))(jnp.asarray(M)))
    # relative to the largest entry: e^M's own conditioning grows with ‖M‖ (measured ≤ 1e-13 here)
    err = np.max(np.abs(got - ref), axis=(1, 2)) / np.max(np.abs(ref), axis=(1, 2))
    assert np.all(err < 1e-12), err
    got32 = np.asarray(jax.jit(jax.vmap(expm))(jnp.asarray(M[:20], jnp.float32)))
    assert got32.dtype == np.float32
    err32 = np.max(np.abs(got32 - ref[:20]), axis=(1, 2)) / np.max(np.abs(ref[:20]), axis=(1, 2))
    assert np.all(err32 < 1e-5), err32
