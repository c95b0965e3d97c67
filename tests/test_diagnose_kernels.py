"""The diagnosis' internal kernels, each against an independent reference at a stated tolerance:
what no public function exposes at that precision (``lj.diagnose`` returns verdicts, scores and
fitted parameters; the numbers below feed them).

- record statistics: the encoder's lattice step, the loop's feedback share, the noise floor,
  the windowed simulation's start states, the record-derived settings;
- filters: the filter bank against scipy's discretisations, the hold correction's order, a
  flexible mode's signals and exact columns against scipy, the input maps, float32 products;
- chunks: every recursion read in chunks (the filter bank forwards and backwards, the
  zero-phase velocity, a mains line's projection, Dahl's states, the mode's seed) against the
  same quantity in one pass over the whole record;
- least squares: the Gram solve, the profiles' added columns and the input-map grids against
  numpy's lstsq on explicit designs, in one chunk and in many; a diagnosis problem's Grams,
  fits, residuals, profile columns and period screen in chunks against one chunk;
- the windowed simulation in segments and from the start states;
- the memory estimate;
- the searches (grid, parabola, golden section, pattern search) against brute force.

Each private import is listed with its reason in tests/test_layout.py (PRIVATE_IMPORTS).
"""

import math

import diagnosis_blind as blind  # benchmarks/ (tests/conftest.py)
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import lionjax as lj
from lionjax._linalg import matvec_unrolled
from lionjax.diagnosis import (
    CoulombCandidate,
    Criteria,
    DelayCandidate,
    FlexibleModeCandidate,
    OffsetCandidate,
    PositionCandidate,
    SpringCandidate,
)
from lionjax.diagnosis._filtering import P_MAX, Discrete, filter_from, padded_length
from lionjax.diagnosis._lstsq import (
    fit_batch,
    residual,
    rss_fixed_with_columns,
    rss_with_columns,
    simulate_windows,
    solve_grams,
)
from lionjax.diagnosis._problem import Problem
from lionjax.diagnosis._regressors import ModeProfileColumns, RecordSignals, Regressors
from lionjax.diagnosis._search import (
    GoldenSection,
    GridSearch,
    ParabolaStep,
    PatternSearch,
    best_so_far,
)
from lionjax.diagnosis._settings import settings
from lionjax.diagnosis._statistics import (
    BYTES_PER_SAMPLE_STREAMED,
    STREAM_FIXED,
    _check_memory,
    _feedback,
    _high_band,
    _lattice_step,
    _passes,
    _position_noise,
    _prediction_noise,
    _robust_diff_std,
    _start_states,
    longest_records,
    memory_estimate,
    streamed_by_default,
)
from lionjax.diagnosis._streaming import (
    FilteredColumns,
    Filters,
    filtered,
    input_map,
    mode_filtered,
    mode_seed,
    rows,
    spans,
    zero_phase,
)
from lionjax.diagnosis.effects._artefacts import MAX_HARMONIC, line_in
from lionjax.diagnosis.effects._friction import dahl_chunked
from lionjax.diagnosis.effects._lookalikes import _adjoint_histograms
from lionjax.diagnosis.effects._position import _local_raw
from lionjax.extend import dahl_states
from lionjax.twin._windows import WINDOW_PARAMETERS

#: Samples per chunk where a record is read in many: far shorter than the records, so that the
#: states are carried across many chunk edges.
CHUNK = 512


def _close(a, b, rtol):
    """b equal to a within ``rtol`` of a's largest magnitude."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    assert a.shape == b.shape
    np.testing.assert_allclose(b, a, rtol=0, atol=rtol * max(np.max(np.abs(a)), 1e-300))


def _bank(hz: float) -> lj.FilterBank:
    """The diagnosis' filter bank (s + λ)³ with unit DC gain, λ = 2π·hz."""
    return lj.FilterBank.from_poles(np.full(3, -2 * np.pi * hz), unit_dc_gain=True)


def _regressors(x, F, dt, hz: float, chunk: int | None = None) -> Regressors:
    """ε₁ regressors of (x, F) through :func:`_bank` (``hz``), in one chunk or in chunks of
    ``chunk`` samples (the velocity is not read by the models of these tests: zeros)."""
    rec = lj.Record(np.asarray(x, np.float64), np.asarray(F, np.float64), dt)
    ch = chunk or padded_length(rec.n_samples)
    rs = RecordSignals(rec, np.asarray(rec.x), np.asarray(rec.F), np.zeros(rec.n_samples), ch)
    return Regressors(rs, _bank(hz), None, ch, 2 * np.pi * hz)


def _whole_outputs(dsc, u, foh: float):
    """(T, 4) outputs V₁…V₄ of one signal filtered over the whole record in one chunk."""
    return filtered(dsc, u, foh).T


def _hold_corrected(x):
    """xₖ − Δ²xₖ/12, Δ² of the first and last samples their neighbour's."""
    d2 = x[2:] - 2 * x[1:-1] + x[:-2]
    return x - np.concatenate([d2[:1], d2, d2[-1:]]) / 12


def _input_reference(F, dt, tau, fmax):
    """sat_Fmax(F(t − τ)) by numpy's linear interpolation of the held force (F before the
    record = F[0]); F_max < 0 the soft saturation |F_max|·tanh(F/|F_max|)."""
    k = np.arange(F.size, dtype=np.float64)
    Fd = np.interp(k - tau / dt, k, F, left=F[0], right=F[-1])
    m = abs(fmax)
    return m * np.tanh(Fd / m) if fmax < 0 else np.clip(Fd, -m, m)


def _free_response(dsc, T: int) -> np.ndarray:
    """(T, n) V₁ of the unforced filter from each unit state: C·Φᵏ·eᵢ, by repeated products."""
    Phi, C = np.asarray(dsc.Phi, np.float64), np.asarray(dsc.C, np.float64)[0]
    out, row = np.empty((T, Phi.shape[0])), C.copy()
    for k in range(T):
        out[k] = row
        row = row @ Phi
    return out


# ----------------------------------------------------------------------------------------------
# Record statistics


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("q", [1e-6, 2.3e-6, 2e-5])
def test_lattice_step_of_a_quantised_record(q, dtype):
    """An encoder's count q is recovered from a quantised, slowly drifting position (to 10⁻⁴ in
    float32, where the smallest step alone is off by more); noise on top leaves no lattice."""
    rng = np.random.default_rng(0)
    t = np.arange(20000) / 3000.0
    x = 0.05 * np.sin(2 * np.pi * 0.3 * t) + 0.01 * t + 0.003
    xq = (q * np.round(x / q)).astype(dtype)
    assert _lattice_step(xq) == pytest.approx(q, rel=1e-4)
    assert _lattice_step(xq + rng.normal(0, 0.3 * q, xq.shape).astype(dtype)) == 0.0


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("q", [1e-6, 2e-5])
def test_lattice_step_behind_noise(q, dtype):
    """A lattice blurred by noise of 0.05·q (the samples' coherence exp(−2π²·0.05²) = 0.95) is
    found to 10⁻⁴ of q; at 0.12·q (coherence exp(−2π²·0.12²) = 0.75, below the limit 0.8) and
    on a smooth signal none is."""
    rng = np.random.default_rng(1)
    t = np.arange(20000) / 3000.0
    x = 0.05 * np.sin(2 * np.pi * 0.3 * t) + 0.01 * t + 0.003
    xq = q * np.round(x / q)
    blurred = (xq + rng.normal(0, 0.05 * q, x.shape)).astype(dtype)
    assert _lattice_step(blurred) == pytest.approx(q, rel=1e-4)
    assert _lattice_step((xq + rng.normal(0, 0.12 * q, x.shape)).astype(dtype)) == 0.0
    assert _lattice_step((x + rng.normal(0, 1e-7, x.shape)).astype(dtype)) == 0.0


def test_position_noise_where_the_excitation_reaches_the_top():
    """White noise σ under a flat multisine to f_s/4: the third differences count the motion
    (over 20× σ here) and the spectrum's flat top gives σ within 10 %; the same noise through an
    anti-aliasing low-pass (a filtered record: its top falls 20× below σ, not white) is not
    read from the top: its estimate stays above σ, at most the third differences'."""
    from scipy import signal

    rng = np.random.default_rng(2)
    T, fs, sigma = 40000, 1000.0, 1e-6
    t = np.arange(T) / fs
    f = np.linspace(1.0, 250.0, 200)[:, None]
    x = np.sum(1e-5 * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi, f.shape)), 0)
    noisy = x + rng.normal(0, sigma, T)
    F = np.zeros(T)  # a force that says nothing of the motion: no prediction from it
    assert _robust_diff_std(noisy) > 20 * sigma
    assert _position_noise(noisy, F) == pytest.approx(sigma, rel=0.1)
    # an anti-aliasing front end: a 4th-order Butterworth low-pass at 0.3·f_s
    smooth = x + signal.lfilter(*signal.butter(4, 0.6), rng.normal(0, sigma, T))
    assert _high_band(smooth)[0] < sigma / 20
    assert sigma < _position_noise(smooth, F) <= _robust_diff_std(smooth)


