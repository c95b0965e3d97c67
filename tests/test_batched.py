"""The fast batched estimator against the reference lionjax.lion / least_squares (float64)."""

import inspect

import jax
import numpy as np
import pytest
from _reference_sim import multisine, simulate

import lionjax as lj
from lionjax.extend import phi_sym2

DT = 1e-3
#: E(hS) by its series alone while tr(hS) ≤ 1/2 (lionjax.Execution, phi="series")
SERIES_BOUND = 0.5


def _records(n=4, T=3000):
    out = []
    for i in range(n):
        t = np.arange(T) * DT
        F = multisine(t, [0.7, 2.3, 5.1], [0.2 + 0.05 * i, 0.15, 0.1])
        x = simulate(F, DT, a=(22.0,), b=(1.916,), bounds=())
        out.append(lj.Record(x, F, DT))
    return out


@pytest.fixture(scope="module")
def recs():
    return _records()


@pytest.mark.parametrize("scale", [0.0, 1e-8, 1e-3, 0.5, 0.99, 1.01, 3.0, 40.0, 1e4])
def test_phi_sym2_against_scipy_expm(scale):
    """E(Z) = (I − e^{−Z})Z⁻¹ against scipy's expm (an independent reference), both branches,
    degenerate eigenvalues included; the short series of the hot path below its bound too."""
    from scipy.linalg import expm

    from lionjax._phi import _phi_series

    rng = np.random.default_rng(1)
    A = rng.normal(size=(60, 2, 2))
    Z = scale * A @ np.swapaxes(A, 1, 2) / 2
    Z[:5] = scale * np.eye(2)  # degenerate eigenvalues
    got = np.stack(phi_sym2(Z[:, 0, 0], Z[:, 0, 1], Z[:, 1, 1]), -1)
    ref = []
    for z in Z:
        if np.abs(z).max() == 0:
            ref.append([1.0, 0.0, 1.0])
            continue
        # (I − e^{−Z})Z⁻¹ = ∫₀¹ e^{−sZ} ds: the top-right block of expm([[−Z, I], [0, 0]])
        M = np.zeros((4, 4))
        M[:2, :2], M[:2, 2:] = -z, np.eye(2)
        E = expm(M)[:2, 2:]
        ref.append([E[0, 0], E[0, 1], E[1, 1]])
    np.testing.assert_allclose(got, np.array(ref), rtol=1e-12, atol=1e-14)
    small = np.trace(Z, axis1=1, axis2=2) <= 0.5
    if small.any():
        fast = np.stack(_phi_series(Z[small, 0, 0], Z[small, 0, 1], Z[small, 1, 1], 14), -1)
        np.testing.assert_allclose(fast, np.array(ref)[small], rtol=1e-14, atol=1e-15)
        # float32's 8 terms: the truncation bound (1/2)⁸/9! = 1.1e-8 (at tr Z = SERIES_BOUND)
        f32 = np.stack(_phi_series(Z[small, 0, 0], Z[small, 0, 1], Z[small, 1, 1], 8), -1)
        np.testing.assert_allclose(f32, np.array(ref)[small], rtol=0, atol=1.1e-8)


@pytest.mark.slow  # eager and parametrised kernels
@pytest.mark.parametrize("unit_dc_gain", [True, False])
@pytest.mark.parametrize("dt", [1e-4, 1e-3, 2e-2])
def test_midpoint_basis_maps_equal_the_filter_maps(unit_dc_gain, dt):
    """The kernel's midpoint basis w = A z (_midpoint_basis) against the
    filter's own maps: the same next state (A·next(z) = next_w(Az)) and the same outputs at the
    start, midpoint and end, for random states and inputs, both holds, float64; the midpoint
    rows read w with exact coefficients (1 and −λ)."""
    from lionjax._kernel_core import _maps, _midpoint_basis

    bank = lj.FilterBank.from_poles([-3.0, -5.0, -40.0], unit_dc_gain=unit_dc_gain)
    rng = np.random.default_rng(3)
    z = rng.normal(size=(3, 5))
    u = rng.normal(size=(2, 5))
    for foh in (True, False):
        mz = _maps(bank, jax.numpy.asarray(dt), foh)
        mw, A = _midpoint_basis(mz, bank.coeffs[::-1])
        A = np.asarray(A)
        zu, wu = np.concatenate([z, u]), np.concatenate([A @ z, u])
        scale = lambda M: np.abs(np.asarray(M) @ zu).max()
        np.testing.assert_allclose(
            np.asarray(mw.next) @ wu, A @ (np.asarray(mz.next) @ zu), atol=1e-12 * scale(mz.next)
        )
        for mode in ("start", "mid", "end"):
            Mz, Mw = np.asarray(getattr(mz, mode)), np.asarray(getattr(mw, mode))
            np.testing.assert_allclose(Mw @ wu, Mz @ zu, atol=1e-12 * scale(Mz))
        mid = np.asarray(mw.mid)
        np.testing.assert_array_equal(mid[:3, :3], np.eye(3))
        np.testing.assert_array_equal(mid[3, :3], -np.asarray(bank.coeffs)[::-1])


