"""What every candidate effect is (:class:`AbstractCandidate`), what it changes in a structure's
design (:class:`Design`) and what its fit is judged against (:class:`Limits`). A candidate is an
immutable Module whose fields are its resolved nonlinear parameters and form; a structure, a
tuple of candidates, is fitted by the pure :func:`lionjax.diagnosis._fit.fit`, which asks a
candidate what it adds and how it is judged, never what kind it is."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar

import equinox as eqx

from ..._models import AbstractEffect, Column

if TYPE_CHECKING:
    from .._settings import Settings


class Limits(eqx.Module):
    """What plausibility is judged against: ``F_abs_max`` the smaller of the two records'
    largest |F| [N] (an input map must act on the validation record too); ``dt`` [s];
    ``position_noise`` the validation record's [m] (:func:`~.._statistics._position_noise`:
    its third differences, its spectrum's white top or its one-step prediction, quantisation
    included);
    ``closed_loop``: F answers the position; ``loop_noise``: closed loop with the baseline's
    error at the noise floor; ``mode_band`` the flexible mode's searched band
    [Hz]; ``excited`` the band the training input excites [Hz] (the default (0, 0): every
    frequency lies above it); ``x_range`` the positions both records cover [m];
    ``train_range`` the training positions [m], over which candidates are fitted (a grid in
    cycles of position steps finely over it); ``stuck_share`` the share of validation samples
    where the axis sticks; ``sticks``: it sticks on either record; ``outside``: validation
    leaves the training positions; ``passed_twice`` the larger of the two records' shares of
    samples at positions that the axis passes at least twice (0 where both move one way), and
    ``reversals`` the validation record's count of reversals, each a move back by 10× the
    position noise (None: not counted); both from :func:`~.._statistics._passes`."""

    F_abs_max: float
    dt: float
    position_noise: float = 0.0
    closed_loop: bool = False
    loop_noise: bool = False
    mode_band: tuple[float, float] = (0.0, math.inf)
    excited: tuple[float, float] = (0.0, 0.0)
    x_range: tuple[float, float] = (-math.inf, math.inf)
    train_range: tuple[float, float] = (-math.inf, math.inf)
    stuck_share: float = 0.0
    sticks: bool = False
    outside: bool = False
    passed_twice: float = 1.0
    reversals: int | None = None


class Design(eqx.Module):
    """What a structure's candidates change besides their columns: force columns masked where
    the axis sticks (``stick``), position signals held at the training range's ends beyond it on
    validation (``held``), and the input map u = sat_Fmax(F(t − τ)) (``tau`` [s], ``fmax`` [N];
    F_max < 0 the soft saturation |F_max|·tanh(F/|F_max|))."""

    stick: bool = False
    held: bool = False
    tau: float = 0.0
    fmax: float = math.inf

    @property
    def maps_input(self) -> bool:
        """Whether the input passes through a map (a delay or a saturation)."""
        return self.tau != 0.0 or math.isfinite(self.fmax)


class OneColumnEffect(AbstractEffect):
    """An effect of one column ``sign``·(1/Λ)[``signal``], parameter ``param``, reported as
    ``phys`` = θ/b (None: nothing reported); its raw signal ``raw(rs)`` on a record (an array,
    or rows (k0, k1) → its samples), held ``hold``."""

    param: ClassVar[str]
    signal: ClassVar[str]
    phys: ClassVar[str | None] = None
    sign: ClassVar[float] = 1.0
    hold: ClassVar[str] = "foh"

    @property
    def names(self) -> tuple[str, ...]:
        return (self.param,)

    def columns(self) -> tuple[Column, ...]:
        return (Column(self.signal, 0, self.sign),)

    def signals(self, rs) -> dict:
        return {self.signal: (self.raw(rs), self.hold)}

    def physical(self, theta, b) -> dict:
        return {} if self.phys is None else {self.phys: theta[..., 0] / b}


class AbstractCandidate(eqx.Module):
    """One candidate effect: its ``name``, what it adds to a structure, how its nonlinear
    parameters are found, the physical parameters it reports (``units``: name → unit) and how a
    fit of it is judged. ``phys`` below is a fitted structure's parameters in physical units, by
    name (``a`` [1/s], ``b`` [1/kg], every candidate's own).

    Relations are by name: ``subsumes`` the candidates whose columns it contains (spring ⊃
    offset), ``simpler`` a structure that stands in for it unless its extra parameters are
    significant (spring → offset), ``excludes`` those never stacked with it (the data cannot
    tell them apart). ``acts_on``: ``"device"``, or ``"measurement"`` for an error of a sensor.
    ``exact_share``: where its model is exact (a linear resonance), the least share of the
    excess validation error above the fitted floor a true instance removes. The methods'
    defaults say nothing: no change, no refusal, itself its only form."""

    name: ClassVar[str]
    n_params: ClassVar[int]
    units: ClassVar[dict[str, str]] = {}
    subsumes: ClassVar[tuple[str, ...]] = ()
    simpler: ClassVar[tuple[str, ...]] = ()
    excludes: ClassVar[tuple[str, ...]] = ()
    acts_on: ClassVar[str] = "device"
    exact_share: ClassVar[float | None] = None

    def effects(self, st: Settings) -> tuple[AbstractEffect, ...]:
        """The linear effects (columns) it adds to the model under the settings ``st``; none
        for an input map."""
        return ()

    def design(self, d: Design) -> Design:
        """The design ``d`` with what it changes besides its columns (default: nothing)."""
        return d

    def params(self) -> int:
        """Its parameter count for the parsimony penalty, linear and nonlinear."""
        return self.n_params

    def variants(self, limits: Limits, chosen: tuple[AbstractCandidate, ...]) -> list[Any]:
        """Its forms tried alone (``chosen``: the candidates resolved before it, whose shared
        forms it takes); by default its forms tried on each stack."""
        return self.stack_variants()

    def pick(self, tries: list[tuple[float, Any, Any]], limits: Limits) -> int:
        """The index of the form kept among ``tries`` [(score, fit, candidate)]: the best
        validated."""
        return max(range(len(tries)), key=lambda i: tries[i][0])

    def stack_variants(self) -> list[Any]:
        """Its forms tried again on each stack."""
        return [self]

    def profile(self, objective, limits: Limits) -> Any:
        """It with its nonlinear parameters found, once, alone on the baseline, from the
        training record's :class:`~.._objective.Objective` (a new Module)."""
        return self

    def profiled(self) -> bool:
        """Whether its nonlinear parameters are found (or it has none)."""
        return True

    def search(self):
        """The search of its parameter repeated in every structure it joins, or None."""
        return None

    def physical(self, phys: dict[str, float], problem) -> dict[str, float]:
        """Values it adds to ``phys``: its profiled parameters, values derived from the fitted
        ones."""
        return {}

    def simulation(self, phys: dict[str, float], problem) -> dict[str, Any]:
        """Its term in the windowed simulation (:func:`~.._fit.simulate`): simulator parameters
        {name: value}, ``"extra"`` (a force term) or ``"du"`` (a correction to the input [N],
        (T,)). Default: none, its fitted parameters reaching the simulator by name."""
        return {}

    def simulated_gap_judges(self, stuck_share: float, crit) -> bool:
        """Whether the simulated gap may refuse it for growing, not only for diverging, on a
        record whose axis sticks ``stuck_share`` of the time."""
        return True

    def artefact(self) -> bool:
        """Whether it is an error of a sensor, not an effect on the device."""
        return self.acts_on == "measurement"

    def fits_noise(self) -> bool:
        """Whether its columns can cancel position noise (its gains then count above the
        estimated noise floor)."""
        return False

    def report(self, phys: dict[str, float]) -> dict[str, float]:
        """Its reported parameters (those of ``units``) from ``phys``."""
        return {k: phys[k] for k in self.units if k in phys}

    def measured_rms(self, phys: dict[str, float], record, v) -> float | None:
        """A measurement artefact's RMS [N] in ``record``'s F under ``phys`` (``v``: its v̂
        [m/s], (T,)); None for an effect on the device."""
        return None

    def detection_limit(self, problem, generic: float, phys: dict[str, float] | None):
        """The least size (as :meth:`~lionjax.diagnosis._run.Run.assess` sizes it) at which
        this candidate would be seen on ``problem``'s validation record, where it is not the
        record's one-parameter limit ``generic`` (over the input's term b·F), given its fit
        alone ``phys`` (None: not fitted); None: it is."""
        return None

    def implausible(self, phys: dict[str, float], lim: Limits) -> str:
        """Why the fitted parameters are not physical (``""`` when they are): by default b ≤ 0
        (every effect leaves the rigid body's mass positive)."""
        return "" if phys.get("b", 1.0) > 0 else "b ≤ 0"

    def refusal(self, lim: Limits, gap_before: float, gap_after: float) -> str:
        """Why a fit taking the simulated gap from ``gap_before`` to ``gap_after`` [m] does not
        describe the device, whatever its parameters ("" where it may)."""
        return ""

    def no_evidence(self, lim: Limits) -> bool:
        """Whether its fit is no evidence, for or against: its search ended on its edge, or the
        records cannot tell it from another force."""
        return False

    def unresolved(self, phys: dict[str, float], lim: Limits) -> bool:
        """Whether an implausible fit is refused only as too small for the record to resolve
        (the effect may be there)."""
        return False

    def other_way(self, phys: dict[str, float], other: dict[str, float], lim: Limits) -> str:
        """Why ``other``, its parameters fitted with the records' roles swapped, is not the
        effect fitted as ``phys`` ("" where it may be)."""
        return ""

    def stand_in_doubtful(self, params: dict[str, float]) -> bool:
        """Whether an implausible fit with these reported ``params`` may still be it, biased by
        what the model leaves out (a stack holding its stand-in then reads it too)."""
        return False

    def imitates(self, params: dict[str, float]) -> tuple[str, ...]:
        """Names of candidates an implausible fit with these ``params`` is a known look-alike
        of (no evidence against them)."""
        return ()


#: The least share of a record's samples at positions the axis passes twice
#: (:attr:`Limits.passed_twice`) for a force of position to be told from one of time.
PASSED_TWICE_LEAST = 0.5


class AbstractPositionOrTime(AbstractCandidate):
    """A candidate whose terms are functions of the position alone (a spring, a
    position-dependent damping or gain) or of time alone (a drifting force sensor). Where the
    axis passes each position once, x is a monotone function of time, so every function of x is
    one of time and back: a spring, a drift and any slow trend fit each other's columns. Where
    under :data:`PASSED_TWICE_LEAST` of each record's samples lie at positions the axis passes
    twice (:attr:`Limits.passed_twice`, the larger share), the records cannot tell it from the
    others: it is refused, and its fit is no evidence."""

    def refusal(self, lim: Limits, gap_before: float, gap_after: float) -> str:
        if not self.no_evidence(lim):
            return ""
        return (
            f"{lim.passed_twice:.0%} of the samples lie where the axis passes twice (least "
            f"{PASSED_TWICE_LEAST:.0%}): moving one way, forces of position and of time are one"
        )

    def no_evidence(self, lim: Limits) -> bool:
        return lim.passed_twice < PASSED_TWICE_LEAST


def design_of(structure) -> Design:
    """A structure's design: every candidate's change folded in, in order."""
    d = Design()
    for c in structure:
        d = c.design(d)
    return d