@pytest.mark.parametrize("loop", ["open", "closed"])
def test_position_noise_predicted_where_the_excitation_fills_the_spectrum(loop):
    """A white force to f_s/2 drives x'' = −a x' + b F (scipy's exact zoh discretisation), in
    closed loop through a P controller on the measured position itself (F reads xₖ at once):
    its motion fills the third differences (over 100× σ) and the spectrum's top (not white),
    and the one-step prediction from the past is an upper bound within 1.5× of σ: nₖ is
    independent of every earlier sample of x and F."""
    import scipy.signal as sg

    fs, a, b, sigma, T = 1000.0, 50.0, 100.0, 1e-7, 20000
    Ad, Bd, *_ = sg.cont2discrete(
        (np.array([[0, 1], [0, -a]]), np.array([[0], [b]]), np.eye(2), np.zeros((2, 1))),
        1 / fs,
        "zoh",
    )
    rng = np.random.default_rng(3)
    exc, n = rng.normal(0, 1.0, T), rng.normal(0, sigma, T)
    s, x, F = np.zeros(2), np.empty(T), np.empty(T)
    for k in range(T):
        x[k] = s[0] + n[k]
        F[k] = exc[k] - (400.0 * x[k] if loop == "closed" else 0.0)
        s = Ad @ s + Bd[:, 0] * F[k]
    assert _robust_diff_std(x) > 100 * sigma
    top, flat = _high_band(x)
    assert top > 20 * sigma and flat < 0.5
    assert sigma < _prediction_noise(x, F) < 1.5 * sigma
    assert _position_noise(x, F) == _prediction_noise(x, F)


def test_share_of_samples_where_the_axis_passes_twice():
    """Closed forms of the share of samples at positions passed twice and of the reversals: a
    ramp (x monotone in t) has none of either, even under white noise of σ (±5σ never reverses
    it: a reversal is a move back by 10σ); a ramp up to 1 over half the record, then back to
    1 − r over the other half, has (1 + r)/2 (the return and the outbound's last r/2 of the
    time) and one reversal; a triangle wave of two periods (3 reversals) or a sine over 20 rad
    (6) has all; a start far from where the axis then oscillates counts only the start's
    samples; a staircase of small steps back (under 10σ) stays one way."""
    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 1.0, 20001)
    sigma = 1e-4
    assert _passes(t + rng.normal(0, sigma, t.size), sigma) == (0.0, 0)
    for r in (0.1, 0.37, 0.8):
        x = np.where(t < 0.5, 2 * t, 1 - 2 * r * (t - 0.5))  # up to 1, back to 1 − r
        share, reversals = _passes(x, sigma)
        assert share == pytest.approx((1 + r) / 2, abs=2e-3) and reversals == 1
    share, reversals = _passes(np.abs(((4 * t) % 2) - 1), sigma)
    assert share == pytest.approx(1.0, abs=2 / 1024) and reversals == 3
    share, reversals = _passes(np.sin(20 * t), sigma)
    assert share == pytest.approx(1.0, abs=2 / 1024) and reversals == 6
    start = np.where(t < 0.01, 1000 * t, 10 + np.sin(200 * t))  # 0 → 10 in 1 %, then ±1
    assert _passes(start, sigma)[0] == pytest.approx(1 - 0.009, abs=2e-3)
    jitter = t + 5 * sigma * (np.arange(t.size) % 2)  # moves back 5σ at every other sample
    assert _passes(jitter, sigma) == (0.0, 0)


def test_feedback_share_tells_closed_from_open_loop():
    """A PD on the measured position puts the position noise into F's third difference (share
    near 1); an open-loop force, smooth at the sample scale, shares nothing with it."""
    rng = np.random.default_rng(1)
    dt = 1 / 2000.0
    t = np.arange(20000) * dt
    x = 0.01 * np.sin(2 * np.pi * 1.3 * t)
    xm = x + rng.normal(0, 2e-6, t.size)
    exc = np.sin(2 * np.pi * 3.1 * t) + 0.5 * np.sin(2 * np.pi * 7.7 * t)
    # a digital PD: backward difference of the measured position
    F_closed = exc - 800.0 * xm - 20.0 * np.diff(xm, prepend=xm[0]) / dt
    share, F_ref = _feedback(xm, F_closed)
    assert share > 0.95
    assert _feedback(xm, exc)[0] < 0.05
    # F less the controller's answer is the excitation, up to a slow drift (a quadratic in t:
    # the third difference leaves it free), removed by a least-squares fit
    e = F_ref - exc
    P = np.vander(t, 3)
    e = e - P @ np.linalg.lstsq(P, e, rcond=None)[0]
    assert np.sqrt(np.mean(e**2)) < 0.02 * np.sqrt(np.mean(exc**2))


def test_feedback_share_reads_a_low_rate_open_loop_as_open():
    """At 117 Hz a rough excitation is partly predicted from the plant's response to it: the R²
    of Δ³F on Δ³x alone read these open loops as 0.84–0.97 (closed). The share of F's
    innovation that the position just measured explains is ≈ 0 in open loop and ≈ 1 under a PD
    on that position. Plant x'' = −a x' + b F discretised exactly (zoh) by scipy; 20 µm
    encoder and 20 µm white position noise; twelve sines up to 47 Hz in open loop, six up to
    5 Hz as the closed loop's feed-forward."""
    import scipy.signal as sg

    fs, n, a, b, q = 117.0, 1200, 3.0, 50.0, 2e-5
    dt = 1 / fs
    Ad, Bd, *_ = sg.cont2discrete(
        (np.array([[0, 1], [0, -a]]), np.array([[0], [b]]), np.eye(2), np.zeros((2, 1))), dt, "zoh"
    )
    t = np.arange(n) * dt
    for seed in range(3):
        rng = np.random.default_rng(seed)
        sines = lambda hi, m: sum(
            np.sin(2 * np.pi * f * t + rng.uniform(0, 6.3)) for f in rng.uniform(0.2, hi, m)
        )
        rough, smooth = sines(47.0, 12), sines(5.0, 6)
        noise = rng.normal(0, 2e-5, n)

        def run(exc, kp, kd):
            s, xm, F = np.zeros(2), np.zeros(n), np.zeros(n)
            for k in range(n):
                xm[k] = q * np.round(s[0] / q) + noise[k]
                F[k] = exc[k] - kp * xm[k] - kd * (xm[k] - xm[max(k - 1, 0)]) / dt
                s = Ad @ s + Bd[:, 0] * F[k]
            return xm, F

        assert _feedback(*run(rough, 0.0, 0.0))[0] < 0.05
        assert _feedback(*run(smooth, 100.0, 1.0))[0] > max(0.9, Criteria().feedback_share)


def _ar1(e: np.ndarray, p: float) -> np.ndarray:
    """The AR(1) series y[k] = p·y[k − 1] + e[k], y[0] = e[0]."""
    out = np.empty_like(e)
    out[0] = e[0]
    for k in range(1, e.size):
        out[k] = p * out[k - 1] + e[k]
    return out


def test_odd_input_dependence_level_and_power():
    """The odd-input test (:func:`~lionjax.diagnosis._where.odd_input_dependence`): on residuals
    independent of the input, autocorrelated (AR(1), pole 0.8) against a low-passed Gaussian
    input (also AR(1)), it is significant in at most 3 % of 300 draws (its family-wise level
    1 %, Bartlett's factor for the autocorrelation); a residual linear in F (lags 0…3) is not
    flagged in more (Bussgang: for a Gaussian input the linear part of sign F and F³ is removed
    at every lag); a dead zone's residual, d·sign F less its least-squares part in F at a
    quarter of the noise's rms, is flagged in at least 95 %."""
    from types import SimpleNamespace

    from lionjax.diagnosis._where import odd_input_dependence

    st = SimpleNamespace(filter_hz=1000.0 / (2 * np.pi), dt=1e-3)  # no decimation
    rng = np.random.default_rng(11)
    n = 1500
    null, linear, dead = 0, 0, 0
    draws = 300
    for _ in range(draws):
        F = _ar1(rng.standard_normal(n), 0.7)
        noise = _ar1(rng.standard_normal(n), 0.8)
        null += odd_input_dependence(noise, F, st) > 1.0
        lin = noise + 0.3 * sum(np.roll(F, k) for k in range(4))
        linear += odd_input_dependence(lin, F, st) > 1.0
        g = np.sign(F)
        g = g - F * (F @ g) / (F @ F)
        dead += odd_input_dependence(noise + 0.25 * noise.std() * g / g.std(), F, st) > 1.0
    assert null <= 0.03 * draws, null
    assert linear <= 0.03 * draws, linear
    assert dead >= 0.95 * draws, dead


