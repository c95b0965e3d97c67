"""The diagnosis' candidate effects, one module per family, and the look-alikes a named stack
must beat. Every candidate is an :class:`AbstractCandidate`: it says what it adds to a
structure, how its nonlinear parameters are found and how a fit of it is judged (docs/effects.md
for one's own, :class:`ForceEffect`)."""

from ._artefacts import ForceSensorDrift as ForceSensorDrift, ForceSensorLine as ForceSensorLine
from ._base import (
    AbstractCandidate as AbstractCandidate,
    AbstractPositionOrTime as AbstractPositionOrTime,
    Design as Design,
    Limits as Limits,
    design_of as design_of,
)
from ._force_effect import (
    ForceColumns as ForceColumns,
    ForceEffect as ForceEffect,
    SimulatedForce as SimulatedForce,
    check_library as check_library,
)
from ._friction import (
    AbstractFriction as AbstractFriction,
    AsymmetricFrictionCandidate as AsymmetricFrictionCandidate,
    CoulombCandidate as CoulombCandidate,
)
from ._input_maps import (
    DelayCandidate as DelayCandidate,
    InputMapSearch as InputMapSearch,
    SaturationCandidate as SaturationCandidate,
)
from ._lookalikes import (
    DEFAULT_LOOKALIKES as DEFAULT_LOOKALIKES,
    AbstractLookalike as AbstractLookalike,
    DeadZoneLookalike as DeadZoneLookalike,
    DragLookalike as DragLookalike,
    LookalikeTest as LookalikeTest,
    PeriodicLookalike as PeriodicLookalike,
)
from ._mode import FlexibleModeCandidate as FlexibleModeCandidate, ModeColumns as ModeColumns
from ._position import PositionCandidate as PositionCandidate
from ._springs import OffsetCandidate as OffsetCandidate, SpringCandidate as SpringCandidate

#: The default library, in a fixed order (ties are broken by it: simplest first): the
#: mechanical effects, then the sensor artefacts.
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