def test_phi_sym2_gradient_finite_at_zero():
    g = jax.grad(lambda z: sum(phi_sym2(z, 0.0 * z, z)))(0.0)
    assert np.isfinite(g)


@pytest.mark.parametrize("g", [1e2, 1e6, 1e9])
def test_batched_equals_lion_fixed_gain(recs, g):
    batch, _ = lj.stack_records(recs)
    sol = lj.lion_batched(lj.MassDamper(), batch, gain=lj.FixedGain(g))
    for i, r in enumerate(recs):
        ref = lj.lion(lj.MassDamper(), r, gain=lj.FixedGain(g))
        np.testing.assert_allclose(sol.theta[i], ref.theta_final, rtol=1e-10)
        np.testing.assert_allclose(sol.J[i], ref.J[-1], rtol=1e-8, atol=1e-20)


def test_batched_autogain_ls_and_convergence(recs):
    batch, _ = lj.stack_records(recs)
    sol = lj.lion_batched(
        lj.MassDamper(),
        batch,
        gain=lj.AutoGain(3.0),
        outputs=(lj.LSStatistics(), lj.ConvergenceTime(), lj.Trajectory(100)),
    )
    for i, r in enumerate(recs):
        ref = lj.lion(lj.MassDamper(), r, gain=lj.AutoGain(3.0))
        np.testing.assert_allclose(sol.gain[i], ref.gain, rtol=1e-10)
        np.testing.assert_allclose(sol.theta[i], ref.theta_final, rtol=1e-10)
        ls = lj.least_squares(lj.MassDamper(), r, initial="discard")
        np.testing.assert_allclose(sol.theta_ls[i], ls.theta, rtol=1e-9)
        # convergence time from the stored trajectory of the reference
        th = np.asarray(ref.theta)
        out = np.any(np.abs(th - np.asarray(ls.theta)) > 0.02 * np.abs(np.asarray(ls.theta)), 1)
        last = np.flatnonzero(out)[-1]
        assert float(sol.t_converged[i]) == pytest.approx((last + 1) * DT, abs=1e-9)
        # one definition: the stored-trajectory convergence time of lj.lion agrees
        assert float(ref.convergence_time(ls.theta)) == pytest.approx(
            float(sol.t_converged[i]), abs=1e-9
        )
    assert sol.trajectory.shape == (29, len(recs), 2)
    np.testing.assert_allclose(sol.trajectory[-1, 0], ref_traj_at(recs[0], 2900), rtol=1e-10)


def ref_traj_at(rec, k):
    return lj.lion(lj.MassDamper(), rec, gain=lj.AutoGain(3.0)).theta[k]


@pytest.fixture(scope="module")
def masked(recs):
    """One run with every output on, AutoGain and a padded record (lengths): shared by the
    padding, statistics and split-loop tests (one compilation)."""
    batch, lengths = lj.stack_records(
        recs[:3] + [lj.Record(recs[3].x[:2500], recs[3].F[:2500], DT)]
    )
    outputs = (lj.LSStatistics(), lj.ConvergenceTime(), lj.TailStatistics(), lj.Trajectory(500))
    kw = dict(gain=lj.AutoGain(2.0), outputs=outputs, lengths=lengths)
    sol = lj.lion_batched(lj.MassDamper(), batch, execution=lj.Execution(split=1), **kw)
    return batch, lengths, kw, sol