def test_whiteness_reads_lags_one_to_twenty():
    """The whiteness test (MATLAB ``resid``'s: max |ρ(r, r)| over lags 1…20 against 2.576/√n):
    white noise passes it in at least 70 % of 200 draws (each lag's level 1 %: 1 − 0.99²⁰ =
    18 % expected to fail), an AR(1) residual of pole 0.5 (ρ(1) = 0.5) fails it in all; lag 0,
    ρ = 1, is no part of it."""
    from types import SimpleNamespace

    from lionjax.diagnosis._where import structure

    st = SimpleNamespace(filter_hz=1000.0 / (2 * np.pi), dt=1e-3)  # no decimation
    rng = np.random.default_rng(12)
    n, draws = 2000, 200
    white = ar = 0
    for _ in range(draws):
        e, F = rng.standard_normal(n), rng.standard_normal(n)
        white += structure(e, F, st)["whiteness"] <= 1.0
        ar += structure(_ar1(e, 0.5), F, st)["whiteness"] > 1.0
    assert white >= 0.7 * draws, white
    assert ar == draws, ar


def test_noise_floor_counts_sparse_noise():
    """σ of the noise floor (third differences) against the drawn noise: Gaussian noise within
    5 %; sparse noise (a coarse encoder's steps: nonzero at 10 % of samples) within 20 % of its
    RMS, where the median absolute deviation alone gives less than half."""
    rng = np.random.default_rng(11)
    t = np.arange(200_000) * 1e-3
    smooth = 0.01 * np.sin(2 * np.pi * 0.7 * t)
    n = 2e-6 * rng.normal(size=t.size)
    assert _robust_diff_std(smooth + n) == pytest.approx(2e-6, rel=0.05)
    sparse = np.where(rng.random(t.size) < 0.1, 2e-5 * rng.normal(size=t.size), 0.0)
    rms = float(np.sqrt(np.mean(sparse**2)))
    # (the trim drops the largest 1 % of |Δ³|, the spikes' tail: 0.86× the RMS here)
    assert _robust_diff_std(smooth + sparse) == pytest.approx(rms, rel=0.2)
    d = np.diff(smooth + sparse, 3)
    mad = 1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(20)
    assert mad < 0.5 * rms


def test_excited_band_of_an_open_loop_multisine():
    """The excited band of an open-loop record (the twin's mass–damper driven by a flat
    multisine, Schroeder phases, lines 0.5 Hz apart over 1–199.5 Hz at 1 kHz) is the force's
    own: its top within 2 % of the closed form 1 + 0.99·198.5 Hz (99 % of a flat spectrum's
    power lies below it). A FIR of x fitted to F here fits the plant's inverse and would take
    the upper band out with it."""
    dt, n = 1e-3, 8000
    lines = np.arange(1.0, 200.0, 0.5)
    amp = 2.0 * np.sqrt(2.0 / lines.size)  # 2 N rms
    F = np.asarray(lj.twin.multisine(lines, amp, phases="schroeder")(dt * np.arange(n)))
    rec = lj.twin.simulate(lj.twin.Plant(20.0, 2.0, (), []), F, dt=dt)
    lo, hi = settings(rec).excited
    assert hi == pytest.approx(1.0 + 0.99 * 198.5, rel=0.02)
    assert lo < 5.0


#: The sample rates of test_diagnose_rates.py (Hz, deliberately non-round).
RATES = (97.3, 2011.7, 4987.3, 10103.9)


@pytest.mark.parametrize("fs", RATES)
@pytest.mark.parametrize("duration", (5.0, 60.0, 600.0))
def test_settings_finite_over_rates_and_lengths(fs, duration):
    """Every record-derived setting of a 5 s … 10 min record at 100 Hz … 10 kHz (non-round dt)
    is finite and valid; v_ε = 0.02·median|v| against the closed form for x = A sin(2πf₀t),
    median|v| = A·2πf₀·cos(π/4), to 1 % (the zero-phase derivative filter's corner is at least
    29 Hz, 0.3·f_s, at 97 Hz: it takes < 0.5 % off f₀ = 0.7 Hz at every rate; at f_s/10 it took
    4.4 % at 97 Hz)."""
    A, f0 = 0.01, 0.7  # m, Hz
    t = np.arange(int(duration * fs)) / fs
    rec = lj.Record(A * np.sin(2 * np.pi * f0 * t), np.cos(2 * np.pi * f0 * t), 1 / fs)
    st = settings(rec)
    nyq = fs / 2
    assert 0 < st.filter_hz < nyq and 0 < st.velocity_hz < nyq
    assert st.v_eps == pytest.approx(0.02 * A * 2 * np.pi * f0 * np.cos(np.pi / 4), rel=0.01)
    for name, g in (("tau", st.tau_grid), ("mode", st.mode_grid)):
        g = np.asarray(g)
        assert np.all(np.isfinite(g)) and np.all(g > 0) and np.all(np.diff(g) > 0), name
    assert st.tau_grid[0] >= 0.25 / fs * (1 - 1e-12) and st.tau_grid[-1] <= 0.1 * duration
    assert st.mode_grid[-1] <= 0.2 * fs * (1 + 1e-12)
    fm = np.asarray(st.fmax_grid)
    assert np.all(np.isfinite(fm)) and np.all(fm != 0)
    assert np.all(np.abs(fm[fm > 0]) <= 1.0 + 1e-12)  # hard clips within the force's range
    assert math.isfinite(st.x_center) and st.x_scale == pytest.approx(A / np.sqrt(2), rel=0.01)


@pytest.mark.parametrize(
    "fs, f0, q, tol_v",
    [(97.3, 9.0, 2e-6, 0.01), (277.3, 25.0, 10e-6, 0.02), (1000.0, 20.0, 20e-6, 0.05),
     (10103.9, 2.0, 20e-6, 0.03), (10103.9, 15.0, 1e-6, 0.03)],
)  # fmt: skip
def test_start_states_against_the_closed_form(fs, f0, q, tol_v):
    """The windowed simulation's start states (x₀, v₀) of x = A sin(2πf₀t + 0.3), A = 1 mm,
    quantised to q, against the closed form: x₀ within q/√12·1.2 (or ≤ q where a filter is
    chosen), v₀ within ``tol_v`` of the rms velocity (interior samples). At f₀ = f_s/11 the
    smoothed states of v̂'s filter were 163 µm and 27 % off (measured when written), the raw
    samples 2.9 µm and 0.7 %; at 10 kHz with a 20 µm encoder on a slow axis the raw samples'
    derivative would be 2.6× the rms velocity in noise, and a filter must be chosen."""
    A = 1e-3
    t = np.arange(int(8 * fs)) / fs
    x_true = A * np.sin(2 * np.pi * f0 * t + 0.3)
    v_true = A * 2 * np.pi * f0 * np.cos(2 * np.pi * f0 * t + 0.3)
    x = q * np.round(x_true / q)
    st = settings(lj.Record(x, np.cos(t), 1 / fs))
    v_hat = zero_phase(x, 1 / fs, 2 * np.pi * st.velocity_hz)[1]
    f, x0, v0 = _start_states(x, 1 / fs, st.velocity_hz, v_hat)
    inner = slice(int(fs), -int(fs))
    ex = np.sqrt(np.mean((x0 - x_true)[inner] ** 2))
    ev = np.sqrt(np.mean((v0 - v_true)[inner] ** 2)) / (A * 2 * np.pi * f0 / np.sqrt(2))
    assert ex <= (1.2 * q / np.sqrt(12) if math.isinf(f) else q), (f, ex)
    assert ev <= tol_v, (f, ev)
    assert math.isinf(f) or st.velocity_hz <= f <= 0.3 * fs


# ----------------------------------------------------------------------------------------------
# Filters


def test_matvec_unrolled_against_numpy():
    """A·z of the recursions' unrolled elementwise products against numpy, broadcast over
    leading axes as the recursion uses it (Φʲ·S_m: A (L, 1, n, n), z (1, M, n)), 1e-15."""
    rng = np.random.default_rng(0)
    for n in (2, 3, 5):
        z = rng.standard_normal((1, 7, n))
        A = rng.standard_normal((4, 1, n, n))
        ref = np.einsum(
            "lmab,lmb->lma", np.broadcast_to(A, (4, 7, n, n)), np.broadcast_to(z, (4, 7, n))
        )
        got = np.asarray(matvec_unrolled(A, z))
        assert got.shape == (4, 7, n)
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-15 * np.max(np.abs(ref)) * n)


