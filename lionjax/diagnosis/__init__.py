"""Sim-to-real gap diagnosis (layer 3 of docs/method.md), on recorded data alone.

:func:`diagnose` (also ``lionjax.diagnose``) names the unmodelled effect that explains the
model's error, with a confidence; :func:`diagnose_many` runs many (train, valid) pairs, one row
each; :func:`plot_diagnosis` draws the one-page figure; :func:`decimation_for` gives the least
decimation that lets long records fit the memory. The library (:mod:`lionjax.diagnosis.effects`,
one module per family) is open: a :class:`ForceEffect` subclass is a candidate of one's own
(docs/effects.md), passed as ``DEFAULT_CANDIDATES + (MyEffect(),)`` or loaded from a file by
:func:`load_candidates`. :func:`find_regions` searches the validation record for the regions
where the gap lies (``Diagnosis.regions``, :class:`Region`).
"""

from . import effects as effects
from ._core import diagnose as diagnose
from ._criteria import Criteria as Criteria
from ._load import load_candidates as load_candidates
from ._many import (
    DiagnosisRow as DiagnosisRow,
    ManyDiagnoses as ManyDiagnoses,
    diagnose_many as diagnose_many,
)
from ._plot import plot_diagnosis as plot_diagnosis
from ._regions import Region as Region, find_regions as find_regions
from ._result import Diagnosis as Diagnosis, EffectScore as EffectScore
from ._statistics import decimation_for as decimation_for
from .effects import (
    DEFAULT_CANDIDATES as DEFAULT_CANDIDATES,
    AbstractCandidate as AbstractCandidate,
    AsymmetricFrictionCandidate as AsymmetricFrictionCandidate,
    CoulombCandidate as CoulombCandidate,
    DelayCandidate as DelayCandidate,
    FlexibleModeCandidate as FlexibleModeCandidate,
    ForceEffect as ForceEffect,
    ForceSensorDrift as ForceSensorDrift,
    ForceSensorLine as ForceSensorLine,
    Limits as Limits,
    OffsetCandidate as OffsetCandidate,
    PositionCandidate as PositionCandidate,
    SaturationCandidate as SaturationCandidate,
    SpringCandidate as SpringCandidate,
)
