"""The answer of :func:`lionjax.diagnose`: :class:`Diagnosis` and its :class:`EffectScore` rows."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .._tables import jsonable
from ..twin._windows import WINDOW_PARAMETERS
from ._regions import Region


@dataclasses.dataclass(frozen=True)
class EffectScore:
    """One candidate (alone on the baseline, or as added to the stack)."""

    name: str
    params: dict[str, float]
    gap: float
    shrink: float
    equation_gap: float
    equation_shrink: float
    score: float
    share: float
    significant: bool
    reason: str
    plausible: bool = True
    #: rms of ε₁ removed on validation over the rms of the input's term b·F/Λ
    size: float = 0.0
    #: ``"ok"`` or ``"diverged"`` (its windowed simulation; gap and shrink are then null)
    simulation: str = "ok"

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclasses.dataclass(frozen=True)
class Diagnosis:
    """The answer of :func:`lionjax.diagnose` (its JSON contract: :meth:`to_json`).

    Attributes:
        baseline: {"model", "params", "gap", …} of ẍ + aẋ = bF.
        where: findings (dicts with ``kind``, ``band``, ``share`` …, see :mod:`._where`).
        effects: every candidate alone on the baseline, best first.
        stack: names of the significant effects in the order added.
        verdict: ``stack[0]``, ``"none"`` or ``"unexplained"``.
        confidence: evidence for the verdict in [0, 1] (see :func:`diagnose`).
        ambiguous: the names within a weight ratio of 1/20 of the verdict (near-ties,
            best first, the verdict included), then the candidates of which the stack is
            a reading too (asymmetric friction for Coulomb friction plus a larger offset,
            where its fit may be biased), or ``[]``.
        weights: BIC weights of ``"none"`` and of each plausible candidate alone.
        rivals: {name: score} of the implausible candidates that, alone, explain the
            validation error better than the whole stack, and of the out-of-library
            look-alikes (``"dead_zone_lookalike"``, ``"drag_lookalike"``) that score above the
            stack with fewer parameters (evidence against the verdict: its confidence is
            discounted by their odds), or ``{}``.
        final: the stacked model's physical parameters and its ``gap``.
        noise: noise estimates and the floor of ε₁; settings: what was chosen from the record.
        regions: where the gap lies: the regions of the validation record where the dynamics
            depart from the rest, each significant at the family-wise level ``Criteria.alpha``,
            strongest first (:class:`~._regions.Region`; ``[]``: none is significant).
        series: validation signals for plotting (not in the JSON).
    """

    baseline: dict[str, Any]
    where: list[dict[str, Any]]
    effects: list[EffectScore]
    stack: list[str]
    verdict: str
    final: dict[str, Any]
    noise: dict[str, float]
    settings: dict[str, Any]
    steps: list[EffectScore]
    confidence: float
    ambiguous: list[str]
    weights: dict[str, float]
    rivals: dict[str, float]
    regions: list[Region] = dataclasses.field(default_factory=list)
    series: dict[str, np.ndarray] = dataclasses.field(repr=False, compare=False, default=None)

    def to_json(self) -> dict[str, Any]:
        """The JSON payload (plain Python types; non-finite numbers become ``None``; converted by
        :func:`lionjax._tables.jsonable`, the one conversion the writers use)."""
        return jsonable(
            {
                "baseline": self.baseline,
                "where": self.where,
                "regions": [r.to_json() for r in self.regions],
                "effects": [e.to_json() for e in self.effects],
                "stack": self.stack,
                "verdict": self.verdict,
                "confidence": self.confidence,
                "ambiguous": self.ambiguous,
                "weights": self.weights,
                "rivals": self.rivals,
                "final": self.final,
                "steps": [e.to_json() for e in self.steps],
                "noise": self.noise,
                "settings": self.settings,
            }
        )


#: Units of the baseline's and the derived parameters (each candidate owns its own: ``units``).
_UNITS = {"a": "1/s", "b": "1/kg", "F0": "N", "tau": "s", "Fmax": "N"}

#: Parameter names the diagnosis reports itself or for its built-in candidates (a ForceEffect
#: may not reuse them).
RESERVED = (
    *WINDOW_PARAMETERS,
    *_UNITS,
    "x0",
    "x_lo",
    "x_hi",
    "Fc_pos",
    "Fc_neg",
    "presliding",
    "soft",
    "mass_ratio",
    "beta",
    "f_mode",
    "zeta_mode",
    "input_share",
    "deflection",
)
