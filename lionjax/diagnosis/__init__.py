"""Sim-to-real gap diagnosis: ``lionjax.diagnosis`` (layer 3 of docs/method.md).

:func:`diagnose` works on recorded data alone: it names the unmodelled effect that explains the
model's error, with a confidence; :func:`plot_diagnosis` draws the one-page figure;
:func:`decimation_for` gives the least decimation that lets long records fit the memory;
:func:`diagnose_many` diagnoses many (train, valid) pairs in one process, one row per pair;
:func:`find_regions` searches the validation record for the regions where the gap lies
(``Diagnosis.regions``, :class:`Region`).
The library is open: a :class:`ForceEffect` subclass is a candidate of the user's own
(docs/effects.md), passed as ``candidates=DEFAULT_CANDIDATES + (MyEffect(),)`` or loaded from a
file by :func:`load_candidates`.
``lionjax.diagnose`` is the same function as :func:`lionjax.diagnosis.diagnose`.
"""

from ._artefacts import (
    ForceSensorDrift as ForceSensorDrift,
    ForceSensorLine as ForceSensorLine,
)
from ._candidates import (
    AbstractCandidate as AbstractCandidate,
    AsymmetricFrictionCandidate as AsymmetricFrictionCandidate,
    CoulombCandidate as CoulombCandidate,
    DelayCandidate as DelayCandidate,
    Limits as Limits,
    OffsetCandidate as OffsetCandidate,
    PositionCandidate as PositionCandidate,
    SaturationCandidate as SaturationCandidate,
    SpringCandidate as SpringCandidate,
)
from ._core import diagnose as diagnose
from ._criteria import Criteria as Criteria
from ._force_effects import ForceEffect as ForceEffect
from ._library import DEFAULT_CANDIDATES as DEFAULT_CANDIDATES
from ._load import load_candidates as load_candidates
from ._many import (
    DiagnosisRow as DiagnosisRow,
    ManyDiagnoses as ManyDiagnoses,
    diagnose_many as diagnose_many,
)
from ._mode import FlexibleModeCandidate as FlexibleModeCandidate
from ._plot import plot_diagnosis as plot_diagnosis
from ._regions import Region as Region, find_regions as find_regions
from ._result import Diagnosis as Diagnosis, EffectScore as EffectScore
from ._statistics import decimation_for as decimation_for
