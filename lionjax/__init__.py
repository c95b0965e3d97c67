"""lionjax: Lion's identification method in JAX, a device twin, and sim-to-real diagnosis.

The top level is the method's core, read top to bottom as the method runs (docs/method.md):

- data: :class:`Record` (x [m], F [N], dt [s]), :func:`load_record` / :func:`save_record`,
  :func:`resample`; batches of records: :func:`stack_records`, :func:`shard_records`;
- the filter bank 1/Λ(s): :class:`FilterBank`, :func:`default_bank`;
- models ẍ + aẋ = bF + effects, as regressors: :class:`MassDamper`, :class:`Piecewise`,
  :class:`Augmented` with :class:`Offset`, :class:`Coulomb`, :class:`PreslidingFriction`,
  :class:`Spring`, :class:`PolynomialPosition`, :class:`LocalizedPosition` (bases
  :class:`AbstractModel`, :class:`AbstractEffect`);
- Lion's law on one record: :func:`lion` with a gain (:class:`FixedGain`, :class:`AutoGain`)
  and a stepper (:class:`ExactStep`, :class:`EulerStep`, :class:`DiffraxStep`);
  least squares: :func:`least_squares`, :func:`linear_lstsq`;
- many records at once: :func:`lion_batched` with accumulated ``outputs``
  (:class:`LSStatistics`, :class:`ConvergenceTime`, :class:`TailStatistics`,
  :class:`Trajectory`) and an :class:`Execution`; :func:`least_squares_batched`,
  :func:`lion_parallel`; :func:`identify_batch` with a method (:class:`Lion`,
  :class:`LeastSquares`);
- errors: :class:`InputError` (bad input, raised before any work), :class:`IdentificationError`
  and :data:`RESULTS` (a run that failed), :func:`raise_if_failed`;
- the everyday entry points :func:`study` and :func:`diagnose`.

Namespaces: :mod:`lionjax.twin` (the device twin: plant, effects, excitations, simulate),
:mod:`lionjax.studies` (gain/pole studies, tuning, their figures), :mod:`lionjax.diagnosis`
(the sim-to-real diagnosis and its figure), :mod:`lionjax.paper` (the paper's reproduction, one
module per section), :mod:`lionjax.datasets` (bundled measured data), :mod:`lionjax.solutions`
(what the estimators return, and reading result codes), :mod:`lionjax.extend` (the abstract
bases and building blocks for writing new outputs, steppers, batch methods, candidates).
"""

from . import (
    datasets as datasets,
    diagnosis as diagnosis,
    extend as extend,
    paper as paper,
    solutions as solutions,
    studies as studies,
    twin as twin,
)
from ._batched import (
    Execution as Execution,
    least_squares_batched as least_squares_batched,
    lion_batched as lion_batched,
    lion_parallel as lion_parallel,
    shard_records as shard_records,
    stack_records as stack_records,
)
from ._errors import (
    RESULTS as RESULTS,
    IdentificationError as IdentificationError,
    InputError as InputError,
    raise_if_failed as raise_if_failed,
)
from ._estimators import (
    AbstractGain as AbstractGain,
    AbstractStepper as AbstractStepper,
    AutoGain as AutoGain,
    DiffraxStep as DiffraxStep,
    EulerStep as EulerStep,
    ExactStep as ExactStep,
    FixedGain as FixedGain,
    default_bank as default_bank,
    lion as lion,
)
from ._filters import FilterBank as FilterBank
from ._identify_many import (
    LeastSquares as LeastSquares,
    Lion as Lion,
    identify_batch as identify_batch,
)
from ._io import (
    load_record as load_record,
    load_records as load_records,
    save_record as save_record,
)
from ._least_squares import least_squares as least_squares, linear_lstsq as linear_lstsq
from ._model_effects import (
    Coulomb as Coulomb,
    LocalizedPosition as LocalizedPosition,
    PolynomialPosition as PolynomialPosition,
    PreslidingFriction as PreslidingFriction,
    Spring as Spring,
)
from ._models import (
    AbstractEffect as AbstractEffect,
    AbstractModel as AbstractModel,
    Augmented as Augmented,
    MassDamper as MassDamper,
    Offset as Offset,
    Piecewise as Piecewise,
)
from ._outputs import (
    ConvergenceTime as ConvergenceTime,
    LSStatistics as LSStatistics,
    TailStatistics as TailStatistics,
    Trajectory as Trajectory,
)
from ._record import Record as Record, resample as resample
from .diagnosis import diagnose as diagnose
from .studies import study as study

__version__ = "0.1.0"

#: The top-level public names (the method's core and the everyday entry points); the sub-packages
#: are namespaces (see the module docstring) and are not counted here.
__all__ = [
    # data
    "Record", "load_record", "load_records", "save_record", "resample", "stack_records",
    "shard_records",
    # filters
    "FilterBank", "default_bank",
    # models and effects
    "AbstractModel", "MassDamper", "Piecewise", "Augmented", "AbstractEffect", "Offset",
    "Coulomb", "PreslidingFriction", "Spring", "PolynomialPosition", "LocalizedPosition",
    # Lion's law and least squares on one record
    "AbstractGain", "FixedGain", "AutoGain", "AbstractStepper", "ExactStep", "EulerStep",
    "DiffraxStep", "lion", "least_squares", "linear_lstsq",
    # many records
    "lion_batched", "least_squares_batched", "lion_parallel", "Execution", "LSStatistics",
    "ConvergenceTime", "TailStatistics", "Trajectory", "identify_batch", "Lion",
    "LeastSquares",
    # errors
    "InputError", "IdentificationError", "RESULTS", "raise_if_failed",
    # entry points
    "study", "diagnose",
]  # fmt: skip
