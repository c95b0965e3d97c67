"""Least squares and Lion's estimator on records from an independent simulator.

Reference simulator: tests/_reference_sim.py (closed form per held-force interval, brentq for
region crossings) — it shares no code with lionjax.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _reference_sim import PAPER_A, PAPER_B, multisine, simulate

import lionjax as lj

DT = 1e-3
TRUTH6 = np.array([v for pair in zip(PAPER_A, PAPER_B, strict=True) for v in pair])
AB = np.array([22.0, 1.916])


def single_region_record(T=30000, noise=(0.0, 0.0), seed=0, amps=(0.2, 0.15, 0.1, 0.1)):
    t = np.arange(T) * DT
    F = multisine(t, [0.7, 2.3, 5.1, 9.7][: len(amps)], list(amps))
    x = simulate(F, DT, a=(22.0,), b=(1.916,), bounds=())
    rng = np.random.default_rng(seed)
    return lj.Record(x + noise[0] * rng.normal(size=T), F + noise[1] * rng.normal(size=T), DT)


def crossing_record(T=30000):
    t = np.arange(T) * DT
    F = multisine(t, [0.5, 1.7, 3.9], [1.0, 0.4, 0.3], [np.pi / 2, 1.0, 2.0])
    return lj.Record(simulate(F, DT), F, DT)


@pytest.fixture(scope="module")
def single():
    return single_region_record()


@pytest.fixture(scope="module")
def crossing():
    rec = crossing_record()
    x = np.asarray(rec.x)
    assert x.min() < -0.012 and x.max() > 0.012, "record must visit all three regions"
    return rec


# ---------------------------------------------------------------------------------------------
# Least squares


def test_ls_single_region_within_0p1_percent(single):
    sol = lj.least_squares(lj.MassDamper(), single)
    err = np.abs(np.asarray(sol.theta) - AB) / AB
    assert np.all(err < 1e-3), err  # acceptance: 0.1 %; measured ~4e-6
    assert np.all(err < 1e-5), err  # and in fact near the discretisation floor


def test_ls_three_regions_within_1_percent(crossing):
    sol = lj.least_squares(lj.Piecewise((-0.01, 0.01)), crossing)
    assert sol.names == ("a_1", "b_1", "a_2", "b_2", "a_3", "b_3")
    err = np.abs(np.asarray(sol.theta) - TRUTH6) / TRUTH6
    assert np.all(err < 1e-2), err  # acceptance: 1 %; measured ~6e-6
    assert np.all(err < 1e-4), err


def _numpy_reference(model, rec, bank):
    regs = model.regressors(rec, bank)
    W = np.asarray(regs.W)
    N = np.swapaxes(np.asarray(bank.free_response(rec.dt, rec.n_samples))[:, :, :2], 1, 2)
    Phi = np.concatenate([W, N], axis=-1).reshape(-1, W.shape[-1] + N.shape[-1])
    y = np.asarray(regs.W0).reshape(-1)
    return np.linalg.lstsq(Phi, -y, rcond=None)[0][: W.shape[-1]]


@pytest.mark.parametrize("which", ["single", "crossing"])
def test_ls_matches_numpy_lstsq(which, single, crossing):
    rec = single_region_record(noise=(1e-5, 0.05), T=8000) if which == "single" else crossing
    model = lj.MassDamper() if which == "single" else lj.Piecewise((-0.01, 0.01))
    bank = lj.default_bank()
    sol = lj.least_squares(model, rec, bank=bank)
    ref = _numpy_reference(model, rec, bank)
    np.testing.assert_allclose(sol.theta, ref, rtol=1e-8)


def test_ls_discard_mode_matches_numpy_lstsq_on_masked_rows():
    rec = single_region_record(noise=(1e-5, 0.05), T=8000)
    bank = lj.FilterBank.paper()
    sol = lj.least_squares(lj.MassDamper(), rec, bank=bank, initial="discard", transient=1.5)
    regs = lj.MassDamper().regressors(rec, bank)
    k = int(np.ceil(1.5 / DT - 1e-9))
    Phi = np.asarray(regs.W)[k:].reshape(-1, 2)
    ref = np.linalg.lstsq(Phi, -np.asarray(regs.W0)[k:].reshape(-1), rcond=None)[0]
    np.testing.assert_allclose(sol.theta, ref, rtol=1e-8)
    assert int(sol.n_used) == 8000 - k


def test_ls_covariance_matches_closed_form():
    rec = single_region_record(noise=(1e-5, 0.05), T=8000)
    bank = lj.default_bank()
    sol = lj.least_squares(lj.MassDamper(), rec, bank=bank, initial="discard")
    # the samples after the transient: the last n_used of the record
    w = np.arange(rec.n_samples) >= rec.n_samples - int(sol.n_used)
    regs = lj.MassDamper().regressors(rec, bank)
    Phi = np.asarray(regs.W)[w].reshape(-1, 2)
    y = np.asarray(regs.W0)[w].reshape(-1)
    th = np.linalg.lstsq(Phi, -y, rcond=None)[0]
    r = Phi @ th + y
    cov = (r @ r) / (Phi.shape[0] - 2) * np.linalg.inv(Phi.T @ Phi)
    np.testing.assert_allclose(sol.covariance, cov, rtol=1e-6)
    cn = Phi / np.linalg.norm(Phi, axis=0)
    np.testing.assert_allclose(sol.condition, np.linalg.cond(cn), rtol=1e-8)


def test_ls_unexcited_region_raises_naming_parameters(single):
    # The single-region record never visits x < -10 mm or x > 10 mm.
    with pytest.raises(lj.IdentificationError, match=r"does not excite.*\n.*a_1|b_1|a_3|b_3"):
        lj.least_squares(lj.Piecewise((-0.01, 0.01)), single)
    sol = lj.least_squares(lj.Piecewise((-0.01, 0.01)), single, throw=False)
    assert sol.result == lj.RESULTS.unidentifiable


def test_ls_no_excitation_raises():
    rec = lj.Record(np.zeros(3000), np.zeros(3000), DT)
    with pytest.raises(lj.IdentificationError, match="does not excite"):
        lj.least_squares(lj.MassDamper(), rec)


# ---------------------------------------------------------------------------------------------
# Lion's estimator


def test_lion_default_converges_within_1_percent(single):
    sol = lj.lion(lj.MassDamper(), single, save_every=500)
    assert sol.t[-1] <= 30.0
    err = np.abs(np.asarray(sol.theta_final) - AB) / AB
    assert np.all(err < 1e-2), err  # acceptance 1 %; measured ~5e-7
    # the trajectory keeps the first and last samples
    np.testing.assert_allclose(sol.theta[0], 0.0)
    np.testing.assert_allclose(sol.theta[-1], sol.theta_final)


def test_lion_paper_settings_run():
    # The paper's settings (λ = (12, 48, 64), G = 1e4·I, θ₀ = 0) in SI units: they run, stay
    # finite and move towards the truth — slowly (docs/method.md, "Lion's law").
    rec = single_region_record(T=10000)
    sol = lj.lion(lj.MassDamper(), rec, bank=lj.FilterBank.paper(), gain=lj.FixedGain(1e4))
    th = np.asarray(sol.theta)
    assert np.all(np.isfinite(th))
    assert np.all(th[-1] > 0) and np.all(th[-1] < AB)


def test_lion_end_point_equals_ls_noise_free(single):
    ls = lj.least_squares(lj.MassDamper(), single)
    li = lj.lion(lj.MassDamper(), single)
    np.testing.assert_allclose(li.theta_final, ls.theta, rtol=1e-5)  # measured ~5e-7


def test_lion_end_point_near_ls_with_noise():
    rec = single_region_record(noise=(2e-6, 0.01), seed=3)
    ls = lj.least_squares(lj.MassDamper(), rec)
    li = lj.lion(lj.MassDamper(), rec)
    np.testing.assert_allclose(li.theta_final, ls.theta, rtol=1e-2)  # measured ~2e-3


@pytest.mark.slow  # eager or ODE reference runs
def test_exact_step_matches_diffrax():
    rec = single_region_record(T=2500)
    kw = dict(gain=lj.AutoGain(5.0), save_every=10)
    exact = lj.lion(lj.MassDamper(), rec, **kw)
    ode = lj.lion(lj.MassDamper(), rec, stepper=lj.DiffraxStep(), **kw)
    # Midpoint-frozen regressors are second order in dt: measured max deviation ~5e-5·|θ|.
    dev = np.max(np.abs(np.asarray(exact.theta - ode.theta)) / AB)
    assert dev < 2e-4, dev
    # the causal (zoh) freeze is only first order: visibly worse, which shows the test can fail
    zoh = lj.lion(lj.MassDamper(), rec, stepper=lj.ExactStep("zoh"), **kw)
    assert np.max(np.abs(np.asarray(zoh.theta - ode.theta))) > 5 * np.max(
        np.abs(np.asarray(exact.theta - ode.theta))
    )


@pytest.mark.slow  # eager or ODE reference runs
def test_exact_step_matches_diffrax_piecewise_fixed_gain(crossing):
    rec = lj.Record(crossing.x[:2400], crossing.F[:2400], DT)
    kw = dict(bank=lj.FilterBank.paper(), gain=lj.FixedGain(1e4), save_every=20)
    exact = lj.lion(lj.Piecewise((-0.01, 0.01)), rec, **kw)
    ode = lj.lion(lj.Piecewise((-0.01, 0.01)), rec, stepper=lj.DiffraxStep(), **kw)
    scale = np.max(np.abs(np.asarray(ode.theta)), axis=0) + 1e-12
    assert np.max(np.abs(np.asarray(exact.theta - ode.theta)) / scale) < 1e-3


@pytest.mark.parametrize("g", [1e6, 1e9, 1e12])
def test_exact_step_stable_for_huge_gain_where_euler_diverges(g):
    # Consistent record (starts at rest with F(0) = 0) so the instantaneous solve is exact.
    rec = single_region_record(T=4000)
    exact = lj.lion(lj.MassDamper(), rec, gain=lj.FixedGain(g))
    assert np.all(np.isfinite(np.asarray(exact.theta)))
    np.testing.assert_allclose(exact.theta_final, AB, rtol=1e-4)
    euler = lj.lion(lj.MassDamper(), rec, gain=lj.FixedGain(g), stepper=lj.EulerStep(), throw=False)
    assert euler.result == lj.RESULTS.unstable_step
    assert not np.all(np.isfinite(np.asarray(euler.theta))) or np.max(
        np.abs(np.asarray(euler.theta))
    ) > 1e3 * np.max(AB)
    with pytest.raises(lj.IdentificationError, match="Euler is unstable"):
        lj.lion(lj.MassDamper(), rec, gain=lj.FixedGain(g), stepper=lj.EulerStep())


def test_euler_agrees_with_exact_for_small_gain():
    rec = single_region_record(T=3000)
    kw = dict(gain=lj.AutoGain(2.0))
    a = lj.lion(lj.MassDamper(), rec, stepper=lj.ExactStep("zoh"), **kw)
    b = lj.lion(lj.MassDamper(), rec, stepper=lj.EulerStep(), **kw)
    dev = np.max(np.abs(np.asarray(a.theta - b.theta)) / AB)
    assert dev < 1e-3, dev


def test_phi_closed_form_against_series_and_scipy():
    from scipy.linalg import expm

    from lionjax.extend import phi_sym2

    rng = np.random.default_rng(1)
    for scale in [1e-10, 1e-4, 0.3, 1.0, 10.0, 1e6, 1e12]:
        A = rng.normal(size=(2, 3))
        Z = scale * A @ A.T
        if scale < 1:
            ref, P, f = np.zeros((2, 2)), np.eye(2), 1.0
            for n in range(40):
                f *= n + 1
                ref += (-1) ** n * P / f
                P = P @ Z
        else:
            ref = (np.eye(2) - expm(-Z)) @ np.linalg.inv(Z)
        zp, zq, zr = phi_sym2(Z[0, 0], Z[0, 1], Z[1, 1])
        got = np.array([[zp, zq], [zq, zr]])
        np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12 * np.max(np.abs(ref)))
    # degenerate S (W = 0, equal eigenvalues): finite values and gradients
    g = jax.grad(lambda a: sum(phi_sym2(a, 0.0 * a, a)))(0.0)
    assert np.isfinite(g) and abs(g + 1.0) < 1e-12  # d/da of 2·E(a) at 0 = 2·(−1/2)


def test_normalised_law_converges():
    rec = single_region_record()
    sol = lj.lion(lj.MassDamper(), rec, normalisation=1.0)
    np.testing.assert_allclose(sol.theta_final, AB, rtol=1e-2)


# ---------------------------------------------------------------------------------------------
# Transformations: jit, vmap, grad


# the fast filter keeps the 40-sample record longer than the transient; its bias (|p|·dt = 0.24,
# lionjax._validity) does not matter for jit == no jit
@pytest.mark.slow  # eager or ODE reference runs
@pytest.mark.filterwarnings("ignore::lionjax.solutions.FilterSpeedWarning")
def test_jit_equals_no_jit(single):
    # disable_jit runs every op eagerly (slow): keep the records short.
    rec = lj.Record(single.x[1000:1040], single.F[1000:1040], DT)
    fast = lj.FilterBank.from_poles([-240.0, -240.0, -240.0], unit_dc_gain=True)
    kw = dict(save_every=3, transient=0.005, gain=lj.AutoGain(50.0), bank=fast)
    jitted = lj.lion(lj.MassDamper(), rec, **kw)
    with jax.disable_jit():
        plain = lj.lion(lj.MassDamper(), rec, **kw)
    assert np.max(np.abs(np.asarray(jitted.theta[-1]))) > 0.1  # it moved
    np.testing.assert_allclose(jitted.theta, plain.theta, rtol=1e-10, atol=1e-12)
    ls_j = lj.least_squares(lj.MassDamper(), rec, bank=fast)
    with jax.disable_jit():
        ls_p = lj.least_squares(lj.MassDamper(), rec, bank=fast)
    np.testing.assert_allclose(ls_j.theta, ls_p.theta, rtol=1e-10)


def test_vmap_equals_loop():
    recs = [single_region_record(T=3000, noise=(1e-6, 0.01), seed=s) for s in range(3)]
    batch = jax.tree.map(lambda *a: jnp.stack(a), *recs)
    gains = jnp.array([0.5, 1.0, 2.0])
    f = lambda r, g: lj.lion(lj.MassDamper(), r, gain=lj.AutoGain(g), save_every=50, throw=False)
    out = jax.vmap(f)(batch, gains)
    lsb = jax.vmap(lambda r: lj.least_squares(lj.MassDamper(), r, throw=False))(batch)
    lj.raise_if_failed(out)
    for i, r in enumerate(recs):
        one = f(r, gains[i])
        np.testing.assert_allclose(out.theta[i], one.theta, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(
            lsb.theta[i], lj.least_squares(lj.MassDamper(), r).theta, rtol=1e-10
        )


def test_batched_failure_names_the_element():
    good = single_region_record(T=3000)
    bad = lj.Record(jnp.zeros(3000), jnp.zeros(3000), DT)
    batch = jax.tree.map(lambda *a: jnp.stack(a), good, bad, good)
    sols = jax.vmap(lambda r: lj.least_squares(lj.MassDamper(), r, throw=False))(batch)
    with pytest.raises(lj.IdentificationError, match=r"1 of 3.*\n.*batch element \(1,\)"):
        lj.raise_if_failed(sols)


@pytest.mark.slow  # eager or ODE reference runs
def test_grad_matches_finite_differences():
    rec = single_region_record(T=3000, noise=(1e-6, 0.01))
    x0 = jnp.asarray(rec.x)

    def final(x, log_rate, poles):
        r = lj.Record(x, rec.F, DT)
        bank = lj.FilterBank.from_poles(poles, unit_dc_gain=True)
        sol = lj.lion(
            lj.MassDamper(),
            r,
            bank=bank,
            gain=lj.AutoGain(jnp.exp(log_rate)),
            transient=1.0,
            throw=False,
        )
        return sol.theta_final[0] + 3.0 * sol.theta_final[1]

    poles = jnp.array([-4.0, -5.0, -6.0])
    g = jax.grad(final, argnums=(0, 1, 2))(x0, 0.0, poles)
    rng = np.random.default_rng(0)
    v = jnp.asarray(rng.normal(size=x0.shape)) * 1e-6
    fd_x = (final(x0 + v, 0.0, poles) - final(x0 - v, 0.0, poles)) / 2
    np.testing.assert_allclose(jnp.dot(g[0], v), fd_x, rtol=1e-4)
    e = 1e-5
    fd_g = (final(x0, e, poles) - final(x0, -e, poles)) / (2 * e)
    np.testing.assert_allclose(g[1], fd_g, rtol=1e-4)
    for i in range(3):
        dp = jnp.zeros(3).at[i].set(e)
        fd_p = (final(x0, 0.0, poles + dp) - final(x0, 0.0, poles - dp)) / (2 * e)
        np.testing.assert_allclose(g[2][i], fd_p, rtol=1e-3, atol=1e-7)


def test_grad_of_ls_matches_finite_differences():
    rec = single_region_record(T=3000, noise=(1e-6, 0.01))

    def f(F):
        return lj.least_squares(lj.MassDamper(), lj.Record(rec.x, F, DT), throw=False).theta[1]

    F0 = jnp.asarray(rec.F)
    g = jax.grad(f)(F0)
    v = jnp.asarray(np.random.default_rng(1).normal(size=F0.shape)) * 1e-4
    np.testing.assert_allclose(jnp.dot(g, v), (f(F0 + v) - f(F0 - v)) / 2, rtol=1e-4)


# ---------------------------------------------------------------------------------------------
# Bad input


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: lj.FixedGain(np.array([[1.0, 2.0], [0.0, 1.0]])), "symmetric"),
        (lambda: lj.FixedGain(np.array([[1.0, 0.0], [0.0, -1.0]])), "positive definite"),
        (lambda: lj.FixedGain(-3.0), "positive"),
        (lambda: lj.FixedGain(np.ones((2, 3))), "square"),
        (lambda: lj.Piecewise((0.01, -0.01)), "strictly increasing"),
        (lambda: lj.Piecewise(()), "non-empty"),
        (lambda: lj.MassDamper(x_hold="cubic"), "x_hold"),
        (lambda: lj.Record(np.zeros(10), np.zeros(11), DT), "same shape"),
        (lambda: lj.ExactStep("linear"), "midpoint"),
    ],
)
def test_bad_arguments(make, match):
    with pytest.raises(lj.InputError, match=match):
        make()


def test_bad_call_arguments():
    rec = single_region_record(T=3000)
    with pytest.raises(lj.InputError, match=r"theta0 must have shape \(2,\)"):
        lj.lion(lj.MassDamper(), rec, theta0=np.zeros(3))
    with pytest.raises(lj.InputError, match="G has shape"):
        lj.lion(lj.MassDamper(), rec, gain=lj.FixedGain(np.eye(3)))
    with pytest.raises(lj.InputError, match="save_every"):
        lj.lion(lj.MassDamper(), rec, save_every=0)
    with pytest.raises(lj.InputError, match="initial must be"):
        lj.least_squares(lj.MassDamper(), rec, initial="guess")
    with pytest.raises(lj.InputError, match="shorter than the filter transient"):
        lj.least_squares(lj.MassDamper(), lj.Record(rec.x[:500], rec.F[:500], DT))
    with pytest.raises(lj.InputError, match="shorter than the filter transient"):
        lj.lion(lj.MassDamper(), lj.Record(rec.x[:500], rec.F[:500], DT))
    with pytest.raises(lj.InputError, match="record must be"):
        lj.lion(lj.MassDamper(), (rec.x, rec.F))
