"""The diagnosis on measured records (issue 64): Silverbox, an analogue mass–damper with a
hardening spring whose natural frequency lies above the default filter corner, so that a
mass–damper fitted to it is qualitatively wrong (b ≤ 0). The spring is named first, the final
model is a result (b > 0), and its natural frequency is within 5 % of two independent estimates:
a linear state-variable-filter least squares (scipy's cont2discrete/lfilter, numpy's lstsq) and
the peak of the nonparametric H1 frequency response (scipy's Welch estimates)."""

import math

import numpy as np
import pytest
from scipy import signal

import lionjax as lj


def _svf_f0(rec: lj.Record, lam_hz: float = 50.0) -> float:
    """f₀ [Hz] of y'' = −c·y' − k·y + g·u + d by least squares on (λ/(s + λ))³-filtered signals."""
    y, u, h = np.asarray(rec.x, float), np.asarray(rec.F, float), float(rec.dt)
    lam = 2 * math.pi * lam_hz
    den = np.poly([-lam] * 3)

    def f(num, x):
        b, a = signal.cont2discrete((num, den), h, method="bilinear")[:2]
        return signal.lfilter(np.squeeze(b), a, x)

    X = np.column_stack(
        [-f([lam**3, 0], y), -f([lam**3], y), f([lam**3], u), f([lam**3], np.ones_like(y))]
    )[300:]
    z = f([lam**3, 0, 0], y)[300:]
    _, k, _, _ = np.linalg.lstsq(X, z, rcond=None)[0]
    return math.sqrt(k) / (2 * math.pi)


def _h1_peak(rec: lj.Record) -> float:
    """The frequency [Hz] of |P_uy/P_uu|'s peak between 5 and 200 Hz."""
    fs = 1 / float(rec.dt)
    u, y = np.asarray(rec.F, float), np.asarray(rec.x, float)
    f, Puu = signal.welch(u, fs, nperseg=8192)
    _, Puy = signal.csd(u, y, fs, nperseg=8192)
    band = (f > 5) & (f < 200)
    return float(f[band][np.argmax(np.abs(Puy / Puu)[band])])


@pytest.mark.slow
def test_silverbox_spring_dominant():
    train = lj.datasets.silverbox("train")
    valid = lj.datasets.silverbox("test_multisine")
    d = lj.diagnose(train, valid)
    assert d.verdict == "spring", (d.verdict, d.stack, d.confidence)
    assert d.confidence > 0.5
    # the baseline is said to be qualitatively wrong, in words; the final model is a result
    assert d.baseline["params"]["b"] <= 0
    assert any("b ≤ 0" in why for why in d.baseline["qualitatively_wrong"])
    fin = d.final["params"]
    assert fin["b"] > 0 and d.final["result"]
    f_n = math.sqrt(fin["b"] * fin["k"]) / (2 * math.pi)
    for ref in (_svf_f0(train), _h1_peak(train)):
        assert abs(f_n / ref - 1) < 0.05, (f_n, ref)
    # each step carries the figures of the effect it names
    units = {c.name: set(c.units) for c in lj.diagnosis.DEFAULT_CANDIDATES}
    for s in d.steps:
        assert set(s.params) <= units[s.name], (s.name, s.params)
