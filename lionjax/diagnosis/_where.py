"""Where is the gap: shares of the validation residual by region, band and time.

Each finding is a dict ``{"kind", "band", "share", "fraction", "ratio", …}``: ``share`` is the
band's part of the residual's sum of squares (ε₁ of the baseline), ``fraction`` the part of the
samples (or of the input's power, for frequency bands) it holds, ``ratio = share/fraction`` (≫ 1:
the gap concentrates there). Plus MATLAB ``resid``'s two tests with 99 % bounds, on the residual
decimated to the filter's time constant: whiteness (autocorrelation at lags 1…20) and
cross-correlation with the input F (lags 0…20).
"""

from __future__ import annotations

import math
from itertools import pairwise
from statistics import NormalDist
from typing import Any

import numpy as np

#: Lags of the residual tests (MATLAB ``resid``'s 20), and the autocorrelation lags Bartlett's
#: factor sums for the odd-input test (:func:`odd_input_dependence`).
LAGS, BARTLETT_LAGS = 20, 50
#: Family-wise level of the odd-input test (over its two functions and 21 lags).
ODD_LEVEL = 0.01


def _bands(kind, labels, masks, r2, note="", weight=None):
    """The findings of the bands ``masks`` (bool, like ``r2``) of the squared residual ``r2``;
    ``fraction`` the band's share of ``weight`` (default: of the samples)."""
    total, weight = float(np.sum(r2)) or 1.0, np.ones(r2.size) if weight is None else weight
    out = []
    for lab, m in zip(labels, masks, strict=True):
        share = float(np.sum(r2[m])) / total
        frac = float(np.sum(weight[m])) / (float(np.sum(weight)) or 1.0)
        ratio = share / frac if frac > 0 else None
        out.append(dict(kind=kind, band=lab, share=share, fraction=frac, ratio=ratio, note=note))
    return out


def _lagged(a: np.ndarray, b: np.ndarray, first: int, last: int) -> np.ndarray:
    """ρ(a, b) at lags ``first`` … ``last``: the means of a[k:]·b[:n − k] of the two series
    standardised (a series without spread left centred)."""
    a = (a - a.mean()) / (a.std() or 1.0)
    b = (b - b.mean()) / (b.std() or 1.0)
    n = a.size
    return np.array([np.mean(a[k:] * b[: n - k]) for k in range(first, last + 1)])


def _xcorr_test(a: np.ndarray, b: np.ndarray, lags: int, first: int = 0) -> dict[str, Any]:
    """The largest |ρ(a, b)| over lags ``first`` … ``lags`` against the 99 % bound of white
    noise, 2.576/√n."""
    vals = _lagged(a, b, first, lags)
    bound = 2.576 / math.sqrt(a.size)
    worst = float(np.max(np.abs(vals)))
    return {"max_abs": worst, "bound_99": bound, "passed": bool(worst <= bound)}


def _decimated(r: np.ndarray, F: np.ndarray, st) -> tuple[np.ndarray, np.ndarray]:
    """``r`` and ``F`` decimated to the filter's time constant."""
    step = max(1, int(round(1.0 / (2 * math.pi * st.filter_hz * st.dt))))
    return r[::step], F[::step]


def _resid_tests(r: np.ndarray, F: np.ndarray, st) -> tuple[dict, dict]:
    """(whiteness, input correlation) of ``r`` decimated to the filter's time constant."""
    rd, Fd = _decimated(r, F, st)
    return _xcorr_test(rd, rd, LAGS, first=1), _xcorr_test(rd, Fd, LAGS)


def odd_input_dependence(r: np.ndarray, F: np.ndarray, st) -> float:
    """How far a residual ``r`` (n,) depends on the input ``F`` (its first n samples) beyond
    linearly, by Billings and Voon's higher-order correlation test (docs/method.md, "The
    verdict"): an odd function of the force (a dead zone, a saturation) leaves a least-squares
    residual uncorrelated with F, but not with g = sign F or g = F³, each less its least-squares
    part in (1, F). On r and F decimated to the filter's time constant,

        max over g and lags 0…20 of |ρ(r, g)|·√(n/β),  β = 1 + 2Σₖ ρ_r(k)ρ_g(k) (k = 1…50),

    β Bartlett's factor for two autocorrelated series, over the normal quantile of
    1 − ODD_LEVEL/(2·2·21) (Bonferroni over both g and all lags): > 1 is significant."""
    rd, Fd = _decimated(np.asarray(r, np.float64), np.asarray(F, np.float64)[: np.size(r)], st)
    n = rd.size
    if n < 2 * BARTLETT_LAGS or not np.std(rd) > 0 or not np.std(Fd) > 0:
        return 0.0
    X = np.column_stack([np.ones(n), Fd])
    ra = _lagged(rd, rd, 1, BARTLETT_LAGS)
    worst = 0.0
    for g in (np.sign(Fd), Fd**3):
        g = g - X @ np.linalg.lstsq(X, g, rcond=None)[0]
        if not np.std(g) > 0:
            continue
        beta = max(1.0 + 2.0 * float(np.sum(ra * _lagged(g, g, 1, BARTLETT_LAGS))), 1.0)
        rho = _xcorr_test(rd, g, LAGS)["max_abs"]
        worst = max(worst, rho * math.sqrt(n / beta))
    return worst / NormalDist().inv_cdf(1.0 - ODD_LEVEL / (2 * 2 * (LAGS + 1)))


