"""A diagnosis problem (:class:`Problem`): the two records and what every fit of a diagnosis
shares. Immutable; its memo of what it computed (regressors, signals, profiles) never changes
an answer."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .._errors import InputError
from .._models import Augmented, MassDamper
from .._record import Record
from ._criteria import Criteria
from ._filtering import padded_length
from ._regressors import RecordSignals, Regressors
from ._settings import STICK_MIN_S, WINDOWS_LEAST, Settings
from ._statistics import _long_runs, _noise_gain, _position_noise, _start_states
from ._streaming import chunk_length, zero_phase
from .effects import Design, Limits, design_of

#: How messages name the two records (the command line puts the file names in).
ROLES = {
    "train": "training record (argument 'train')",
    "valid": "validation record (argument 'valid')",
}


@dataclasses.dataclass(frozen=True, eq=False)
class Problem:
    """The records and what every fit of a diagnosis shares.

    Attributes:
        train, valid: the records; ``v_train``, ``v_valid`` their zero-phase velocities [m/s].
        st: the settings adapted to the training record; ``crit`` the thresholds.
        x_start, v_start: the windowed simulation's start states at every validation sample
            [m], [m/s], estimated in the band ``state_hz`` (:func:`~._statistics._start_states`).
        position_noise: (train, valid) σ of the positions' noise [m]
            (:func:`~._statistics._position_noise`).
        stuck: (train, valid) (T,) True where the axis sticks (:func:`stuck_mask`).
        streamed: whether the records are read in chunks (of ``chunk`` samples where given).
        H: the windowed simulation's restart interval [samples].
        limits: what plausibility is judged against (set once the baseline is fitted).
        memo: what the problem computed, by key.
    """

    train: Record
    valid: Record
    st: Settings
    crit: Criteria
    v_train: np.ndarray
    v_valid: np.ndarray
    x_start: np.ndarray
    v_start: np.ndarray
    state_hz: float
    position_noise: tuple[float, float]
    stuck: tuple[np.ndarray, np.ndarray]
    streamed: bool = False
    chunk: int | None = None
    H: int = 0
    limits: Limits | None = None
    memo: dict = dataclasses.field(default_factory=dict)

    @classmethod
    def of(cls, train, valid, st, crit, streamed=False, chunk=None, position_noise=None) -> Problem:
        """The problem of two records, its restart interval not yet set (:meth:`with_window`);
        ``position_noise`` their σ_x where known (it does not depend on the settings)."""
        dt, wv = st.dt, 2 * math.pi * st.velocity_hz
        v_valid = zero_phase(valid.x, dt, wv)[1]
        v_train = v_valid if train is valid else zero_phase(train.x, dt, wv)[1]
        state_hz, x_start, v_start = _start_states(
            np.asarray(valid.x, np.float64), dt, st.velocity_hz, v_valid
        )
        if position_noise is None:
            s_valid = _position_noise(np.asarray(valid.x), np.asarray(valid.F))
            s_train = (
                s_valid
                if train is valid
                else _position_noise(np.asarray(train.x), np.asarray(train.F))
            )
            position_noise = (s_train, s_valid)
        stuck = tuple(
            stuck_mask(v, s, st) for v, s in zip((v_train, v_valid), position_noise, strict=True)
        )
        return cls(
            train, valid, st, crit, v_train, v_valid, x_start, v_start, state_hz, position_noise,
            stuck, streamed, chunk,
        )  # fmt: skip

    def with_window(self, scale: float) -> Problem:
        """The problem with its restart interval H: the settings' ``window_s``, else the record's
        time scale ``scale`` [s] within [20 dt, 2 s], short enough for the validation record to
        hold :data:`~._settings.WINDOWS_LEAST` windows."""
        dt, Hs = self.st.dt, self.st.window_s
        if Hs is None:
            Hs = min(max(scale, 20 * dt), 2.0, self.valid.n_samples * dt / WINDOWS_LEAST)
        n = int(round(Hs / dt))
        if n < 2 or n > self.valid.n_samples:
            raise InputError(
                f"window_s: the restart interval H = {Hs!r} s gives {n} samples; expected "
                f"2 … {self.valid.n_samples} (the validation record's length)."
            )
        return dataclasses.replace(self, H=n)

    def gap_from(self, n: int) -> int:
        """The first of ``n`` simulated samples the gap scores: the second window's, where one
        follows."""
        return self.H if n >= 2 * self.H else 0

    @property
    def hold_gap(self) -> float:
        """The rms error [m] of holding each window's start position (the gap of a model that
        predicts no motion), scored as the gaps are."""
        key = ("hold_gap",)
        if key not in self.memo:
            H, x = self.H, np.asarray(self.valid.x, np.float64)
            n = (x.size // H) * H
            held = np.repeat(np.asarray(self.x_start, np.float64)[:n:H], H)
            e = x[:n] - held
            self.memo[key] = float(np.sqrt(np.mean(e[self.gap_from(n) :] ** 2)))
        return self.memo[key]

    @property
    def stuck_share(self) -> float:
        """The share of the validation samples where the axis sticks."""
        return float(np.mean(self.stuck[1]))

    @property
    def sticks(self) -> bool:
        """Whether the axis sticks anywhere on either record."""
        return any(bool(np.any(m)) for m in self.stuck)

    def signals(self, role: str) -> RecordSignals:
        """The record ``role`` ("train" or "valid") as the effects read it, once."""
        key = ("signals", role)
        if key not in self.memo:
            rec, v = (self.train, self.v_train) if role == "train" else (self.valid, self.v_valid)
            x, F = (np.asarray(a, np.float64) for a in (rec.x, rec.F))
            T = rec.n_samples
            chunk = self.chunk or (chunk_length(T) if self.streamed else padded_length(T))
            self.memo[key] = RecordSignals(rec, x, F, np.asarray(v), chunk, role=role)
        return self.memo[key]

    def regressors(self, d: Design | tuple) -> tuple[Regressors, Regressors]:
        """(train, valid) regressors of a design (or of a structure's): force-masked where the
        axis sticks (``d.stick``); with ``d.held`` (the position signals held beyond train's
        range) the validation record's own, the signals' names being the same."""
        d = d if isinstance(d, Design) else design_of(d)
        lam = 2 * math.pi * self.st.filter_hz
        out = []
        for i, (role, key) in enumerate((("train", (d.stick,)), ("valid", (d.stick, d.held)))):
            k = ("regressors", role, *key)
            if k not in self.memo:
                rs = self.signals(role)
                mask = 1.0 - self.stuck[i] if d.stick else None
                self.memo[k] = Regressors(rs, self.st.bank(), mask, rs.chunk, lam)
            out.append(self.memo[k])
        return out[0], out[1]

    def train_regressors(self) -> list[Regressors]:
        """Every training regressors made so far."""
        return [v for k, v in self.memo.items() if k[:2] == ("regressors", "train")]

    def model(self, structure) -> Augmented:
        """The mass–damper with the structure's columns: each effect type once (a spring and an
        offset share the offset column), each force effect once."""
        out, seen = [], set()
        for c in structure:
            for e in c.effects(self.st):
                key = (type(e), tuple(c.signal for c in e.columns()))
                if key not in seen:
                    seen.add(key)
                    out.append(e)
        return Augmented(MassDamper(), tuple(out))


def stuck_mask(v: np.ndarray, sx: float, st: Settings) -> np.ndarray:
    """(T,) True where the axis sticks: |v̂| (T,) within 3σ of its noise (the position noise
    ``sx`` [m] through the zero-phase derivative) for at least :data:`STICK_MIN_S` (and 3
    samples)."""
    va = np.abs(v)
    gain = _noise_gain(st.dt, 2 * math.pi * st.velocity_hz)
    thr = max(3.0 * sx * gain, 1e-4 * float(np.quantile(va, 0.99)))
    return _long_runs(va <= thr, max(3, int(math.ceil(STICK_MIN_S / st.dt))))