def test_padding_contributes_nothing(recs, masked):
    """The padded record (2500 of 3000 samples) equals lj.lion / lj.least_squares on its own
    samples: its gain (from the masked statistics), θ and θ_LS."""
    *_, sol = masked
    short = lj.Record(recs[3].x[:2500], recs[3].F[:2500], DT)
    for i, r in ((0, recs[0]), (3, short)):
        ref = lj.lion(lj.MassDamper(), r, gain=lj.AutoGain(2.0))
        np.testing.assert_allclose(sol.gain[i], ref.gain, rtol=1e-10)
        np.testing.assert_allclose(sol.theta[i], ref.theta_final, rtol=1e-10)
        ls = lj.least_squares(lj.MassDamper(), r, initial="discard")
        np.testing.assert_allclose(sol.theta_ls[i], ls.theta, rtol=1e-9)


def test_least_squares_batched(recs, masked, monkeypatch):
    """The statistics pass alone: no gain is constructed; equals lion_batched's LSStatistics
    output and the per-record lj.least_squares(initial="discard"), padded record included."""
    batch, lengths, _, masked_sol = masked

    def no_gain(*args, **kwargs):
        raise AssertionError("least_squares_batched constructed a gain")

    with monkeypatch.context() as m:
        m.setattr(lj.FixedGain, "__init__", no_gain)
        m.setattr(lj.AutoGain, "__init__", no_gain)
        sol = lj.least_squares_batched(lj.MassDamper(), batch, lengths=lengths)
    stats = masked_sol.output(lj.LSStatistics)
    for name in ("theta", "covariance", "std", "condition", "rms", "n_used"):
        np.testing.assert_allclose(getattr(stats, name), getattr(sol, name), rtol=1e-12)
    short = lj.Record(recs[3].x[:2500], recs[3].F[:2500], DT)
    for i, r in enumerate(recs[:3] + [short]):
        ls = lj.least_squares(lj.MassDamper(), r, initial="discard")
        np.testing.assert_allclose(sol.theta[i], ls.theta, rtol=1e-9)
        # RSS = θᵀAθ + 2θᵀb + yᵀy cancels: a few 1e-4 relative on noise-free data
        np.testing.assert_allclose(sol.rms[i], ls.rms, rtol=1e-2)


@pytest.mark.slow  # several kernels compiled
def test_piecewise_and_normalised(recs):
    batch, _ = lj.stack_records(recs[:2])
    model = lj.Piecewise((-0.001, 0.001))
    G = lj.FixedGain(1e4)
    # the records never enter region 1 (x ≥ 0): both paths flag a_1, b_1 unidentified (issue 39,
    # case 3) and still agree on the trajectory
    kw = dict(gain=G, throw=False)
    sol = lj.lion_batched(model, batch, stepper=lj.ExactStep(normalisation=0.5), **kw)
    for i, r in enumerate(recs[:2]):
        ref = lj.lion(model, r, normalisation=0.5, **kw)
        np.testing.assert_allclose(sol.theta[i], ref.theta_final, rtol=1e-9, atol=1e-12)
        bad = lj.solutions.result_codes(lj.RESULTS.unidentifiable)
        assert lj.solutions.result_codes(sol.result)[i] == bad
        assert lj.solutions.result_codes(ref.result) == bad
        np.testing.assert_array_equal(sol.unexcited[i], ref.unexcited)


@pytest.mark.slow  # eager and parametrised kernels
def test_jit_equals_nojit(recs):
    """The kernel traced and compiled equals its ops run one by one (30 samples: eager is slow)."""
    batch, _ = lj.stack_records(recs)
    short = jax.tree.map(lambda v: v[:, :30] if v.ndim == 2 else v, batch)
    G = lj.FixedGain(1e3)
    with jax.disable_jit():
        b = lj.lion_batched(lj.MassDamper(), short, gain=G).theta
    c = lj.lion_batched(lj.MassDamper(), short, gain=G).theta
    assert np.max(np.abs(np.asarray(c))) > 0  # it moved
    np.testing.assert_allclose(b, c, rtol=1e-12)


