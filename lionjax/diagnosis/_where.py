"""Where is the gap: shares of the validation residual by region, band and time.

Each finding is a dict ``{"kind", "band", "share", "fraction", "ratio", …}``: ``share`` is the
band's part of the residual's sum of squares (ε₁ of the baseline), ``fraction`` the part of the
samples (or of the input's power, for frequency bands) it holds, ``ratio = share/fraction`` (≫ 1:
the gap concentrates there). Plus two tests with 99 % bounds: whiteness of the residual
(autocorrelation at lags 1…20 after decimation to the filter's time constant) and its
cross-correlation with the input F.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def _bands(kind, labels, masks, r2, note=""):
    total = float(np.sum(r2)) or 1.0
    out = []
    for lab, m in zip(labels, masks, strict=True):
        frac = float(np.mean(m)) if m.size else 0.0
        share = float(np.sum(r2[m])) / total
        out.append(
            {
                "kind": kind,
                "band": lab,
                "share": share,
                "fraction": frac,
                "ratio": share / frac if frac > 0 else None,
                "note": note,
            }
        )
    return out


def _xcorr_test(a: np.ndarray, b: np.ndarray, lags: int) -> dict[str, Any]:
    a = (a - a.mean()) / (a.std() or 1.0)
    b = (b - b.mean()) / (b.std() or 1.0)
    n = a.size
    vals = [float(np.mean(a[k:] * b[: n - k])) for k in range(0 if a is not b else 1, lags + 1)]
    bound = 2.576 / math.sqrt(n)
    worst = float(np.max(np.abs(vals))) if vals else 0.0
    return {"max_abs": worst, "bound_99": bound, "passed": bool(worst <= bound)}


def where_findings(series: dict[str, np.ndarray], st, floor: float) -> list[dict[str, Any]]:
    """The "where" findings from the validation series of a diagnosis."""
    r = np.asarray(series["residual_base"])
    x, F, v = (np.asarray(series[k]) for k in ("x", "F", "v"))
    r2 = r * r
    out: list[dict[str, Any]] = []
    # position regions: terciles of the validation positions
    q = np.quantile(x, [1 / 3, 2 / 3])
    out += _bands(
        "position",
        [f"x < {q[0]:.4g} m", f"{q[0]:.4g} ≤ x ≤ {q[1]:.4g} m", f"x > {q[1]:.4g} m"],
        [x < q[0], (x >= q[0]) & (x <= q[1]), x > q[1]],
        r2,
    )
    # velocity: near zero (reversals, stick) vs moving
    va = np.abs(v)
    v0 = 0.1 * float(np.median(va))
    out += _bands(
        "velocity",
        [f"|v| < {v0:.3g} m/s (near zero, reversals)", f"|v| ≥ {v0:.3g} m/s"],
        [va < v0, va >= v0],
        r2,
    )
    # force magnitude: below the median, median…95 %, top 5 %
    Fa = np.abs(F)
    fq = np.quantile(Fa, [0.5, 0.95])
    out += _bands(
        "force",
        [f"|F| < {fq[0]:.3g} N", f"{fq[0]:.3g} ≤ |F| < {fq[1]:.3g} N", f"|F| ≥ {fq[1]:.3g} N"],
        [Fa < fq[0], (Fa >= fq[0]) & (Fa < fq[1]), Fa >= fq[1]],
        r2,
    )
    # time: quarters of the record
    n = r.size
    idx = np.arange(n)
    out += _bands(
        "time", [f"quarter {i + 1}" for i in range(4)], [idx * 4 // n == i for i in range(4)], r2
    )
    # frequency bands of the residual's spectrum, octaves relative to the filter corner
    spec = np.abs(np.fft.rfft(r - r.mean())) ** 2
    fF = np.abs(np.fft.rfft(F - F.mean())) ** 2
    f = np.fft.rfftfreq(n, st.dt)
    fc = st.filter_hz
    edges = [0, fc / 16, fc / 4, fc, 4 * fc, np.inf]
    tot, totF = float(np.sum(spec)) or 1.0, float(np.sum(fF)) or 1.0
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        m = (f >= lo) & (f < hi)
        share = float(np.sum(spec[m])) / tot
        fin = float(np.sum(fF[m])) / totF
        out.append(
            {
                "kind": "frequency",
                "band": f"{lo:.3g}–{hi:.3g} Hz",
                "share": share,
                "fraction": fin,
                "ratio": share / fin if fin > 0 else None,
                "note": "fraction = share of the input F's power in the band",
            }
        )
    peak = float(f[1:][np.argmax(spec[1:])]) if n > 2 else 0.0
    out.append({"kind": "frequency_peak", "band": f"{peak:.4g} Hz", "share": None})
    # tests, on the residual decimated to roughly independent samples
    step = max(1, int(round(1.0 / (2 * math.pi * fc * st.dt))))
    rd, Fd = r[::step], F[::step]
    w = _xcorr_test(rd, rd, 20)
    w.update(kind="whiteness", band="lags 1…20", share=None)
    c = _xcorr_test(rd, Fd, 20)
    c.update(kind="input_correlation", band="lags 0…20", share=None)
    out += [w, c]
    rms = float(np.sqrt(np.mean(r2)))
    out.append(
        {
            "kind": "noise_floor",
            "band": "all",
            "share": None,
            "rms": rms,
            "floor": floor,
            "ratio": rms / floor if floor > 0 else None,
        }
    )
    return out


def structure(r: np.ndarray, F: np.ndarray, st) -> dict[str, float]:
    """How structured a validation residual is, relative to the 99 % bound of white noise
    (MATLAB ``resid``'s two tests, on the residual decimated to the filter's time constant):

    - ``input_correlation``: max |ρ(r, F)| over lags 0…20 / bound — a residual that still
      follows the input holds an unmodelled input-driven effect;
    - ``whiteness``: max |ρ(r, r)| over lags 1…20 / bound (ε₁ is filtered, so this is > 1 even
      for white noise on x; compare a structure before and after a candidate);
    - ``peak``: the largest power of the residual's spectrum (smoothed over ±2 bins) in
      0…4·f_filter over its median there — a narrow-band residual (a mode) has a high peak.
    """
    r = np.asarray(r, np.float64)
    F = np.asarray(F, np.float64)[: r.size]
    step = max(1, int(round(1.0 / (2 * math.pi * st.filter_hz * st.dt))))
    rd, Fd = r[::step], F[::step]
    w = _xcorr_test(rd, rd, 20)
    c = _xcorr_test(rd, Fd, 20)
    spec = np.abs(np.fft.rfft(r - r.mean())) ** 2
    f = np.fft.rfftfreq(r.size, st.dt)
    band = spec[(f > 0) & (f < 4 * st.filter_hz)]
    if band.size >= 5:
        sm = np.convolve(band, np.ones(5) / 5, mode="same")
        peak = float(np.max(sm) / max(np.median(sm), 1e-300))
        peak_power = float(np.max(sm)) / r.size
    else:
        peak, peak_power = 1.0, 0.0
    return {
        "input_correlation": c["max_abs"] / c["bound_99"],
        "whiteness": w["max_abs"] / w["bound_99"],
        "peak": peak,
        "peak_power": peak_power,
    }
