"""Forces of the position alone: a constant force (:class:`OffsetCandidate`) and a spring with
its equilibrium (:class:`SpringCandidate`)."""

from __future__ import annotations

import math
from typing import ClassVar

from ..._model_effects import Offset, Spring
from ._base import AbstractCandidate, AbstractPositionOrTime


class OffsetCandidate(AbstractCandidate):
    """Constant force F₀ [N]: column −(1/Λ)[1]."""

    name: ClassVar[str] = "offset"
    n_params: ClassVar[int] = 1
    units: ClassVar[dict[str, str]] = {"F0": "N"}

    def effects(self, st):
        return (Offset(),)


class SpringCandidate(AbstractPositionOrTime):
    """Spring −k(x − x₀) [N]: columns +(1/Λ)[x] and the offset column (the equilibrium's
    constant force k·x₀); contains the offset, which stands in for it unless k is significant."""

    name: ClassVar[str] = "spring"
    n_params: ClassVar[int] = 2
    units: ClassVar[dict[str, str]] = {"k": "N/m", "x0": "m"}
    subsumes: ClassVar[tuple[str, ...]] = ("offset",)
    simpler: ClassVar[tuple[str, ...]] = ("offset",)

    def effects(self, st):
        return (Spring(), Offset())

    def physical(self, phys, problem) -> dict:
        k = phys.get("k", math.nan)
        return {"x0": phys["F0"] / k if k != 0 else math.nan}
