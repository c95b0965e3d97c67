"""The answer of :func:`lionjax.diagnose`: :class:`Diagnosis` and its :class:`EffectScore` rows."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .._tables import jsonable
from .._units import check_units, convert_units, unit
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
        where: findings (dicts with ``kind``, ``band``, ``share`` …, see :mod:`._where`): the
            descriptive table of fixed bands.
        effects: every candidate alone on the baseline, best first.
        stack: names of the significant effects in the order added.
        verdict: ``stack[0]``, ``"none"``, ``"unexplained"`` or ``"inconclusive"``.
        final: the stacked model's physical parameters and its ``gap``.
        noise: noise estimates and the floor of ε₁; settings: what was chosen from the record.
        steps: each stacked effect's score as it was added.
        confidence: evidence for the verdict in [0, 1] (docs/method.md, "The confidence");
            0 for ``"inconclusive"``, an abstention that claims nothing about the device.
        ambiguous: the names within a weight ratio of 1/20 of the verdict (near-ties, best
            first, the verdict included), then the candidates of which the stack is a reading
            too (asymmetric friction for Coulomb friction plus a larger offset), or ``[]``.
        weights: BIC weights of ``"none"`` and of each plausible candidate alone.
        rivals: {name: score} of the implausible candidates that, alone, explain the
            validation error better than the whole stack, and of the look-alikes
            (``"dead_zone_lookalike"``, ``"drag_lookalike"``) that score above the stack with
            no more parameters: evidence against the verdict, whose confidence they discount.
        series: validation signals for plotting (not in the JSON).
        inconclusive: where the records cannot decide whether an effect is there (too few
            effective samples, nothing significant left under a detection limit of half the
            input's term, or records moving one way on which a force of position fits as one
            of time), ``{"reason", "advice"}``: why, and what to record instead; else None.
        units: the records' unit system, ``"linear"`` (x [m], F [N]) or ``"rotary"`` (x [rad],
            F [N·m]), which every figure and text states (:meth:`in_units`).
        regions: where the gap lies, searched: the regions of the validation record where the
            dynamics depart from the rest, each significant at the family-wise level
            ``Criteria.alpha``, strongest first (:class:`~._regions.Region`; ``[]``: none is).
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
    series: dict[str, np.ndarray] = dataclasses.field(repr=False, compare=False)
    inconclusive: dict[str, str] | None = None
    units: str = "linear"
    regions: list[Region] = dataclasses.field(default_factory=list)

    def in_units(self, units: str) -> Diagnosis:
        """The same diagnosis stated in ``units`` (``"linear"`` or ``"rotary"``): every unit a
        linear diagnosis states rewritten by :func:`lionjax._units.unit` (m → rad, N → N·m …);
        the numbers, in the record's own units, unchanged."""
        if check_units(units) == self.units:
            return self
        if self.units != "linear":
            raise ValueError(f"in_units: a diagnosis in {self.units!r} units is already restated")
        where = [
            {**w, "band": unit(w["band"], units)} if isinstance(w.get("band"), str) else w
            for w in self.where
        ]
        return dataclasses.replace(
            self,
            baseline=convert_units(self.baseline, units),
            final=convert_units(self.final, units),
            where=where,
            units=units,
            regions=[dataclasses.replace(r, units=units) for r in self.regions],
        )

    def to_json(self) -> dict[str, Any]:
        """The JSON payload (plain Python types, non-finite numbers ``None``:
        :func:`lionjax._tables.jsonable`)."""
        out = {k: getattr(self, k) for k in _JSON_KEYS}
        out.update(
            effects=[e.to_json() for e in self.effects],
            steps=[e.to_json() for e in self.steps],
            regions=[r.to_json() for r in self.regions],
        )
        return jsonable(out)


#: The keys of :meth:`Diagnosis.to_json`, in order.
_JSON_KEYS = (
    "baseline where regions effects stack verdict confidence ambiguous weights rivals "
    "inconclusive final steps noise settings units"
).split()
#: Units of the baseline's and the derived parameters (each candidate owns its own: ``units``).
_UNITS = {"a": "1/s", "b": "1/kg", "F0": "N", "tau": "s", "Fmax": "N"}
#: Parameter names the diagnosis reports itself or for its built-in candidates (a ForceEffect
#: may not reuse them).
RESERVED = (
    *WINDOW_PARAMETERS,
    *_UNITS,
    *"x0 x_lo x_hi Fc_pos Fc_neg presliding soft mass_ratio beta tau_samples".split(),
    *"f_mode zeta_mode input_share deflection".split(),
)
