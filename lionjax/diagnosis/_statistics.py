"""Record statistics the diagnosis starts from: memory, noise floors, start states, the loop."""

from __future__ import annotations

import hashlib
import math
import numbers
import os

import numpy as np

from .._errors import InputError
from .._record import Record
from ._filtering import MIN_PADDED, _capacity, padded_length
from ._streaming import zero_phase

# Host memory as measured (benchmarks/results/2026-11-28_diagnosis_lengths.md,
# 2026-11-28_streamed_diagnosis.md), with 20–25 % over the heaviest record.
#: In one chunk [bytes per padded sample of each record]: filtered signals and designs kept.
BYTES_PER_SAMPLE_CACHED = 6_500
#: Padded lengths above this are read in chunks by default: in one chunk 2¹⁸ samples peak at up
#: to 2.7 GB; in chunks about 1.1 GB at any length, at up to twice the time.
STREAM_ABOVE = 1 << 17
#: In chunks [bytes per sample of each record]: the raw per-sample signals.
BYTES_PER_SAMPLE_STREAMED = 160
#: In chunks, at any length [bytes]: the process, its programs and a chunk's intermediates.
STREAM_FIXED = 1_200_000_000


def streamed_by_default(*n_samples: int) -> bool:
    """Whether records of ``n_samples`` samples are read in chunks by default."""
    return max(padded_length(int(n)) for n in n_samples) > STREAM_ABOVE


def memory_estimate(*n_samples: int, streamed: bool | None = None) -> int:
    """Peak host memory [bytes] of a diagnosis of records of ``n_samples`` samples, read in
    chunks (``streamed``; default :func:`streamed_by_default`) or each in one."""
    if streamed is None:
        streamed = streamed_by_default(*n_samples)
    if streamed:
        return STREAM_FIXED + BYTES_PER_SAMPLE_STREAMED * sum(int(n) for n in n_samples)
    return sum(BYTES_PER_SAMPLE_CACHED * padded_length(int(n)) for n in n_samples)


