"""The device twin (GUIDE §6): ``lionjax.twin.Plant``, its effects, ``simulate``, excitations.

A public namespace over the private ``lionjax._plant`` and ``lionjax._excitation`` modules. The
twin's effects live here (``lionjax.twin.CoulombFriction`` …) so they are never confused with the
*regressor* effects the identification uses (``lionjax.Offset`` …).
"""

from ._excitation import (
    PAPER_OPERATING_POINTS as PAPER_OPERATING_POINTS,
)
from ._excitation import (
    PAPER_SINE_SETS as PAPER_SINE_SETS,
)
from ._excitation import (
    PRBS as PRBS,
)
from ._excitation import (
    VERIFICATION_DURATION as VERIFICATION_DURATION,
)
from ._excitation import (
    AbstractExcitation as AbstractExcitation,
)
from ._excitation import (
    Chirp as Chirp,
)
from ._excitation import (
    SineSum as SineSum,
)
from ._excitation import (
    VerificationInput as VerificationInput,
)
from ._excitation import (
    multisine as multisine,
)
from ._plant import (
    FALCON_CABLE_GAIN as FALCON_CABLE_GAIN,
)
from ._plant import (
    FALCON_COUNTS_PER_REV as FALCON_COUNTS_PER_REV,
)
from ._plant import (
    FALCON_DRUM_DIAMETER as FALCON_DRUM_DIAMETER,
)
from ._plant import (
    FALCON_ENCODER_RESOLUTION as FALCON_ENCODER_RESOLUTION,
)
from ._plant import (
    FALCON_PAPER as FALCON_PAPER,
)
from ._plant import (
    AbstractCoefficientEffect as AbstractCoefficientEffect,
)
from ._plant import (
    AbstractForceEffect as AbstractForceEffect,
)
from ._plant import (
    AbstractFriction as AbstractFriction,
)
from ._plant import (
    AbstractInputEffect as AbstractInputEffect,
)
from ._plant import (
    AbstractMeasurement as AbstractMeasurement,
)
from ._plant import (
    AbstractPlantEffect as AbstractPlantEffect,
)
from ._plant import (
    AsymmetricFriction as AsymmetricFriction,
)
from ._plant import (
    CentringPD as CentringPD,
)
from ._plant import (
    CoulombFriction as CoulombFriction,
)
from ._plant import (
    EncoderQuantisation as EncoderQuantisation,
)
from ._plant import (
    FlexibleMode as FlexibleMode,
)
from ._plant import (
    ForceCalibration as ForceCalibration,
)
from ._plant import (
    ForceNoise as ForceNoise,
)
from ._plant import (
    ForceOffset as ForceOffset,
)
from ._plant import (
    HardSaturation as HardSaturation,
)
from ._plant import (
    InputDelay as InputDelay,
)
from ._plant import (
    LinearSpring as LinearSpring,
)
from ._plant import (
    Plant as Plant,
)
from ._plant import (
    PositionDependence as PositionDependence,
)
from ._plant import (
    PositionNoise as PositionNoise,
)
from ._plant import (
    SmoothCoulombFriction as SmoothCoulombFriction,
)
from ._plant import (
    SoftSaturation as SoftSaturation,
)
from ._plant import (
    simulate as simulate,
)
