"""The position-periodic look-alike (cogging, out of the library) against independent references:
a Runge–Kutta simulation of a mass–damper with a force periodic in position, and numpy ``lstsq`` on
the explicit ε₁ design with the sinusoids' columns."""

import math

import numpy as np
import pytest

import lionjax as lj
from lionjax.diagnosis import _core

DT = 1 / 997.3
A, B = 20.0, 2.0


def _record(seed, cog, period, n=6000, noise=1e-6):
    """ẍ + aẋ = b(F + cog·sin(2πx/period + 0.7)), F held between samples: classical RK4 with
    8 steps per sample (written here; its step error, ~(ωh)⁴, is far below the noise)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    F = sum(
        a * np.sin(2 * np.pi * f * t + p)
        for a, f, p in zip(
            rng.uniform(0.5, 1.0, 6), rng.uniform(0.3, 8.0, 6), rng.uniform(0, 6, 6), strict=True
        )
    )
    w = 2 * math.pi / period

    def acc(x, v, f):
        return -A * v + B * (f + cog * math.sin(w * x + 0.7))

    x = np.empty(n)
    xk = vk = 0.0
    h = DT / 8
    for k in range(n):
        x[k] = xk
        f = float(F[k])
        for _ in range(8):
            a1 = acc(xk, vk, f)
            a2 = acc(xk + h / 2 * vk, vk + h / 2 * a1, f)
            a3 = acc(xk + h / 2 * (vk + h / 2 * a1), vk + h / 2 * a2, f)
            a4 = acc(xk + h * (vk + h / 2 * a2), vk + h * a3, f)
            xk, vk = (
                xk + h * vk + h * h / 6 * (a1 + a2 + a3),
                vk + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4),
            )
    return lj.Record(x + noise * rng.standard_normal(n), F, DT)


@pytest.fixture(scope="module")
def cogging():
    period = 0.0023
    return _record(1, 0.08, period), _record(2, 0.08, period), period


def test_periodic_lookalike_against_numpy(cogging):
    """The look-alike's period and validated mean square: the period within 1 % of the drawn
    one and at the least training RSS of an exact grid (numpy lstsq on the explicit design
    ε₁ = V₃ + aV₂ − bQ₁ + c_s·Λ[sin 2πκξ] + c_c·Λ[cos 2πκξ] + N·η, N the filter's free
    response) within 0.02 cycles; the validation mean square of that training fit (the
    nuisance refitted on validation) to 1e-9."""
    train, valid, period = cogging
    st = _core.settings(train)
    fitter = _core._Fitter(train, valid, st)
    ms, p = fitter.periodic_lookalike([])
    assert p == pytest.approx(period, rel=0.01)
    x_lo = min(train.x.min(), valid.x.min())
    R = max(train.x.max(), valid.x.max()) - x_lo
    k = R / p

    def design(regs, kk):
        T = regs.T
        xi = (regs.x - x_lo) / R
        V = regs.filtered(
            {
                "x": (regs.x, "foh"),
                "F": (regs.F, "zoh"),
                "s": (np.sin(2 * np.pi * kk * xi), "foh"),
                "c": (np.cos(2 * np.pi * kk * xi), "foh"),
            }
        )
        regs.drop(["s", "c"])
        W = np.stack([V["x"][:T, 1], -V["F"][:T, 0], V["s"][:T, 0], V["c"][:T, 0]], 1)
        return W, np.asarray(V["x"][:T, 2]), np.asarray(regs.N)[:T]

    def train_fit(kk):
        W, y, N = design(fitter.rtr, kk)
        D = np.concatenate([W, N], 1)
        c, res = np.linalg.lstsq(D, -y, rcond=None)[:2]
        return c[: W.shape[1]], float(res[0])

    grid = k + np.linspace(-0.3, 0.3, 61)
    best = grid[int(np.argmin([train_fit(kk)[1] for kk in grid]))]
    assert float(k) == pytest.approx(float(best), abs=0.02)
    c, _ = train_fit(k)
    W, y, N = design(fitter.rva, k)
    held = W @ c + y
    eta = np.linalg.lstsq(N, -held, rcond=None)[0]
    ref = np.mean((held + N @ eta) ** 2)
    assert float(ms) == pytest.approx(float(ref), rel=1e-9)


def test_cogging_is_unexplained_with_its_period(cogging):
    """A force periodic in position is not in the library: the record is ``unexplained``, and
    ``where`` names the period (within 1 %). (Clean records stay ``none``: test_diagnose.)"""
    train, valid, period = cogging
    d = lj.diagnose(train, valid)
    assert d.verdict == "unexplained", (d.verdict, d.stack)
    assert d.final["periodic_lookalike"]["significant"]
    found = [w for w in d.where if w["kind"] == "position_period"]
    assert found and found[0]["period"] == pytest.approx(period, rel=0.01)
