"""lionjax: Lion's identification method in JAX, a device twin, and sim-to-real diagnosis."""

from . import datasets as datasets, twin as twin
from ._batched import (
    BatchedSolution as BatchedSolution,
    Execution as Execution,
    LSBatchedSolution as LSBatchedSolution,
    ParallelSolution as ParallelSolution,
    host_devices as host_devices,
    least_squares_batched as least_squares_batched,
    lion_batched as lion_batched,
    lion_parallel as lion_parallel,
    shard_records as shard_records,
    stack_records as stack_records,
)
from ._diagnose import (
    AbstractCandidate as AbstractCandidate,
    Diagnosis as Diagnosis,
    diagnose as diagnose,
)
from ._effects import (
    Coulomb as Coulomb,
    LinearPosition as LinearPosition,
    Spring as Spring,
)
from ._errors import (
    RESULTS as RESULTS,
    IdentificationError as IdentificationError,
    InputError as InputError,
    raise_if_failed as raise_if_failed,
    result_code as result_code,
    result_codes as result_codes,
    result_message as result_message,
)
from ._estimators import (
    AbstractGain as AbstractGain,
    AbstractSampleStepper as AbstractSampleStepper,
    AbstractStepper as AbstractStepper,
    AutoGain as AutoGain,
    DiffraxStep as DiffraxStep,
    EulerStep as EulerStep,
    ExactStep as ExactStep,
    FixedGain as FixedGain,
    LionSolution as LionSolution,
    default_bank as default_bank,
    lion as lion,
)
from ._experiments import (
    Calibration as Calibration,
    EffectCase as EffectCase,
    EffectRow as EffectRow,
    Identification as Identification,
    LionSettings as LionSettings,
    PaperConfig as PaperConfig,
    PaperResult as PaperResult,
    PaperTable as PaperTable,
    Verification as Verification,
    calibrate_force as calibrate_force,
    effect_study as effect_study,
    identify_records as identify_records,
    identify_regions as identify_regions,
    paper_records as paper_records,
    paper_table as paper_table,
    realistic_effects as realistic_effects,
    reproduce_paper as reproduce_paper,
    twin_runs as twin_runs,
    verification_record as verification_record,
    verify as verify,
)
from ._figures import (
    paper_figures as paper_figures,
)
from ._filters import FilterBank as FilterBank
from ._identify_many import (
    AbstractBatchMethod as AbstractBatchMethod,
    BatchIdentification as BatchIdentification,
    LeastSquares as LeastSquares,
    Lion as Lion,
    identify_batch as identify_batch,
)
from ._io import (
    load_record as load_record,
    load_records as load_records,
    parse_columns as parse_columns,
    save_record as save_record,
)
from ._least_squares import (
    LinearFit as LinearFit,
    LSSolution as LSSolution,
    equation_error as equation_error,
    least_squares as least_squares,
    linear_lstsq as linear_lstsq,
)
from ._models import (
    AbstractEffect as AbstractEffect,
    AbstractModel as AbstractModel,
    Augmented as Augmented,
    Column as Column,
    MassDamper as MassDamper,
    Offset as Offset,
    Piecewise as Piecewise,
    Regressors as Regressors,
)
from ._outputs import (
    AbstractOutput as AbstractOutput,
    ConvergenceResult as ConvergenceResult,
    ConvergenceTime as ConvergenceTime,
    LSResult as LSResult,
    LSStatistics as LSStatistics,
    TailResult as TailResult,
    TailStatistics as TailStatistics,
    Trajectory as Trajectory,
    TrajectoryResult as TrajectoryResult,
)
from ._record import Record as Record, resample as resample
from ._study import (
    StudyRecords as StudyRecords,
    StudyResult as StudyResult,
    stack_banks as stack_banks,
    study as study,
    study_records as study_records,
)
from ._study_plot import study_figure as study_figure
from ._tune import (
    TuneObjective as TuneObjective,
    TuneSolution as TuneSolution,
    tune as tune,
    tune_objective as tune_objective,
)

__version__ = "0.1.0"
