"""Checks of the samples themselves, before any fit: glitches in a record, and a pair of records
whose units disagree (layer 1, core; host side, numpy, on concrete values).

**Glitches.** A logger or an encoder sometimes writes one wrong sample (a 1000 N reading among
forces of 1 N, a position 1 m off among millimetres of motion). A fit takes it at face value:
one such force sample moved a diagnosis' baseline to a = −0.05 1/s and named ``saturation`` at
confidence 1.00. :func:`find_glitches` finds them by their shape and size, with robust statistics
of the signal s (x or F) alone:

- a **spike** is a run of at most :data:`SPIKE_RUN` samples s[k … k+m−1] that all depart, on the
  same side, from the mean of the two samples around the run, s̄ = (s[k−1] + s[k+m])/2, by at
  least h, while those two agree within h/4: the signal leaves its course and comes back (at the
  first or last sample: it departs from its neighbour by h, the next two agree within h/4; for
  F its distance beyond the range of all other samples must also pass the size rule below,
  since whether it comes back cannot be seen and a force may step to a new level there). A
  step (an encoder count, a level of a random-step excitation, a saturated force) departs on
  one side only: its outer samples differ by the whole step, and it never counts;
- a **jump** (x only) is one difference Δx[k] = x[k+1] − x[k] larger than :data:`X_RATIO` times
  both of its neighbours |Δx[k−1]|, |Δx[k+1]| and the local step scale below: a velocity that
  leaves its course for one sample and comes back, which a mass cannot do (the encoder lost or
  gained counts);
- **size**: the departure h (for a jump, |Δx[k]|) is at least :data:`X_RATIO` (x) or
  :data:`F_STEP_RATIO` (F) times the record's *common step* Q, the k-th largest |Δs| of the
  whole record with k = max(:data:`COMMON_RANK`, T/200): the steps of its fastest motion, or of
  its quantisation where an encoder count is larger than the motion of one sample (a glitch adds
  two large differences, so up to COMMON_RANK/2 glitches leave Q as it was). A position is
  the integral of a velocity: it cannot leave its course by ten of its own fastest steps and
  return, nor make one such step between two ordinary ones. A force can (a PD controller that
  differentiates encoder counts adds a pulse at every count), so a force spike must also
  exceed :data:`F_SPREAD_RATIO` times the force's robust spread, its interquartile range / 1.349
  (σ of a normal distribution): a force far outside its whole range for one sample is not a
  force the drive applied. A force at one value over more than half the record has no spread,
  and no force spike is judged.

Measured on 440 clean records of every class of the blind benchmark's generator
(``benchmarks/diagnosis_blind.py``: both simulators, open and closed loop, quantised encoders,
position noise, saturation, stiction, random steps, sensor lines): no glitch; the largest
position departure 1.35 Q, step 2.1 Q, force departure 0.15 of its bound
(``benchmarks/results/2026-11-29_data_checks.md``).

**Unit mismatch** (:func:`unit_mismatch`): the force's root mean square of the two records of a
pair differs by :data:`UNIT_RATIO` = 100 or more, or the position's standard deviation and its
steps' both do: a record in mN beside one in N, or mm beside m (on the benchmark's clean pairs
the ratios reach 5.1 and 4.4). A real validation record 100
times weaker or stronger than the training record would also leave its range (the model
extrapolates), so either way no diagnosis of the pair can be trusted.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._errors import InputError
from ._record import Record

#: Longest run of samples a spike may hold.
SPIKE_RUN = 3
#: The common step Q is the k-th largest |Δs|, k = max(COMMON_RANK, T/200).
COMMON_RANK = 16
#: A position spike or jump departs by at least X_RATIO times the common step Q.
X_RATIO = 10.0
#: A force spike departs by at least F_STEP_RATIO times the common step Q ...
F_STEP_RATIO = 10.0
#: ... and by at least F_SPREAD_RATIO times the force's robust spread (IQR / 1.349).
F_SPREAD_RATIO = 10.0
#: The outer samples of a spike agree within AGREE of its departure.
AGREE = 0.25
#: Ratio of the two records' spreads from which a pair is a probable unit mismatch.
UNIT_RATIO = 100.0
#: Glitches named in a message (the count of the rest follows).
NAMED = 3

_UNIT = {"x": "m", "F": "N"}


@dataclasses.dataclass(frozen=True)
class Glitch:
    """One glitch: ``column`` ``"x"`` or ``"F"``, ``kind`` ``"spike"`` or ``"jump"``, the first
    sample ``index`` and the run's ``length``, the samples' ``value`` (the first of a spike's
    run; a jump's sample after it), its neighbours ``before`` and ``after`` (at the first or
    ``last`` sample, its two inner neighbours), and ``ratio``: the departure over the record's
    common step Q."""

    column: str
    kind: str
    index: int
    length: int
    value: float
    before: float
    after: float
    ratio: float
    last: bool = False

    def describe(self, t0: float, dt: float) -> str:
        c, u, k = self.column, _UNIT[self.column], self.index
        at = f"t = {t0 + k * dt:.6g} s"
        if self.kind == "jump":
            return (
                f"a jump of {self.value - self.before:.4g} {u} between {c}[{k - 1}] = "
                f"{self.before:.6g} {u} and {c}[{k}] = {self.value:.6g} {u} ({at}), "
                f"{self.ratio:.3g} times the record's common step"
            )
        run = f"{c}[{k}]" if self.length == 1 else f"{c}[{k}…{k + self.length - 1}]"
        if k == 0 or self.last:
            ends = "first" if k == 0 else "last"
            return (
                f"a spike at the {ends} sample, {run} = {self.value:.6g} {u} ({at}), where its "
                f"neighbours are {self.before:.6g} and {self.after:.6g} {u}, a departure "
                f"{self.ratio:.3g} times the record's common step"
            )
        return (
            f"a spike {run} = {self.value:.6g} {u} ({at}) between {c}[{k - 1}] = "
            f"{self.before:.6g} {u} and {c}[{k + self.length}] = {self.after:.6g} {u}, "
            f"a departure {self.ratio:.3g} times the record's common step"
        )


def common_step(s: np.ndarray) -> float:
    """Q: the k-th largest |Δs|, k = max(COMMON_RANK, T/200), at least 16 ulps of max|s|."""
    ad = np.abs(np.diff(s))
    k = min(max(COMMON_RANK, ad.size // 200), ad.size - 1)
    q = float(np.partition(ad, ad.size - 1 - k)[ad.size - 1 - k]) if ad.size else 0.0
    return max(q, 16 * np.finfo(np.float64).eps * float(np.max(np.abs(s))))


def _spikes(s: np.ndarray, bound: float, ends_leave_range: bool = False) -> list[tuple]:
    """(index, length, departure / Q) of every spike of ``s`` departing by more than
    ``bound`` (module docstring), the shortest run first. ``ends_leave_range``: the first or last
    sample counts only where it also lies beyond the range of the others by ``bound`` (a signal
    that can step: whether an end sample comes back cannot be seen)."""
    T, Q = s.size, common_step(s)
    if Q == 0:
        return []
    found, taken = [], np.zeros(T, bool)
    for m in range(1, SPIKE_RUN + 1):
        if T < m + 2:
            break
        k = np.arange(1, T - m)
        before, after = s[k - 1], s[k + m]
        base = 0.5 * (before + after)
        dev = np.stack([s[k + j] - base for j in range(m)])  # (m, n)
        h = np.min(dev * np.sign(dev[0]), axis=0)
        hit = (h > bound) & (np.abs(after - before) <= AGREE * h)
        for ki, hi in zip(k[hit], h[hit], strict=True):
            if not taken[ki - 1 : ki + m + 1].any():
                found.append((int(ki), m, float(hi / Q)))
                taken[ki : ki + m] = True
    if T >= 3:  # the first and last samples, against their two inner neighbours
        for k, n1, n2 in ((0, 1, 2), (T - 1, T - 2, T - 3)):
            h = abs(s[k] - s[n1])
            rest = s[1:] if k == 0 else s[:-1]
            out = max(s[k] - rest.max(), rest.min() - s[k], 0.0) if ends_leave_range else h
            if (
                min(h, out) > bound
                and abs(s[n1] - s[n2]) <= AGREE * h
                and not taken[min(k, n2) : max(k, n2) + 1].any()
            ):
                found.append((k, 1, float(h / Q)))
    return found


def _jumps(x: np.ndarray, skip: np.ndarray) -> list[tuple]:
    """(index of the sample after the jump, |Δx| / Q) of every jump of ``x`` outside ``skip``."""
    ad, Q = np.abs(np.diff(x)), common_step(x)
    if Q == 0 or ad.size < 3:
        return []
    k = np.arange(1, ad.size - 1)
    big = ad[k] > X_RATIO * np.maximum(np.maximum(ad[k - 1], ad[k + 1]), Q)
    k = k[big & ~skip[k] & ~skip[k + 1]]
    return [(int(i) + 1, float(ad[i] / Q)) for i in k]


def find_glitches(record: Record) -> list[Glitch]:
    """The glitches of one record, x of shape (T,) (module docstring), in sample order."""
    out = []
    for col in ("x", "F"):
        s = np.asarray(getattr(record, col), np.float64)
        if col == "x":
            bound = X_RATIO * common_step(s)
        else:
            q25, q75 = np.percentile(s, [25, 75])
            if not q75 > q25:
                continue
            bound = max(F_STEP_RATIO * common_step(s), F_SPREAD_RATIO * (q75 - q25) / 1.349)
        spikes = _spikes(s, bound, ends_leave_range=col == "F")
        for k, m, r in spikes:
            i, j = (k - 1, k + m) if 0 < k < s.size - 1 else ((1, 2) if k == 0 else (k - 2, k - 1))
            g = Glitch(
                col, "spike", k, m, float(s[k]), float(s[i]), float(s[j]), r, k == s.size - 1
            )
            out.append(g)
        if col == "x":
            skip = np.zeros(s.size, bool)
            for k, m, _ in spikes:
                skip[k - 1 : k + m + 1] = True
            for k, r in _jumps(s, skip):
                out.append(Glitch(col, "jump", k, 1, float(s[k]), float(s[k - 1]), float(s[k]), r))
    return sorted(out, key=lambda g: (g.index, g.column))


def glitch_message(record: Record, glitches: list[Glitch]) -> str:
    """The sentence naming ``glitches`` of ``record`` (the first :data:`NAMED`, then a count)
    and what to do."""
    t0, dt = float(record.t0), float(record.dt)
    first = "; ".join(g.describe(t0, dt) for g in glitches[:NAMED])
    more = f" (and {len(glitches) - NAMED} more)" if len(glitches) > NAMED else ""
    cols = sorted({g.column for g in glitches})
    what = " and ".join({"x": "position x", "F": "force F"}[c] for c in cols)
    return (
        f"the {what} {'has a glitch' if len(glitches) == 1 else 'has glitches'}: {first}{more}. "
        "Such a sample is not a motion or a force the device can have (a reading of the logger "
        "or sensor gone wrong); repair it (e.g. by its neighbours' mean) or cut the record "
        "around it: lionjax does not repair data."
    )


def unit_mismatch(train: Record, valid: Record) -> str:
    """Why ``train`` and ``valid`` look like records in different units ("" when they do not):
    the force's root mean square differs by :data:`UNIT_RATIO` or more, or the position's
    standard deviation and its steps' (of Δx) both do."""

    def ratio(a: np.ndarray, b: np.ndarray, scale) -> tuple[float, float, float]:
        sa, sb = float(scale(a)), float(scale(b))
        return (sb / sa if sa > 0 and sb > 0 else 1.0), sb, sa

    rms = lambda a: np.sqrt(np.mean(np.square(a)))
    far = lambda r: max(r, 1.0 / r) >= UNIT_RATIO
    xt, xv = np.asarray(train.x, np.float64), np.asarray(valid.x, np.float64)
    rF, fv, ft = ratio(np.asarray(train.F, np.float64), np.asarray(valid.F, np.float64), rms)
    rx, sv, st = ratio(xt, xv, np.std)
    rv, _, _ = ratio(np.diff(xt), np.diff(xv), np.std)
    out = []
    if far(rF):
        out.append(
            f"its force F is {rF:.3g} times the training record's (root mean squares {fv:.3g} "
            f"and {ft:.3g} N): N against mN or kN?"
        )
    if far(rx) and far(rv):
        out.append(
            f"its position x spreads {rx:.3g} times as far as the training record's (standard "
            f"deviations {sv:.3g} and {st:.3g} m), and its steps {rv:.3g} times: m against mm "
            "or µm?"
        )
    return "; ".join(out)


