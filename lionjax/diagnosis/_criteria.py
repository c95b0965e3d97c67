"""The thresholds of the diagnosis' decisions: :class:`Criteria` (see :func:`lionjax.diagnose`)."""

from __future__ import annotations

import equinox as eqx

from .._errors import InputError

#: A windowed simulation whose rms error exceeds this many times the validation record's
#: position range has diverged (:attr:`~._fit.Fitted.simulation`).
DIVERGED = 100.0


class Criteria(eqx.Module):
    """Every threshold the diagnosis decides by (defaults: the values it is tested with);
    docs/method.md, "Diagnosis", states the rule each one sets and why it holds.

    Significance of one candidate (all must hold):
        threshold: score (validated log-likelihood gain minus the BIC penalty) above which an
            effect is significant: a likelihood ratio of e⁵ ≈ 150 to 1.
        min_share: least fraction of the excess gap (above the noise floor, in mean square) an
            effect must remove to be named.
        min_share_deep: ``min_share`` for an effect added to a stack of two or more: what two
            effects leave holds both shapes' misfit, which no candidate removes, so a third
            effect's share of it is smaller.
        min_size: least size of a named effect: the rms of ε₁ it removes on validation over the
            rms of the input's term b·F/Λ there (0.5 %): with a precise encoder and no noise, an
            effect of 10⁻⁵ of the force is statistically significant and of no consequence.
        max_worsening: largest relative growth of the windowed-simulation gap a simulated
            candidate may cause and still be named (the simulation's own bias from nonlinear
            terms held over a sample stays well inside it).
        later_sim_share: an effect added to a stack (not the first) that the windowed
            simulation models may instead remove at least this share of the stack's simulated
            gap: what the first effect leaves is mostly its own misfit, which the equation
            error keeps and no candidate removes.
        dominant_sim_share: where the baseline is qualitatively wrong (a ≤ 0 or b ≤ 0), the least
            share of the simulated gap a simulated candidate must remove in place of
            ``min_share`` of the equation error (the equation error of such a baseline is the
            whole response, no measure of an effect).
        stuck_share: on a record whose axis sticks for at least this share of the validation
            samples, friction is refused for its simulated gap only where its simulation
            diverges: the simulated smoothed sign, without static friction, slides where the
            axis stuck.

    The stack:
        max_effects: largest stack, in effects: a candidate another stacked one contains (an
            offset beside a spring) takes no place.
        pair_from: where no candidate is significant alone on the stack, pairs are tried as
            one step: the pair_from·(pair_from − 1)/2 compatible pairs of the highest summed
            scores among the 2·pair_from best plausible candidates (effects that hide each
            other, neither significant alone); where none is either and the stack stays above
            floor_factor × the floor, every compatible pair of device candidates, then the
            pair_from best pairs each with a third, and one removing explained_full of the
            excess is stacked. 0: no pair is tried.

    The verdict:
        floor_factor: the gap is "at the noise floor" (``baseline["at_noise_floor"]``) when ε₁'s
            rms ≤ floor_factor × the estimated floor; there a residual within its input
            correlation bound is ``none`` even with a spectral line.
        noise_peak: spectral peak ratio (:func:`._where.structure`) up to which a residual
            counts as noise.
        peak_growth, peak_power_kept: a named stack whose residual's spectral peak exceeds
            peak_growth × the baseline's (and noise_peak), while keeping more than
            peak_power_kept of the baseline's peak power, does not explain the residual's
            structure: the verdict is ``unexplained``.
        explained_full: share of the excess gap a stack must remove to earn full confidence
            (and above which a line it leaves sharpened is at the noise level).
        dead_zone_lookalike_gain: friction is implausible where a dead zone's input in its
            place, on the same structure, lowers the validated mean square by more than this
            many times what friction lowers it (friction acts with the sign of the velocity, a
            dead zone with the sign of the force; where the two signs nearly agree — stick–slip,
            a small friction under a delay — the two fits come within 25 % of each other).
        dead_zone_lookalike_share: a named stack is ``unexplained`` where the dead zone's
            look-alike on the baseline structure validates below this share of its mean square.
        drag_lookalike_share: a named stack is ``unexplained`` where a force quadratic in the
            velocity on the baseline structure validates below this share of its mean square
            (drag lowers the response to the largest forces as a saturation does).
        periodic_score_factor: the position-periodic look-alike overrules the stack when its
            validated score is above this many times ``threshold`` (and it removes
            ``min_share`` of the excess the stack leaves): it is the best of a family of some
            1000 periods, not one shape, so its score carries a multiplicity of ln 1000 ≈ 7
            and more.
        periodic_over_stack: ... and when its score is at least this share of the evidence
            the stack holds over the baseline (its steps' scores): a force periodic in position
            small beside a dominant named effect is a remainder, not a rival.
        feedback_share: share of the force's innovation explained by the position just
            measured above which a record is taken as closed loop (:func:`~._statistics._feedback`:
            in open loop the measured position predicts nothing new about F).

    The confidence:
        tie_ratio: near-tie: a name whose BIC weight is at least 1/tie_ratio of the verdict's is
            listed in ``ambiguous``.
    """

    threshold: float = 10.0
    min_share: float = 0.3
    min_share_deep: float = 0.2
    min_size: float = 0.005
    max_worsening: float = 0.1
    dominant_sim_share: float = 0.5
    later_sim_share: float = 0.5
    stuck_share: float = 0.3
    max_effects: int = 3
    pair_from: int = 3
    floor_factor: float = 1.5
    noise_peak: float = 100.0
    peak_growth: float = 2.0
    peak_power_kept: float = 0.5
    explained_full: float = 0.9
    dead_zone_lookalike_gain: float = 1.25
    dead_zone_lookalike_share: float = 0.8
    drag_lookalike_share: float = 0.8
    periodic_score_factor: float = 4.0
    periodic_over_stack: float = 0.5
    feedback_share: float = 0.3
    tie_ratio: float = 20.0

    def __check_init__(self):
        if not (
            0 <= self.min_share < 1
            and 0 <= self.min_share_deep < 1
            and 0 <= self.later_sim_share <= 1
            and self.threshold >= 0
            and self.floor_factor >= 1
            and 0 <= self.min_size < 1
        ):
            raise InputError(
                "diagnose: expected 0 ≤ min_share < 1, 0 ≤ min_share_deep < 1, "
                "0 ≤ later_sim_share ≤ 1, threshold ≥ 0, floor_factor ≥ 1, 0 ≤ min_size < 1, got "
                f"{self.min_share!r}, {self.min_share_deep!r}, {self.later_sim_share!r}, "
                f"{self.threshold!r}, {self.floor_factor!r}, {self.min_size!r}."
            )
        if not (isinstance(self.max_effects, int) and self.max_effects >= 1):
            raise InputError(f"diagnose: expected max_effects ≥ 1, got {self.max_effects!r}.")
        if not self.dead_zone_lookalike_gain > 0:
            raise InputError(
                "diagnose: expected dead_zone_lookalike_gain > 0, got "
                f"{self.dead_zone_lookalike_gain!r}."
            )
        if not self.periodic_over_stack >= 0:
            raise InputError(
                f"diagnose: expected periodic_over_stack ≥ 0, got {self.periodic_over_stack!r}."
            )
        if not (isinstance(self.pair_from, int) and self.pair_from >= 0):
            raise InputError(f"diagnose: expected pair_from ≥ 0, got {self.pair_from!r}.")
