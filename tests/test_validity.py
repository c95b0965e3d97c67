"""The validity layer (lionjax._validity, issue 39): every answer is right or refused.

Records come from the independent simulator tests/_reference_sim.py; right answers are compared
with the simulated truth (noise-free, so the tolerances are the discretisation floor's).
"""

import re
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _reference_sim import multisine, simulate

import lionjax as lj
from lionjax import _validity as validity

DT = 1e-3
A, B = 20.0, 2.0
MD = lj.MassDamper()


def record(T=20000, dt=DT, a=A, b=B, freqs=(0.7, 2.3, 5.1, 9.7), amps=(0.2, 0.15, 0.1, 0.1)):
    t = np.arange(T) * dt
    F = multisine(t, list(freqs), list(amps))
    return lj.Record(simulate(F, dt, a=(a,), b=(b,), bounds=()), F, dt)


@pytest.fixture(scope="module")
def rec():
    return record(T=8000)  # 8 s: past the 2.25-s transient, 500-sample gaps between windows


def _fails(sol):
    return int(lj.solutions.result_codes(sol.result)) != 0


# ---------------------------------------------------------------------------------------------
# Case 1: constant position


@pytest.mark.slow  # three-region and fixed-gain batched kernels compiled
def test_case1_constant_position_refused_by_every_method(rec):
    still = lj.Record(np.full(rec.n_samples, 0.003), rec.F, DT)
    for run in (
        lambda: lj.least_squares(MD, still),
        lambda: lj.lion(MD, still),
        lambda: lj.lion(MD, still, gain=lj.FixedGain(1e4)),
    ):
        with pytest.raises(lj.IdentificationError, match=r"Not identified from this record: a \("):
            run()
    rows = lj.identify_batch(MD, [rec, still])
    assert rows.result[0] == 0 and rows.result[1] > 0 and "Not identified: a." in rows.messages[1]
    assert np.all(np.isnan(rows.theta[1]))
    lion_rows = lj.identify_batch(MD, [rec, still], method=lj.Lion(gain=lj.FixedGain(1e4)))
    assert lion_rows.result[1] > 0 and lion_rows.to_rows()[1]["status"] == "failed"


# ---------------------------------------------------------------------------------------------
# Case 2: filter speed against sampling


def test_case2_bias_bound_measured():
    # the bound's measurement (module docstring of lionjax._validity), two points of it: b is
    # biased by about −ρ²/4, ρ = max|pole|·dt, on noise-free data with the exact discretisation
    r = record(T=6000)
    for rho, lo, hi in ((0.2, -0.012, -0.008), (0.02, -2e-4, 0.0)):
        bank = lj.FilterBank.from_poles([-rho / DT] * 3, unit_dc_gain=True)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", lj.solutions.FilterSpeedWarning)
            b = float(lj.least_squares(MD, r, bank=bank).theta[1])
        assert lo < (b - B) / B < hi, (rho, (b - B) / B)


def test_case2_fast_poles_warn_then_refused(rec):
    fast = lj.FilterBank.from_poles([-150.0] * 3, unit_dc_gain=True)  # ρ = 0.15: warned
    with pytest.warns(lj.solutions.FilterSpeedWarning, match=r"argument 'bank'.*slower poles"):
        lj.least_squares(MD, rec, bank=fast)
    # the cases: ρ = 0.5 (a = 28.8 for 20) and ρ = 10 (a = 1496) are refused
    for poles in (-500.0, -1e4):
        faster = lj.FilterBank.from_poles([poles] * 3, unit_dc_gain=True)
        for run in (
            lambda: lj.least_squares(MD, rec, bank=faster),
            lambda: lj.lion(MD, rec, bank=faster),
            lambda: lj.identify_batch(MD, [rec], bank=faster),
        ):
            with pytest.raises(lj.InputError, match=r"argument 'bank'.*too fast.*sample faster"):
                run()
    batch, L = lj.stack_records([rec, rec])
    with pytest.raises(lj.InputError, match=r"lion_batched: argument 'bank'"):
        lj.lion_batched(MD, batch, bank=faster)


def test_case2_slow_sampling_default_filter_is_right():
    slow = record(T=3000, dt=1.0, a=0.2, b=0.1, freqs=(0.002, 0.01, 0.03, 0.07), amps=(0.01,) * 4)
    # the paper's (s + 4)³ is 4 rad/s × 1 s, above Nyquist: refused, naming the argument
    paper = lj.FilterBank.from_poles([-4.0] * 3, unit_dc_gain=True)
    with pytest.raises(lj.InputError, match=r"argument 'bank'.*\|p\| ≤ 0\.1 rad/s"):
        lj.least_squares(MD, slow, bank=paper)
    # the default slows to (s + 0.02/dt)³: right to 1e-4 (was a = 0.126 for 0.2)
    np.testing.assert_allclose(lj.least_squares(MD, slow).theta, [0.2, 0.1], rtol=1e-4)
    assert float(lj.default_bank(1.0).coeffs[-1]) == pytest.approx(0.02**3)
    # and stays the paper's at 1 kHz (bit for bit: every existing figure unchanged)
    np.testing.assert_array_equal(lj.default_bank(DT).coeffs, lj.default_bank().coeffs)
    np.testing.assert_array_equal(lj.default_bank().coeffs, [12.0, 48.0, 64.0])


