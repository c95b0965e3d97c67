"""Sim-to-real gap diagnosis (GUIDE §7, layer 3): works on recorded data alone."""

from ._candidates import (
    DEFAULT_CANDIDATES as DEFAULT_CANDIDATES,
)
from ._candidates import (
    AbstractCandidate as AbstractCandidate,
)
from ._candidates import (
    CoulombCandidate as CoulombCandidate,
)
from ._candidates import (
    DelayCandidate as DelayCandidate,
)
from ._candidates import (
    OffsetCandidate as OffsetCandidate,
)
from ._candidates import (
    PositionCandidate as PositionCandidate,
)
from ._candidates import (
    SaturationCandidate as SaturationCandidate,
)
from ._candidates import (
    SpringCandidate as SpringCandidate,
)
from ._core import Diagnosis as Diagnosis
from ._core import EffectScore as EffectScore
from ._core import diagnose as diagnose
