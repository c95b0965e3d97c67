"""What lionjax's estimators return, and how to read their result codes: ``lionjax.solutions``.

Every estimator returns an ``eqx.Module`` with its estimate θ, diagnostics and a ``result``
(an :data:`lionjax.RESULTS` code per record). :func:`result_code` / :func:`result_codes` turn
a code into its int(s), :func:`result_message` into the sentence that explains it;
:func:`lionjax.raise_if_failed` raises :class:`lionjax.IdentificationError` with that sentence.
"""

from ._batched import (
    BatchedSolution as BatchedSolution,
    LSBatchedSolution as LSBatchedSolution,
    ParallelSolution as ParallelSolution,
)
from ._errors import (
    DataWarning as DataWarning,
    FilterSpeedWarning as FilterSpeedWarning,
    result_code as result_code,
    result_codes as result_codes,
    result_message as result_message,
)
from ._estimators import LionSolution as LionSolution
from ._identify_many import BatchIdentification as BatchIdentification
from ._least_squares import LinearFit as LinearFit, LSSolution as LSSolution
from ._outputs import (
    ConvergenceResult as ConvergenceResult,
    LSResult as LSResult,
    TailResult as TailResult,
    TrajectoryResult as TrajectoryResult,
)
