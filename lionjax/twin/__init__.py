"""The device twin: ``lionjax.twin.Plant``, its effects, ``simulate``, excitations
(docs/method.md, "Effects").

A public namespace over the private ``lionjax._plant`` and ``lionjax.twin._excitation`` modules. The
twin's effects live here (``lionjax.twin.CoulombFriction`` …) so they are never confused with the
*regressor* effects the identification uses (``lionjax.Offset`` …).
"""

from ._effects import (
    FALCON_CABLE_GAIN as FALCON_CABLE_GAIN,
    FALCON_COUNTS_PER_REV as FALCON_COUNTS_PER_REV,
    FALCON_DRUM_DIAMETER as FALCON_DRUM_DIAMETER,
    FALCON_ENCODER_RESOLUTION as FALCON_ENCODER_RESOLUTION,
    AbstractCoefficientEffect as AbstractCoefficientEffect,
    AbstractForceEffect as AbstractForceEffect,
    AbstractFriction as AbstractFriction,
    AbstractInputEffect as AbstractInputEffect,
    AbstractMeasurement as AbstractMeasurement,
    AbstractPlantEffect as AbstractPlantEffect,
    AsymmetricFriction as AsymmetricFriction,
    CoulombFriction as CoulombFriction,
    EncoderQuantisation as EncoderQuantisation,
    FlexibleMode as FlexibleMode,
    ForceCalibration as ForceCalibration,
    ForceNoise as ForceNoise,
    ForceOffset as ForceOffset,
    HardSaturation as HardSaturation,
    InputDelay as InputDelay,
    LinearSpring as LinearSpring,
    PositionDependence as PositionDependence,
    PositionNoise as PositionNoise,
    SmoothCoulombFriction as SmoothCoulombFriction,
    SoftSaturation as SoftSaturation,
)
from ._excitation import (
    PAPER_OPERATING_POINTS as PAPER_OPERATING_POINTS,
    PAPER_SINE_SETS as PAPER_SINE_SETS,
    PRBS as PRBS,
    VERIFICATION_DURATION as VERIFICATION_DURATION,
    AbstractExcitation as AbstractExcitation,
    Chirp as Chirp,
    SineSum as SineSum,
    VerificationInput as VerificationInput,
    multisine as multisine,
)
from ._plant import (
    FALCON_PAPER as FALCON_PAPER,
    CentringPD as CentringPD,
    Plant as Plant,
)
from ._simulate import simulate as simulate
