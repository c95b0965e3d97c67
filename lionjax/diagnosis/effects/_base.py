"""What every candidate effect is (:class:`AbstractCandidate`), what it changes in a structure's
design (:class:`Design`), and what its fitted parameters are judged against (:class:`Limits`).

A candidate is an immutable Module. Its fields are its *resolved* nonlinear parameters and
variant (a flexible mode's ω and ζ, friction's form, a saturation's shape): :meth:`variants`
and :meth:`profile` return new candidates, and a structure — a tuple of candidates — is fitted
by the pure :func:`lionjax.diagnosis._fit.fit`. The pipeline asks a candidate what it adds
and how it is judged; it never asks what kind of candidate it is.
"""

from __future__ import annotations

import abc
import math
from typing import TYPE_CHECKING, Any, ClassVar

import equinox as eqx

from ..._models import AbstractEffect

if TYPE_CHECKING:
    from .._settings import Settings


class Limits(eqx.Module):
    """What plausibility is judged against: the largest |F| [N] that both records reach (the
    smaller of their largest |F|: an input map must act on the record it is validated on, too),
    the sample interval [s], the validation record's position noise [m] (the robust spread of its
    third differences, encoder quantisation included), ``closed_loop``: F answers the position
    (and so its noise), ``loop_noise``: closed loop with the baseline's error at or below the
    estimated noise floor, ``mode_band``: the first and last frequency [Hz] the flexible
    mode's profile searches, ``x_range``: the positions [m] both records cover, and
    ``train_range``: the training record's positions [m], over which a candidate is fitted (a
    grid in cycles of position must step finely over this range, not only over ``x_range``)."""

    F_abs_max: float
    dt: float
    position_noise: float = 0.0
    closed_loop: bool = False
    loop_noise: bool = False
    mode_band: tuple[float, float] = (0.0, math.inf)
    x_range: tuple[float, float] = (-math.inf, math.inf)
    train_range: tuple[float, float] = (-math.inf, math.inf)
    #: the share of the validation samples where the axis sticks
    stuck_share: float = 0.0
    #: whether the axis sticks anywhere on either record
    sticks: bool = False
    #: whether the validation record leaves the training positions
    outside: bool = False


class Design(eqx.Module):
    """What a structure's candidates change in its design besides their columns: whether the
    force columns are masked where the axis sticks (``stick``), whether the position-dependent
    signals are held at their values at the ends of the training positions beyond them on the
    validation record (``held``), and the input map u = sat_Fmax(F(t − τ)) (``tau`` [s],
    ``fmax`` [N]; F_max < 0 the soft saturation |F_max|·tanh(F/|F_max|))."""

    stick: bool = False
    held: bool = False
    tau: float = 0.0
    fmax: float = math.inf

    @property
    def maps_input(self) -> bool:
        """Whether the input passes through a map (a delay or a saturation)."""
        return self.tau != 0.0 or math.isfinite(self.fmax)


