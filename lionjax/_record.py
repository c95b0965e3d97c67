"""A uniformly sampled record of one device axis: position x [m] and force F [N], or, for a
rotary axis, angle x [rad] and torque F [N·m]."""

from __future__ import annotations

from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._errors import InputError
from ._units import check_units

#: Largest accepted relative deviation of any sampling interval from the mean interval.
JITTER_TOLERANCE = 1e-3
#: Fewest samples a record may have (the filter transient alone needs more than this).
MIN_SAMPLES = 16


def time_dtype():
    """The dtype of dt, t0 and t: JAX's default float, float64 under ``jax_enable_x64`` (the
    recommended setting) whatever the signals' dtype — a float32 t loses a 10 kHz record's
    sample spacing after 800 s; float32 where x64 is off."""
    return jnp.result_type(float)


def _kind_error(a, name: str) -> InputError | None:
    kind = np.dtype(a.dtype).kind
    if kind == "b":
        return InputError(
            f"Record: {name} is boolean (True/False samples), not a measured signal; pass the "
            f"{'position [m]' if name == 'x' else 'force [N]' if name == 'F' else 'values'} "
            "as numbers (a logged on/off state is not a force: check the column)."
        )
    if kind == "c":
        return InputError(
            f"Record: {name} is complex ({a.dtype}); pass its real samples (np.real(...) if "
            "the imaginary part is zero by construction)."
        )
    if kind not in "iuf":
        return InputError(f"Record: {name} must be real numbers, got dtype {a.dtype}.")
    return None


def signal_array(v: ArrayLike, name: str) -> Array:
    """A signal as a JAX float array: integers (an encoder's counts, a logger's ints) become
    JAX's default float, half precision (float16, bfloat16) becomes float32, so that every
    estimator computes on it the same way (a float16 record keeps its rounding, ~5·10⁻⁴ of
    |x|, in the data); booleans and complex numbers are refused naming the signal."""
    a = v if isinstance(v, jax.Array | jax.core.Tracer) else np.asarray(v)
    err = _kind_error(a, name)
    if err is not None:
        raise err
    kind, size = np.dtype(a.dtype).kind, np.dtype(a.dtype).itemsize
    if kind in "iu":
        return jnp.asarray(a, dtype=jnp.result_type(float))
    if size < 4:
        return jnp.asarray(a, dtype=jnp.float32)
    return jnp.asarray(a)


def _real(v: ArrayLike, name: str, dtype) -> Array:
    """dt or t0 as a real array of ``dtype`` (booleans and complex numbers refused)."""
    a = v if isinstance(v, jax.Array | jax.core.Tracer) else np.asarray(v)
    err = _kind_error(a, name)
    if err is not None:
        raise err
    return jnp.asarray(a, dtype=dtype)