def test_parallel_in_time_equals_sequential(recs):
    r = recs[0]
    ref = lj.lion(lj.MassDamper(), r, gain=lj.FixedGain(1e4))
    par = lj.lion_parallel(lj.MassDamper(), r, ref.gain)
    np.testing.assert_allclose(par.theta, ref.theta, rtol=1e-8, atol=1e-10)


def test_bad_input_errors(recs):
    with pytest.raises(lj.InputError, match="records must be a batch"):
        lj.lion_batched(lj.MassDamper(), recs[0])
    with pytest.raises(lj.InputError, match="stepper"):
        lj.lion_batched(lj.MassDamper(), lj.stack_records(recs)[0], stepper=lj.DiffraxStep())


def test_unexcited_reported_per_element(recs):
    """A flat record in the batch is reported unidentifiable; the others are not."""
    flat = lj.Record(np.zeros(3000), np.zeros(3000), DT)
    batch, _ = lj.stack_records([recs[0], flat, recs[2], recs[3]])
    # test_batched_autogain_ls_and_convergence's configuration (one compilation for both)
    outputs = (lj.LSStatistics(), lj.ConvergenceTime(), lj.Trajectory(100))
    sol = lj.lion_batched(
        lj.MassDamper(), batch, gain=lj.AutoGain(3.0), outputs=outputs, throw=False
    )
    codes = lj.solutions.result_codes(sol.result)
    assert codes[0] == 0 and codes[1] != 0 and codes[2] == 0 and codes[3] == 0
    with pytest.raises(lj.IdentificationError, match=r"batch element \(1,\)"):
        lj.raise_if_failed(sol)


@pytest.mark.slow  # several kernels compiled
def test_split_loops_equal_one_loop(masked):
    """The batch split into independent loops over its rows (how one CPU device uses every
    core) gives the same numbers as one loop, with LS, convergence and masks on."""
    batch, _, kw, one = masked
    three = lj.lion_batched(lj.MassDamper(), batch, execution=lj.Execution(split=3), **kw)
    for name in ("theta", "J", "theta_ls", "t_converged", "trajectory", "tail_mean"):
        np.testing.assert_allclose(getattr(three, name), getattr(one, name), rtol=1e-12, atol=0)


@pytest.mark.parametrize("n_small", [30, 2])
def test_fast_path_falls_back_per_record_where_the_series_bound_fails(recs, n_small):
    """Records whose tr(hS) exceeds the series bound are re-run with the closed form — gathered
    into a small batch (2 of 32 records beyond the bound) or the whole batch (2 of 4): the
    result equals Execution(phi="closed") and lj.lion for every record."""
    # the system is linear: scaled records are records too, with 0.09× the regressors' W²
    scales = [1.0, 1.0] + [0.3] * n_small
    recs = [lj.Record(recs[i % 4].x * s, recs[i % 4].F * s, DT) for i, s in enumerate(scales)]
    batch, _ = lj.stack_records(recs)
    W = [np.asarray(lj.MassDamper().regressors(r, lj.default_bank()).W) for r in recs[:4]]
    peak = [np.max(np.einsum("tip,tip->t", w, w)) for w in W]  # ≥ max tr(W Wᵀ) per record
    g = 2.0 * SERIES_BOUND / DT / max(peak[:2])  # beyond the bound for the first two only
    assert min(DT * g * q for q in peak[:2]) > SERIES_BOUND
    assert max(DT * g * q for q in peak[2:]) < 0.5 * SERIES_BOUND
    fast = lj.lion_batched(lj.MassDamper(), batch, gain=lj.FixedGain(g))
    slow = lj.lion_batched(
        lj.MassDamper(), batch, gain=lj.FixedGain(g), execution=lj.Execution(phi="closed")
    )
    np.testing.assert_allclose(fast.theta, slow.theta, rtol=1e-10)
    for i in (0, 1, 2, len(recs) - 1):
        ref = lj.lion(lj.MassDamper(), recs[i], gain=lj.FixedGain(g))
        np.testing.assert_allclose(fast.theta[i], ref.theta_final, rtol=1e-10)


def test_signature_has_few_parameters_and_one_boolean():
    """The strategy-object API: at most 12 parameters, ``throw`` the only boolean."""
    params = inspect.signature(lj.lion_batched).parameters
    assert len(params) <= 12, list(params)
    booleans = [
        name
        for name, p in params.items()
        if isinstance(p.default, bool) or p.annotation in (bool, "bool")
    ]
    assert booleans == ["throw"]


