"""A flexible mode: its columns (:class:`ModeColumns`) and its candidate
(:class:`FlexibleModeCandidate`); docs/method.md, "Flexible mode", derives both.

With D(s) = s² + 2ζωs + ω² and h = (s²/D)[·], the model is ẍ + aẋ − μ·s²h[x] = b·(u − κh[u]):
columns −(s²/Λ)[h_x] and +(1/Λ)[h_F], parameters μ and β = κb (κ = 0 collocated, 1 not).
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..._models import AbstractEffect, Column
from ...twin._windows import ModeTerm
from .._filtering import mode_free_responses
from .._lstsq import rss_fixed_with_columns, rss_with_columns
from .._regressors import ModeProfileColumns
from .._search import PatternSearch, best_so_far
from .._streaming import mode_filtered, mode_seed
from ._base import AbstractCandidate

#: Largest mass ratio of a mode the input passes through: friction's pre-sliding stiffness fits a
#: heavy collocated mode as well as a heavy load does. Up to MAX_HEAVY_MODE_MASS only collocated
#: (|κ| ≤ HEAVY_MODE_KAPPA): a delay fits a heavy mode with κ ≈ 1.
MAX_MODE_MASS = 0.6
MAX_HEAVY_MODE_MASS = 0.95
HEAVY_MODE_KAPPA = 0.1
#: Largest damping ratio: a resonance peak 1/(2ζ√(1 − ζ²)) at least 2× (6 dB) above its static
#: gain; a fit more damped is a broadband lag (pre-sliding stiffness, a dead zone, backlash).
MAX_MODE_ZETA = 0.25
#: Smallest ratio of μ to the hold error it could stand for, unless |κ| ≥ HOLD_KAPPA (the hold
#: error's look-alike has κ = 0).
MODE_OVER_HOLD = 3.0
HOLD_KAPPA = 0.5
#: Smallest ratio of the deflection rms(μ·(s²/D)[x]) to the position noise: in closed loop (a
#: position loop feeds the quantisation into F) or for a heavy mode, else _OPEN.
MODE_OVER_NOISE = 2.0
MODE_OVER_NOISE_OPEN = 1.0
#: How close to the searched band's ends (relative) a mode is on its edge.
MODE_EDGE = 1e-3
#: The damping ratios searched, beyond MAX_MODE_ZETA so that a damped look-alike lands where it
#: is (and is refused), not on the plausible edge.
MODE_ZETA_RANGE = (0.005, 0.4)
#: Largest ratio of the frequencies fitted from either record: the same resonance either way.
MODE_SAME_F = 1.25
#: The coarse grid's damping ratios, the pattern search's step halvings and most rings, and the
#: factor a search ending on its band's edge is widened by, once.
MODE_ZETAS = (0.01, 0.03, 0.1, 0.3)
MODE_ROUNDS = 4
MODE_STEPS = 16
MODE_WIDEN = 4.0
#: The neighbourhood (factor on ω either way) in which the located mode is refined on the
#: plain validation RSS (:meth:`FlexibleModeCandidate.profile`).
MODE_REFINE = 1.25


def _edge(w: float, z: float, band: tuple[float, float]) -> int:
    """−1 or +1 where the mode (ω [rad/s], ζ) lies on the lower or upper edge of the band
    [rad/s] (or ζ on its search's upper limit: +1), else 0."""
    if not w > band[0] * (1 + MODE_EDGE):
        return -1
    if not w < band[1] / (1 + MODE_EDGE) or z >= MODE_ZETA_RANGE[1] / (1 + MODE_EDGE):
        return 1
    return 0


def _seeds(objective, st, lam: float, ws: np.ndarray) -> list[tuple[float, float]]:
    """Starts (ω [rad/s], ζ) besides the coarse grid's best (a lightly damped mode's valley is
    narrower than its step): the equation-error guess (:func:`~.._streaming.mode_seed`) and the
    training residual's spectral peak within ``ws`` at ζ 0.03."""
    memo = objective.problem.memo
    if ("mode", "seeds") not in memo:
        rs = objective.problem.signals("train")
        seeds = []
        seed = mode_seed(rs.x, rs.F, st.dt, lam, rs.chunk)
        lo, hi = MODE_ZETA_RANGE
        if seed is not None and ws[0] <= seed[0] <= ws[-1]:
            seeds.append((seed[0], min(max(seed[1], lo), hi)))
        r = objective.base_residual()
        P = np.abs(np.fft.rfft((r - np.mean(r)) * np.hanning(r.size))) ** 2
        w = 2 * math.pi * np.fft.rfftfreq(r.size, st.dt)
        inside = (w >= ws[0]) & (w <= ws[-1])
        if np.any(inside) and np.any(P[inside] > 0):
            seeds.append((float(w[inside][np.argmax(P[inside])]), 0.03))
        memo["mode", "seeds"] = seeds
    return memo["mode", "seeds"]


class ModeColumns(AbstractEffect):
    """A flexible mode at (ω [rad/s], ζ): columns −(s²/Λ)[h_x], +(1/Λ)[h_F] (``input=False``:
    the first alone, κ = 0), parameters μ and β = κ·b; signals the mode's exact stages on the
    filter's outputs (hold ``"mode"``), its free response refitted with the filter's."""

    acts_on_force: ClassVar[bool] = False  # μ multiplies an acceleration: not divided by b

    omega: float
    zeta: float
    input: bool = True

    @property
    def raw(self) -> tuple[str, str]:
        """The names of h_x and h_F, distinct per mode (the regressors cache by name)."""
        key = f"{float(self.omega):.9g},{float(self.zeta):.6g}"
        return f"mode_x@{key}", f"mode_F@{key}"

    @property
    def names(self) -> tuple[str, ...]:
        return ("mu", "beta") if self.input else ("mu",)

    def columns(self) -> tuple[Column, ...]:
        nx, nF = self.raw
        return (Column(nx, 2, -1.0), Column(nF, 0, 1.0))[: 2 if self.input else 1]

    def signals(self, rs) -> dict:
        w, z = float(self.omega), float(self.zeta)
        return {n: ((w, z, h), "mode") for n, h in zip(self.raw, "xF", strict=True)}

    def free_response(self, dt: float, T: int, k0: int = 0):
        """Rows k0 … T − 1 of the mode's initial-state columns (T − k0, 2)."""
        return mode_free_responses([(self.omega, self.zeta)], dt, T, k0)[0].T

    def physical(self, theta: Array, b: Array) -> dict:
        beta = theta[..., 1] if self.input else jnp.zeros_like(theta[..., 0])
        return {"mass_ratio": theta[..., 0], "beta": beta}


class FlexibleModeCandidate(AbstractCandidate):
    """A lightly damped flexible mode (:class:`ModeColumns`): mass ratio μ, frequency f_mode
    [Hz] and damping ζ profiled, the input share κ fitted (``input``) or held at 0, the best
    validated plausible variant kept (in closed loop a free κ also fits the position noise fed
    into F). Plausible as :meth:`_refusals` tests (docs/method.md, "Flexible mode", 1–6)."""

    input: bool = True
    omega: float = 0.0
    zeta: float = 0.0
    band: tuple = ()  # the band its search covered [Hz]; failed: it ended on the edge
    failed: bool = False
    name: ClassVar[str] = "flexible_mode"
    n_params: ClassVar[int] = 4
    exact_share: ClassVar[float | None] = 0.98
    units: ClassVar[dict[str, str]] = {
        "mass_ratio": "",
        "f_mode": "Hz",
        "zeta_mode": "",
        "input_share": "",
        "deflection": "m",
    }

    def effects(self, st):
        if not self.omega > 0:
            raise ValueError("FlexibleModeCandidate: the mode (ω, ζ) is not profiled yet")
        return (ModeColumns(self.omega, self.zeta, input=self.input),)

    def params(self):
        return self.n_params if self.input else self.n_params - 1

    def profiled(self) -> bool:
        return self.omega > 0

    def variants(self, limits, chosen):
        # with and without the input-share column (κ free, or held at 0: collocated)
        return [dataclasses.replace(self, input=m) for m in (False, True)]

    def pick(self, tries, limits) -> int:
        # the best validated *plausible* variant: the wider form fitted outside the effect's
        # physics describes something else
        ok = [i for i, t in enumerate(tries) if not t[2].implausible(t[1].physical, limits)]
        return max(ok or range(len(tries)), key=lambda i: tries[i][0])

    def fits_noise(self) -> bool:
        return True  # (s²/D)[x] passes the position noise through the resonance

    def simulation(self, phys, problem) -> dict:
        # the mode's states step with the axis' (ModeTerm); κ = β/b
        b = phys.get("b", 0.0)
        kappa = phys.get("beta", 0.0) / b if b else 0.0
        f = lambda v: jnp.asarray(float(v), jnp.float64)  # noqa: E731 (traced: one program)
        term = ModeTerm(f(phys.get("mass_ratio", 0.0)), f(self.omega), f(self.zeta), f(kappa))
        return {"mode": term}

    def profile(self, objective, limits):
        """(ω [rad/s], ζ): least *validation* RSS / (1 − μ)² of the mode alone fitted on the
        training record (errors in variables; above the mode ẍ − μ·s²h[x] → (1 − μ)ẍ), over the
        settings' frequencies × :data:`MODE_ZETAS`, then pattern searches in (ln ω, ln ζ) from
        the best and from :func:`_seeds`, widened once by :data:`MODE_WIDEN` off the band's
        edge (``failed``: on an edge again), then refined on the plain validation RSS within
        :data:`MODE_REFINE` (docs/method.md, "Flexible mode")."""
        if self.omega > 0:
            return self
        st = objective.problem.st
        lam = 2 * math.pi * st.filter_hz

        # the free responses of both records at once, where each is held in one chunk
        rows = max((r.T for r in (objective.rtr, objective.rva) if r.whole), default=0)

        def rss_of(modes, variants, scaled=True) -> dict[bool, np.ndarray]:
            rss: dict[bool, list] = {v: [] for v in variants}
            for i in range(0, len(modes), 32):  # a pass per 32 modes
                cols = ModeProfileColumns(modes[i : i + 32], lam, st.dt, rows=rows)
                for v in variants:
                    sel = cols.select(slice(None) if v else [0, 2, 3])
                    c, _, n = rss_with_columns(objective.rtr, objective.model, sel, coef=True)
                    n_fixed = 2 if v else 1
                    r = rss_fixed_with_columns(objective.rva, objective.model, sel, c, n_fixed)
                    mu = c[:, n]
                    ok = (mu > 0) & (mu < (1 if scaled else MAX_MODE_MASS))
                    scale = np.where(ok, 1 - mu, 1.0) ** 2 if scaled else 1.0
                    rss[v].append(np.where(ok, r / scale, np.inf))
            return {k: np.concatenate(v) for k, v in rss.items()}

        ws = 2 * math.pi * np.asarray(st.mode_grid)
        memo = objective.problem.memo
        if ("mode", "coarse") not in memo:  # the coarse grid serves both variants
            grid = [(float(w), z) for w in ws for z in MODE_ZETAS]
            memo["mode", "coarse"] = (grid, rss_of(grid, (True, False)))
        grid, coarse = memo["mode", "coarse"]
        i = int(np.argmin(coarse[self.input]))
        fn = lambda todo: rss_of(todo, (self.input,))[self.input]  # noqa: E731
        seeds = _seeds(objective, st, lam, ws)
        starts = [(grid[i], float(coarse[self.input][i]))] + [(q, float(fn([q])[0])) for q in seeds]
        (w, z), r = self._search(fn, starts, ws)
        band = (float(ws[0]), float(ws[-1]))
        side = _edge(w, z, band)
        if side:  # widened once on that side, its new edge then the limit
            if side < 0:
                band = (max(band[0] / MODE_WIDEN, 2 * math.pi * 0.1), band[1])
            else:
                band = (band[0], min(band[1] * MODE_WIDEN, 2 * math.pi * 0.45 / st.dt))
            new = np.geomspace(*band, len(ws))
            wide = [(float(f), zz) for f in new for zz in MODE_ZETAS]
            rw = fn(wide)
            k = int(np.argmin(rw))
            (w, z), r = self._search(fn, [(wide[k], float(rw[k])), ((w, z), r)], new)
            side = _edge(w, z, band)
        if not side:  # refined where the plain RSS is least, near the located mode
            plain = lambda todo: rss_of(todo, (self.input,), False)[self.input]  # noqa: E731
            near = np.clip([w / MODE_REFINE, w * MODE_REFINE], *band)
            (w2, z2), _ = self._search(plain, [((w, z), float(plain([(w, z)])[0]))], near)
            if not _edge(w2, z2, tuple(near)):  # on its edge it left the located valley
                w, z = w2, z2
        hz = (band[0] / (2 * math.pi), band[1] / (2 * math.pi))
        # failed: on the band's edge in frequency, where the valley lies beyond it (at ζ's upper
        # limit it is a damped look-alike: located, and refused by its damping)
        failed = bool(_edge(w, 0.0, band))
        return dataclasses.replace(self, omega=float(w), zeta=float(z), band=hz, failed=failed)

    def _search(self, fn, starts, ws):
        """The best of pattern searches from ``starts`` within the frequencies ``ws``."""
        lo, hi = MODE_ZETA_RANGE

        def move(q, i, j, steps):
            return (
                min(max(q[0] * math.exp(i * steps[0]), ws[0]), ws[-1]),
                min(max(q[1] * math.exp(j * steps[1]), lo), hi),
            )

        steps = (0.5 * math.log(ws[1] / ws[0]), 0.5 * math.log(3.0))
        search = PatternSearch(MODE_ROUNDS, MODE_STEPS)
        seen: dict = {}  # successive rings (and bounds) share points
        return best_so_far([search.minimise(fn, q, r, steps, move, seen) for q, r in starts])

    def no_evidence(self, lim) -> bool:
        return self.failed

    def physical(self, phys, problem) -> dict:
        mode = (self.omega, self.zeta)
        key = ("mode", "deflection", mode)
        if key not in problem.memo:  # the mode's deflection μ·(s²/D)[x] on validation
            v = problem.valid
            problem.memo[key] = float(np.std(mode_filtered(v.x, 1.0, problem.st.dt, *mode)))
        return {
            "f_mode": self.omega / (2 * math.pi),
            "zeta_mode": self.zeta,
            "deflection": abs(phys.get("mass_ratio", 0.0)) * problem.memo[key],
        }

    def report(self, phys):
        out = super().report(phys)
        if "beta" in phys and phys.get("b"):
            out["input_share"] = phys["beta"] / phys["b"]
        return out

    def imitates(self, params):
        # a heavy mode the input passes through is a delay's look-alike (a delay fits one with
        # κ ≈ 1, scoring above the delay in open loop)
        heavy = params.get("mass_ratio", 0.0) > MAX_MODE_MASS
        return ("delay",) if heavy and params.get("input_share", 0.0) >= HOLD_KAPPA else ()

    def other_way(self, phys, other, lim):
        # the same resonance both ways: its frequency is the device's, whatever the excitation;
        # a broadband lag or another frequency the other way is not the resonance
        z, z_other = phys.get("zeta_mode", 0.0), other.get("zeta_mode", 0.0)
        if z <= MAX_MODE_ZETA < z_other:
            return (
                f"the other way the mode is a broadband lag (ζ {z_other:.3g} above "
                f"{MAX_MODE_ZETA:g}), not the resonance at ζ {z:.3g}"
            )
        f, f_other = phys.get("f_mode", math.nan), other.get("f_mode", math.nan)
        if not abs(math.log(f_other / f)) <= math.log(MODE_SAME_F):
            return (
                f"the other way the mode is at {f_other:.3g} Hz, not {f:.3g} Hz (the same "
                f"resonance lies within {MODE_SAME_F - 1:.0%} of it from either record)"
            )
        return ""

    def implausible(self, phys, lim):
        return next((why for _, why in self._refusals(phys, lim)), "")

    def unresolved(self, phys, lim):
        refusals = list(self._refusals(phys, lim))
        return bool(refusals) and all(small for small, _ in refusals)

    def _refusals(self, phys, lim):
        """(within the resolution, why) of each test the fit fails, in order."""
        r = self.report(phys)
        mu = r.get("mass_ratio", 0)
        # collocated: κ held at 0 (β ≡ 0), or fitted within HEAVY_MODE_KAPPA of it
        collocated = abs(r.get("input_share", 0.0)) <= HEAVY_MODE_KAPPA
        if not 0 < mu <= (MAX_HEAVY_MODE_MASS if collocated else MAX_MODE_MASS):
            why = (
                f"no flexible mode: mass ratio outside (0, {MAX_MODE_MASS}] (up to "
                f"{MAX_HEAVY_MODE_MASS} collocated, |κ| ≤ {HEAVY_MODE_KAPPA})"
            )
            yield False, why
        # x held first-order between samples leaves ≈ (h²/12)·x⁽⁴⁾ in ε₁, which a mode above the
        # excitation reproduces with μ/ω² = h²/12 and κ = 0: the sampling, not the device; a
        # mode within the excited band answers it with its resonance, which that law lacks
        hold = (2 * math.pi * r.get("f_mode", 0.0) * lim.dt) ** 2 / 12
        through_input = abs(r.get("input_share", 0.0)) >= HOLD_KAPPA
        above = r.get("f_mode", 0.0) > lim.excited[1]
        if r["mass_ratio"] < MODE_OVER_HOLD * hold and above and not through_input:
            why = (
                f"no flexible mode: mass ratio {r['mass_ratio']:.3g} within {MODE_OVER_HOLD:g}× "
                f"the sampling's hold error at f_mode ({hold:.3g})"
            )
            yield True, why
        if not -0.5 <= r.get("input_share", 0) <= 1.5:
            yield False, "no flexible mode: input share outside [−0.5, 1.5]"
        # on the search's edge the valley lies beyond it: no resonance was located
        f, (f_lo, f_hi) = r.get("f_mode", 0.0), self.band or lim.mode_band
        if self.failed or not f_lo * (1 + MODE_EDGE) < f < f_hi / (1 + MODE_EDGE):
            why = (
                f"no flexible mode: its search ended on the edge of the searched band "
                f"[{f_lo:.3g}, {f_hi:.3g}] Hz (f_mode {f:.3g} Hz): no resonance located"
            )
            yield False, why
        if r.get("zeta_mode", 0.0) > MAX_MODE_ZETA:
            why = (
                f"no flexible mode: its damping ratio {r['zeta_mode']:.3g} is above "
                f"{MAX_MODE_ZETA:g} (a resonance peak below 2×: a broadband lag, not a resonance)"
            )
            yield False, why
        # in open loop no controller feeds the quantisation into F (and the score counts from the
        # floor): a light mode need only stand above the noise, a heavy one 2× (pre-sliding)
        light = mu <= MAX_MODE_MASS
        over = MODE_OVER_NOISE_OPEN if light and not lim.closed_loop else MODE_OVER_NOISE
        if r.get("deflection", math.inf) < over * lim.position_noise:
            why = (
                f"no flexible mode: its deflection μ·(s²/D)[x] (rms {r['deflection']:.3g} m) "
                f"is within {over:g}× the position noise ({lim.position_noise:.3g} m)"
            )
            yield True, why
        if why := super().implausible(phys, lim):
            yield False, why
