"""lionjax: Lion's identification method in JAX, a device twin, and sim-to-real diagnosis."""

from . import datasets as datasets
from . import twin as twin

# --- studies and batched estimation (issue 4) ---
# --- diagnosis (issue 5) ---
from ._diagnose import (
    AbstractCandidate as AbstractCandidate,
)
from ._diagnose import (
    Diagnosis as Diagnosis,
)
from ._diagnose import (
    diagnose as diagnose,
)
from ._effects import (
    Coulomb as Coulomb,
)
from ._effects import (
    LinearPosition as LinearPosition,
)
from ._effects import (
    Spring as Spring,
)
from ._errors import (
    RESULTS as RESULTS,
)
from ._errors import (
    IdentificationError as IdentificationError,
)
from ._errors import (
    InputError as InputError,
)
from ._errors import (
    raise_if_failed as raise_if_failed,
)
from ._estimators import (
    AbstractGain as AbstractGain,
)
from ._estimators import (
    AbstractStepper as AbstractStepper,
)
from ._estimators import (
    AutoGain as AutoGain,
)
from ._estimators import (
    DiffraxStep as DiffraxStep,
)
from ._estimators import (
    EulerStep as EulerStep,
)
from ._estimators import (
    ExactStep as ExactStep,
)
from ._estimators import (
    FixedGain as FixedGain,
)
from ._estimators import (
    LionSolution as LionSolution,
)
from ._estimators import (
    default_bank as default_bank,
)
from ._estimators import (
    lion as lion,
)

# --- experiments (issue 3) ---
from ._experiments import (
    Calibration as Calibration,
)
from ._experiments import (
    EffectCase as EffectCase,
)
from ._experiments import (
    EffectRow as EffectRow,
)
from ._experiments import (
    Identification as Identification,
)
from ._experiments import (
    LionSettings as LionSettings,
)
from ._experiments import (
    PaperConfig as PaperConfig,
)
from ._experiments import (
    PaperResult as PaperResult,
)
from ._experiments import (
    PaperTable as PaperTable,
)
from ._experiments import (
    Verification as Verification,
)
from ._experiments import (
    calibrate_force as calibrate_force,
)
from ._experiments import (
    effect_study as effect_study,
)
from ._experiments import (
    identify_records as identify_records,
)
from ._experiments import (
    identify_regions as identify_regions,
)
from ._experiments import (
    paper_records as paper_records,
)
from ._experiments import (
    paper_table as paper_table,
)
from ._experiments import (
    realistic_effects as realistic_effects,
)
from ._experiments import (
    reproduce_paper as reproduce_paper,
)
from ._experiments import (
    twin_runs as twin_runs,
)
from ._experiments import (
    verification_record as verification_record,
)
from ._experiments import (
    verify as verify,
)
from ._figures import (
    paper_figures as paper_figures,
)
from ._filters import FilterBank as FilterBank
from ._io import (
    load_record as load_record,
)
from ._io import (
    load_records as load_records,
)
from ._io import (
    parse_columns as parse_columns,
)
from ._io import (
    save_record as save_record,
)
from ._least_squares import LSSolution as LSSolution
from ._least_squares import least_squares as least_squares
from ._models import (
    AbstractEffect as AbstractEffect,
)
from ._models import (
    AbstractModel as AbstractModel,
)
from ._models import (
    Augmented as Augmented,
)
from ._models import (
    Column as Column,
)
from ._models import (
    MassDamper as MassDamper,
)
from ._models import (
    Offset as Offset,
)
from ._models import (
    Piecewise as Piecewise,
)
from ._models import (
    Regressors as Regressors,
)
from ._record import Record as Record
from ._record import resample as resample

__version__ = "0.1.0"
