"""The thresholds of the diagnosis' decisions: :class:`Criteria` (see :func:`lionjax.diagnose`)."""

from __future__ import annotations

import equinox as eqx

from .._errors import InputError

#: A windowed simulation whose rms error exceeds this many times the validation record's
#: position range has diverged (:attr:`~._structures.Fitted.simulation`).
DIVERGED = 100.0


class Criteria(eqx.Module):
    """Every threshold the diagnosis decides by (defaults: the values it is tested with).

    Significance of one candidate (all must hold):
        threshold: score (validated log-likelihood gain minus the BIC penalty) above which an
            effect is significant.
        min_share: least fraction of the excess gap (above the noise floor, in mean square) an
            effect must remove to be named.
        min_share_deep: ``min_share`` for an effect added to a stack of two or more: what two
            effects leave holds both shapes' misfit, which no candidate removes (Stribeck or
            Dahl friction fitted as Coulomb's), so a third effect's share of it is smaller
            (held-out triples: Coulomb friction under a delay and a spring, score 53, share
            0.24; a delay under Dahl friction and an offset, score 70, share 0.25).
        min_size: least size of a named effect: the rms of ε₁ it removes on validation over the
            rms of the input's term b·F/Λ there (0.5 %): with a precise encoder and no noise, a
            spring of 10⁻⁵ of the force is statistically significant and of no consequence.
        max_worsening: largest relative growth of the windowed-simulation gap a simulated
            candidate may cause and still be named (the simulation's own bias from held
            nonlinear terms stays well inside it).
        later_sim_share: an effect added to a stack (not the first) that the windowed
            simulation models may instead remove at least this share of the stack's simulated
            gap: what the first effect leaves is mostly its own misfit, which the equation error
            shows and no candidate removes (held-out triple, open loop: under a 15 ms delay,
            asymmetric friction for Stribeck friction with an offset removed 20 % of the excess
            equation error, score 94, and 78 % of the simulated gap).
        dominant_sim_share: where the baseline is qualitatively wrong (a ≤ 0 or b ≤ 0), the least
            share of the simulated gap a simulated candidate must remove in place of
            ``min_share`` of the equation error (a spring at 36 Hz above a 17.5 Hz filter corner,
            baseline a = −0.24, b = −0.009, removed 78 % of the simulated gap and 23 % of the
            excess equation error).

        stuck_share: on a record whose axis sticks for at least this share of the validation
            samples (``noise["stuck_share"]``), friction is refused for its simulated gap only
            where its simulation diverges: the simulated smoothed sign without static friction
            slides where the axis stuck, and a mass–damper fitted to a sticking record predicts
            little motion (held-out stiction records at 2–2.4 F_c, sticking 70 %, where Coulomb
            friction removed 100 % of the excess equation error at a score of 128, were refused
            so).

    The stack:
        max_effects: largest stack, in effects: a candidate another stacked one contains (an
            offset beside a spring) takes no place.
        pair_from: where no candidate is significant alone on the stack, pairs are tried as
            one step: the pair_from·(pair_from − 1)/2 compatible pairs of the highest summed
            scores among the 2·pair_from best plausible candidates (effects that hide each other:
            a spring under a 15 ms delay, neither significant alone); where none is either and
            the stack stays above floor_factor × the floor, every compatible pair of device
            candidates, then the pair_from best pairs each with a third, and one removing
            explained_full of the excess is stacked. 0: no pair is tried.

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
        dead_zone_lookalike_gain: friction (a candidate with ``dead_zone_lookalike``) is
            implausible where a dead zone's input in its place, on the same structure, lowers
            the validated mean square by more than this many times what friction lowers it
            (held-out dead zones: 1.36–15; friction records vetoed at 1.03–1.21 by a bare
            comparison: stiction in stick–slip and a friction small under a delay, where the
            force's sign and the velocity's nearly agree).
        dead_zone_lookalike_share: a named stack is ``unexplained`` where the dead zone's
            look-alike on the baseline structure validates below this share of its mean square.
        drag_lookalike_share: a named stack is ``unexplained`` where a force quadratic in the
            velocity on the baseline structure validates below this share of its mean square
            (drag records were named ``saturation`` at 0.58 and 0.63).
        periodic_score_factor: the position-periodic look-alike overrules the stack when its
            validated score is above this many times ``threshold`` (and it removes
            ``min_share`` of the excess the stack leaves): it is searched over a family of some
            1000 periods, not one shape, and on a closed-loop Coulomb record at 10 kHz one at 67
            cycles scored 15; the drawn cogging records of development scored 175–1950.
        periodic_over_stack: ... and when its score is at least this share of the evidence
            the stack holds over the baseline (its steps' scores): a force periodic in position
            small beside a dominant named effect is a remainder, not a rival (held-out
            dominant springs and stiction were ``unexplained`` at 0.63–0.94 for a periodic
            remainder scoring 0.02–0.23 of the stack's; cogging and dead zones that a library
            effect took in part scored 0.99–4.0 of it).
        feedback_share: share of the force's innovation explained by the position just
            measured above which a record is taken as closed loop (held-out records: ≤ 0.17 on
            63 open loops, ≥ 0.33 on the 61 of 73 closed loops whose controller's answer shows).

    The confidence:
        tie_ratio: near-tie: a name whose BIC weight is at least 1/tie_ratio of the verdict's is
            listed in ``ambiguous``.

    Where the gap lies:
        alpha: the family-wise error rate of the searched regions (``Diagnosis.regions``,
            :func:`~._regions.find_regions`): over the six variables, every candidate interval
            and the steps of the search; nothing else is decided by it.
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
    alpha: float = 0.05

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
        if not 0 < self.alpha < 1:
            raise InputError(
                f"diagnose: expected 0 < alpha < 1 (the regions' family-wise level), got "
                f"{self.alpha!r}."
            )
        if not (isinstance(self.pair_from, int) and self.pair_from >= 0):
            raise InputError(f"diagnose: expected pair_from ≥ 0, got {self.pair_from!r}.")