def test_execution_checks_its_knobs():
    assert lj.Execution().kernel == "auto" and lj.Execution(kernel="xla").kernel == "xla"
    with pytest.raises(lj.InputError, match=r"kernel must be one of \('auto', 'xla', 'pallas'\)"):
        lj.Execution(kernel="cuda")
    with pytest.raises(lj.InputError, match="chunk"):
        lj.Execution(chunk=0)
    with pytest.raises(lj.InputError, match="phi"):
        lj.Execution(phi="fast")
    with pytest.raises(lj.InputError, match="outputs"):
        lj.lion_batched(lj.MassDamper(), lj.stack_records(_records(1, 300))[0], outputs=("ls",))


def test_per_record_bank_and_gain_equal_per_record_runs(recs):
    """A FilterBank with coeffs (B, n) and gains with values (B,) give every record its own
    filter and gain: the same numbers as lj.lion / lj.least_squares record by record."""
    batch, _ = lj.stack_records(recs)
    poles = [(-4.0, -4.0, -4.0), (-8.0, -8.0, -8.0), (-5.0, -6.0, -7.0), (-12.0, -12.0, -12.0)]
    bank = lj.studies.stack_banks(poles)
    assert bank.batch_shape == (4,)
    g = np.array([1e2, 1e3, 3e3, 1e4])
    rate = np.array([1.0, 2.0, 3.0, 4.0])
    fixed = lj.lion_batched(lj.MassDamper(), batch, bank=bank, gain=lj.FixedGain(g))
    auto = lj.lion_batched(
        lj.MassDamper(), batch, bank=bank, gain=lj.AutoGain(rate), outputs=(lj.LSStatistics(),)
    )
    for i, r in enumerate(recs):
        b = lj.FilterBank.from_poles(np.array(poles[i]), True)
        ref = lj.lion(lj.MassDamper(), r, bank=b, gain=lj.FixedGain(g[i]))
        np.testing.assert_allclose(fixed.theta[i], ref.theta_final, rtol=1e-10)
        ref = lj.lion(lj.MassDamper(), r, bank=b, gain=lj.AutoGain(rate[i]))
        np.testing.assert_allclose(auto.gain[i], ref.gain, rtol=1e-10)
        np.testing.assert_allclose(auto.theta[i], ref.theta_final, rtol=1e-10)
        ls = lj.least_squares(lj.MassDamper(), r, bank=b, initial="discard")
        np.testing.assert_allclose(auto.theta_ls[i], ls.theta, rtol=1e-9)
    with pytest.raises(lj.InputError, match="one per record"):
        lj.lion_batched(lj.MassDamper(), batch, gain=lj.FixedGain(g[:3]))
    with pytest.raises(lj.InputError, match="one filter"):
        lj.lion(lj.MassDamper(), recs[0], bank=bank)


def test_euler_stepper_runs_batched(recs):
    """The stepper's increment is the one law of lion and lion_batched: the explicit Euler
    step runs batched too, and an unstable gain is reported per record."""
    batch, _ = lj.stack_records(recs)
    sol = lj.lion_batched(lj.MassDamper(), batch, gain=lj.FixedGain(1e3), stepper=lj.EulerStep())
    for i, r in enumerate(recs):
        ref = lj.lion(lj.MassDamper(), r, gain=lj.FixedGain(1e3), stepper=lj.EulerStep())
        np.testing.assert_allclose(sol.theta[i], ref.theta_final, rtol=1e-10)
    bad = lj.lion_batched(
        lj.MassDamper(), batch, gain=lj.FixedGain(1e9), stepper=lj.EulerStep(), throw=False
    )
    unstable = lj.solutions.result_codes(lj.RESULTS.unstable_step).item()
    assert np.all(lj.solutions.result_codes(bad.result) == unstable)


def test_missing_output_is_named(recs):
    sol = lj.lion_batched(lj.MassDamper(), lj.stack_records(recs)[0], gain=lj.FixedGain(1e3))
    with pytest.raises(lj.InputError, match="LSStatistics"):
        _ = sol.theta_ls