def _judged(rec) -> bool:
    """Whether ``rec`` is one record of finite samples (the others are refused by the
    estimators' checks, with their own messages)."""
    return (
        isinstance(rec, Record)
        and rec.x.ndim == 1
        and bool(np.all(np.isfinite(np.asarray(rec.x))) and np.all(np.isfinite(np.asarray(rec.F))))
    )


def check_diagnosis_data(train: Record, valid: Record | None, roles: dict[str, str]) -> None:
    """The diagnosis' data checks, before any fit and before the estimators' warnings: glitches
    in either record and a pair in different units are an :class:`~lionjax.InputError` naming
    the record (``roles``: the names of ``"train"`` and ``"valid"`` in messages), the samples
    and the times. Records that are not one record of finite samples are left to the
    estimators' checks."""
    if not _judged(train) or not (valid is None or _judged(valid)):
        return
    for nm, rec in (("train", train), ("valid", valid)):
        glitches = [] if rec is None else find_glitches(rec)
        if glitches:
            raise InputError(f"diagnose: in the {roles[nm]}, {glitch_message(rec, glitches)}")
    if valid is not None and valid is not train:
        why = unit_mismatch(train, valid)
        if why:
            raise InputError(
                f"diagnose: the {roles['valid']} and the {roles['train']} look like records in "
                f"different units: {why} Convert them to t in s, x in m and F in N; a "
                "validation record that really is that much weaker or stronger leaves the "
                "training record's range, and no diagnosis of the pair would hold."
            )
