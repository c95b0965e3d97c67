"""The validity layer: what every estimator checks before and after it runs (layer 1, core).

Every entry point (:func:`lionjax.lion`, :func:`lionjax.least_squares`,
:func:`lionjax.lion_batched`, :func:`lionjax.least_squares_batched`,
:func:`lionjax.identify_batch`, :func:`lionjax.lion_parallel`) goes through the same pieces, so
no gain, method or path skips one:

1. **Arguments and data** (host side, on concrete values; skipped under ``jit``/``vmap``):
   :func:`check_theta0` (shape and finiteness, naming ``theta0``), :func:`check_record`
   (non-finite or out-of-range samples are an :class:`~lionjax.InputError` naming the column;
   probable unit mistakes and glitches (:mod:`lionjax._data_checks`) are a
   :class:`DataWarning`),
   :func:`check_duration` (the record outlasts the filter transient) and
   :func:`check_padding` (a padded batch without ``lengths`` is refused).
2. **Filter speed against sampling** (:func:`check_filter_speed`). The filters are exact for
   held or linear signals; a measured position is neither, and the intersample error grows
   with ρ = max|pole|·dt. Measured on noise-free records of ẍ + aẋ = bF (a held multisine
   force, x under ``"foh"``, F under ``"zoh"``, the exact discretisation, least squares,
   (s + p)³ with unit DC gain; ``tests/test_validity.py`` re-measures two points):

   ====  ==========  =====================  =====================
   ρ     bias of b   bias of a, a·dt=0.02   bias of a, a·dt=0.002
   ====  ==========  =====================  =====================
   0.004 −4e-6       −3e-6                  −3e-6
   0.02  −1e-4       −9e-5                  +8e-5
   0.1   −0.25 %     +0.03 %                +2.3 %
   0.2   −1.0 %      +1.9 %                 +20 %
   0.5   −6 %        +44 %                  +309 %
   1     −21 %       +354 %                 +2300 %
   ====  ==========  =====================  =====================

   so b is biased by about −ρ²/4 and a by about +0.05·ρ³/(a·dt) (relative). Above
   :data:`WARN_POLE_DT` = 0.1 a :class:`FilterSpeedWarning` is issued; above
   :data:`MAX_POLE_DT` = 0.25 the call is refused (:class:`~lionjax.InputError` naming the
   argument): there b is biased by −1.6 % and a by +4 % (a·dt = 0.02) to +40 %
   (a·dt = 0.002). The default filter (:func:`default_poles`) is the paper's (s + 4)³ while
   4·dt ≤ :data:`DEFAULT_POLE_DT` = 0.02 (every record sampled at 200 Hz or faster: nothing
   changes there) and (s + 0.02/dt)³ for slower sampling (bias of b about 1e-4).
3. **Identifiability, whatever the gain** (:func:`unexcited`), on the regressors' moment matrix
   R = mean WₖᵀWₖ over the samples after the transient (what :class:`~lionjax.AutoGain` sees):
   a parameter is *not excited* when its column's root mean square is below
   :data:`EXCITATION_TOL`·eps of what its raw signal u would give at the filter's speed
   ω₀ = λₙ^(1/n) (rms(u)·ω₀ᵐ, m the column's order; a constant position gives a column of
   rounding noise, measured 2e-14 of that, float64), and it *lies in an unexcited direction*
   when R (column-normalised) has an eigenvalue below its largest / ``max_condition`` with a
   large component on it. Lion's law with any gain uses ``max_condition`` =
   :data:`MAX_MOMENT_CONDITION` (AutoGain's bound on R) over the samples the gain's rule sees
   (after the transient for a data gain; every sample for a fixed gain, whose law uses them
   all); least squares its own bound on Φ (a column not excited at all fails too). The batched
   estimators take R from their streamed statistics with a data gain (and in
   :func:`lionjax.least_squares_batched`); with a fixed gain they check the raw signals
   (:func:`raw_unexcited`: order ≥ 1 columns must move, order-0 columns be nonzero) on
   :data:`RAW_WINDOWS` short runs of each record, and every sample of only the records those
   flag (:func:`confirm_raw_unexcited`), so the streaming kernel does no extra per-sample work
   (B = 4096, T = 8000, float32: 2 ms beside a ~130 ms kernel; every 64th sample cost about a
   full pass, 8–12 ms, and 7–28 % of ``benchmarks/throughput.py``'s rates). Batched
   results flag such records ``RESULTS.unidentifiable`` and name the parameters in the
   solution's ``unexcited`` (B, p); single-record estimators raise
   :class:`~lionjax.IdentificationError` naming them (``throw=True``).
4. **Padded batches.** :func:`lionjax.stack_records` pads with the last sample; a stacked batch
   passed without ``lengths`` whose record ends in such padding under a nonzero force is
   refused (:func:`check_padding`): the lengths are not inferred.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from ._data_checks import find_glitches, glitch_message
from ._errors import RESULTS, DataWarning, FilterSpeedWarning, InputError, result_codes
from ._filters import FilterBank
from ._record import Record
from ._solution_tools import default_transient, is_traced
from ._units import unit

# ----------------------------------------------------------------------------------------------
# Bounds

#: ρ = max|pole|·dt above which a :class:`FilterSpeedWarning` is issued (b biased ≈ −ρ²/4).
WARN_POLE_DT = 0.1
#: ρ above which an estimator refuses the filter (b biased ≥ 1.6 %, a by 4 % to 40 %).
MAX_POLE_DT = 0.25
#: The default filter's pole [rad/s] (the paper's (s + 4)³) ...
DEFAULT_POLE = 4.0
#: ... slowed to DEFAULT_POLE_DT/dt where DEFAULT_POLE·dt would exceed it.
DEFAULT_POLE_DT = 0.02
#: A column is not excited below EXCITATION_TOL·eps(dtype) of its raw signal's scale.
EXCITATION_TOL = 1e3
#: Lion's law (any gain): R's column-normalised condition number above this is unidentifiable
#: (AutoGain's default ``max_condition``, the square of least squares' 1e6-on-Φ scale).
MAX_MOMENT_CONDITION = 1e12
#: The raw-signal checks of a batch (:func:`batch_reference`, :func:`raw_unexcited`) read
#: RAW_WINDOWS contiguous runs of RAW_WINDOW samples spread evenly over each record:
#: contiguous runs read a few cache lines per record instead of one per sample (B = 4096,
#: T = 8000, float32: 2 ms, against 8 ms for every 64th sample and 10 ms for a full pass).
RAW_WINDOWS = 16
RAW_WINDOW = 8
#: Units warnings: |x| above X_UNITS_BOUND [m] looks like millimetres, unless the travel is
#: below X_OFFSET_SHARE of |x| (an encoder origin far away: µm of motion 1 km from the origin is
#: no axis in mm, and its identification is right); dt in
#: [MS_DT_RANGE] s with at least MS_MIN_SAMPLES samples and under 1 m of travel looks like a
#: time column in milliseconds (a 1 kHz device read as 1 Hz).
X_UNITS_BOUND = 10.0
X_OFFSET_SHARE = 1e-3
MS_DT_RANGE = (0.5, 2.0)
MS_MIN_SAMPLES = 10_000


def value_bound(dtype) -> float:
    """Largest |x| or |F| accepted: max(dtype)^(1/4), so that products of squares summed over
    a record stay finite (1.3e77 in float64, 4.3e9 in float32)."""
    return float(np.finfo(dtype).max) ** 0.25


# ----------------------------------------------------------------------------------------------
# The default filter and its speed


def default_poles(dt: ArrayLike | None = None):
    """The default filter's pole magnitude [rad/s]: :data:`DEFAULT_POLE` (4, the paper's), or
    ``DEFAULT_POLE_DT/dt`` when that is slower (records sampled slower than 200 Hz). Works on
    tracers (``jnp.minimum``); ``dt`` may be ``(B,)`` (the largest is used: one filter for
    all)."""
    if dt is None:
        return DEFAULT_POLE
    if not isinstance(dt, jax.core.Tracer):
        h = float(np.max(np.asarray(dt, dtype=np.float64)))
        return DEFAULT_POLE if DEFAULT_POLE * h <= DEFAULT_POLE_DT else DEFAULT_POLE_DT / h
    return jnp.minimum(DEFAULT_POLE, DEFAULT_POLE_DT / jnp.max(dt))


def pole_dt(bank: FilterBank, dt) -> np.ndarray | None:
    """ρ = max|pole|·dt per filter/record (concrete values; None when traced)."""
    if is_traced((bank.coeffs, dt)):
        return None
    c = np.asarray(bank.coeffs, dtype=np.float64).reshape(-1, bank.order)
    fastest = np.array([np.max(np.abs(np.roots(np.concatenate([[1.0], row])))) for row in c])
    return fastest * np.asarray(dt, dtype=np.float64)


def _g(v) -> str:
    return f"{float(v):g}"


def check_filter_speed(bank: FilterBank, dt, what: str, argument: str = "bank") -> None:
    """Warn above :data:`WARN_POLE_DT`, refuse above :data:`MAX_POLE_DT` (ρ = max|pole|·dt)."""
    rho = pole_dt(bank, dt)
    if rho is None:
        return
    # roots of a repeated pole are off by ~eps^(1/3) (6e-6): compare with that slack
    rho = rho * (1.0 - 1e-4)
    worst = int(np.argmax(rho))
    r = float(rho.reshape(-1)[worst])
    if not r > WARN_POLE_DT:
        return
    h = float(np.max(np.asarray(dt)))
    fastest = r / float(np.asarray(dt).reshape(-1)[worst % np.asarray(dt).size])
    where = "" if rho.size == 1 else f" (filter/record {worst} of {rho.size})"
    detail = (
        f"the fastest filter pole, |p| = {_g(fastest)} rad/s{where}, times the sampling "
        f"interval dt = {_g(h)} s is {_g(r)}"
    )
    fix = (
        f"Use slower poles (|p| ≤ {_g(WARN_POLE_DT / h)} rad/s at this dt, e.g. leave {argument} "
        "out for the sampling-aware default) or sample faster."
    )
    if r > MAX_POLE_DT:
        raise InputError(
            f"{what}: argument {argument!r}: {detail}, above the bound {MAX_POLE_DT:g}: the "
            "filter is too fast for the sampling and the estimate would be biased (b by about "
            f"−ρ²/4 = {-r * r / 4:.2%}, a by several times more). {fix}"
        )
    warnings.warn(
        f"{what}: argument {argument!r}: {detail}, above {WARN_POLE_DT:g}: the estimate is "
        f"biased (b by about −ρ²/4 = {-r * r / 4:.2%}, a often more). {fix}",
        FilterSpeedWarning,
        stacklevel=3,
    )


def check_duration(
    record: Record, bank: FilterBank, what: str, transient: float | None = None
) -> None:
    """Refuse a record shorter than the filter transient (when the values are concrete); the
    fix it suggests respects the speed bound."""
    if is_traced((record.dt, bank.coeffs)):
        return
    need = float(np.max(np.asarray(default_transient(bank)))) if transient is None else transient
    h = float(np.min(np.asarray(record.dt)))
    have = h * (record.n_samples - 1)
    if have < need:
        raise InputError(
            f"{what}: the record lasts {have:.4g} s ({record.n_samples} samples), shorter than "
            f"the filter transient {need:.4g} s (3·λₙ₋₁/λₙ of Λ with coefficients "
            f"{np.asarray(bank.coeffs).tolist()}). {duration_fix(have, h)}"
        )


def duration_fix(have: float, dt: float) -> str:
    """The fix for a record shorter than the transient: faster poles only within the bound.

    The transient of (s + p)³ is 9/p, so poles from 9/duration up to WARN_POLE_DT/dt fit both
    the record and the speed bound, if that range is not empty."""
    lo = 9.0 / have if have > 0 else math.inf
    hi = WARN_POLE_DT / dt
    if lo <= hi:
        return (
            f"Use a longer record, or faster filter poles within the speed bound: (s + p)³ "
            f"with {_g(lo)} ≤ p ≤ {_g(hi)} rad/s (max|pole|·dt ≤ {WARN_POLE_DT:g})."
        )
    return (
        f"Use a longer record: at dt = {_g(dt)} s no filter within the speed bound "
        f"max|pole|·dt ≤ {WARN_POLE_DT:g} settles in it (at least "
        f"{math.ceil(9.0 / WARN_POLE_DT) + 1} samples are needed)."
    )


# ----------------------------------------------------------------------------------------------
# Arguments and data


def check_theta0(theta0, p: int, names: Sequence[str], what: str, batch: int | None = None):
    """``theta0`` must have shape (p,) (or (B, p) for a batch), checked traced or not (shapes
    are static), and be finite, checked where its values are concrete."""
    if theta0 is None:
        return
    shapes = [(p,)] + ([] if batch is None else [(batch, p)])
    if is_traced(theta0):
        a = theta0
    else:
        try:
            a = np.asarray(theta0, dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise InputError(
                f"{what}: theta0 must be {p} numbers (one per parameter {tuple(names)}), got "
                f"{theta0!r}."
            ) from err
    if tuple(np.shape(a)) not in shapes:
        want = " or ".join(str(s) for s in shapes)
        raise InputError(
            f"{what}: theta0 must have shape {want} for parameters {tuple(names)}, got "
            f"{tuple(np.shape(a))}."
        )
    if is_traced(theta0):
        return
    bad = np.argwhere(~np.isfinite(a))
    if bad.size:
        i = tuple(int(v) for v in bad[0])
        raise InputError(
            f"{what}: theta0 must be finite, got {_g(a[i])} at index {i if a.ndim > 1 else i[0]}"
            f" ({names[i[-1]]}). Pass finite initial estimates (default zeros)."
        )


def check_record(record: Record, what: str, *, warn: bool = True) -> None:
    """Data checks of one concrete record before estimation.

    Raises :class:`~lionjax.InputError` for non-finite samples and for samples out of range
    (|v| > :func:`value_bound`, whose squares overflow), naming the column and first index.
    Warns (:class:`DataWarning`, ``warn=True``) for a time column that looks like
    milliseconds, positions that look like millimetres and glitches
    (:func:`lionjax._data_checks.find_glitches`).
    Skipped under tracing; a batch (x of shape (B, T)) gets the errors only.
    """
    if is_traced((record.x, record.F, record.dt)):
        return
    bound = value_bound(np.asarray(record.x).dtype)
    for name in ("x", "F"):
        a = np.asarray(getattr(record, name))
        flat = a.reshape(-1, a.shape[-1])
        bad = np.argwhere(~np.isfinite(flat))
        if bad.size:
            r, k = (int(v) for v in bad[0])
            rec = f"record {r}, " if a.ndim > 1 else ""
            raise InputError(
                f"{what}: column {name!r} has a non-finite value ({flat[r, k]}) at {rec}index "
                f"{k}; repair or remove it (lionjax does not drop or interpolate samples)."
            )
        big = np.argwhere(np.abs(flat) > bound)
        if big.size:
            r, k = (int(v) for v in big[0])
            rec = f"record {r}, " if a.ndim > 1 else ""
            raise InputError(
                f"{what}: column {name!r} is out of range: |{name}| = {abs(float(flat[r, k])):.3g}"
                f" at {rec}index {k} exceeds {bound:.3g}, beyond which the regressors' squares "
                f"overflow {a.dtype} (an overflow, not a lack of excitation). Check the "
                f"column's units and scaling ({unit('m' if name == 'x' else 'N', record.units)} "
                "expected)."
            )
    if warn and record.x.ndim == 1:
        for message in sanity_messages(record):
            warnings.warn(f"{what}: {message}", DataWarning, stacklevel=3)


def sanity_messages(record: Record) -> list[str]:
    """Probable mistakes in one record (the text of each :class:`DataWarning`)."""
    x = np.asarray(record.x, dtype=np.float64)
    dt = float(record.dt)
    T = x.size
    out = []
    xmax = float(np.max(np.abs(x)))
    length = unit("m", record.units)
    travel = float(np.max(x) - np.min(x))
    # A rotor turns without bound (a motor at 3000 rpm passes 300 rad a second), so no angle is
    # implausible in itself: the millimetre check is for linear axes only.
    if record.units == "linear" and xmax > X_UNITS_BOUND and travel > X_OFFSET_SHARE * xmax:
        out.append(
            f"column 'x' reaches |x| = {xmax:.4g} m with {travel:.4g} m of travel; lionjax "
            "expects metres: is x in millimetres? Divide it by 1000 (or convert to metres) "
            "before identifying."
        )
    if MS_DT_RANGE[0] <= dt <= MS_DT_RANGE[1] and T >= MS_MIN_SAMPLES and 0 < travel < 1.0:
        out.append(
            f"dt = {dt:g} s with {T} samples ({T * dt / 3600:.3g} h) and {travel:.3g} {length} of "
            "travel: is the time column in milliseconds (a 1 kHz record read as 1 Hz)? "
            "lionjax expects t in seconds; divide t by 1000."
        )
    glitches = find_glitches(record)  # a sample of the logger or sensor gone wrong
    if glitches:
        out.append(glitch_message(record, glitches))
    return out


#: Share of the filtered response a fit may leave unexplained before :func:`warn_poor_fit`
#: warns: 0.8 (the model explains under 20 %). Measured: noise-free and twin records 1e-11 to
#: 4e-5, the real EMPS drive (Coulomb friction and an offset unmodelled) 0.38; x and F swapped
#: 0.96, a force column logged as a constant 0.89.
MAX_UNEXPLAINED = 0.8


def warn_poor_fit(unexplained, what: str) -> None:
    """Warn (:class:`DataWarning`) when a least-squares fit leaves more than
    :data:`MAX_UNEXPLAINED` of the filtered response (V₃, V₄) unexplained: the model then says
    next to nothing about the data, which is almost always a data mistake (columns swapped, a
    force column that is not the applied force, wrong signals), not a property of the device.
    Host side only (no-op on traced or batched values)."""
    if unexplained is None or is_traced(unexplained) or np.ndim(unexplained) != 0:
        return
    share = float(unexplained)
    if np.isfinite(share) and share > MAX_UNEXPLAINED:
        warnings.warn(
            f"{what}: the fitted model explains only {100 * (1 - share):.0f} % of the filtered "
            "response (V₃, V₄): check that the columns are position x [m] and the applied force "
            "F [N], not swapped, and that F is the force that drives the axis.",
            DataWarning,
            stacklevel=3,
        )


def check_padding(what: str, records: Record, lengths):
    """A stacked batch without ``lengths``: refuse it if a record ends in the padding of
    :func:`lionjax.stack_records` (its last sample of x and F repeated exactly, over more than
    1 % of the samples, at least 2, under a nonzero force). ``lengths`` all equal to T is the
    same as None (nothing padded: the unmasked kernel)."""
    if lengths is not None:
        if is_traced(lengths):
            return lengths
        L = np.asarray(lengths)
        return None if np.all(L == records.x.shape[-1]) else lengths
    if is_traced((records.x, records.F)) or records.x.ndim != 2:
        return None
    T = records.x.shape[-1]
    k = max(2, T // 100 + 1)  # a tail of k repeated samples (k - 1 copies of the last one)
    if k >= T:
        return None
    tail_x = np.asarray(records.x[:, -k:])
    tail_F = np.asarray(records.F[:, -k:])
    same = np.all(tail_x == tail_x[:, -1:], axis=1) & np.all(tail_F == tail_F[:, -1:], axis=1)
    padded = np.flatnonzero(same & np.any(tail_F != 0, axis=1))
    if padded.size:
        raise InputError(
            f"{what}: record(s) {padded[:10].tolist()} end in at least {k} identical samples "
            "of x and F (held force, resting position): the padding of lionjax.stack_records, "
            "which the model cannot explain. Pass lengths= (the second value stack_records "
            "returns); if the records are really that long, pass lengths=np.full(B, T)."
        )
    return None


def flag_bad_data(sol, records: Record):
    """Failed records of a batch solution whose data are non-finite or out of range
    (:func:`value_bound`) get ``RESULTS.nonfinite`` (an overflow, not a lack of excitation).
    Host side, on the failed records only (nothing is read when every record succeeded)."""
    if is_traced((sol.result, records.x, records.F)):
        return sol
    codes = result_codes(sol.result)
    failed = np.flatnonzero(codes.reshape(-1) != 0)
    if codes.ndim != 1 or not failed.size:
        return sol
    bound = value_bound(np.asarray(records.x[:1, :1]).dtype)
    x = np.asarray(records.x[failed])
    F = np.asarray(records.F[failed])
    good = lambda a: np.all(np.isfinite(a) & (np.abs(a) <= bound), axis=-1)
    bad = ~(good(x) & good(F))
    if not np.any(bad):
        return sol
    mask = np.zeros(codes.shape, bool)
    mask[failed[bad]] = True
    where = lambda m, r: RESULTS.where(m, RESULTS.nonfinite, r)
    result = jax.vmap(where)(jnp.asarray(mask), sol.result)
    return eqx.tree_at(lambda s: s.result, sol, result)


# ----------------------------------------------------------------------------------------------
# Identifiability


def column_reference(model, record: Record, bank: FilterBank) -> Float[Array, " p"]:
    """What each column would measure if its raw signal u moved at the filter's speed:
    rms(u)·ω₀ᵐ (times 1/λₙ without unit DC gain), ω₀ = |λₙ|^(1/n). One record (jit-safe):
    :func:`batch_reference` of a batch of one, every sample."""
    one = jax.tree.map(lambda a: jnp.asarray(a)[None], record)
    return batch_reference(model, one, bank, every_sample=True)[0]


def excited(measure: Array, reference: Array) -> Bool[Array, "..."]:
    """Whether a column is excited: its ``measure`` exceeds EXCITATION_TOL·eps of its
    ``reference`` scale (0 against 0 is not excited). The one test of the idea."""
    eps = jnp.finfo(jnp.result_type(measure)).eps
    return measure > EXCITATION_TOL * eps * reference


def well_conditioned(ev: Array, max_condition: float) -> Bool[Array, "..."]:
    """Eigenvalues ``ev`` (ascending) of a column-normalised moment matrix: each above
    ev_max/max_condition (so ``[0]`` decides the whole matrix)."""
    return ev > ev[..., -1:] / max_condition


def normalise(R: Float[Array, "p p"]) -> tuple[Array, Array]:
    """(Rₙ, s): R with unit diagonal, Rₙ = R/(s sᵀ), s = √diag(R) (floored at the tiniest
    float)."""
    scale = jnp.sqrt(jnp.clip(jnp.diagonal(R), jnp.finfo(R.dtype).tiny, None))
    return R / scale[:, None] / scale[None, :], scale


def dead_columns(R: Float[Array, "p p"], reference: Float[Array, " p"]) -> Bool[Array, " p"]:
    """Columns that are not :func:`excited`: √Rⱼⱼ (their rms) against ``reference``."""
    return ~excited(jnp.sqrt(jnp.clip(jnp.diagonal(R), 0.0, None)), reference)


def unexcited(
    R: Float[Array, "p p"], reference: Float[Array, " p"], max_condition: float
) -> Bool[Array, " p"]:
    """Parameters the data do not identify, from R = mean WₖᵀWₖ (after the transient).

    True where the column is not :func:`excited` (√Rⱼⱼ against ``reference``) or carries a
    large share (at least half the largest) of an eigenvector of the normalised R whose
    eigenvalue is not :func:`well_conditioned` under ``max_condition``. Jit-safe."""
    dead = dead_columns(R, reference)
    Rn, _ = normalise(R)
    ev, V = jnp.linalg.eigh(Rn)
    weak = ~well_conditioned(ev, max_condition) | ~jnp.isfinite(ev)
    share = jnp.abs(V)
    big = share >= 0.5 * jnp.max(share, axis=0, keepdims=True)
    in_null = jnp.any(big & weak[None, :], axis=1)
    return dead | in_null


def _sampled(records: Record, lengths, take, k):
    """The samples ``take`` picks from each record of a batch, as a batch Record (dt and t0
    one per record), and the weights (B, n) of the valid ones: their indices ``k`` (n,) before
    each record's length."""
    B, T = records.x.shape
    dt = jnp.broadcast_to(jnp.asarray(records.dt), (B,))
    t0 = jnp.broadcast_to(jnp.asarray(records.t0), (B,))
    small = Record(
        take(records.x), take(records.F), dt, t0, {k: take(v) for k, v in records.extras.items()}
    )
    L = jnp.full((B,), T) if lengths is None else jnp.asarray(lengths)
    return small, (k[None, :] < L[:, None]).astype(records.x.dtype)