@pytest.mark.filterwarnings("ignore::scipy.signal.BadCoefficients")  # λ³sᵏ: trailing zeros
def test_filter_against_scipy():
    """Zero-order-held signals read in chunks of 700 samples through the diagnosis' bank
    Λ = (s + λ)³ with unit DC gain: output k (V₁…V₄) is λ³sᵏ/Λ[u] from rest under u[0],
    against scipy's cont2discrete + dlsim, 1e-9 of each output's peak."""
    from scipy import signal

    dt, T, lam = 1 / 1013.0, 2500, 2 * np.pi * 31.0
    rng = np.random.default_rng(1)
    # held steps of random levels
    U = np.stack([np.repeat(rng.standard_normal(T // 50 + 1), 50)[:T] for _ in range(3)])
    dsc = Discrete.of(_bank(31.0), dt)
    V = np.stack([filtered(dsc, u, 0.0, 700).T for u in U])
    assert V.shape == (3, T, 4)
    den = np.poly(np.full(3, -lam))
    for k in range(4):
        num = np.zeros(4)
        num[3 - k] = lam**3  # λ³sᵏ
        A, B, C, D, _ = signal.cont2discrete(signal.tf2ss(num, den), dt, "zoh")
        for i in range(3):
            x0 = np.linalg.solve(np.eye(3) - A, B[:, 0] * U[i, 0])  # at rest under u[0]
            ref = signal.dlsim((A, B, C, D, dt), U[i], t=np.arange(T) * dt, x0=x0)[1][:, 0]
            np.testing.assert_allclose(V[i, :, k], ref, rtol=0, atol=1e-9 * np.max(np.abs(ref)))


def test_diagnosis_filter_products_full_precision():
    """The diagnosis' filter recursion traced in float32 holds no matrix product below full
    precision (none at all: its products are unrolled multiply-adds, matvec_unrolled), so a
    GPU's TF32 cannot round the accumulation over a record (test_parallel.py's walker, which
    test_walker_catches_default_precision shows finds dots)."""
    from test_parallel import DT, _assert_highest

    dsc = Discrete.of(lj.default_bank(), DT)
    dsc = jax.tree.map(lambda a: jnp.asarray(a, jnp.float32), dsc)
    u = jnp.linspace(0.0, 1.0, 256, dtype=jnp.float32)
    z0 = jnp.zeros(3, jnp.float32)
    assert _assert_highest(lambda v: filter_from(dsc, v, v, v, z0)[0], u) == []


@pytest.mark.parametrize("fs", [400.0, 1000.0])
def test_hold_correction_is_fourth_order(fs):
    """A smooth x sampled at fs through h = (s²/D)[·] (the mode filter): the first-order hold of
    the raw samples (scipy's lsim) is off by ≈ (ωh)²/12, that of the hold-corrected samples
    (mode_filtered) by O(h⁴). Reference: the exact steady-state response |H(jω)|·sin(ωt + ∠H)
    of each sine (closed form), after the transient (ζ = 0.3: decays as e^{−ζω_n t}, < 1e-12
    of the signal after 0.5 s)."""
    from scipy import signal

    w, z = 2 * np.pi * 30.0, 0.3
    freqs, amps = (3.1, 17.0, 37.0), (0.01, 0.004, 0.002)

    def exact(t):
        out = np.zeros_like(t)
        for f, a in zip(freqs, amps, strict=True):
            s = 2j * np.pi * f
            H = s**2 / (s**2 + 2 * z * w * s + w * w)
            out += a * np.abs(H) * np.sin(2 * np.pi * f * t + np.angle(H))
        return out

    errs = {}
    for h in (1 / fs, 0.5 / fs):
        t = np.arange(int(round(2.0 / h))) * h
        x = sum(a * np.sin(2 * np.pi * f * t) for f, a in zip(freqs, amps, strict=True))
        keep = (t > 0.5) & (t < t[-1])  # the last sample's Δ² sees the padding
        ref = exact(t)[keep]
        hx = mode_filtered(x, 1.0, h, w, z)
        # the plain first-order hold of the raw samples: scipy's lsim (linear interpolation)
        lti = signal.lti([1.0, 0.0, 0.0], [1.0, 2 * z * w, w * w])
        hraw = signal.lsim(lti, x, t, interp=True)[1]
        scale = np.max(np.abs(ref))
        errs[h] = (
            np.max(np.abs(hx[keep] - ref)) / scale,
            np.max(np.abs(hraw[keep] - ref)) / scale,
        )
    (c1, r1), (c2, r2) = errs[1 / fs], errs[0.5 / fs]
    assert c1 < 0.1 * r1  # the correction removes ≥ 90 % of the hold error
    assert 3.0 < r1 / r2 < 5.0  # the plain hold: second order (ratio 4)
    assert c1 / c2 > 10.0  # the corrected hold: fourth order (ratio 16)


def test_mode_signals_and_input_maps_against_scipy_and_numpy():
    """h = (s²/D)[·] of the flexible-mode candidate against scipy's
    lsim (first-order hold of the hold-corrected samples: linear interpolation) and zero-order-
    hold discretisation, 1e-8; the soft input map against tanh; and the input map u =
    sat(F(t − τ)) of any rows (read per chunk) against the whole record's (numpy's
    interpolation of the delayed force), 1e-12, for τ of either sign; at τ = −dt/2 the held
    reading of a force sampled at instants, the midpoints (F[k] + F[k+1])/2."""
    from scipy import signal

    dt, T = 1 / 997.3, 3000
    t = np.arange(T) * dt
    x = 0.01 * np.sin(2 * np.pi * 3.1 * t) + 0.002 * np.sin(2 * np.pi * 37.0 * t)  # x(0) = 0
    F = np.sign(np.sin(2 * np.pi * 1.3 * t + 0.3))
    w, z = 2 * np.pi * 21.0, 0.07
    num, den = [1.0, 0.0, 0.0], [1.0, 2 * z * w, w * w]
    # x is held first-order after the hold correction xₖ − Δ²xₖ/12 (ends: the neighbour's Δ²)
    xc = _hold_corrected(x)
    # (the state sees xc; the feedthrough D·x the samples themselves)
    A, B, C, D = signal.tf2ss(num, den)
    x0_ss = -np.linalg.solve(A, B[:, 0] * xc[0])  # at rest under xc[0], as the filter
    hx_ref = signal.lsim((A, B, C, 0 * D), xc, t, X0=x0_ss, interp=True)[1] + D[0, 0] * x
    A, B, C, D, _ = signal.cont2discrete(signal.tf2ss(num, den), dt, "zoh")
    x0 = np.linalg.solve(np.eye(2) - A, B[:, 0] * F[0])  # at rest under F[0]: h = 0
    hF_ref = signal.dlsim((A, B, C, D, dt), F, t=t, x0=x0)[1][:, 0]
    hx, hF = mode_filtered(x, 1.0, dt, w, z), mode_filtered(F, 0.0, dt, w, z)
    scale = np.max(np.abs(hx_ref))
    # the last sample's Δ² sees the padding (its own value repeated), not the neighbour's Δ²
    np.testing.assert_allclose(hx[:-1], hx_ref[:-1], atol=1e-8 * scale)
    assert abs(hx[-1] - hx_ref[-1]) < 0.01 * scale
    np.testing.assert_allclose(hF, hF_ref, atol=1e-8 * np.max(np.abs(hF_ref)))
    np.testing.assert_allclose(input_map(F * 2.0, dt, 0.0, -1.5), 1.5 * np.tanh(F * 2.0 / 1.5))
    # per rows, as a chunk reads them: a fractional delay, hard and soft clips, no map
    Fr = np.sin(2 * np.pi * 2.3 * t) + 0.3 * np.random.default_rng(4).standard_normal(T)
    cases = [(0.0, math.inf), (3.37 * dt, math.inf), (0.0, 0.8), (1.6 * dt, -1.2)]
    for tau, fmax in [*cases, (-0.5 * dt, math.inf), (-2.71 * dt, 0.8), (-0.3 * dt, -1.2)]:
        whole = _input_reference(Fr, dt, tau, fmax)
        got = np.concatenate([input_map(Fr, dt, tau, fmax, k0, k1) for k0, k1 in spans(T, 700)])
        _close(whole, got, 1e-12)
    mid = np.concatenate([0.5 * (Fr[:-1] + Fr[1:]), Fr[-1:]])
    _close(mid, input_map(Fr, dt, -0.5 * dt, math.inf), 1e-12)


@pytest.mark.filterwarnings("ignore::scipy.signal.BadCoefficients")  # λ³sʲ⁺¹: trailing zeros
@pytest.mark.parametrize(
    "fs, f_filter, f_mode, zeta",
    [(1003.7, 40.0, 21.0, 0.2), (1003.7, 40.0, 8.0, 0.1), (277.3, 11.0, 60.0, 0.05)],
)
@pytest.mark.parametrize("chunk", [None, 1000])
def test_mode_columns_against_scipy(fs, f_filter, f_mode, zeta, chunk):
    """The flexible mode's ε₁ columns λ³s⁴/((s + λ)³D)[x] (x under the first-order hold of its
    hold-corrected samples) and λ³s²/((s + λ)³D)[F] (F under a zero-order hold), computed as the
    diagnosis filter's output followed by an exact stage of order 2 (the profile's columns, in
    one chunk and in chunks of 1000 samples), against scipy's cont2discrete + dlsim of the
    order-5 transfer functions: 1e-9 once the initial states (steady vs scipy's zero) have
    decayed (25 time constants). A mode below the filter corner, a lightly damped one further
    below, and one above a low sample rate's filter."""
    from scipy import signal

    dt, T = 1 / fs, 12000
    t = np.arange(T) * dt
    rng = np.random.default_rng(3)
    x = sum(1e-3 * np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in (0.7, 3.1, 9.0, 27.0))
    F = np.repeat(rng.standard_normal(T // 10), 10)
    w, z, lam = 2 * np.pi * f_mode, zeta, 2 * np.pi * f_filter
    regs = _regressors(x, F, dt, f_filter, chunk)
    assert regs.whole == (chunk is None)
    blk = np.concatenate(list(ModeProfileColumns([(w, z)], lam, dt).blocks(regs)), -1)
    cx, cF = -blk[0, 0], blk[0, 1]  # the profile's columns carry ε₁'s signs: −x's, +F's
    den = np.polymul(np.poly([-lam] * 3), [1.0, 2 * z * w, w * w])
    xc = _hold_corrected(x)
    tail = slice(int(25 / min(z * w, lam) / dt), T - 1)
    assert tail.start < T // 2
    yF = signal.dlsim(signal.cont2discrete(([lam**3, 0, 0], den), dt, "zoh"), F, t=t)[1][:, 0]
    np.testing.assert_allclose(cF[tail], yF[tail], atol=1e-9 * np.max(np.abs(yF)))
    yx = signal.dlsim(signal.cont2discrete(([lam**3, 0, 0, 0, 0], den), dt, "foh"), xc, t=t)
    np.testing.assert_allclose(cx[tail], yx[1][tail, 0], atol=1e-9 * np.max(np.abs(yx[1])))


# ----------------------------------------------------------------------------------------------
# Chunks against one pass over the whole record


def test_chunked_filter_equals_whole_record():
    """:class:`Filters` over chunks of 256 samples (a short last one) against one chunk
    (:func:`filtered`), first- and zero-order holds, all four outputs: 1e-12
    of each output's peak; and the backward pass's short first chunk (:meth:`step_values`,
    padded in front) against the whole reversed record."""
    dt, T = 1 / 997.0, 3001
    rng = np.random.default_rng(3)
    U = np.cumsum(rng.standard_normal((3, T)), 1) * 1e-3
    dsc = Discrete.of(_bank(30.0), dt)
    foh = np.array([1.0, 0.0, 1.0])
    whole = np.stack([_whole_outputs(dsc, u, f) for u, f in zip(U, foh, strict=True)])
    f = Filters(dsc, T, 256, {i: (rows(U[i]), foh[i]) for i in range(3)})
    got = np.zeros((3, T, 4))
    for k0, k1 in spans(T, 256):
        out = f.step(k0, k1)
        for i in range(3):
            got[i, k0:k1] = out[i].T
    for i in range(3):
        _close(whole[i, :T], got[i], 1e-12)
    # backwards: chunks of the reversed record, its first one short (3001 = 11·256 + 185)
    Ur = U[1, ::-1]
    ref = filtered(dsc, Ur, 0.0)[0]
    b = Filters(dsc, T, 256, {0: (None, 0.0)})
    back = np.zeros(T)
    for k0, k1 in reversed(spans(T, 256)):
        seg = U[1, k0:k1][::-1][None]
        back[k0:k1] = b.step_values(seg, last=k0 == 0)[0, 0, ::-1]
    _close(ref, back[::-1], 1e-12)


# the slow tier: bit for bit at XLA's default optimisation level, which the diagnosis runs at (the
# README's test command compiles at level 0, where LLVM vectorises a batch of one and of several
# differently and the last bits differ: 2.9e-11 of 4.6e-3, tests/conftest.py)
@pytest.mark.slow
def test_batches_of_any_size_give_the_same_numbers(monkeypatch):
    """Signals filtered, and flexible modes' stages computed, several per call (the default) and
    one per call (:data:`~lionjax.diagnosis._streaming.FILTER_SAMPLES` and ``MODE_SAMPLES`` at
    one chunk): the same numbers bit for bit, so the calls' sizes, chosen for the processor's
    caches, never change a diagnosis."""
    from lionjax.diagnosis import _streaming

    dt, T = 1 / 997.0, 3001
    rng = np.random.default_rng(4)
    U = np.cumsum(rng.standard_normal((5, T)), 1) * 1e-3
    dsc = Discrete.of(_bank(30.0), dt)
    modes = np.array([[2 * np.pi * f, z] for f, z in ((12.0, 0.02), (40.0, 0.1), (90.0, 0.3))])

    def run():
        f = Filters(dsc, T, 1024, {i: (rows(U[i]), float(i % 2)) for i in range(5)})
        st = _streaming.ModeStages(modes, 2 * np.pi * 30.0, dt, 1024)
        outs = []
        for k0, k1 in spans(T, 1024):
            o = f.step(k0, k1)
            outs += [o[i] for i in range(5)]
            outs += st.step(o[0], o[1], U[0], U[1], k0, k1)
        return outs

    batched = run()
    monkeypatch.setattr(_streaming, "FILTER_SAMPLES", 1024)
    monkeypatch.setattr(_streaming, "MODE_SAMPLES", 1024)
    assert _streaming.batch_top(_streaming.BATCHES, 1024, 1024) == 1
    single = run()
    assert len(batched) == len(single)
    for a, b in zip(batched, single, strict=True):
        np.testing.assert_array_equal(a, b)


def test_long_record_helpers_in_chunks(monkeypatch):
    """What a long record computes in chunks: the zero-phase velocity (forwards, then
    backwards, chunk by chunk) in chunks of 1024 samples against one chunk, 1e-12 of its peak; a mains
    line's least-squares projection in row blocks against numpy's lstsq on the whole design,
    1e-10."""
    from lionjax.diagnosis.effects import _artefacts

    rng = np.random.default_rng(5)
    T, dt, om = 20_001, 1e-4, 2 * np.pi * 100
    x = np.cumsum(rng.standard_normal(T)) * 1e-6 + np.sin(np.arange(T) * dt * 30)
    sm, g = zero_phase(x, dt, om)  # one chunk
    s2, g2 = zero_phase(x, dt, om, 1024)
    _close(sm, s2, 1e-12)
    _close(g, g2, 1e-12)
    t = np.arange(T) * dt
    F = 0.3 * np.sin(2 * np.pi * 50.2 * t + 0.4) + 0.1 * rng.standard_normal(T)
    ks = [k for k in range(1, MAX_HARMONIC + 1) if k * 50.2 < 0.45 / dt]
    A = np.stack([f(2 * np.pi * k * 50.2 * t) for k in ks for f in (np.cos, np.sin)], 1)
    ref = A @ np.linalg.lstsq(A, F - F.mean(), rcond=None)[0]
    monkeypatch.setattr(_artefacts, "LINE_ROWS", 3000)  # seven blocks
    _close(ref, line_in(F, t, 50.2, dt), 1e-10)


# ----------------------------------------------------------------------------------------------
# Least squares


def test_gram_solve_is_float64_without_x64():
    """The diagnosis' solve (augmented Gram [W | y]ᵀ[W | y] → lj's gram_lstsq) against numpy's
    lstsq (an independent SVD reference) at 1e-9, with jax_enable_x64 switched off by the
    caller."""
    rng = np.random.default_rng(3)
    W = rng.normal(size=(500, 5)) * np.array([1e-3, 1.0, 30.0, 1.0, 5e2])
    y = W @ np.array([2.0, -1.0, 0.5, 0.0, 3e-3]) + 1e-4 * rng.normal(size=500)
    B = np.concatenate([W, y[:, None]], 1)
    with jax.enable_x64(False):
        coef, rss, gi, cond = solve_grams((B.T @ B)[None], 500)
    ref, res, *_ = np.linalg.lstsq(W, -y, rcond=None)
    assert coef.dtype == np.float64
    np.testing.assert_allclose(coef[0], ref, rtol=1e-9, atol=1e-12)
    # RSS = yᵀy − bᵀθ by cancellation in the Gram: its rounding floor is eps·yᵀy/RSS (4.8e-6
    # relative here, so a bound of 1e-6 would test the compiler's rounding, not the solve)
    floor = np.finfo(np.float64).eps * float(y @ y) / float(res[0])
    assert rss[0] == pytest.approx(float(res[0]), rel=4 * floor)
    np.testing.assert_allclose(gi[0], np.linalg.inv(W.T @ W), rtol=1e-8)


@pytest.mark.parametrize("chunk", [None, CHUNK])
def test_validation_rss_of_a_training_fit_against_numpy(chunk):
    """The flexible mode's profile fits each point on train (``rss_with_columns``) and judges
    it on validation (``rss_fixed_with_columns``: the structure's and the mode's coefficients
    held, the filter's initial state and the mode's free response refitted), in one chunk and
    accumulated over chunks of 512 samples. Against numpy's lstsq on the explicit designs
    ε₁ = V₃ + aV₂ − bQ₁ + Σ cⱼ·colⱼ + N·η (V, Q the whole record's filter outputs, N the
    filter's free response C·Φᵏ): the training coefficients and RSS, and the validation RSS,
    to 1e-9 relative."""
    dt, T, hz = 1 / 997.3, 4000, 30.0
    model = lj.Augmented(lj.MassDamper(), ())
    rng = np.random.default_rng(11)
    t = np.arange(T) * dt
    regs, designs = [], []
    for _ in range(2):
        F = np.repeat(rng.standard_normal(T // 20), 20)
        x = np.cumsum(np.cumsum(F)) * dt * dt * 0.05 + 1e-6 * rng.standard_normal(T)
        r = _regressors(x, F, dt, hz, chunk)
        Vx, VF = _whole_outputs(r.dsc, x, 1.0), _whole_outputs(r.dsc, F, 0.0)
        regs.append(r)
        designs.append((np.stack([Vx[:, 1], -VF[:, 0]], 1), Vx[:, 2], _free_response(r.dsc, T)))
    # two sets of K = 4 extra columns per record: 2 held (a mode's), 2 refitted (its free
    # response), smooth enough to be identifiable
    m, K = 2, 4
    cols = [
        np.stack(
            [
                np.stack([np.sin(2 * np.pi * (3 + i + k) * t + j) for k in range(K)])
                for i in range(m)
            ]
        )
        for j in range(2)
    ]
    c, rss, n = rss_with_columns(regs[0], model, cols[0], coef=True)
    W, y, N = designs[0]
    assert n == W.shape[1] + N.shape[1]
    for i in range(m):
        D = np.concatenate([W, N, cols[0][i].T], 1)
        ref, res = np.linalg.lstsq(D, -y, rcond=None)[:2]
        np.testing.assert_allclose(c[i], ref, rtol=1e-9, atol=1e-9 * np.max(np.abs(ref)))
        np.testing.assert_allclose(rss[i], res[0], rtol=1e-9)
    got = rss_fixed_with_columns(regs[1], model, cols[1], c, 2)
    W, y, N = designs[1]
    for i in range(m):
        held = W @ c[i, :2] + y + cols[1][i, :2].T @ c[i, n : n + 2]
        B = np.concatenate([N, cols[1][i, 2:].T], 1)
        eta = np.linalg.lstsq(B, -held, rcond=None)[0]
        np.testing.assert_allclose(got[i], np.sum((held + B @ eta) ** 2), rtol=1e-9)


def test_fits_hold_only_small_arrays_per_structure():
    """ε₁'s least squares of a structure with an F-dependent column (b(x) = b + b₁ξ: the
    column ξ·u) under input maps u = sat_Fmax(F(t − τ)) — the profile grid's path — and for
    u = F, against numpy's lstsq on the explicit design [V₂(x), −Q₁(u), V₂(g), −Q₁(ξu), N]
    (the whole record's filter outputs; N the filter's free response), to 1e-9 relative. In one
    chunk (the design kept) and in chunks of 512 samples (the design rebuilt chunk by chunk)
    the same fits to 1e-9; in chunks nothing of the record's length is held per structure,
    only its plan and its Gram."""
    dt, T, hz = 1 / 997.3, 3000, 30.0
    rng = np.random.default_rng(5)
    F = np.repeat(rng.standard_normal(T // 20), 20)
    x = 0.01 * np.sin(np.arange(T) * dt * 2.1) + 1e-4 * np.cumsum(rng.standard_normal(T)) * dt
    c, ell = float(np.mean(x)), float(np.std(x))
    model = lj.Augmented(lj.MassDamper(), (lj.PolynomialPosition(c, ell, 1),))
    inputs = [(0.0, np.inf), (0.0031, np.inf), (0.0, 0.8), (0.0017, -1.2)]

    def fits(chunk):
        regs = _regressors(x, F, dt, hz, chunk)
        out = [fit_batch(regs, model, [inp])[:2] for inp in inputs[:1]]
        out.append(fit_batch(regs, model, inputs[1:])[:2])
        return regs, out

    regs, whole = fits(None)
    long_regs, chunked = fits(CHUNK)
    assert regs.whole and not long_regs.whole
    for a, b in zip(whole, chunked, strict=True):
        for u, v in zip(a, b, strict=True):
            _close(u, v, 1e-9)
    kinds = {k[0] for k in long_regs.cache if isinstance(k, tuple)}
    assert "design" not in kinds and {"plan", "gram"} <= kinds
    for k, v in long_regs.cache.items():
        if isinstance(k, tuple) and k[0] in ("plan", "gram"):
            arrays = [a for a in (v if isinstance(v, tuple) else (v,)) if isinstance(a, np.ndarray)]
            assert arrays and all(a.size <= (P_MAX + 1) ** 2 for a in arrays), k
    theta = np.concatenate([whole[0][0], whole[1][0]])
    rss = np.concatenate([whole[0][1], whole[1][1]])
    xi = (x - c) / ell
    g = ell * xi**2 / 2
    dsc = regs.dsc
    Vx, Vg = _whole_outputs(dsc, x, 1.0), _whole_outputs(dsc, g, 1.0)
    N = _free_response(dsc, T)
    for i, (tau, fmax) in enumerate(inputs):
        u = _input_reference(F, dt, tau, fmax)
        Qu, Qxu = _whole_outputs(dsc, u, 0.0), _whole_outputs(dsc, xi * u, 0.0)
        D = np.stack([Vx[:, 1], -Qu[:, 0], Vg[:, 1], -Qxu[:, 0]], 1)
        D = np.concatenate([D, N], 1)
        ref, res = np.linalg.lstsq(D, -Vx[:, 2], rcond=None)[:2]
        np.testing.assert_allclose(theta[i], ref[:4], rtol=1e-9, atol=1e-9 * np.abs(ref[:4]).max())
        np.testing.assert_allclose(rss[i], res[0], rtol=1e-9)


@pytest.fixture(scope="module")
def problems():
    """(one chunk, chunks of :data:`CHUNK`) diagnosis problems of one friction record (the
    axis sticks: its force columns are masked there)."""
    with jax.enable_x64(True):
        tr, va, _ = blind.make_case("coulomb_friction", 300_001_000, source="twin")
        st = settings(tr)
        one = Problem.of(tr, va, st, Criteria(), False, None)
        many = Problem.of(tr, va, st, Criteria(), True, CHUNK)
        assert tr.n_samples > 8 * CHUNK and one.sticks
        yield one, many


def test_grams_fits_and_residuals_in_chunks(problems):
    """A structure with an offset, Coulomb friction (its forces masked where the axis sticks), a
    position-dependent a(x), b(x) (an F-dependent column) and a delay/saturation input map:
    the Gram, the fits over an input grid (coefficients and RSS) and the validation residual,
    in chunks of 512 samples against one chunk: the Gram 1e-10, the fits 1e-8, the residuals
    1e-9."""
    structure = (
        OffsetCandidate(),
        CoulombCandidate(stick=True),
        PositionCandidate(degree=1),
        DelayCandidate(),
    )
    with jax.enable_x64(True):
        (rm, vm), (rs, vs) = (p.regressors(structure) for p in problems)
        assert rm.whole and not rs.whole and rs.force_mask is not None
        model_m, model_s = (p.model(structure) for p in problems)
        _close(rm.design_gram(model_m), rs.design_gram(model_s), 1e-10)
        inputs = [(0.0, math.inf), (0.0021, math.inf), (0.0, 1.3), (0.001, -2.0)]
        for a, b in zip(fit_batch(rm, model_m, inputs), fit_batch(rs, model_s, inputs)):
            _close(a, b, 1e-8)
        th = fit_batch(rm, model_m, inputs[1:2])[0][0]
        for inp in (inputs[0], inputs[1], inputs[3]):
            _close(residual(vm, model_m, th, inp), residual(vs, model_s, th, inp), 1e-9)


def test_profile_columns_in_chunks(problems):
    """Columns a profile adds (the localized step and bump, computed per chunk; a flexible
    mode's exact columns and free response; the mode itself as a structure's columns):
    training RSS with them, their coefficients and the validation RSS with the coefficients
    held, in chunks of 512 samples against one chunk, 1e-8."""
    one = problems[0]
    with jax.enable_x64(True):
        x, F = np.asarray(one.train.x), np.asarray(one.train.F)
        c0, w0 = float(np.median(x)), float(np.ptp(x)) / 5
        pts = [(c0, w0), (c0 + w0, w0 / 2)]
        signs = (1.0, -1.0, 1.0, -1.0)
        local = FilteredColumns(
            [
                [
                    (_local_raw(x, F, c, w, j), (1.0, 0.0)[j % 2], 1 - j % 2, signs[j])
                    for j in range(4)
                ]
                for c, w in pts
            ]
        )
        rss = [rss_with_columns(p.regressors(())[0], p.model(()), local) for p in problems]
        _close(*rss, 1e-9)
        lam = 2 * math.pi * one.st.filter_hz
        modes = [(2 * math.pi * 17.0, 0.05), (2 * math.pi * 31.0, 0.2), (2 * math.pi * 9.0, 0.03)]
        out = []
        for p in problems:
            (rtr, rva), base = p.regressors(()), p.model(())
            cols = ModeProfileColumns(modes, lam, p.st.dt)
            c, r, _ = rss_with_columns(rtr, base, cols, coef=True)
            out.append((c, r, rss_fixed_with_columns(rva, base, cols, c, 2)))
        for a, b in zip(*out, strict=True):
            _close(a, b, 1e-8)
        # the mode as a structure's columns (the exact stages on the filter's outputs)
        mode = (FlexibleModeCandidate(True, *modes[0]),)
        grams = [p.regressors(mode)[0].design_gram(p.model(mode)) for p in problems]
        _close(*grams, 1e-9)


def test_period_screen_and_mode_seed_in_chunks(problems):
    """The periodic look-alike's adjoint histograms (chunks visited backwards from saved filter
    states) and the flexible mode's equation-error seed (its Gram accumulated chunk by chunk),
    in chunks of 512 samples against one chunk: 1e-9 and 1e-6."""
    structure = (OffsetCandidate(), SpringCandidate())
    H = []
    with jax.enable_x64(True):
        for p in problems:
            rtr, model = p.regressors(structure)[0], p.model(structure)
            n = rtr.width(model)
            c = np.linspace(-1.0, 1.0, 18) * 1e-3
            x = rtr.x
            bins = np.clip(((x - x.min()) / np.ptp(x) * 64).astype(np.int64), 0, 63)
            H.append(_adjoint_histograms(rtr, model, c, n, np.ones(rtr.T), bins, 64))
        _close(H[0], H[1], 1e-9)
        one = problems[0]
        tr, lam = one.train, 2 * math.pi * one.st.filter_hz
        a = mode_seed(tr.x, tr.F, one.st.dt, lam, padded_length(tr.n_samples))
        b = mode_seed(tr.x, tr.F, one.st.dt, lam, CHUNK)
    assert (a is None) == (b is None)
    if a is not None:
        _close(a, b, 1e-6)


def test_dahl_states_in_chunks(problems):
    """Dahl's pre-sliding states of a friction record's v̂ (the axis sticks and reverses) at
    three distances, read in chunks of 700 samples (the states carried between chunks,
    distances batched) against the core's one scan over the whole record
    (lionjax.extend.dahl_states): 1e-12."""
    one = problems[0]
    v, dt = np.asarray(one.v_train, np.float64), one.st.dt
    zs = [1e-6, 3e-5, 2e-4]
    with jax.enable_x64(True):
        ref = np.asarray(dahl_states(jnp.asarray(v), dt, np.asarray(zs)))
    _close(ref, dahl_chunked(v, dt, zs, 700), 1e-12)


def test_mode_seed_lands_in_a_narrow_valley(monkeypatch):
    """The flexible mode's equation-error seed on a non-collocated mode at 12.9 Hz, ζ = 0.047
    (independent simulator, open loop, 312 Hz, noise-free; test_diagnose_modes.py diagnoses
    it): within 1 % of the simulator's ω and 5 % of its ζ, in one chunk and in chunks of 512
    samples. The mode's RSS valley in (ω, ζ) is a few per cent wide and falls between the
    coarse grid's points: the search starts from here."""
    from test_diagnose_modes import _noise_free_noncollocated_mode

    train, _, info = _noise_free_noncollocated_mode(monkeypatch, 12081004)
    p = info["effects"][0]["params"]
    w, z = 2 * math.pi * p["frequency"], p["damping_ratio"]
    dt = float(train.dt)
    lam = 2 * math.pi * min(1 / dt / 25, 40.0)
    for chunk in (padded_length(train.n_samples), CHUNK):
        ws, zs = mode_seed(train.x, train.F, dt, lam, chunk)
        assert ws == pytest.approx(w, rel=0.01) and zs == pytest.approx(z, rel=0.05)


# ----------------------------------------------------------------------------------------------
# The windowed simulation


def test_windowed_simulation_in_segments(monkeypatch):
    """A long record's windowed simulation in segments of whole windows against the whole
    record at once (each window restarts from its own state: the same steps), friction that
    sticks and a spring included: equal to 1e-12 of the error's peak; the samples after the last
    whole window 0 in both."""
    from lionjax.diagnosis import _lstsq

    rng = np.random.default_rng(7)
    T, dt, H = 20_003, 1e-3, 150
    t = np.arange(T) * dt
    u = np.sin(2 * np.pi * 0.7 * t) + 0.3 * rng.standard_normal(T)
    x = 0.01 * np.sin(2 * np.pi * 0.7 * t - 0.3)
    v = np.gradient(x, dt)
    p = {k: 0.0 for k in WINDOW_PARAMETERS}
    p |= {"a": 20.0, "b": 3.0, "Fc": 0.4, "k": 2.0, "x_lo": -np.inf, "x_hi": np.inf}
    whole = simulate_windows(p, u, x, x, v, dt, H)
    monkeypatch.setattr(_lstsq, "STREAM_ABOVE", 1 << 12)
    monkeypatch.setattr(_lstsq, "SIM_SEGMENT", 1 << 12)
    seg = _lstsq.simulate_windows(p, u, x, x, v, dt, H)
    n = (T // H) * H
    assert np.all(seg[n:] == 0) and np.all(whole[n:] == 0) and np.any(whole[:n] != 0)
    _close(whole, seg, 1e-12)


def test_true_model_simulates_at_the_noise_at_low_rates():
    """At 277 Hz, excited up to 24 Hz (f_s/11), the windowed simulation of the true model (a
    hard clip at 6 N of a 9.5 N force) from the start states stays within 2 encoder counts of
    the twin's record and at most half the gap of the same model without the clip; from the
    states of the former f_s/10 velocity filter both were 150 µm (measured when written), and the
    diagnosis rejected true models for making the simulated gap worse."""
    from lionjax import twin as tw

    fs, q, a, b, clip = 277.3, 5e-6, 40.0, 0.9, 6.0
    plant = tw.Plant(a, b, (), [tw.EncoderQuantisation(q)]).with_effects(tw.HardSaturation(clip))
    freqs = np.array([0.7, 2.3, 5.1, 9.7, 14.3, 19.9, 24.1])
    exc = tw.multisine(freqs, 1.5, key=jax.random.key(1))
    r = tw.simulate(plant, exc, dt=1 / fs, n_samples=int(10 * fs), key=jax.random.key(11))
    x, F = np.asarray(r.x), np.asarray(r.F)
    st = settings(lj.Record(x, F, r.dt))
    v_hat = zero_phase(x, r.dt, 2 * np.pi * st.velocity_hz)[1]
    _, x0, v0 = _start_states(x, r.dt, st.velocity_hz, v_hat)
    p = {k: 0.0 for k in WINDOW_PARAMETERS} | {"a": a, "b": b}
    H = round(fs / a)
    gaps = []
    for u in (np.clip(F, -clip, clip), F):
        e = simulate_windows(p, u, x, x0, v0, r.dt, H)
        gaps.append(np.sqrt(np.mean(e[H : (e.size // H) * H] ** 2)))
    assert np.max(np.abs(F)) > 1.4 * clip
    assert gaps[0] <= 2 * q and gaps[0] <= 0.5 * gaps[1], gaps


# ----------------------------------------------------------------------------------------------
# The memory estimate


def test_memory_estimate_in_one_chunk_and_in_chunks():
    """The host memory a diagnosis is estimated to need (diagnose refuses records above the
    budget before computing; the figures are measured, benchmarks/results/): in one chunk
    6.5 kB per padded sample of each record (its filtered signals and designs kept); in chunks
    the process' 1.2 GB and 160 B per raw sample. Records above 2¹⁷ padded samples are read in
    chunks by default: a 10-minute record at 10 kHz (and a 2-minute one) needs under 3 GB so,
    68 GB in one chunk.
    The longest records that fit a budget, against the formulas."""
    assert not streamed_by_default(100_000, 20_000)
    assert streamed_by_default(6_000_000, 1_200_000)
    assert memory_estimate(6_000_000, 1_200_000) < 3e9
    assert memory_estimate(6_000_000, 1_200_000, streamed=False) > 30e9
    # diagnose's check: read in chunks, such records fit 3 GB; in one chunk they are refused,
    # the message pointing to the chunks
    assert _check_memory(6_000_000, 1_200_000, 3.0) is True
    with pytest.raises(lj.InputError, match="streamed=True"):
        _check_memory(6_000_000, 1_200_000, 3.0, False)
    assert memory_estimate(20_000, 20_000) == 6500 * 2 * 2**15
    assert memory_estimate(6_000_000, 6_000_000, streamed=False) == 6500 * 2 * 2**23
    assert memory_estimate(6_000_000, 6_000_000) == STREAM_FIXED + BYTES_PER_SAMPLE_STREAMED * 12e6
    # in one chunk per padded sample, at every length: at 3.5 GB two records of 2¹⁸ fit
    # (6500·2·2¹⁸ = 3.41 GB), at 7 GB two of 2¹⁹ (6.82 GB); padded_length pads n + 20
    assert longest_records(3.5e9, streamed=False) == 2**18 - 20
    assert longest_records(7.0e9, streamed=False) == 2**19 - 20
    assert longest_records(0.01e9) == 0
    # in chunks (by default above 2¹⁷ padded samples), far longer records fit
    n = longest_records(3.8e9)
    assert n == (3.8e9 - STREAM_FIXED) // (2 * BYTES_PER_SAMPLE_STREAMED) and n > 2**22


# ----------------------------------------------------------------------------------------------
# The searches, against brute force


def test_grid_search_against_argmin():
    """The least of a function over a grid, evaluated in batches of 3 (a short last one):
    numpy's argmin of the values computed one by one; NaN values never win, unless
    ``nan_wins`` (then the first NaN, as numpy's argmin has it)."""
    pts = tuple(float(p) for p in np.linspace(-2.0, 3.0, 11))
    f = lambda p: (p - 0.7) ** 2 + 0.1 * math.sin(5 * p)  # noqa: E731
    calls = []

    def batch(ps):
        calls.append(len(ps))
        return [f(p) for p in ps]

    i, values = GridSearch(pts, 3).minimise(batch)
    ref = np.array([f(p) for p in pts])
    assert calls == [3, 3, 3, 2]
    np.testing.assert_array_equal(values, ref)
    assert i == int(np.argmin(ref))
    nan = lambda ps: [math.nan if p in (pts[2], pts[8]) else f(p) for p in ps]  # noqa: E731
    assert GridSearch(pts).minimise(nan)[0] == int(np.nanargmin(nan(pts)))
    assert GridSearch(pts, nan_wins=True).minimise(nan)[0] == 2


def test_parabola_step_against_polyfit():
    """The vertex through a grid's best point and its neighbours, in the parameter or its
    logarithm, against numpy's polyfit of degree 2 through the same three points: 1e-12;
    None on the grid's edge and where the parabola opens downward; held within the three."""
    rng = np.random.default_rng(8)
    for log in (False, True):
        grid = np.sort(rng.uniform(0.1, 10.0, 7))
        g = np.log(grid) if log else grid
        values = (g - g[3] - 0.3 * (g[4] - g[3])) ** 2 + 0.05 * rng.standard_normal(7) ** 2
        i = 3
        A, B, _ = np.polyfit(g[i - 1 : i + 2], values[i - 1 : i + 2], 2)
        ref = -B / (2 * A)
        ref = min(max(ref, g[i - 1]), g[i + 1])
        assert A > 0
        v = ParabolaStep(log=log).vertex(grid, values, i)
        assert v == pytest.approx(math.exp(ref) if log else ref, rel=1e-12)
        assert ParabolaStep(log=log).vertex(grid, values, 0) is None
        assert ParabolaStep(log=log).vertex(grid, values, 6) is None
        assert ParabolaStep(log=log).vertex(grid, -values, i) is None  # opens downward
    # a vertex beyond the neighbours (at 13/6) is held on them
    grid, values = np.array([0.0, 1.0, 2.0]), np.array([3.0, 1.0, 0.2])
    assert ParabolaStep().vertex(grid, values, 1) == 2.0


def test_golden_section_against_brute_force():
    """Golden-section steps of a unimodal function between two points against the least of a
    dense brute-force grid (10⁶ points): within the bracket's width after the steps (0.618ⁿ of
    the interval) plus the grid's spacing; the best value is that of the returned point, and a
    start already better than every step is kept."""
    c = 0.31370

    def f(v):
        return math.cosh(3.0 * (v - c)) + 0.2 * (v - c) ** 3

    dense = np.linspace(-1.0, 2.0, 1_000_001)
    ref = dense[int(np.argmin(np.cosh(3.0 * (dense - c)) + 0.2 * (dense - c) ** 3))]
    for steps in (10, 30):
        best, value = GoldenSection(steps).minimise(f, -1.0, 2.0, 2.0, f(2.0))
        assert abs(best - ref) <= 3.0 * 0.618034**steps + 3e-6
        assert value == f(best)
    assert GoldenSection(10).minimise(f, -1.0, 2.0, c, 0.0) == (c, 0.0)


def test_pattern_search_against_brute_force():
    """A compass search in two parameters on a smooth, skewed bowl, its moves held within a box:
    against the least of a dense brute-force grid over the box (2001² points), within the
    final step (halved ``rounds`` times) plus the grid's spacing, with the minimum inside the
    box and beyond its edge; no point is evaluated twice (its rings share points)."""
    lo, hi = (-3.0, -2.0), (3.0, 2.0)

    def f(p, c):
        a, b = p[0] - c[0], p[1] - c[1]
        return a * a + 3.0 * b * b + 1.5 * a * b + 0.1 * a**4

    def move(p, i, j, steps):
        return (
            min(max(p[0] + i * steps[0], lo[0]), hi[0]),
            min(max(p[1] + j * steps[1], lo[1]), hi[1]),
        )

    g0, g1 = np.meshgrid(np.linspace(lo[0], hi[0], 2001), np.linspace(lo[1], hi[1], 2001))
    for centre in ((1.23, -0.47), (4.0, 0.3)):  # inside the box, beyond its right edge
        dense = f((g0, g1), centre)
        k = np.unravel_index(np.argmin(dense), dense.shape)
        ref = (g0[k], g1[k])
        counts: dict = {}

        def batch(ps, centre=centre, counts=counts):
            for p in ps:
                counts[p] = counts.get(p, 0) + 1
            return np.array([f(p, centre) for p in ps])

        search = PatternSearch(rounds=20, max_steps=500)
        p, value = search.minimise(batch, (0.0, 0.0), f((0.0, 0.0), centre), (1.0, 1.0), move, {})
        tol = 2.0**-20 + 3e-3
        assert abs(p[0] - ref[0]) <= tol and abs(p[1] - ref[1]) <= tol, (p, ref)
        assert value == f(p, centre) <= float(np.min(dense)) + 1e-12
        assert max(counts.values()) == 1


def test_best_so_far_takes_the_least_and_the_first_on_a_tie():
    assert best_so_far([("a", 2.0), ("b", 1.0), ("c", 1.0)]) == ("b", 1.0)
