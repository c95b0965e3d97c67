"""The default library of candidates: the mechanical effects, then the sensor artefacts."""

from __future__ import annotations

from ._artefacts import ForceSensorDrift, ForceSensorLine
from ._candidates import (
    AbstractCandidate,
    AsymmetricFrictionCandidate,
    CoulombCandidate,
    DelayCandidate,
    OffsetCandidate,
    PositionCandidate,
    SaturationCandidate,
    SpringCandidate,
)
from ._mode import FlexibleModeCandidate

#: The default library, in a fixed order (ties are broken by it: simplest first).
DEFAULT_CANDIDATES: tuple[AbstractCandidate, ...] = (
    OffsetCandidate(),
    CoulombCandidate(),
    SpringCandidate(),
    DelayCandidate(),
    SaturationCandidate(),
    PositionCandidate(),
    AsymmetricFrictionCandidate(),
    FlexibleModeCandidate(),
    ForceSensorLine(),
    ForceSensorDrift(),
)