def longest_records(budget: float, count: int = 2, streamed: bool | None = None) -> int:
    """The most samples each of ``count`` records may have for :func:`memory_estimate` to stay
    within ``budget`` [bytes] (it drops where records are read in chunks); 0 when none fit."""
    fits = [
        _capacity(Tp)
        for Tp in (MIN_PADDED << k for k in range(29))
        if memory_estimate(*[_capacity(Tp)] * count, streamed=streamed) <= budget
    ]
    if streamed is not False:
        n = int((budget - STREAM_FIXED) // (BYTES_PER_SAMPLE_STREAMED * count))
        if n > 0 and (streamed or streamed_by_default(n)):
            fits.append(n)
    return max(fits, default=0)


def decimation_to_fit(budget: float, *n_samples: int, streamed: bool | None = None) -> int:
    """The least factor r ≥ 1 for which the records decimated by r (⌊n/r⌋ samples each) fit
    :func:`memory_estimate` within ``budget`` [bytes]; 0 when none does."""
    r = 1
    while True:
        n = [int(k) // r for k in n_samples]
        if memory_estimate(*n, streamed=streamed) <= budget:
            return r
        if max(n) <= _capacity(MIN_PADDED):  # already in the shortest bucket: none helps
            return 0
        r += 1


def physical_memory() -> int | None:
    """This machine's physical memory [bytes], or None where the OS does not say."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):
        return None


def _memory_budget(max_memory_gb: float | None) -> float | None:
    """Host memory [bytes] a diagnosis may take: ``max_memory_gb``, else this machine's
    physical memory (None where the OS does not say)."""
    if max_memory_gb is not None and not (
        isinstance(max_memory_gb, numbers.Real)
        and not isinstance(max_memory_gb, bool)
        and max_memory_gb > 0
    ):
        raise InputError(f"diagnose: max_memory_gb must be a number > 0, got {max_memory_gb!r}.")
    return physical_memory() if max_memory_gb is None else max_memory_gb * 1e9


def decimation_for(
    train: Record,
    valid: Record | None = None,
    *,
    max_memory_gb: float | None = None,
    streamed: bool | None = None,
) -> int:
    """The least factor r for which :func:`diagnose` of ``train.decimate(r)`` and
    ``valid.decimate(r)`` fits the host memory (``max_memory_gb``, default this machine's;
    ``streamed`` as :func:`diagnose` takes it): 1 when the records fit as they are, 0 when no
    factor helps (``lionjax diagnose --decimate auto``)."""
    valid = train if valid is None else valid
    have = _memory_budget(max_memory_gb)
    if have is None:
        return 1
    return decimation_to_fit(have, train.n_samples, valid.n_samples, streamed=streamed)


def _check_memory(n_train: int, n_valid: int, max_memory_gb, streamed=None) -> bool:
    """Whether the records are read in chunks (``streamed``: True, False, a chunk length, or
    None: by their length); InputError when they need more host memory than allowed."""
    if not (
        streamed is None
        or isinstance(streamed, bool)
        or (isinstance(streamed, numbers.Integral) and streamed >= 16)
    ):
        raise InputError(
            "diagnose: streamed must be True, False, None or a chunk length of at least 16 "
            f"samples, got {streamed!r}."
        )
    streamed = streamed_by_default(n_train, n_valid) if streamed is None else bool(streamed)
    have = _memory_budget(max_memory_gb)
    need = memory_estimate(n_train, n_valid, streamed=streamed)
    if have is None or need <= have:
        return streamed
    limit = "this machine" + ("" if streamed else "'s physical memory")
    head = (
        f"diagnose: the train and valid records ({n_train} and {n_valid} samples) need about "
        f"{need / 1e9:.3g} GB of host memory{' streamed' if streamed else ''}, more than "
        f"{'max_memory_gb' if max_memory_gb is not None else limit} ({have / 1e9:.3g} GB)."
    )
    if streamed:
        raise InputError(
            f"{head} Diagnose shorter excerpts or decimate both records (Record.decimate; CLI: "
            "--decimate)."
        )
    n = longest_records(have, streamed=False)
    r = decimation_to_fit(have, n_train, n_valid, streamed=False)
    how = (
        f"Decimate both records by {r} or more (train.decimate({r}), valid.decimate({r}): "
        f"the diagnosis then runs at {r}× the sample interval; CLI: --decimate {r}, or "
        f"--decimate auto), diagnose shorter excerpts (at most about {n} samples each), or"
        if n
        else "Even the shortest records do not fit:"
    )
    raise InputError(
        f"{head} {how} diagnose them streamed (streamed=True; CLI: --streamed on), or pass a "
        "larger max_memory_gb (CLI: --max-memory-gb) on a machine with swap."
    )


def _long_runs(flag: np.ndarray, n: int) -> np.ndarray:
    """``flag`` (T,) bool with its runs of True shorter than ``n`` samples cleared."""
    f = np.concatenate([[False], np.asarray(flag, bool), [False]])
    d = np.diff(f.astype(np.int8))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    out = np.zeros(f.size - 2, bool)
    for s0, e0 in zip(starts, ends, strict=True):
        if e0 - s0 >= n:
            out[s0:e0] = True
    return out


#: A reversal counts once the axis moves back by this many times the position noise: noise
#: alone does not move x by ±5σ, so it never reverses the axis.
REVERSAL_NOISE = 10.0
#: Bins over a record's range in which the passes are counted.
PASS_BINS = 1024


def _passes(x: np.ndarray, sx: float) -> tuple[float, int]:
    """(the share of the samples of x (T,) at positions the axis passes at least twice, the
    number of its reversals): the path cut at its reversals (a move back by more than
    :data:`REVERSAL_NOISE`·``sx`` [m]) into one-way passes, each covering the positions between
    its ends. The share is 0 for an axis moving one way, about 1 for one moving back and forth (a
    start far from where it then moves counts only for the samples of that start)."""
    x = np.asarray(x, np.float64)
    lo, span = float(np.min(x)), float(np.ptp(x))
    h = max(REVERSAL_NOISE * sx, 1e-12 * max(span, abs(lo)))
    if not span > h:
        return 0.0, 0
    # the path at its crossings of levels h/2 apart, then its local extrema: every reversal by
    # more than h is between two of them
    lvl = np.floor((x - lo) / (h / 2))
    keep = np.concatenate([[0], np.flatnonzero(np.diff(lvl)) + 1, [x.size - 1]])
    y = x[keep]
    d = np.sign(np.diff(y))
    ext = np.concatenate([[0], np.flatnonzero(d[1:] * d[:-1] < 0) + 1, [y.size - 1]])
    turns, up, hi, low = [], 0, y[0], y[0]  # the passes' ends: the start's, then each reversal's
    for v in y[ext]:
        if up == 0:  # the first move by more than h sets the direction
            hi, low = max(hi, v), min(low, v)
            if hi - low > h:
                up = 1 if v == hi else -1
                turns.append(low if up == 1 else hi)
                ext_v = v
        elif (v - ext_v) * up > 0:
            ext_v = v
        elif (ext_v - v) * up > h:
            turns.append(ext_v)
            up, ext_v = -up, v
    if not turns:
        return 0.0, 0
    turns.append(ext_v)

    def bin_of(v):
        return np.clip(((np.asarray(v) - lo) / span * PASS_BINS).astype(np.int64), 0, PASS_BINS - 1)

    edges = bin_of(turns)  # a pass covers the bins from one end's to the other's, both included
    cover = np.zeros(PASS_BINS + 1)
    np.add.at(cover, np.minimum(edges[:-1], edges[1:]), 1.0)
    np.add.at(cover, np.maximum(edges[:-1], edges[1:]) + 1, -1.0)
    twice = np.cumsum(cover)[:PASS_BINS] >= 2
    return float(np.mean(twice[bin_of(x)])), len(turns) - 2


#: Largest noise of the windowed simulation's start velocity, as a share of the rms of v̂.
STATE_NOISE = 0.02
#: The top of the spectrum or the one-step prediction stands for a position's noise where it
#: lies this far below the third differences: beyond the estimators' disagreement on a
#: quantised record's uniform noise (≈ 15 %); the top only where it is white: its halves'
#: levels within NOISE_FLAT of each other.
NOISE_DISAGREE = 2.0
NOISE_FLAT = 2.0
#: The one-step predictor of a position (:func:`_prediction_noise`): from PREDICT_X past
#: positions (a rigid axis' two states, a mode's two, and room for a filter's) and up to
#: PREDICT_F past forces (the plant's memory, at most 1/32 of the record), fitted over at most
#: PREDICT_SAMPLES samples from the record's middle.
PREDICT_X = 8
PREDICT_F = 128
PREDICT_SAMPLES = 1 << 15


def _noise_gain(dt: float, omega: float | None) -> float:
    """‖h‖₂ of the velocity estimator's impulse response: white position noise σ [m] gives the
    estimate the noise σ·‖h‖₂ [m/s]. ``omega`` [rad/s]: the zero-phase filter's corner; None:
    the five-point derivative (:func:`_five_point`), √130/(12·dt)."""
    if omega is None:
        return math.sqrt(130.0) / (12.0 * dt)
    imp = np.zeros(2048)
    imp[1024] = 1.0
    return float(np.linalg.norm(zero_phase(imp, dt, omega)[1]))


def _start_states(
    x: np.ndarray, dt: float, velocity_hz: float, v: np.ndarray
) -> tuple[float, np.ndarray, np.ndarray]:
    """(f [Hz], x₀, v₀): the states the windowed simulation restarts from, at each sample.

    Estimated in the widest band whose velocity noise (σ through the estimator,
    :func:`_noise_gain`) stays within :data:`STATE_NOISE` of the rms of ``v`` (v̂ at
    ``velocity_hz``): the raw samples and their five-point derivative (f = ∞), else the
    zero-phase filter at 8, 4 or 2 × ``velocity_hz`` (below 0.3·f_s), else at ``velocity_hz``.
    v̂'s own band suits sgn ẋ, not the states: its filter (1 + (f/f_v)²)⁻³ keeps 1/8 of the
    motion at f_v, which lies at the excited band's edge at low sample rates."""
    sx = _white_noise(x)
    limit = STATE_NOISE * float(np.sqrt(np.mean(np.asarray(v, np.float64) ** 2)))
    if sx * _noise_gain(dt, None) <= limit:
        return math.inf, x, _five_point(x, dt)
    for m in (8.0, 4.0, 2.0):
        f = min(m * velocity_hz, 0.3 / dt)
        if sx * _noise_gain(dt, 2 * math.pi * f) <= limit:
            break
    else:
        f = velocity_hz
    sm, g = zero_phase(x, dt, 2 * math.pi * f)
    return f, sm, g


def _five_point(x: np.ndarray, dt: float) -> np.ndarray:
    """ẋ [m/s] of x [m] by the five-point stencil (x₋₂ − 8x₋₁ + 8x₁ − x₂)/(12·dt) (second-order
    differences at the ends): gain (8 sin ωdt − sin 2ωdt)/(6ωdt) = 1 − (ωdt)⁴/30 + … on a sine,
    0.3 % low at f_s/11 where central differences are 5 % low."""
    v = np.gradient(x, dt, edge_order=2)
    if x.size >= 5:
        v[2:-2] = (x[:-4] - 8.0 * x[1:-3] + 8.0 * x[3:-1] - x[4:]) / (12.0 * dt)
    return v


def _high_band(x: np.ndarray) -> tuple[float, float]:
    """(σ, flatness) of a signal's white noise (x [m] or F [N]) from the top of the spectrum:
    the median periodogram of Δx (Hann window) over 0.3–0.5·f_s, divided by Δ's gain
    4·sin²(πf/f_s) and by ln 2 (an exponential's median over its mean). An upper bound (motion
    there counts as noise) that, unlike the third differences, holds when the excitation
    reaches f_s/11 (Δ³ of a sine there is 0.18× its amplitude). The flatness is the ratio of
    the level over 0.4–0.5·f_s to that over 0.3–0.4·f_s: near 1 for white noise."""
    d = np.diff(np.asarray(x, np.float64))
    n = d.size
    if n < 16:
        return math.inf, math.nan
    w = np.hanning(n)
    P = np.abs(np.fft.rfft((d - d.mean()) * w)) ** 2 / np.sum(w * w)
    k = np.arange(P.size)
    band = (k >= 0.3 * n) & (k < 0.5 * n)
    Q = P[band] / (4.0 * np.sin(np.pi * k[band] / n) ** 2)
    lower, upper = np.median(Q[: Q.size // 2]), np.median(Q[Q.size // 2 :])
    flat = float(upper / lower) if lower > 0 else math.nan
    return float(np.sqrt(np.median(Q) / math.log(2.0))), flat


def _white_noise(u: np.ndarray) -> float:
    """σ of a signal's white noise: the lesser of two upper bounds, the third differences
    (:func:`_robust_diff_std`: a rough excitation counts as noise) and the top of the spectrum
    (:func:`_high_band`: motion at 0.3–0.5·f_s counts), but never below q/√12 of its
    converter's count q (:func:`_lattice_step`): a slow signal's quantisation error is a
    staircase, not white, and hides from the top of the spectrum."""
    return max(min(_robust_diff_std(u), _high_band(u)[0]), _lattice_step(u) / math.sqrt(12.0))


def _position_noise(x: np.ndarray, F: np.ndarray) -> float:
    """σ [m] of a position record's noise (x [m], F [N] (T,) each): the third-difference estimate
    (:func:`_robust_diff_std`), or the top of the spectrum (:func:`_high_band`) where that is
    white (its two halves within :data:`NOISE_FLAT` of each other) and :data:`NOISE_DISAGREE`
    below it: an excitation reaching f_s/5 puts its own Δ³ into the third differences, a
    filtered record's noise is not white and falls off at the top. Where an excitation fills
    the top as well, the one-step prediction from the past (:func:`_prediction_noise`) where it
    lies :data:`NOISE_DISAGREE` below: the force predicts the motion it drives. Never below q/√12
    of its encoder's count q (:func:`_lattice_step`): a quantised position's error is uniform
    over one count when the axis moves several counts per sample, and the third differences
    then miss it."""
    d3 = _robust_diff_std(x)
    top, flat = _high_band(x)
    white = 1.0 / NOISE_FLAT <= flat <= NOISE_FLAT
    sigma = top if white and d3 > NOISE_DISAGREE * top else d3
    predicted = _prediction_noise(x, F)
    if sigma > NOISE_DISAGREE * predicted:
        sigma = predicted
    return max(sigma, _lattice_step(x) / math.sqrt(12.0))


def _prediction_noise(x: np.ndarray, F: np.ndarray) -> float:
    """An upper bound of σ [m], a position's white noise nₖ: the rms error of x's least-squares
    one-step predictor from :data:`PREDICT_X` past positions and up to :data:`PREDICT_F` past
    forces (and a constant), its degrees of freedom taken out; ∞ on a record too short for it.

    nₖ is independent of every earlier sample, of x and of F (in closed loop the controller
    feeds it into F only from the next sample on), so no predictor from the past errs by less
    than σ: xₖ = sₖ + nₖ leaves E(xₖ − P)² = σ² + E(sₖ − P)². The bound is tight where the past
    forces predict the motion they drive (σ √(1 + Σaᵢ²) where the past positions carry it, aᵢ
    their weights), and holds where an excitation fills the spectrum up to f_s/2, where the third
    differences and the spectrum's top count the motion. The positions enter as Δⁱxₖ₋₁
    (i < PREDICT_X), the same span as xₖ₋₁ … xₖ₋ₚ and well conditioned, and the target is Δᵖxₖ
    (xₖ less a combination of them)."""
    x, F = np.asarray(x, np.float64), np.asarray(F, np.float64)
    p, m = PREDICT_X, min(PREDICT_F, x.size // 32)
    lag = max(p, m)
    k0 = max((x.size - lag - PREDICT_SAMPLES) // 2, 0)
    x, F = x[k0 : k0 + lag + PREDICT_SAMPLES], F[k0 : k0 + lag + PREDICT_SAMPLES]
    N, cols = x.size - lag, p + m + 1
    if N < 16 * cols:
        return math.inf
    A = np.empty((N, cols))
    d = x - np.mean(x)
    for i in range(p):
        A[:, i] = d[lag - 1 - i : lag - 1 - i + N]  # Δⁱx at k − 1 (d shrinks from the front)
        d = np.diff(d)
    y = d[lag - p : lag - p + N]  # Δᵖx at k
    Fc = F - np.mean(F)
    for j in range(1, m + 1):
        A[:, p + j - 1] = Fc[lag - j : lag - j + N]
    A[:, -1] = 1.0
    A /= np.maximum(np.sqrt(np.mean(A * A, 0)), 1e-300)
    w, V = np.linalg.eigh(A.T @ A)
    keep = w > 1e-14 * w[-1]
    solve = lambda g: V[:, keep] @ ((V[:, keep].T @ g) / w[keep])  # noqa: E731
    c = solve(A.T @ y)
    r = y - A @ c
    c = c + solve(A.T @ r)  # one step of refinement
    r = y - A @ c
    return math.sqrt(float(r @ r) / (N - cols))


def _robust_diff_std(u: np.ndarray) -> float:
    """σ of white noise on a smooth signal from its third differences (Var(Δ³n) = 20σ²): the
    larger of the MAD (Gaussian noise) and the RMS of the 99 % smallest |Δ³u| (stick–slip
    outliers left out). A coarse encoder on a slow axis gives sparse noise (Δ³ = 0 except around
    each count's step), whose variance the MAD misses."""
    d = np.diff(u, 3)
    if d.size == 0:
        return 0.0
    mad = 1.4826 * np.median(np.abs(d - np.median(d)))
    a = np.sort(np.abs(d))
    trimmed = float(np.sqrt(np.mean(a[: max(1, int(0.99 * a.size))] ** 2)))
    return float(max(mad, trimmed) / math.sqrt(20.0))


def _feedback(
    x: np.ndarray, F: np.ndarray, lags: int = 4, past: int = 8
) -> tuple[float, np.ndarray]:
    """(share, F_ref): a controller on the measured position, read from the record.

    ``share``: the part of the force's innovation that the position just measured explains. On
    third differences (they whiten the position noise and drop a slow drift), Δ³F is regressed
    on its own lags 1…``past`` and Δ³x at lags 2…``past``, then Δ³x at lags 0 and 1 is added:
    share = 1 − RSS(with)/RSS(without). In open loop F is exogenous and the position just
    measured predicts nothing new about it (the R² of Δ³F on Δ³x alone does not hold: a rough
    excitation is partly predicted from the plant's response to it).
    F_ref = F − C∗x [N] (C a causal FIR on lags 0…``lags`` fitted on the third differences):
    the excitation up to a slow drift, which a closed-loop residual test correlates against
    (F itself carries the position noise that ε₁ also carries)."""
    x = np.asarray(x, np.float64)
    F = np.asarray(F, np.float64)
    dx, dF = np.diff(x, 3), np.diff(F, 3)
    n = dx.size
    L = max(lags, past)
    if n <= 8 * (L + 1):
        return 0.0, F
    y = dF[L:]
    if not float(np.sum(y * y)) > 0:
        return 0.0, F

    def lagged_d(u, js):
        return np.stack([u[L - j : n - j] for j in js], axis=1)

    def rss(A):
        return float(np.sum((y - A @ np.linalg.lstsq(A, y, rcond=None)[0]) ** 2))

    P = np.hstack([lagged_d(dF, range(1, past + 1)), lagged_d(dx, range(2, past + 1))])
    r0 = rss(P)
    share = 0.0 if not r0 > 0 else max(0.0, 1.0 - rss(np.hstack([P, lagged_d(dx, (0, 1))])) / r0)
    A = lagged_d(dx, range(lags + 1))
    th = np.linalg.lstsq(A, y, rcond=None)[0]
    lagged = [np.concatenate([np.full(j, x[0]), x[: x.size - j]]) for j in range(lags + 1)]
    return float(share), F - sum(t * xl for t, xl in zip(th, lagged, strict=True))


#: A lattice blurred by noise of σ keeps the coherence |mean exp(2πi·u/q)| = exp(−2π²σ²/q²):
#: 0.8 at σ = 0.106·q, beyond which the quantisation error is dithered into white noise.
LATTICE_COHERENCE = 0.8
#: The finest lattice looked for behind noise, relative to the signal's magnitude: 16 float32
#: ulps (a float32 record's own resolution is not an encoder's count).
LATTICE_RESOLUTION = 2.0**-20


#: Lattice steps found, by the signal's bytes: a diagnosis asks for each record's several times.
_LATTICES: dict[tuple, float] = {}


def _lattice_step(u: np.ndarray) -> float:
    """The step q of the lattice a quantised signal's samples lie on (an encoder's count), or 0.

    Exact: q₀ the 1 % quantile of the nonzero |Δu|, refined by least squares over every step as
    k counts (q = Σ|Δu|·k/Σk²: a float32 record's q₀ is off by 10⁻⁴); on the lattice when 99 %
    of the samples lie within 1 % of q of a multiple of it (offset by u₀). Blurred by noise:
    the steps of a few counts (q/2 ≤ |Δu| ≤ 8q) lie near multiples of q, so their comb
    mean cos(2π|Δu|/q) peaks at q and its divisors; from the widest peak down, the first whose
    refined q holds the samples' coherence ≥ :data:`LATTICE_COHERENCE` (multiples of q fail
    it: the samples spread over both parities)."""
    u = np.ascontiguousarray(u, np.float64)
    key = (u.size, hashlib.blake2b(u.view(np.uint8), digest_size=16).digest())
    if key not in _LATTICES:
        if len(_LATTICES) >= 64:
            _LATTICES.clear()
        _LATTICES[key] = _lattice(u)
    return _LATTICES[key]


def _lattice(u: np.ndarray) -> float:
    """:func:`_lattice_step` of ``u`` (T,) float64, not kept."""
    du = np.abs(np.diff(u))
    nz = du[du > 0]
    if nz.size < 20:
        return 0.0
    q = float(np.quantile(nz, 0.01))
    if not q > 0:
        return 0.0
    k = np.round(nz / q)
    q = float(np.sum(nz * k) / np.sum(k * k))
    r = (u - u[0]) / q
    if float(np.quantile(np.abs(r - np.round(r)), 0.99)) < 0.01:
        return q
    return _blurred_lattice(u, nz)


def _blurred_lattice(u: np.ndarray, nz: np.ndarray) -> float:
    """q of a lattice blurred by noise (:func:`_lattice_step`), or 0; ``nz`` the nonzero |Δu|.
    A candidate refined on the steps (±σ_q) is refined again on the samples' coherence, whose
    peak is q/span wide (a span of many counts needs q to better than the steps give it)."""
    s = nz[:: max(1, nz.size // 4000)]
    lo, hi = np.quantile(s, [0.01, 0.99])
    lo = max(lo, LATTICE_RESOLUTION * float(np.max(np.abs(u))))
    if not hi > lo > 0:
        return 0.0
    grid = np.exp(np.arange(math.log(lo), math.log(hi), 0.01))  # a comb peak is ≥ 1/32 wide
    near = (s >= 0.5 * grid[:, None]) & (s <= 8.0 * grid[:, None])
    n = near.sum(1)
    J = np.sum(np.cos(2.0 * np.pi * s / grid[:, None]) * near, 1) / np.maximum(n, 1)
    J = np.where(n >= 20, J, -1.0)
    peaks = [i for i in range(1, grid.size - 1) if J[i] >= max(J[i - 1], J[i + 1])]
    v = u[:: max(1, u.size // 4000)] - u[0]
    span = float(np.ptp(v))
    for i in sorted((i for i in peaks if J[i] >= LATTICE_COHERENCE), key=lambda i: -grid[i]):
        k = np.round(nz / grid[i])
        m = k >= 1
        if np.count_nonzero(m) < 20:
            continue
        q = float(np.sum(nz[m] * k[m]) / np.sum(k[m] ** 2))
        sq = float(np.sqrt(np.sum((nz[m] - k[m] * q) ** 2) / np.sum(k[m] ** 2) / m.sum()))
        step = 0.25 * q * q / max(span, q)  # a quarter of the coherence peak's width
        half = min(200, int(6.0 * sq / step) + 1)
        qs = q + step * np.arange(-half, half + 1)
        C = np.abs(np.mean(np.exp(2j * np.pi * v[None, :] / qs[:, None]), 1))
        if C.max() >= LATTICE_COHERENCE:
            return float(qs[np.argmax(C)])
    return 0.0


def _n_eff(r: np.ndarray) -> float:
    """Effective number of independent samples of a correlated residual (Bartlett sum)."""
    r = r - np.mean(r)
    n = r.size
    f = np.fft.rfft(r, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[:n]
    ac = ac / ac[0] if ac[0] > 0 else ac
    below = np.flatnonzero(ac < 0.05)
    K = int(below[0]) if below.size else n
    tau_int = 1.0 + 2.0 * float(np.sum(ac[1:K]))
    return float(max(n / max(tau_int, 1.0), 10.0))
