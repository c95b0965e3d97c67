"""lionjax.studies.tune: gradients vs central finite differences; the tuned point vs the grid optimum of
the same objective; the map of lj.study is the same function; the tuned settings vs lj.lion."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lionjax as lj
from lionjax import twin
from lionjax.studies import _tune

# the slow tier (.ci/run's second step): gradient tuning (its compile alone takes 15 s)
pytestmark = pytest.mark.slow

# a 6 × 5 grid over (AutoGain rate g [1/s], triple filter pole p [rad/s]), log-spaced
GAINS = np.geomspace(2.0, 200.0, 6)
POLES = np.geomspace(8.0, 128.0, 5)
Z_FD = np.log([8.0, 30.0])  # where the gradient is checked
H_FD = 1e-4  # central-difference step in log g, log p


@pytest.fixture(scope="module")
def records():
    # the paper's device (eq. 13) around x = 0 (region 2), the paper's input 4, Falcon encoder
    # quantisation and 0.01 N force noise: two 3-s records (noise seeds 1, 2)
    plant = twin.FALCON_PAPER.with_effects(twin.EncoderQuantisation())
    return lj.studies.study_records(noise_seeds=[1, 2], plant=plant, n_samples=3000)


@pytest.fixture(scope="module")
def objective_values(records):
    """J on the grid and at the four finite-difference points, in one batched call."""
    G, P = np.meshgrid(GAINS, POLES, indexing="ij")
    steps = np.array([[H_FD, 0.0], [-H_FD, 0.0], [0.0, H_FD], [0.0, -H_FD]])
    zs = Z_FD + steps
    g = np.concatenate([G.ravel(), np.exp(zs[:, 0])])
    p = np.concatenate([P.ravel(), np.exp(zs[:, 1])])
    J = lj.studies.tune_objective(lj.MassDamper(), records, g, p)
    return J[: G.size].reshape(G.shape), J[G.size :]


def test_gradient_matches_central_differences(records, objective_values):
    setup, _ = _tune._prepare(
        lj.MassDamper(), records, lj.AutoGain, 3, True, None, None, lj.Execution(), "test"
    )
    grad = jax.jit(jax.grad(lambda z: _tune._objective(z, setup)[0]))(jnp.asarray(Z_FD))
    _, Jfd = objective_values
    fd = np.array([(Jfd[0] - Jfd[1]) / (2 * H_FD), (Jfd[2] - Jfd[3]) / (2 * H_FD)])
    # float64; central differences of step 1e-4 in log space: truncation ~1e-8 relative
    np.testing.assert_allclose(np.asarray(grad), fd, rtol=1e-5)
    assert np.all(np.abs(fd) > 1e-3)  # a real slope, not two zeros


def test_tune_lands_on_the_grid_optimum(records, objective_values):
    J, _ = objective_values
    i, j = np.unravel_index(np.argmin(J), J.shape)
    # an interior optimum, so "within one cell" is a real statement
    assert 0 < i < len(GAINS) - 1 and 0 < j < len(POLES) - 1
    dg = np.log(GAINS[1] / GAINS[0])
    dp = np.log(POLES[1] / POLES[0])
    # start at two far corners of the grid: low gain with a wide or a narrow filter
    for g0, p0 in [(GAINS[0], POLES[-1]), (GAINS[0], POLES[0])]:
        sol = lj.studies.tune(lj.MassDamper(), records, init_gain=g0, init_pole=p0)
        assert sol.success and sol.n_steps < 64
        assert abs(np.log(sol.gain / GAINS[i])) <= dg, (g0, p0, sol.gain)
        assert abs(np.log(sol.pole / POLES[j])) <= dp, (g0, p0, sol.pole)
        # at least as good as the best grid cell (up to 0.01 s)
        assert sol.objective <= J[i, j] + 0.01
        assert np.all(np.abs(sol.gradient) < 0.05)
    # J at the answer, recomputed by the grid function
    Jt = lj.studies.tune_objective(lj.MassDamper(), records, [sol.gain] * 2, [sol.pole] * 2)
    np.testing.assert_allclose(Jt, sol.objective, rtol=1e-10)
    # the tuned settings, run by the reference estimator on each record
    for r, rec in enumerate(records):
        ref = lj.lion(
            lj.MassDamper(),
            rec,
            bank=sol.bank,
            gain=sol.gain_strategy,
            stepper=lj.ExactStep(),
            transient=sol.spec.transient,
        )
        np.testing.assert_allclose(sol.theta[r], np.asarray(ref.theta[-1]), rtol=1e-9)
        assert sol.convergence_time[r] < 1.0
    d = sol.to_dict()
    assert d["records"][1]["label"] == "noise_seed=2" and d["kappa"] == 1.0


# the grid's fastest poles (128 rad/s at 1 kHz: max|pole|·dt = 0.128) are warned as biased
@pytest.mark.filterwarnings("ignore::lionjax.solutions.FilterSpeedWarning")
def test_study_map_is_the_tuned_function(records, objective_values):
    J, _ = objective_values
    obj = lj.studies.TuneObjective()
    res = lj.study(
        lj.MassDamper(),
        records,
        gains=GAINS,
        gain=lj.AutoGain,
        poles=[(-p, -p, -p) for p in POLES],
        tolerance=obj.tolerance,
        softness=obj.softness,
        transient=obj.transient,
        progress=False,
    )
    assert res.dims == ("noise_seed", "gain", "poles")
    np.testing.assert_allclose(obj.on_study(res), J, rtol=1e-9)
    with pytest.raises(lj.InputError, match="softness"):
        lj.studies.TuneObjective(softness=0.25).on_study(res)


def test_tune_bad_input(records):
    with pytest.raises(lj.InputError, match="init_gain"):
        lj.studies.tune(lj.MassDamper(), records, init_gain=-1.0)
    with pytest.raises(lj.InputError, match="gain_type"):
        lj.studies.tune(lj.MassDamper(), records, gain_type="adaptive")
    with pytest.raises(lj.InputError, match=r"gain=lionjax\.FixedGain"):
        lj.studies.tune(lj.MassDamper(), records, gain_type="fixed")
    with pytest.raises(lj.InputError, match="Module class"):
        lj.studies.tune(lj.MassDamper(), records, gain="auto")
    with pytest.raises(lj.InputError, match="solver"):
        lj.studies.tune(lj.MassDamper(), records, solver="bfgs")
    with pytest.raises(lj.InputError, match="transient"):
        lj.studies.tune(lj.MassDamper(), records, objective=lj.studies.TuneObjective(transient=2.9))
    with pytest.raises(lj.InputError, match="kappa"):
        lj.studies.TuneObjective(kappa=-1.0)
    with pytest.raises(lj.InputError, match="broadcast"):
        lj.studies.tune_objective(lj.MassDamper(), records, [1.0, 2.0], [3.0, 4.0, 5.0])
