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
        threshold: least score (validated log-likelihood gain less the BIC penalty): a
            likelihood ratio of e⁵ ≈ 150 to 1.
        min_share: least share of the excess gap (above the noise floor, in mean square) an
            effect removes to be named; ``min_share_deep`` on a stack of two or more, whose
            shapes' misfit no candidate removes.
        min_size: least rms of ε₁ removed over the rms of the input's term b·F/Λ, in (0, 1): with
            a precise encoder, an effect of 10⁻⁵ of the force is significant and of no consequence.
        max_worsening: largest relative growth of the simulated gap a simulated candidate may
            cause (the simulation's own bias stays well inside it).
        later_sim_share: least share of the stack's simulated gap a simulated effect after the
            first may remove instead (what the first leaves is mostly its own misfit).
        dominant_sim_share: where the baseline is qualitatively wrong (a ≤ 0 or b ≤ 0), the least
            share of the simulated gap a simulated candidate removes instead of ``min_share``.
        stuck_share: on a record whose axis sticks this share of the validation samples,
            friction is refused for its simulated gap only where its simulation diverges.

    The stack:
        max_effects: largest stack, in effects (one another contains takes no place).
        pair_from: where nothing is significant alone, the pair_from·(pair_from − 1)/2
            compatible pairs of the highest summed scores among the 2·pair_from best are tried as
            one step; failing those, above floor_factor × the floor, every compatible pair, then
            the pair_from best each with a third, removing explained_full. 0: no pairs.

    The verdict:
        floor_factor: the gap is "at the noise floor" when ε₁'s rms ≤ floor_factor × the
            estimated floor; there a residual within its input correlation bound is ``none``.
        noise_peak: spectral peak ratio (:func:`._where.structure`) up to which a residual is
            noise.
        peak_growth, peak_power_kept: a named stack whose residual's peak exceeds peak_growth ×
            the baseline's (and noise_peak), keeping more than peak_power_kept of its power, is
            ``unexplained``.
        explained_full: share of the excess gap a stack removes for full confidence.
        dead_zone_lookalike_gain: friction is implausible where a dead zone's input in its place
            lowers the validated mean square this many times more.
        dead_zone_lookalike_share, drag_lookalike_share: a named stack is ``unexplained`` where
            the dead zone's or the drag's look-alike on the baseline validates below this share
            of its mean square.
        periodic_score_factor, periodic_over_stack: the position-periodic look-alike overrules
            the stack when its score exceeds this many times ``threshold`` (the best of some
            1000 periods) and this share of the stack's evidence.
        feedback_share: share of the force's innovation the position explains above which a
            record is closed loop (:func:`~._statistics._feedback`).

    The confidence:
        tie_ratio: a name whose BIC weight is at least 1/tie_ratio of the verdict's is listed
            in ``ambiguous``.

    Where the gap lies:
        alpha: the family-wise error rate of the searched regions (``Diagnosis.regions``,
            :func:`~._regions.find_regions`) over the six variables, their candidate intervals
            and the search's steps; it decides nothing else.
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
        rules = {
            "threshold": (lambda v: v >= 0, "≥ 0"),
            "min_share": (lambda v: 0 <= v < 1, "in [0, 1)"),
            "min_share_deep": (lambda v: 0 <= v < 1, "in [0, 1)"),
            "later_sim_share": (lambda v: 0 <= v <= 1, "in [0, 1]"),
            "min_size": (
                lambda v: 0 < v < 1,
                "in (0, 1) (the confidence of 'none' weighs the sizes from min_size to 1 that "
                "could hide below the detection limit on a log scale, which 0 does not have; "
                "to name effects of any size use a small value such as 1e-6)",
            ),
            "floor_factor": (lambda v: v >= 1, "≥ 1"),
            "max_effects": (lambda v: isinstance(v, int) and v >= 1, "an int ≥ 1"),
            "pair_from": (lambda v: isinstance(v, int) and v >= 0, "an int ≥ 0"),
            "dead_zone_lookalike_gain": (lambda v: v > 0, "> 0"),
            "periodic_over_stack": (lambda v: v >= 0, "≥ 0"),
            "alpha": (lambda v: 0 < v < 1, "in (0, 1)"),
        }
        for name, (ok, want) in rules.items():
            if not ok(getattr(self, name)):
                raise InputError(
                    f"diagnose: criterion {name} must be {want}, got {getattr(self, name)!r}."
                )