def test_too_short_message_suggests_poles_within_the_bound(rec):
    short = lj.Record(rec.x[:1000], rec.F[:1000], DT)
    with pytest.raises(lj.InputError, match=r"9\.00901 ≤ p ≤ 100 rad/s \(max\|pole\|·dt ≤ 0\.1\)"):
        lj.least_squares(MD, short)
    tiny = lj.Record(rec.x[:50], rec.F[:50], DT)
    with pytest.raises(lj.InputError, match="Use a longer record: at dt"):
        lj.least_squares(MD, tiny)


# ---------------------------------------------------------------------------------------------
# Case 3: a fixed gain no longer skips the excitation check


@pytest.mark.slow  # three-region and fixed-gain batched kernels compiled
@pytest.mark.parametrize("batched", [False, True])
def test_case3_fixed_gain_unvisited_regions_named(rec, batched):
    pw = lj.Piecewise((-0.5, 0.5))  # the record stays in the middle region
    G = lj.FixedGain(1e4)
    names = "a_1, b_1, a_3, b_3"  # all four, not one of them
    if not batched:
        with pytest.raises(
            lj.IdentificationError, match=f"Not identified from this record: {names}"
        ):
            lj.lion(pw, rec, gain=G)
        with pytest.raises(lj.IdentificationError, match=names):
            lj.least_squares(pw, rec)
        return
    batch = jax.tree.map(lambda *a: jnp.stack(a), rec, rec)
    sol = lj.lion_batched(pw, batch, gain=G, throw=False)
    assert np.all(lj.solutions.result_codes(sol.result) > 0)
    np.testing.assert_array_equal(sol.unexcited, [[1, 1, 0, 0, 1, 1]] * 2)
    with pytest.raises(lj.IdentificationError, match=r"batch element \(1,\): a_1, b_1, a_3, b_3"):
        lj.lion_batched(pw, batch, gain=G)
    rows = lj.identify_batch(pw, [rec], method=lj.Lion(gain=G))
    assert rows.result[0] > 0 and f"Not identified: {names}." in rows.messages[0]


def test_case3_fixed_gain_zero_force(rec):
    dead = lj.Record(rec.x, np.zeros(rec.n_samples), DT)
    with pytest.raises(lj.IdentificationError, match=r"Not identified from this record: b \("):
        lj.lion(MD, dead, gain=lj.FixedGain(1e4))
    batch = jax.tree.map(lambda *a: jnp.stack(a), rec, dead)
    sol = lj.lion_batched(MD, batch, gain=lj.FixedGain(1e4), throw=False)
    np.testing.assert_array_equal(lj.solutions.result_codes(sol.result) > 0, [False, True])
    np.testing.assert_array_equal(sol.unexcited, [[False, False], [False, True]])