def _spectrum(r: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(power of ``r``'s spectrum, its frequencies [Hz])."""
    return np.abs(np.fft.rfft(r - r.mean())) ** 2, np.fft.rfftfreq(r.size, dt)


def where_findings(series: dict[str, np.ndarray], st, floor: float) -> list[dict[str, Any]]:
    """The "where" findings (this module's docstring) of the validation series, arrays (T,):
    ``residual_base`` (the baseline's ε₁ [m/s²]), ``x`` [m], ``F`` [N], ``v`` [m/s]; ``st`` holds
    ``dt`` [s] and ``filter_hz``, ``floor`` ε₁'s rms from noise alone [m/s²] (≤ 0: unknown)."""
    r, x, F, v = (np.asarray(series[k]) for k in ("residual_base", "x", "F", "v"))
    r2 = r * r
    q = np.quantile(x, [1 / 3, 2 / 3])  # terciles of the validation positions
    v0 = 0.1 * float(np.median(np.abs(v)))  # near zero: reversals, stick
    Fa = np.abs(F)
    fq = np.quantile(Fa, [0.5, 0.95])
    n = r.size
    quarter = np.arange(n) * 4 // n
    out = [
        *_bands(
            "position",
            [f"x < {q[0]:.4g} m", f"{q[0]:.4g} ≤ x ≤ {q[1]:.4g} m", f"x > {q[1]:.4g} m"],
            [x < q[0], (x >= q[0]) & (x <= q[1]), x > q[1]],
            r2,
        ),
        *_bands(
            "velocity",
            [f"|v| < {v0:.3g} m/s (near zero, reversals)", f"|v| ≥ {v0:.3g} m/s"],
            [np.abs(v) < v0, np.abs(v) >= v0],
            r2,
        ),
        *_bands(
            "force",
            [f"|F| < {fq[0]:.3g} N", f"{fq[0]:.3g} ≤ |F| < {fq[1]:.3g} N", f"|F| ≥ {fq[1]:.3g} N"],
            [Fa < fq[0], (Fa >= fq[0]) & (Fa < fq[1]), Fa >= fq[1]],
            r2,
        ),
        *_bands(
            "time", [f"quarter {i + 1}" for i in range(4)], [quarter == i for i in range(4)], r2
        ),
    ]
    # octaves of the residual's spectrum relative to the filter corner
    spec, f = _spectrum(r, st.dt)
    fc = st.filter_hz
    edges = list(pairwise([0, fc / 16, fc / 4, fc, 4 * fc, np.inf]))
    out += _bands(
        "frequency",
        [f"{lo:.3g}–{hi:.3g} Hz" for lo, hi in edges],
        [(f >= lo) & (f < hi) for lo, hi in edges],
        spec,
        "fraction = share of the input F's power in the band",
        weight=_spectrum(F, st.dt)[0],
    )
    peak = float(f[1:][np.argmax(spec[1:])]) if n > 2 else 0.0
    out.append({"kind": "frequency_peak", "band": f"{peak:.4g} Hz", "share": None})
    w, c = _resid_tests(r, F, st)
    out += [
        {**w, "kind": "whiteness", "band": "lags 1…20", "share": None},
        {**c, "kind": "input_correlation", "band": "lags 0…20", "share": None},
    ]
    rms = float(np.sqrt(np.mean(r2)))
    ratio = rms / floor if floor > 0 else None
    out.append(dict(kind="noise_floor", band="all", share=None, rms=rms, floor=floor, ratio=ratio))
    return out


def structure(
    r: np.ndarray, F: np.ndarray, st, F_odd: np.ndarray | None = None
) -> dict[str, float]:
    """How structured a validation residual ``r`` (n,) is against the input ``F`` (its first n
    samples), the tests over their 99 % bound of white noise (docs/method.md, "The verdict"):

    - ``input_correlation``: max |ρ(r, F)| over lags 0…20 — an unmodelled input-driven effect;
    - ``input_odd``: :func:`odd_input_dependence` on ``F_odd`` (default F) — one odd in F;
    - ``whiteness``: max |ρ(r, r)| over lags 1…20 (ε₁ is filtered, so > 1 even for white noise
      on x: compare a structure before and after a candidate);
    - ``peak``: the largest power of the spectrum (smoothed over ±2 bins) in 0…4·f_filter over
      its median there, high for a narrow-band residual (a mode); ``peak_power`` that power / n.
    """
    r = np.asarray(r, np.float64)
    w, c = _resid_tests(r, np.asarray(F, np.float64)[: r.size], st)
    spec, f = _spectrum(r, st.dt)
    band = spec[(f > 0) & (f < 4 * st.filter_hz)]
    if band.size >= 5:
        sm = np.convolve(band, np.ones(5) / 5, mode="same")
        peak = float(np.max(sm) / max(np.median(sm), 1e-300))
        peak_power = float(np.max(sm)) / r.size
    else:
        peak, peak_power = 1.0, 0.0
    return {
        "input_correlation": c["max_abs"] / c["bound_99"],
        "input_odd": odd_input_dependence(r, F if F_odd is None else F_odd, st),
        "whiteness": w["max_abs"] / w["bound_99"],
        "peak": peak,
        "peak_power": peak_power,
    }
