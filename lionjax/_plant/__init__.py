"""The device twin (GUIDE §6): piecewise base model, effects, simulation of records."""

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
from ._plant import FALCON_PAPER as FALCON_PAPER, CentringPD as CentringPD, Plant as Plant
from ._simulate import simulate as simulate