def test_fixed_gain_burst_between_the_windows_is_excited(rec):
    # the batch check reads windows of the raw signals (validity.RAW_WINDOWS runs of
    # RAW_WINDOW samples); a force that acts only between two windows is missed there, and
    # every sample of the flagged record is read again: excited, not refused
    T = rec.n_samples
    seg = T // validity.RAW_WINDOWS
    F = np.zeros(T)
    F[seg + 100 : seg + 400] = np.asarray(rec.F)[seg + 100 : seg + 400]
    burst = lj.Record(rec.x, F, DT)
    batch = jax.tree.map(lambda *a: jnp.stack(a), rec, burst)
    on_windows = validity.raw_unexcited(MD, batch)
    np.testing.assert_array_equal(on_windows, [[False, False], [False, True]])  # missed there
    sol = lj.lion_batched(MD, batch, gain=lj.FixedGain(1e4), throw=False)
    np.testing.assert_array_equal(lj.solutions.result_codes(sol.result), [0, 0])
    np.testing.assert_array_equal(sol.unexcited, [[False, False], [False, False]])
    one = lj.lion(MD, burst, gain=lj.FixedGain(1e4))  # the single-record check: every sample
    np.testing.assert_allclose(sol.theta[1], one.theta_final, rtol=1e-9, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# Case 4: padded batches


def test_case4_padded_batch_without_lengths_refused(rec):
    short = lj.Record(rec.x[:6000], rec.F[:6000], DT)
    batch, L = lj.stack_records([rec, short])
    for run in (lj.lion_batched, lj.least_squares_batched):
        with pytest.raises(lj.InputError, match=r"record\(s\) \[1\].*Pass lengths="):
            run(MD, batch)
    # with the lengths the answer is right: the shorter record equals least squares on itself
    sol = lj.least_squares_batched(MD, batch, lengths=L)
    ref = lj.least_squares(MD, short, initial="discard")
    np.testing.assert_allclose(sol.theta[1], ref.theta, rtol=1e-8)
    np.testing.assert_allclose(sol.theta[1], [A, B], rtol=1e-3)
    # lengths all equal to T declare records that really end at rest (nothing refused)
    full = lj.lion_batched(MD, batch, lengths=np.full(2, batch.n_samples), throw=False)
    assert full.theta.shape == (2, 2)


# ---------------------------------------------------------------------------------------------
# The weak items


def test_record_dt_and_t0_named():
    for dt in (0.0, -1e-3, np.nan, np.inf):
        with pytest.raises(lj.InputError, match=r"Record: dt must be the sampling interval"):
            lj.Record(np.zeros(100), np.zeros(100), dt)
    with pytest.raises(lj.InputError, match="t0"):
        lj.Record(np.zeros(100), np.zeros(100), 1e-3, np.nan)


def test_theta0_named(rec):
    for run in (
        lambda: lj.lion(MD, rec, theta0=[np.nan, 1.0]),
        lambda: lj.identify_batch(MD, [rec], method=lj.Lion(theta0=[np.nan, 1.0])),
    ):
        with pytest.raises(lj.InputError, match=r"theta0 must be finite, got nan at index 0 \(a\)"):
            run()
    batch = jax.tree.map(lambda *a: jnp.stack(a), rec, rec)
    with pytest.raises(lj.InputError, match="theta0 must be finite"):
        lj.lion_batched(MD, batch, theta0=[1.0, np.inf])


def test_overflow_is_out_of_range_not_unexcited(rec):
    huge = lj.Record(rec.x, np.asarray(rec.F) * 1e200, DT)
    with pytest.raises(
        lj.InputError, match=r"column 'F' is out of range.*not a lack of excitation"
    ):
        lj.least_squares(MD, huge)
    rows = lj.identify_batch(MD, [rec, huge], labels=["good", "huge"])
    assert rows.result[0] == 0 and rows.result[1] > 0
    assert "record 'huge'" in rows.messages[1] and "out of range" in rows.messages[1]
    assert "excite" not in rows.messages[1]
    batch = jax.tree.map(lambda *a: jnp.stack(a), rec, huge)
    sol = lj.least_squares_batched(MD, batch, throw=False)
    codes = lj.solutions.result_codes(sol.result)
    assert codes[0] == 0 and codes[1] == lj.solutions.result_codes(lj.RESULTS.nonfinite)


def test_messages_print_plain_floats(rec):
    with pytest.raises(lj.InputError) as err:
        lj.lion(MD, rec, theta0=np.array([np.float64(3.0), np.nan]))
    assert "np.float64" not in str(err.value)
    fast = lj.FilterBank.from_poles([-1e4] * 3, unit_dc_gain=True)
    with pytest.raises(lj.InputError) as err:
        lj.least_squares(MD, rec, bank=fast)
    assert "np.float64" not in str(err.value)


def test_sanity_warnings(rec):
    mm = lj.Record(np.asarray(rec.x) * 1e3 + 50.0, rec.F, DT)
    with pytest.warns(lj.solutions.DataWarning, match="millimetres"):
        lj.least_squares(MD, mm)
    spiky = np.asarray(rec.F).copy()
    spiky[5000] = 1e6 * np.median(np.abs(spiky))
    with pytest.warns(lj.solutions.DataWarning) as caught:
        lj.least_squares(MD, lj.Record(rec.x, spiky, DT), throw=False)
    said = [str(w.message) for w in caught]
    assert any(re.search(r"glitch: a spike F\[5000\] = ", m) for m in said), said
    # and the fit it spoils explains next to nothing of the response (warn_poor_fit)
    assert any("explains only" in m for m in said), said
    twice = lambda a: np.concatenate([np.asarray(a)] * 2)  # ≥ 10 000 samples
    ms = lj.Record(twice(rec.x), twice(rec.F), 1.0)  # a 1 kHz record whose t was read in ms
    msgs = validity.sanity_messages(ms)
    assert any("milliseconds" in m for m in msgs)
    # none on an ordinary record
    assert validity.sanity_messages(rec) == []


def test_bounds_stated():
    assert validity.WARN_POLE_DT == 0.1 and validity.MAX_POLE_DT == 0.25
    assert validity.DEFAULT_POLE_DT == 0.02 and validity.DEFAULT_POLE * DT <= 0.02