def _every_sample(records: Record, lengths):
    """Every sample of each record of a batch (:func:`_sampled`)."""
    return _sampled(records, lengths, lambda a: a, jnp.arange(records.x.shape[-1]))


def _windows(records: Record, lengths):
    """:data:`RAW_WINDOWS` contiguous runs of :data:`RAW_WINDOW` samples, evenly spread over
    each record of a batch (:func:`_sampled`); every sample where the record is shorter than
    that. A signal derived through dt (a velocity) jumps where two runs join: what is read
    here is a scale, or whether a signal moves at all, never a measurement."""
    T = records.x.shape[-1]
    seg = T // RAW_WINDOWS
    if seg < RAW_WINDOW:
        return _every_sample(records, lengths)

    def take(a):
        a = a[..., : seg * RAW_WINDOWS].reshape(a.shape[:-1] + (RAW_WINDOWS, seg))
        return a[..., :RAW_WINDOW].reshape(a.shape[:-2] + (RAW_WINDOWS * RAW_WINDOW,))

    k = (jnp.arange(RAW_WINDOWS)[:, None] * seg + jnp.arange(RAW_WINDOW)[None, :]).reshape(-1)
    return _sampled(records, lengths, take, k)


def _column_moments(model, small: Record, w):
    """(rms, spread) of every column's raw signal over the weighted samples, each (B, p)."""

    def one(r, wi):
        sigs = model.signals(r)
        m = jnp.maximum(jnp.sum(wi), 1.0)
        rms, spread = [], []
        for c in model.columns():
            u = jnp.asarray(sigs[c.signal][0]).astype(wi.dtype)
            mean = jnp.sum(wi * u) / m
            rms.append(jnp.sqrt(jnp.sum(wi * u * u) / m))
            spread.append(jnp.sqrt(jnp.sum(wi * (u - mean) ** 2) / m))
        return jnp.stack(rms), jnp.stack(spread)

    return jax.vmap(one)(small, w)


