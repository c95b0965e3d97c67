"""Studies of how gains and filter poles shape convergence: ``lionjax.studies``.

:func:`study` runs Lion's law over a grid of gains × filter poles on many records at once (one
batched call), :func:`tune` searches the grid for the fastest setting that meets an accuracy
target, :func:`study_figure` draws either. ``lionjax.study`` is the same function as
:func:`lionjax.studies.study`.
"""

from ._grid import stack_banks as stack_banks
from ._plot import (
    study_figure as study_figure,
)
from ._records import StudyRecords as StudyRecords, study_records as study_records
from ._result import StudyResult as StudyResult
from ._study import study as study
from ._tune import (
    TuneObjective as TuneObjective,
    TuneSolution as TuneSolution,
    tune as tune,
    tune_objective as tune_objective,
)
