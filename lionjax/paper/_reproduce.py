"""All of the paper's reproduction in one call: :func:`reproduce_paper`."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import equinox as eqx
import jax
from jaxtyping import PRNGKeyArray

from .._progress import reporter
from ._calibration import Calibration, calibrate_force
from ._config import LionSettings, PaperConfig
from ._effect_study import EffectCase, EffectRow, effect_study
from ._identification import Identification, PaperTable, identify_records, paper_table
from ._records import twin_runs
from ._verification import Verification, verify


class PaperResult(eqx.Module):
    """Everything of the reproduction (:func:`reproduce_paper`).

    Attributes:
        calibration: :class:`Calibration`.
        table: :class:`PaperTable`.
        identifications: one :class:`Identification` per settings (θ(t), ε(t) for the figures),
            batch shape ``(R, I, K)``.
        verifications: one :class:`Verification` per settings (same fresh record).
        effects: the :class:`EffectRow` s (empty if not run).
        config: the :class:`PaperConfig`.
    """

    calibration: Calibration
    table: PaperTable
    identifications: tuple[Identification, ...]
    verifications: tuple[Verification, ...]
    effects: tuple[EffectRow, ...]
    config: PaperConfig


def reproduce_paper(
    config: PaperConfig | None = None,
    *,
    key: PRNGKeyArray,
    effects: bool | Sequence[EffectCase] = True,
    progress: Callable[[str], None] | None = None,
) -> PaperResult:
    """Run the paper's Sec. IV on the twin: calibration, Table 3, verification, effects.

    The identification records use the *fitted* calibration gain (the calibration's error
    propagates into b, as on the device). Both settings see the same records and the same fresh
    verification record. The effect study (``effects=True``: :func:`realistic_effects`) runs the
    recommended settings with the same records' key, so its baseline is the main table's.

    Arguments:
        config: sizes (default :class:`PaperConfig`; :meth:`PaperConfig.quick` for tests).
        key: PRNG key (everything is deterministic given it).
        effects: ``True`` (the realistic effects), ``False`` (none) or a sequence of
            :class:`EffectCase`.
        progress: called with a short message before each step (e.g. print to stderr).
    """
    config = PaperConfig() if config is None else config
    say = reporter(progress)
    k_cal, k_run = jax.random.split(key)
    say(
        f"calibration: {len(config.calibration_points)} points × "
        f"{len(config.calibration_levels)} set forces"
    )
    cal = calibrate_force(config, key=k_cal)
    R, I, K = config.shape
    say(
        f"twin records: {R} operating points × {I} inputs × {K} repetitions of "
        f"{config.duration:g} s, and the verification record"
    )
    recs, vers = twin_runs(config, key=k_run, calibration_gain=cal.gain)
    recs = jax.tree.map(lambda z: z[0], recs)
    ver = jax.tree.map(lambda z: z[0], vers)
    idns = []
    for s in (LionSettings.paper(), LionSettings.recommended()):
        say(f"identification: Lion's law, {s.name} settings, {R * I * K} records")
        idns.append(identify_records(recs, s, save_every=config.save_every))
    table = paper_table(recs, config, identifications=idns)
    say("verification: identified models vs the fresh twin record (1.6 s)")
    verifications = tuple(
        verify(table.summary_a[i], table.summary_b[i], ver, config)
        for i in range(len(table.settings))
    )
    rows: tuple[EffectRow, ...] = ()
    if effects is not False:
        rows = effect_study(
            config,
            key=k_run,
            cases=None if effects is True else effects,
            baseline_nrmse=verifications[table.settings.index("recommended")].nrmse,
            calibration_gain=cal.gain,
            progress=say,
        )
    return PaperResult(
        calibration=cal,
        table=table,
        identifications=tuple(idns),
        verifications=verifications,
        effects=rows,
        config=config,
    )
