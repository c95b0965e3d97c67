"""The package's one linear least-squares solve against numpy.linalg.lstsq."""

import jax.numpy as jnp
import numpy as np
import pytest

import lionjax as lj
from lionjax import twin as tw
from lionjax.extend import gram_lstsq


def test_linear_lstsq_matches_numpy():
    rng = np.random.default_rng(0)
    Phi = rng.normal(size=(500, 4)) * np.array([1e-3, 1.0, 1e3, 5.0])  # badly scaled columns
    y = rng.normal(size=500)
    fit = lj.linear_lstsq(jnp.asarray(Phi), jnp.asarray(y))
    ref = np.linalg.lstsq(Phi, -y, rcond=None)[0]
    np.testing.assert_allclose(np.asarray(fit.coef), ref, rtol=1e-10)
    r = Phi @ ref + y
    assert float(fit.rss) == pytest.approx(r @ r, rel=1e-12)
    np.testing.assert_allclose(np.asarray(fit.gram_inverse), np.linalg.inv(Phi.T @ Phi), rtol=1e-8)
    n = Phi / np.linalg.norm(Phi, axis=0)
    assert float(fit.condition) == pytest.approx(np.linalg.cond(n), rel=1e-10)


def test_gram_lstsq_matches_numpy_and_linear_lstsq():
    """The streamed path's solve (from ΦᵀΦ, Φᵀy, yᵀy) equals numpy's lstsq and linear_lstsq."""
    rng = np.random.default_rng(1)
    Phi = rng.normal(size=(800, 3)) * np.array([1e-2, 1.0, 1e2])
    y = Phi @ np.array([3.0, -1.0, 0.02]) + 0.1 * rng.normal(size=800)
    fit = gram_lstsq(jnp.asarray(Phi.T @ Phi), jnp.asarray(Phi.T @ y), jnp.asarray(y @ y), 800)
    ref = np.linalg.lstsq(Phi, -y, rcond=None)[0]
    np.testing.assert_allclose(np.asarray(fit.coef), ref, rtol=1e-9)
    r = Phi @ ref + y
    assert float(fit.rss) == pytest.approx(r @ r, rel=1e-8)
    np.testing.assert_allclose(np.asarray(fit.gram_inverse), np.linalg.inv(Phi.T @ Phi), rtol=1e-8)
    svd = lj.linear_lstsq(jnp.asarray(Phi), jnp.asarray(y))
    assert float(fit.condition) == pytest.approx(float(svd.condition), rel=1e-8)
    np.testing.assert_allclose(np.abs(fit.weakest), np.abs(svd.weakest), rtol=1e-8)


def test_gram_lstsq_flat_or_indefinite_has_infinite_condition():
    """A zero Gram (a flat record) or a rounding-negative one: condition inf, not NaN; the
    coefficients on the unexcited direction are the minimum-norm 0."""
    zero = gram_lstsq(jnp.zeros((2, 2)), jnp.zeros(2), jnp.asarray(0.0), 100)
    assert np.isinf(float(zero.condition))
    np.testing.assert_array_equal(np.asarray(zero.coef), 0.0)
    indefinite = jnp.asarray([[1.0, 1.0 + 1e-12], [1.0 + 1e-12, 1.0]])
    fit = gram_lstsq(indefinite, jnp.asarray([1.0, 1.0]), jnp.asarray(2.0), 100)
    assert np.isinf(float(fit.condition))
    assert np.all(np.isfinite(np.asarray(fit.coef)))


@pytest.fixture(scope="module")
def record():
    plant = tw.Plant(22.0, 1.916, (), [tw.PositionNoise(1e-6)])
    exc = tw.multisine(np.array([0.5, 1.3, 2.9, 5.1]), 1.0, key=__import__("jax").random.key(0))
    r = tw.simulate(plant, exc, dt=1e-3, n_samples=4000, key=__import__("jax").random.key(1))
    return lj.Record(r.x, r.F, r.dt)


@pytest.mark.parametrize("rows", [(0, 1), (0,)])
def test_least_squares_rows_match_numpy(record, rows):
    """θ_LS on the chosen equation errors (with the nuisance columns) equals numpy's lstsq."""
    bank = lj.default_bank()
    model = lj.MassDamper()
    sol = lj.least_squares(model, record, bank=bank, rows=rows)
    regs = model.regressors(record, bank)
    T = record.n_samples
    N = np.swapaxes(np.asarray(bank.free_response(record.dt, T))[:, :, :2], 1, 2)
    W = np.concatenate([np.asarray(regs.W), N], axis=-1)[:, list(rows), :]
    ref = np.linalg.lstsq(
        W.reshape(-1, W.shape[-1]), -np.asarray(regs.W0)[:, list(rows)].ravel(), rcond=None
    )[0][:2]
    np.testing.assert_allclose(np.asarray(sol.theta), ref, rtol=1e-8)
    np.testing.assert_allclose(np.asarray(sol.theta), [22.0, 1.916], rtol=2e-3)


def test_equation_error_at_the_answer_is_the_fit_residual(record):
    """ε₁ for θ fixed at the ε₁-only LS answer equals that fit's own residual (same record)."""
    bank = lj.default_bank()
    sol = lj.least_squares(lj.MassDamper(), record, bank=bank, rows=(0,))
    e = np.asarray(lj.extend.equation_error(lj.MassDamper(), record, sol.theta, bank=bank))
    assert e.shape == (record.n_samples, 1)
    assert np.sqrt(np.mean(e**2)) == pytest.approx(float(sol.rms), rel=1e-8)


def test_rows_are_checked(record):
    with pytest.raises(lj.InputError, match="rows"):
        lj.least_squares(lj.MassDamper(), record, rows=(2,))