class AbstractCandidate(eqx.Module):
    """One candidate effect: ``name``, its parameter count for the parsimony penalty
    (:meth:`params`), what it adds to a structure (:meth:`effects`, :meth:`design`), how its
    nonlinear parameters are found (:meth:`variants`, :meth:`profile`, :meth:`search`), the
    physical parameters it reports with their ``units``, and how a fit of it is judged.

    Relations to other candidates are by name: the candidates whose columns it contains
    (``subsumes``: spring ⊃ offset), a simpler structure that stands in for it unless its extra
    parameters are significant (``simpler``: spring → offset), and candidates never stacked
    with it (``excludes``: the data cannot tell them apart)."""

    name: ClassVar[str]
    n_params: ClassVar[int]
    #: reported physical parameter → unit
    units: ClassVar[dict[str, str]] = {}
    subsumes: ClassVar[tuple[str, ...]] = ()
    simpler: ClassVar[tuple[str, ...]] = ()
    excludes: ClassVar[tuple[str, ...]] = ()
    #: ``"device"``: an effect of the device's dynamics; ``"measurement"``: an error of a sensor
    #: (where the stack holds one, a device effect left out of the stack explained alone what
    #: the artefact explains: it holds no weight in the confidence)
    acts_on: ClassVar[str] = "device"
    #: the least share of the excess validation error (above the fitted floor) the candidate
    #: removes where it is the whole cause, or None: its model is then exact (a linear
    #: resonance is a second-order system, whatever it is driven by), so a stack of such
    #: candidates that leaves more describes something else with their columns, and its
    #: confidence falls with the remainder. None for an effect whose form the library only
    #: approximates.
    exact_share: ClassVar[float | None] = None

    # ------------------------------------------------------------------ the structure

    @abc.abstractmethod
    def effects(self, st: Settings) -> tuple[AbstractEffect, ...]:
        """Linear effect columns added to the model (may be empty), under the settings ``st``."""

    def design(self, d: Design) -> Design:
        """The design with what the candidate changes besides its columns (default: nothing)."""
        return d

    def params(self) -> int:
        """Parameter count for the parsimony penalty (its linear and nonlinear parameters)."""
        return self.n_params

    # ------------------------------------------------------------------ its search

    def variants(self, limits: Limits, chosen: tuple[AbstractCandidate, ...]) -> list[Any]:
        """The forms the candidate alone is tried in (the best validated one is kept,
        :meth:`pick`); ``chosen``: the candidates resolved before it (forms shared with one of
        them are taken from it). Default: itself."""
        return [self]

    def pick(self, tries: list[tuple[float, Any, Any]], limits: Limits) -> int:
        """The index of the variant kept among ``tries`` [(score, fit, candidate)]: the best
        validated one (default)."""
        return max(range(len(tries)), key=lambda i: tries[i][0])

    def stack_variants(self) -> list[Any]:
        """The forms the candidate is tried in again on each stack (the best validated one kept
        where it joins): forms of its own law that the effects beside it can change. Default:
        itself."""
        return [self]

    def profile(self, objective, limits: Limits) -> Any:
        """The candidate with its nonlinear parameters found once, on the training record, as
        the only effect on the baseline (``objective``: :class:`~.._objective.Objective`).
        Default: itself (no nonlinear parameter)."""
        return self

    def profiled(self) -> bool:
        """Whether its nonlinear parameters are found (or it has none): default True."""
        return True

    def search(self):
        """Its parameter searched again in every structure it joins (an input map's τ or F_max:
        :class:`~._input_maps.InputMapSearch`), or None (default)."""
        return None

    # ------------------------------------------------------------------ a fit of it

    def physical(self, phys: dict[str, float], problem) -> dict[str, float]:
        """Physical values the candidate adds to a fit's parameters ``phys`` (its profiled
        parameters, values derived from the fitted ones). Default: none."""
        return {}

    def simulation(self, phys: dict[str, float], problem) -> dict[str, Any]:
        """Its term in the windowed simulation (:func:`~.._fit.simulate`): parameters
        ``{name: value}`` of the simulator, or ``"extra"`` (a force term) and ``"du"`` (a
        correction to the input). Default: none (its fitted parameters reach the simulator by
        their names)."""
        return {}

    def simulated(self) -> bool:
        """Whether the windowed simulation models the effect in full, so that its simulated
        gap can judge it (default True)."""
        return True

    def simulated_gap_judges(self, stuck_share: float, crit) -> bool:
        """Whether the simulated gap may refuse this effect for making it worse (not only for
        diverging) on a record whose axis sticks ``stuck_share`` of the time (default True)."""
        return True

    def artefact(self) -> bool:
        """Whether it is an error of a sensor, not an effect on the device (``acts_on``)."""
        return self.acts_on == "measurement"

    def exactness(self) -> float | None:
        """The least share of the excess a true instance removes where its model is exact
        (``exact_share``), else None."""
        return self.exact_share

    def fits_noise(self) -> bool:
        """Whether its columns can cancel position noise, so that its gains count only above
        the estimated noise floor (default False)."""
        return False

    def report(self, phys: dict[str, float]) -> dict[str, float]:
        """Its physical parameters from a fitted structure's (``phys``: every parameter)."""
        return {k: phys[k] for k in self.units if k in phys}

    def measured_rms(self, phys: dict[str, float], record, v) -> float | None:
        """A measurement artefact's RMS [N] in ``record``'s measured F under the fitted
        ``phys`` (``v``: the record's v̂ [m/s]), by which it is sized against F; None (the
        default) for an effect on the device, sized by the equation error it removes."""
        return None

    # ------------------------------------------------------------------ judging it

    def implausible(self, phys: dict[str, float], lim: Limits) -> str:
        """Why the fitted parameters are not physical (``""`` when they are)."""
        return ""

    def refusal(self, lim: Limits, gap_before: float, gap_after: float) -> str:
        """Why a fit that removes the simulated gap ``gap_before`` → ``gap_after`` [m] does not
        describe the device on these records, whatever its parameters ("" by default)."""
        return ""

    def search_failed(self) -> bool:
        """Whether its search ended on the edge of what it searched (after widening): its fit
        located nothing and is no evidence, for it or against another (default False)."""
        return False

    def unresolved(self, phys: dict[str, float], lim: Limits) -> bool:
        """Whether an implausible fit is refused only for lying within the record's resolution
        (its shape is this effect's, its size within the noise or the sampling's error): the
        effect may be there, too small for this record to name. False by default."""
        return False

    def other_way(self, phys: dict[str, float], other: dict[str, float], lim: Limits) -> str:
        """Why ``other``, this effect's parameters fitted with the records' roles swapped,
        does not describe the effect fitted as ``phys`` ("" where it may): an exact model of
        the device holds both ways. Nothing by default."""
        return ""

    def stand_in_doubtful(self, params: dict[str, float]) -> bool:
        """Whether an implausible fit with these reported ``params`` may still be this effect,
        its parameters biased by what the model leaves out: a stack that holds its stand-in
        (``simpler``) is then a reading of it too. False by default."""
        return False

    def imitates(self, params: dict[str, float]) -> tuple[str, ...]:
        """Names of library candidates that an implausible fit with these reported ``params``
        is a known look-alike of: it is then no evidence against them. None by default."""
        return ()


def b_positive(phys) -> str:
    """ "b ≤ 0" where the fitted b is not positive, else ""."""
    return "" if phys.get("b", 1.0) > 0 else "b ≤ 0"


def design_of(structure) -> Design:
    """A structure's design: every candidate's change folded in, in order."""
    d = Design()
    for c in structure:
        d = c.design(d)
    return d
