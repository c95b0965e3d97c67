"""The diagnosis' filter kernel (:mod:`lionjax.diagnosis._filtering`): the batched filter bank
λ³sᵏ/(s + λ)³ against scipy's zero-order-hold discretisation, the one-output reader
:func:`filter_columns` against the whole outputs, the unrolled products against numpy, and the
two-signal calls of long records."""

import numpy as np
import pytest


def test_matvec_unrolled_against_numpy():
    """A·z of the recursions' unrolled elementwise products against numpy, broadcast over
    leading axes as the recursion uses it (Φʲ·S_m: A (L, 1, n, n), z (1, M, n)), 1e-15."""
    from lionjax._linalg import matvec_unrolled

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
def test_filter_signals_against_scipy_and_filter_columns():
    """Eleven zero-order-held signals (two batches: 8 and 3 padded to 8) through the diagnosis'
    bank Λ = (s + λ)³ with unit DC gain: output k (V₁…V₄) is λ³sᵏ/Λ[u] from rest under u[0],
    against scipy's cont2discrete + dlsim, 1e-9 of each output's peak; and
    :func:`filter_columns` gives each signal's chosen output exactly as
    :func:`filter_signals` does."""
    from scipy import signal

    from lionjax._filters import FilterBank
    from lionjax.diagnosis._filtering import (
        Discrete,
        edge_pad,
        filter_columns,
        filter_signals,
        padded_length,
    )

    dt, T, lam = 1 / 1013.0, 2500, 2 * np.pi * 31.0
    Tp = padded_length(T)
    rng = np.random.default_rng(1)
    # held steps of random levels, a different switching pattern per signal
    U = np.stack([np.repeat(rng.standard_normal(T // 50 + 1), 50)[:T] for _ in range(11)])
    bank = FilterBank.from_poles(np.full(3, -lam), unit_dc_gain=True)
    dsc = Discrete.of(bank, dt)
    Up = np.stack([edge_pad(u, Tp) for u in U])
    V = filter_signals(dsc, Up, np.zeros(len(U)))
    assert V.shape == (11, Tp, 4)
    den = np.poly(np.full(3, -lam))
    for k in range(4):
        num = np.zeros(4)
        num[3 - k] = lam**3  # λ³sᵏ
        A, B, C, D, _ = signal.cont2discrete(signal.tf2ss(num, den), dt, "zoh")
        for i in (0, 5, 10):
            x0 = np.linalg.solve(np.eye(3) - A, B[:, 0] * U[i, 0])  # at rest under u[0]
            ref = signal.dlsim((A, B, C, D, dt), U[i], t=np.arange(T) * dt, x0=x0)[1][:, 0]
            np.testing.assert_allclose(V[i, :T, k], ref, rtol=0, atol=1e-9 * np.max(np.abs(ref)))
    orders = rng.integers(0, 4, len(U))
    cols = filter_columns(dsc, Up, np.zeros(len(U)), orders, T)
    assert cols.shape == (11, T)
    for i, k in enumerate(orders):
        np.testing.assert_array_equal(cols[i], V[i, :T, k])


def test_long_records_filter_two_signals_per_call(monkeypatch):
    """Above :data:`LONG_BATCH` padded samples a filter call takes at most two signals (its
    intermediates grow with the batch); the outputs agree with the batched ones to rounding
    (1e-12 of each signal's peak: a batch of another size may round the last bits)."""
    from lionjax._filters import FilterBank
    from lionjax.diagnosis import _filtering
    from lionjax.diagnosis._filtering import Discrete, filter_signals

    rng = np.random.default_rng(2)
    U = rng.standard_normal((7, 4096)).cumsum(1)
    foh = np.array([1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0])
    dsc = Discrete.of(FilterBank.from_poles(np.full(3, -2 * np.pi * 20.0), unit_dc_gain=True), 1e-3)
    batched = filter_signals(dsc, U, foh)
    sizes = []
    many = _filtering._filter_many

    def spy(d, u, f):
        sizes.append(u.shape[0])
        return many(d, u, f)

    monkeypatch.setattr(_filtering, "_filter_many", spy)
    monkeypatch.setattr(_filtering, "LONG_BATCH", 2048)
    long = filter_signals(dsc, U, foh)
    assert sizes == [2, 2, 2, 1]
    peak = np.max(np.abs(batched), axis=(1, 2))[:, None, None]
    assert np.all(np.abs(long - batched) <= 1e-12 * peak)