class Record(eqx.Module):
    """One uniformly sampled record (or a batch of them, leading axes on every array).

    Attributes:
        x: position samples, shape ``(T,)`` [m].
        F: force samples, shape ``(T,)`` [N] (as applied: calibration is the user's choice).
        dt: sampling interval, shape ``()`` [s].
        t0: time of the first sample, shape ``()`` [s].
        extras: further measured signals a model may use, each shape ``(T,)``.
        units: ``"linear"`` (x [m], F [N]) or ``"rotary"`` (x [rad], F [N·m]); the same
            method either way (ẍ + aẋ = bF, b = 1/J for a rotor), only the units that the checks
            and the reports name change (:mod:`lionjax._units`). A static field.

    Build one from raw samples with :meth:`Record.from_samples`, which checks the samples
    (finite, strictly increasing uniform time) and names the first bad index. The constructor
    itself only converts to arrays, so a ``Record`` can be built inside ``jit``/``vmap``:
    integer signals become JAX's default float and half-precision ones float32
    (:func:`signal_array`), dt and t0 take :func:`time_dtype` (float64 under x64) whatever the
    signals' dtype; boolean or complex signals and a column of shape (T, 1) are refused.
    """

    x: Float[Array, "*batch T"]
    F: Float[Array, "*batch T"]
    dt: Float[Array, "*batch"]
    t0: Float[Array, "*batch"]
    extras: dict[str, Float[Array, "*batch T"]]
    units: str = eqx.field(static=True)

    def __init__(
        self,
        x: ArrayLike,
        F: ArrayLike,
        dt: ArrayLike,
        t0: ArrayLike = 0.0,
        extras: Mapping[str, ArrayLike] | None = None,
        *,
        units: str = "linear",
    ):
        self.x = signal_array(x, "x")
        self.F = signal_array(F, "F")
        time = time_dtype()
        self.dt = _real(dt, "dt", time)
        self.t0 = _real(t0, "t0", time)
        self.extras = {k: signal_array(v, f"extra signal {k!r}") for k, v in (extras or {}).items()}
        self.units = check_units(units, "Record: units")

    def __check_init__(self):
        if self.x.shape != self.F.shape:
            raise InputError(
                f"Record: x and F must have the same shape, got x {self.x.shape} and "
                f"F {self.F.shape}. Pass one force sample per position sample."
            )
        if self.x.ndim < 1:
            raise InputError("Record: x must have a time axis (shape (T,)), got a scalar.")
        if self.x.ndim >= 2 and self.x.shape[-1] == 1 and self.x.shape[-2] > 1:
            raise InputError(
                f"Record: x has shape {self.x.shape}: one sample per row of a column, which "
                f"reads as {self.x.shape[-2]} records of 1 sample each. For one record pass "
                "x and F of shape (T,) (x.ravel(), or x[:, 0]); for a batch, shape (B, T)."
            )
        if not isinstance(self.dt, jax.core.Tracer):
            dt = np.asarray(self.dt, dtype=np.float64)
            if not np.all(np.isfinite(dt) & (dt > 0)):
                bad = dt.reshape(-1)[~(np.isfinite(dt.reshape(-1)) & (dt.reshape(-1) > 0))][0]
                raise InputError(
                    f"Record: dt must be the sampling interval in seconds, a finite number > 0, "
                    f"got {float(bad)!r}. Pass dt = t[1] - t[0] of a uniformly sampled record "
                    "(Record.from_samples computes it from the time column)."
                )
        if not isinstance(self.t0, jax.core.Tracer) and not np.all(
            np.isfinite(np.asarray(self.t0, dtype=np.float64))
        ):
            raise InputError(
                f"Record: t0 (the time of the first sample [s]) must be finite, got "
                f"{np.asarray(self.t0).tolist()!r}."
            )
        for k, v in self.extras.items():
            if v.shape != self.x.shape:
                raise InputError(
                    f"Record: extra signal {k!r} has shape {v.shape}, expected {self.x.shape} "
                    "(the shape of x)."
                )

    @property
    def n_samples(self) -> int:
        """Number of samples T."""
        return self.x.shape[-1]

    @property
    def t(self) -> Float[Array, "*batch T"]:
        """Sample times ``t0 + k·dt`` [s], in the dtype of dt (:func:`time_dtype`)."""
        k = jnp.arange(self.n_samples, dtype=self.dt.dtype)
        return self.t0[..., None] + self.dt[..., None] * k

    def decimate(self, factor: int) -> Record:
        """The record at the interval ``factor``·dt, for a long record at a high rate (only on
        request: lionjax never decimates silently).

        With r = ``factor`` and N = ⌊T/r⌋ blocks of r samples:

            x'ⱼ = x_{jr},    F'ⱼ = (1/r)·Σ_{i<r} F_{jr+i},    dt' = r·dt,   j = 0 … N − 1.

        The positions are kept at the new sample instants (no smoothing: nothing lags); the
        force, held by the device over each interval, becomes its mean over the new interval:
        the held input with the same impulse ∫F dt per interval. The response to it differs
        from the response to the fine one by the hold error of the longer interval, O((ωr·dt)²)
        at angular frequency ω: decimate only so far that the dynamics and effects of interest
        stay well below the new Nyquist frequency 1/(2r·dt). The last T − N·r samples (fewer
        than r, part of one new interval) are not used.

        Arguments:
            factor: r, an integer ≥ 1 (1 returns the record unchanged) and ≤ T/2.

        Returns:
            a :class:`Record` with x, F of shape ``(*batch, N)``, dt·r, the same t0.

        Raises:
            InputError: a factor that is not an integer in [1, T/2]; a record with
                ``extras`` (whether each is a held input, to average, or a sampled signal, to
                keep, is the user's call: decimate them and build the record).
        """
        T = self.n_samples
        if (
            not isinstance(factor, (int, np.integer))
            or isinstance(factor, bool)
            or not 1 <= factor <= T // 2
        ):
            raise InputError(
                f"Record.decimate: factor must be an integer from 1 to {T // 2} (half the "
                f"record's {T} samples), got {factor!r}."
            )
        if self.extras:
            raise InputError(
                f"Record.decimate: the record has extra signals {sorted(self.extras)}; whether "
                "each is a held input (to average) or a sampled signal (to keep) is not known. "
                "Decimate them yourself and build the Record from the results."
            )
        r = int(factor)
        if r == 1:
            return self
        n = T // r
        x = self.x[..., : n * r : r]
        F = jnp.mean(self.F[..., : n * r].reshape(*self.F.shape[:-1], n, r), axis=-1)
        return Record(x, F, self.dt * r, self.t0, units=self.units)

    def hold_force(self) -> Record:
        """The record with a force sampled at instants turned into the force held over each
        interval, which lionjax reads (F zero-order hold; docs/data.md, "Timing within a sample").

        A measured force — a motor current, a load cell — read at the instants tₖ is F(tₖ); read
        as held over [tₖ, tₖ₊₁), it acts half a sample early, which the diagnosis reads as a
        delay of −½ sample and a resonance's fit suffers from. With F straight between its samples
        (MATLAB's InterSample ``'foh'``), its mean over each interval is

            F'ₖ = (Fₖ + Fₖ₊₁)/2,    x'ₖ = xₖ,    k = 0 … T − 2,

        the held force with the same impulse ∫F dt per interval; for ẍ = bF the response to it
        differs from the response to the straight-line force by b·h²·ΔF/12 in position (h = dt,
        ΔF the force's change since the start): a bounded hold error, as :meth:`decimate`'s. Use
        it on records whose force is sampled, not on a commanded force that the drive holds.

        Returns:
            a :class:`Record` of T − 1 samples (the last sample has no interval after it), with
            the same dt, t0 and units; ``extras`` keep their samples (the last one dropped).

        Raises:
            InputError: a record of fewer than 2 samples.
        """
        T = self.n_samples
        if T < 2:
            raise InputError(
                f"Record.hold_force: the record has {T} sample(s); the held force over an "
                "interval needs the samples at both its ends (at least 2)."
            )
        F = 0.5 * (self.F[..., :-1] + self.F[..., 1:])
        extras = {k: v[..., :-1] for k, v in self.extras.items()}
        return Record(self.x[..., :-1], F, self.dt, self.t0, extras, units=self.units)

    @classmethod
    def from_samples(
        cls,
        t: ArrayLike,
        x: ArrayLike,
        F: ArrayLike,
        *,
        extras: Mapping[str, ArrayLike] | None = None,
        source: str = "record",
        jitter_tolerance: float = JITTER_TOLERANCE,
        min_samples: int = MIN_SAMPLES,
        dtype=None,
        units: str = "linear",
    ) -> Record:
        """Check raw samples and build a :class:`Record`.

        Arguments:
            t: sample times, shape ``(T,)`` [s], strictly increasing and uniform within
                ``jitter_tolerance`` (relative deviation of each interval from the mean).
            x: positions, shape ``(T,)`` [m].
            F: forces, shape ``(T,)`` [N].
            extras: further signals, each shape ``(T,)``.
            source: how to name the data in error messages (a file name, say).
            dtype: array dtype (default: JAX's default float, float64 under ``jax_enable_x64``).
            units: ``"linear"`` (x [m], F [N]) or ``"rotary"`` (x [rad], F [N·m]).

        Raises:
            InputError: naming ``source``, the column and the first bad index, for: wrong
                shapes, NaN/inf, time not strictly increasing, jitter beyond tolerance, fewer
                than ``min_samples`` samples.
        """
        cols = {"t": t, "x": x, "F": F, **dict(extras or {})}
        arrays = {}
        n = None
        for name, v in cols.items():
            a = np.asarray(v, dtype=np.float64)
            if a.ndim != 1:
                raise InputError(
                    f"{source}: column {name!r} must be one-dimensional (one value per sample), "
                    f"got shape {a.shape}."
                )
            if n is None:
                n = a.shape[0]
            elif a.shape[0] != n:
                raise InputError(
                    f"{source}: column {name!r} has {a.shape[0]} samples but 't' has {n}; every "
                    "column needs one value per sample."
                )
            bad = np.flatnonzero(~np.isfinite(a))
            if bad.size:
                raise InputError(
                    f"{source}: column {name!r} has a non-finite value ({a[bad[0]]}) at index "
                    f"{bad[0]} ({bad.size} non-finite in all); remove or repair those samples "
                    "(lionjax does not drop or interpolate them for you)."
                )
            arrays[name] = a
        if n < min_samples:
            raise InputError(
                f"{source}: {n} samples is too few; at least {min_samples} are needed (and many "
                "more for the filter transient to settle)."
            )
        ta = arrays["t"]
        d = np.diff(ta)
        nonpos = np.flatnonzero(d <= 0)
        if nonpos.size:
            i = nonpos[0]
            raise InputError(
                f"{source}: column 't' must be strictly increasing, but t[{i + 1}] = {ta[i + 1]!r}"
                f" <= t[{i}] = {ta[i]!r}. Sort the record or remove duplicated samples."
            )
        dt = (ta[-1] - ta[0]) / (n - 1)
        rel = np.abs(d - dt) / dt
        jit = np.flatnonzero(rel > jitter_tolerance)
        if jit.size:
            i = jit[0]
            raise InputError(
                f"{source}: sampling is not uniform: interval t[{i + 1}] - t[{i}] = {d[i]:.6g} s "
                f"deviates {rel[i]:.2%} from the mean interval {dt:.6g} s (tolerance "
                f"{jitter_tolerance:.2%}). Resample the record to a uniform grid first "
                "(lionjax.resample) if that is what you want."
            )
        kw = {} if dtype is None else {"dtype": dtype}
        ext = {k: jnp.asarray(arrays[k], **kw) for k in (extras or {})}
        return cls(
            jnp.asarray(arrays["x"], **kw),
            jnp.asarray(arrays["F"], **kw),
            dt,
            ta[0],
            ext,
            units=units,
        )


def resample(
    t: ArrayLike, x: ArrayLike, F: ArrayLike, *, dt: float | None = None, source: str = "record"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resample a non-uniformly sampled record onto a uniform grid (linear interpolation).

    Only on request: lionjax never resamples silently. ``dt`` defaults to the median interval.
    Returns ``(t_uniform, x, F)`` as numpy arrays.
    """
    t = np.asarray(t, dtype=np.float64)
    if t.ndim != 1 or t.size < 2 or np.any(np.diff(t) <= 0):
        raise InputError(f"{source}: resample needs a strictly increasing 1-D 't' column.")
    step = float(np.median(np.diff(t))) if dt is None else float(dt)
    if not step > 0:
        raise InputError(f"resample: dt must be positive, got {dt!r}.")
    n = int(np.floor((t[-1] - t[0]) / step + 1e-9)) + 1
    tu = t[0] + step * np.arange(n)
    return tu, np.interp(tu, t, np.asarray(x, float)), np.interp(tu, t, np.asarray(F, float))
