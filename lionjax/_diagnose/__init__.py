"""Sim-to-real gap diagnosis (layer 3 of docs/method.md): works on recorded data alone."""

from ._candidates import (
    DEFAULT_CANDIDATES as DEFAULT_CANDIDATES,
    AbstractCandidate as AbstractCandidate,
    CoulombCandidate as CoulombCandidate,
    DelayCandidate as DelayCandidate,
    OffsetCandidate as OffsetCandidate,
    PositionCandidate as PositionCandidate,
    SaturationCandidate as SaturationCandidate,
    SpringCandidate as SpringCandidate,
)
from ._core import Diagnosis as Diagnosis, EffectScore as EffectScore, diagnose as diagnose
