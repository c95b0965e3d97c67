"""The device twin (GUIDE §6): piecewise base model, effects, simulation of records."""

from ._effects import (
    FALCON_CABLE_GAIN as FALCON_CABLE_GAIN,
)
from ._effects import (
    FALCON_COUNTS_PER_REV as FALCON_COUNTS_PER_REV,
)
from ._effects import (
    FALCON_DRUM_DIAMETER as FALCON_DRUM_DIAMETER,
)
from ._effects import (
    FALCON_ENCODER_RESOLUTION as FALCON_ENCODER_RESOLUTION,
)
from ._effects import (
    AbstractCoefficientEffect as AbstractCoefficientEffect,
)
from ._effects import (
    AbstractForceEffect as AbstractForceEffect,
)
from ._effects import (
    AbstractFriction as AbstractFriction,
)
from ._effects import (
    AbstractInputEffect as AbstractInputEffect,
)
from ._effects import (
    AbstractMeasurement as AbstractMeasurement,
)
from ._effects import (
    AbstractPlantEffect as AbstractPlantEffect,
)
from ._effects import (
    AsymmetricFriction as AsymmetricFriction,
)
from ._effects import (
    CoulombFriction as CoulombFriction,
)
from ._effects import (
    EncoderQuantisation as EncoderQuantisation,
)
from ._effects import (
    FlexibleMode as FlexibleMode,
)
from ._effects import (
    ForceCalibration as ForceCalibration,
)
from ._effects import (
    ForceNoise as ForceNoise,
)
from ._effects import (
    ForceOffset as ForceOffset,
)
from ._effects import (
    HardSaturation as HardSaturation,
)
from ._effects import (
    InputDelay as InputDelay,
)
from ._effects import (
    LinearSpring as LinearSpring,
)
from ._effects import (
    PositionDependence as PositionDependence,
)
from ._effects import (
    PositionNoise as PositionNoise,
)
from ._effects import (
    SmoothCoulombFriction as SmoothCoulombFriction,
)
from ._effects import (
    SoftSaturation as SoftSaturation,
)
from ._plant import FALCON_PAPER as FALCON_PAPER
from ._plant import CentringPD as CentringPD
from ._plant import Plant as Plant
from ._simulate import simulate as simulate
