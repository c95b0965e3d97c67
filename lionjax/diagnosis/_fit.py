"""A structure (a tuple of resolved candidates) fitted on the training record and scored on the
validation record: the pure :func:`fit` and its result :class:`Fitted`."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable

import numpy as np

from ..twin._windows import WINDOW_PARAMETERS
from ._criteria import DIVERGED
from ._lstsq import fit_batch, residual, simulate_windows
from ._statistics import _n_eff
from ._streaming import input_map, mode_states
from .effects import Design, SimulatedForce, design_of


@dataclasses.dataclass(frozen=True)
class Fitted:
    """One structure fitted on training and scored on validation."""

    structure: tuple
    design: Design
    theta: np.ndarray
    std: np.ndarray
    physical: dict[str, float]
    ms_valid: float  # mean square ε₁ on validation
    #: (ε₁, the windowed simulation error [m]) on validation, or what computes them when read
    signals: tuple[np.ndarray, np.ndarray] | Callable
    condition: float
    gap_from: int = 0  # the first sample the gap counts (the second window's)
    #: a simulated gap above this [m] is a diverging simulation (:data:`DIVERGED`)
    diverge_at: float = math.inf
    n_sim: int = 0  # the simulation error's samples
    gap_rms: float = math.nan  # its rms from gap_from [m]
    n_eff_at_fit: float | None = None  # the residual's effective sample count (long records)

    @property
    def residual(self) -> np.ndarray:
        """ε₁ on validation (T,)."""
        return (self.signals if isinstance(self.signals, tuple) else self.signals())[0]

    @property
    def sim_error(self) -> np.ndarray:
        """The windowed simulation error on validation [m] (T,)."""
        return (self.signals if isinstance(self.signals, tuple) else self.signals())[1]

    @property
    def gap(self) -> float:
        """rms windowed simulation error [m]; ``inf`` where the simulation diverges."""
        g = self.gap_rms
        return g if g <= self.diverge_at else math.inf

    @property
    def simulation(self) -> str:
        """``"ok"``, or ``"diverged"``: the simulation left the record's range by :data:`DIVERGED`×
        or overflowed (an unstable fit, a < 0 or b < 0); its gap is then reported as ``null``."""
        return "ok" if math.isfinite(self.gap) else "diverged"

    @property
    def equation_gap(self) -> float:
        return float(np.sqrt(self.ms_valid))

    @functools.cached_property
    def n_eff(self) -> float:
        """Effective sample count of the validation residual (:func:`_n_eff`), once per fit."""
        return self.n_eff_at_fit if self.n_eff_at_fit is not None else _n_eff(self.residual)


def fit(problem, structure: tuple) -> Fitted:
    """``structure`` fitted on the training record and scored on the validation record: its
    input map's parameters searched (each candidate's :meth:`search`, twice in turn where there
    are two: each moves the other's optimum), one least-squares fit of ε₁, the validation
    residual with θ held (the initial-state columns refitted), and the windowed simulation."""
    structure = tuple(structure)
    d = design_of(structure)
    rtr, rva = problem.regressors(d)
    model = problem.model(structure)
    searches = [s for c in structure if (s := c.search()) is not None]
    for _ in range(2 if len(searches) > 1 else 1):
        for s in searches:
            d = s.run(lambda inputs: fit_batch(rtr, model, inputs)[1], d, problem.st)
    inp = (d.tau, d.fmax)
    th, _, cov, cond = fit_batch(rtr, model, [inp])
    theta = th[0]
    std = np.sqrt(np.maximum(np.diag(cov[0]), 0))
    phys = {k: float(v) for k, v in model.physical(np.asarray(theta, np.float64)).items()}
    if d.tau:
        phys["tau"] = d.tau
    if math.isfinite(d.fmax):
        phys["Fmax"] = d.fmax
    for c in structure:
        phys.update(c.physical(phys, problem))
    valid = problem.valid

    def signals():
        u = input_map(valid.F, problem.st.dt, d.tau, d.fmax)
        return residual(rva, model, theta, inp), simulate(problem, phys, structure, u)

    r, sim = signals()
    keep = rva.whole  # a long record's fit holds no (T,) array: computed again when read
    with np.errstate(over="ignore", invalid="ignore"):
        g0 = problem.gap_from(sim.size)
        gap = float(np.sqrt(np.mean(sim[g0:] ** 2)))
    return Fitted(
        structure=structure,
        design=d,
        theta=theta,
        std=std,
        physical=phys,
        ms_valid=float(np.mean(r**2)),
        signals=(r, sim) if keep else functools.cache(signals),
        condition=float(cond[0]),
        # the first window is not scored where a second one follows: its input before the
        # record is unknown (a delayed input needs τ of it), and the zero-phase start states
        # are least accurate at the record's edge
        gap_from=g0,
        diverge_at=DIVERGED * max(float(np.ptp(np.asarray(valid.x))), 1e-300),
        n_sim=int(sim.size),
        gap_rms=gap,
        n_eff_at_fit=None if keep else _n_eff(r),
    )


def simulate(problem, phys: dict[str, float], structure, u: np.ndarray) -> np.ndarray:
    """The windowed simulation error x_sim − x_meas [m] of the fitted structure on the validation
    record driven by ``u`` [N]: the mass–damper's fitted parameters the simulator reads by name
    (:data:`~lionjax.twin._windows.WINDOW_PARAMETERS`) and each candidate's own
    :meth:`~.effects.AbstractCandidate.simulation` term: simulator parameters, a force term
    (``"extra"``), a correction of the input (``"du"``), a flexible mode (``"mode"``, a
    :class:`~lionjax.twin._windows.ModeTerm`, its states restarted by :func:`mode_states`)."""
    p = {k: float(phys.get(k, 0.0)) for k in WINDOW_PARAMETERS if k != "xc"}
    p["xc"] = float(problem.st.x_center)
    p["x_lo"], p["x_hi"] = -math.inf, math.inf  # always passed: one compiled program
    effects, coefs, mode = [], [], None
    du = np.zeros(problem.valid.n_samples)
    for c in structure:
        term = dict(c.simulation(phys, problem))
        if "mode" in term:
            mode = term.pop("mode")
        if "extra" in term:
            e, k = term.pop("extra")
            effects.append(e)
            coefs.append(k)
        if "du" in term:
            du = du + term.pop("du")
        p.update({k: float(v) for k, v in term.items()})
    extra = SimulatedForce(tuple(effects), tuple(coefs)) if effects else None
    valid, H = problem.valid, problem.H
    u = np.asarray(u, np.float64) + du

    def run(mode_starts=None, upto: int | None = None):
        # the error over the first ``upto`` samples (whole windows), all where None
        s = slice(0, upto)
        return simulate_windows(
            p,
            u[s],
            np.asarray(valid.x)[s],
            problem.x_start[s],
            problem.v_start[s],
            problem.st.dt,
            H,
            extra=extra,
            t0=float(valid.t0),
            mode=None if mode_starts is None else (mode, mode_starts[s]),
        )

    n = (valid.n_samples // H) * H
    if mode is None:
        return run()[:n]
    return _with_mode(problem, mode, u, run)[:n]


def _with_mode(problem, mode, u: np.ndarray, run) -> np.ndarray:
    """The windowed simulation error with a flexible mode, its states restarted from
    :func:`mode_states` corrected for their unknown initial state: the causal filters start the
    record at rest, and their error, a free response of D (decaying as e^{−ζωt}, over 1/ζω
    seconds: long for a light mode), is fitted by least squares on the scored samples (four
    coefficients: the load's and the input filter's, as the equation error refits its
    initial-state columns on validation), the simulation being linear in them but for friction."""
    dt, w, z = problem.st.dt, float(mode.omega), float(mode.zeta)
    valid = problem.valid
    starts = mode_states(valid.x, problem.x_start, problem.v_start, u, dt, w, z)
    e0 = run(starts)
    H = problem.H
    g0 = problem.gap_from(e0.size)
    n = (valid.n_samples // H) * H
    if not np.all(np.isfinite(e0[g0:n])):
        return e0
    # the free responses fall below 10⁻⁹ of their start after 21/ζω: the windows beyond do not
    # see them (a long record's prefix alone is corrected and simulated for the sensitivities)
    m = min(n, max(-(-int(math.ceil(21.0 / (z * w * dt))) // H) * H, g0 + H))
    t = np.arange(m) * dt
    wd = w * math.sqrt(max(1.0 - z * z, 1e-12))
    scale = (max(float(np.std(starts[:, 0])), 1e-300), max(float(np.std(starts[:, 2])), 1e-300))
    # D's two free responses e^{−ζωt}·cos(ω_d t) and e^{−ζωt}·sin(ω_d t), each with its
    # derivative, computed once
    decay = np.exp(-z * w * t)
    cos, sin = decay * np.cos(wd * t), decay * np.sin(wd * t)
    pairs = ((cos, -z * w * cos - wd * sin), (sin, -z * w * sin + wd * cos))

    def free(i: int) -> np.ndarray:
        # the i-th error of the states (m, 4): a free response of D and its derivative, in the
        # load's states (d = x − y: its error enters with −) or the input filter's
        out = np.zeros((m, 4))
        sign, k = (-scale[0], 0) if i % 2 == 0 else (scale[1], 2)
        f, f_dot = pairs[i // 2]
        out[:, k], out[:, k + 1] = sign * f, sign * f_dot
        return out

    head = starts[:m]
    J = np.stack([run(head + free(i), m)[g0:m] - e0[g0:m] for i in range(4)], axis=1)
    if not np.all(np.isfinite(J)):
        return e0
    c = np.linalg.lstsq(J, -e0[g0:m], rcond=None)[0]
    for i in range(4):
        starts[:m] += c[i] * free(i)
    e = run(starts)
    return e if np.sqrt(np.mean(e[g0:n] ** 2)) <= np.sqrt(np.mean(e0[g0:n] ** 2)) else e0