def raw_unexcited(model, records: Record, lengths=None, every_sample: bool = False):
    """(B, p): columns whose raw signal does not move (order ≥ 1: its spread) or is zero
    (order 0) — the check of a batch that has no streamed statistics (a fixed gain). On
    :func:`_windows` of each record's valid samples (a few cache lines per record: the check
    costs next to nothing beside the kernel), or on every valid sample (``every_sample``). The
    windows can miss motion confined between them: :func:`confirm_raw_unexcited` re-reads
    every sample of the records they flag. Jit-safe."""
    sample = (_every_sample if every_sample else _windows)(records, lengths)
    rms, spread = _column_moments(model, *sample)
    order = jnp.asarray([c.order for c in model.columns()])
    return ~excited(jnp.where(order >= 1, spread, rms), rms)


def confirm_raw_unexcited(sol, model, records: Record, lengths):
    """Host side, after a fixed-gain batch: the records :func:`raw_unexcited` flagged on its
    windows are checked again on every sample; a record whose columns all move there gets its
    ``unexcited`` row cleared and, where that was its only failure
    (``RESULTS.unidentifiable``), ``RESULTS.successful`` back (its θ was computed all along).
    Nothing is read when no record was flagged."""
    if sol.unexcited is None or is_traced((sol.unexcited, sol.result, records.x)):
        return sol
    mask = np.asarray(sol.unexcited)
    rows = np.flatnonzero(mask.any(axis=-1))
    if mask.ndim != 2 or not rows.size:
        return sol
    B = mask.shape[0]
    pick = lambda a: a[rows] if jnp.ndim(a) >= 1 and jnp.shape(a)[0] == B else a
    sub = Record(
        pick(records.x),
        pick(records.F),
        pick(records.dt),
        pick(records.t0),
        {k: pick(v) for k, v in records.extras.items()},
    )
    L = None if lengths is None else pick(jnp.asarray(lengths))
    full = np.asarray(raw_unexcited(model, sub, L, every_sample=True))
    new = mask.copy()
    new[rows] = full
    codes = result_codes(sol.result).reshape(-1)
    fix = np.zeros(B, bool)
    cleared = rows[~full.any(axis=-1)]
    fix[cleared] = codes[cleared] == int(result_codes(RESULTS.unidentifiable))
    result = jax.vmap(lambda m, r: RESULTS.where(m, RESULTS.successful, r))(
        jnp.asarray(fix), sol.result
    )
    return eqx.tree_at(lambda s: (s.unexcited, s.result), sol, (jnp.asarray(new, bool), result))


