"""The paper's experiments (Khadivar et al., Sec. IV) reproduced on the device twin:
``lionjax.paper``, one module per section of the paper (layer 3).

Composes the core (filters, models, Lion's estimator, least squares) with the twin
(:mod:`lionjax.twin`); no plotting, no files. The steps, each a pure function returning a result
Module:

1. :func:`calibrate_force` — Sec. IV.A, eq. (12): at the five points x = −30, −15, 0, 15, 30 mm
   the program sets forces Fs, a force sensor (noise σ) reads the produced force Fd, and a
   least-squares line Fs = k·Fd + c gives the calibration gain k (truth: the twin's
   ``ForceCalibration`` gain, 1.75).
2. :func:`paper_records` — Sec. IV.B: closed-loop records of the twin around the operating points
   x = −20, 0, +20 mm (``CentringPD(x_ref=point)``; the program commands k̂·(PD + excitation) and
   the record logs the *desired* force F = F_cmd/k̂), four sine inputs × three repetitions (noise
   seeds). Each operating point's records stay inside one region of eq. (13).
3. :func:`identify_records` — Lion's law on every record with one :class:`LionSettings` (the
   paper's, or the recommended), batched with ``vmap``; :func:`paper_table` — both settings, all
   regions: the Table 3-like numbers.
4. :func:`verify` — Sec. IV.C: the identified piecewise model (13) against a fresh open-loop twin
   record under F = 3 cos(40t + 400) + 0.5t, 0 ≤ t ≤ 1.6 s; NRMSE.
5. :func:`effect_study` — the first picture of the sim-to-real gap: the same identification with
   one unmodelled twin effect switched on at a realistic size, validated the same way.

:func:`reproduce_paper` runs all of it.

Figures of Fig. 3–6: :func:`paper_figures`.
"""

from ._calibration import (
    Calibration as Calibration,
    calibrate_force as calibrate_force,
)
from ._config import (
    LionSettings as LionSettings,
    PaperConfig as PaperConfig,
)
from ._effect_study import (
    EffectCase as EffectCase,
    EffectRow as EffectRow,
    effect_study as effect_study,
    identify_regions as identify_regions,
    realistic_effects as realistic_effects,
)
from ._figures import (
    paper_figures as paper_figures,
)
from ._identification import (
    Identification as Identification,
    PaperTable as PaperTable,
    identify_records as identify_records,
    paper_table as paper_table,
)
from ._records import (
    paper_records as paper_records,
    twin_runs as twin_runs,
    verification_record as verification_record,
)
from ._reproduce import (
    PaperResult as PaperResult,
    reproduce_paper as reproduce_paper,
)
from ._verification import (
    Verification as Verification,
    verify as verify,
)
