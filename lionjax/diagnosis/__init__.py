"""Sim-to-real gap diagnosis: ``lionjax.diagnosis`` (layer 3 of docs/method.md).

:func:`diagnose` works on recorded data alone: it names the unmodelled effect that explains the
model's error, with a confidence; :func:`plot_diagnosis` draws the one-page figure;
:func:`decimation_for` gives the least decimation that lets long records fit the memory.
``lionjax.diagnose`` is the same function as :func:`lionjax.diagnosis.diagnose`.
"""

from ._candidates import (
    DEFAULT_CANDIDATES as DEFAULT_CANDIDATES,
    AbstractCandidate as AbstractCandidate,
    AsymmetricFrictionCandidate as AsymmetricFrictionCandidate,
    CoulombCandidate as CoulombCandidate,
    DelayCandidate as DelayCandidate,
    FlexibleModeCandidate as FlexibleModeCandidate,
    OffsetCandidate as OffsetCandidate,
    PositionCandidate as PositionCandidate,
    SaturationCandidate as SaturationCandidate,
    SpringCandidate as SpringCandidate,
)
from ._core import (
    Diagnosis as Diagnosis,
    EffectScore as EffectScore,
    decimation_for as decimation_for,
    diagnose as diagnose,
)
from ._plot import plot_diagnosis as plot_diagnosis