def batch_reference(
    model, records: Record, bank: FilterBank, lengths=None, every_sample: bool = False
):
    """(B, p): :func:`column_reference` of every record of a batch, on :func:`_windows` of its
    valid samples (a scale, so a sample of the record serves), or on every valid sample
    (``every_sample``); ``bank`` one filter or one per record."""
    B = records.x.shape[0]
    sample = (_every_sample if every_sample else _windows)(records, lengths)
    rms, _ = _column_moments(model, *sample)
    lam = jnp.broadcast_to(jnp.abs(bank.coeffs[..., -1]), (B,)).astype(rms.dtype)
    w0 = lam ** (1.0 / bank.order)
    k = jnp.ones_like(lam) if bank.unit_dc_gain else 1.0 / lam
    order = jnp.asarray([c.order for c in model.columns()], rms.dtype)
    return rms * w0[:, None] ** order[None, :] * k[:, None]


# ----------------------------------------------------------------------------------------------
# Messages


def unexcited_names(names: Sequence[str], mask) -> list[str]:
    """The names where ``mask`` (p,) is True."""
    return [n for n, m in zip(names, np.asarray(mask).reshape(-1), strict=True) if m]


def not_identified(names: Sequence[str]) -> str:
    """The sentence naming the parameters a record does not identify, and why."""
    return (
        f"Not identified from this record: {', '.join(names)} (not excited: the record does "
        "not move them, or never enters their region; or they are not separable from the "
        "others)."
    )


def explain_unexcited(sol) -> str:
    """The detail of an ``unidentifiable`` failure: every parameter the data do not identify
    (per failed batch element), from the solution's ``unexcited`` mask."""
    mask = getattr(sol, "unexcited", None)
    if mask is None:
        return ""
    m = np.asarray(mask)
    codes = result_codes(sol.result)
    bad = result_codes(RESULTS.unidentifiable).item()
    if m.ndim == 1:
        names = unexcited_names(sol.names, m)
        if codes != bad or not names:
            return ""
        return not_identified(names)
    lines = []
    for idx in np.argwhere(codes == bad)[:20]:
        names = unexcited_names(sol.names, m[tuple(idx)])
        if names:
            lines.append(f"  batch element {tuple(int(i) for i in idx)}: {', '.join(names)}")
    return ("Not identified (not excited) per element:\n" + "\n".join(lines)) if lines else ""
