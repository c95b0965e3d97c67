"""Diagnose many (train, valid) pairs in one process, one short row per pair
(:class:`DiagnosisRow`): the full diagnoses (with their signals) are not kept, so memory does not
grow with the number of pairs.

Compilation is shared: the diagnosis pads every record to its length bucket (the next power of
two ≥ T + 16, :func:`~lionjax.diagnosis._filtering.padded_length`) and traces dt, the filter and
every parameter, so the first pair of a bucket compiles its programs and every later pair of the
bucket reuses them (``benchmarks/diagnosis_speed.py --many`` measures both).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping, Sequence
from typing import Any

from .._errors import IdentificationError, InputError
from .._progress import run_chunks
from .._record import Record
from .._tables import Table, jsonable
from ._core import diagnose
from ._result import Diagnosis
from .effects import DEFAULT_CANDIDATES, AbstractCandidate

#: ``error`` of the pairs not reached when the run was interrupted (Ctrl-C).
NOT_RUN = "not run: interrupted before this pair"


@dataclasses.dataclass(frozen=True)
class DiagnosisRow:
    """One pair's answer: fields of :meth:`lionjax.diagnosis.Diagnosis.to_json`, each ``None``
    (``stack`` empty) when ``error``.

    Attributes:
        name: the pair's name.
        verdict: an effect's name, ``"none"``, ``"unexplained"`` or ``"inconclusive"``.
        confidence: the verdict's confidence in [0, 1].
        stack: the significant effects in the order added.
        shrink: ``final.shrink``, 1 − gap_final/gap_baseline of the windowed simulation
            (``None`` where not defined).
        detection_limit: the least effect this pair would name, as a share of the input's term
            b·F (``noise.detection_limit``).
        error: ``None`` on success, else why the pair was not diagnosed (a file that could not
            be read, an :class:`~lionjax.InputError` or :class:`~lionjax.IdentificationError`,
            or :data:`NOT_RUN`).
    """

    name: str
    verdict: str | None = None
    confidence: float | None = None
    stack: tuple[str, ...] = ()
    shrink: float | None = None
    detection_limit: float | None = None
    error: str | None = None

    @classmethod
    def of(cls, name: str, d: Diagnosis) -> DiagnosisRow:
        """The row of the diagnosis ``d`` of the pair ``name``."""
        out = d.to_json()  # the JSON contract: non-finite numbers already None
        return cls(
            name=name,
            verdict=out["verdict"],
            confidence=out["confidence"],
            stack=tuple(out["stack"]),
            shrink=out["final"]["shrink"],
            detection_limit=out["noise"]["detection_limit"],
        )

    def to_json(self) -> dict[str, Any]:
        """The row as plain data (``stack`` a list; non-finite numbers ``None``)."""
        return jsonable({**dataclasses.asdict(self), "stack": list(self.stack)})


@dataclasses.dataclass(frozen=True)
class ManyDiagnoses(Table):
    """The answer of :func:`diagnose_many`: one :class:`DiagnosisRow` per pair, in the order
    given (``rows``); ``complete`` is False when the run was interrupted (the rows not reached
    carry :data:`NOT_RUN`). :meth:`to_json` (path) writes ``{"rows": [...]}``, :meth:`to_csv`
    (path) one line per pair (the stack joined with ';')."""

    rows: tuple[DiagnosisRow, ...]
    complete: bool = True

    def to_rows(self) -> list[dict[str, Any]]:
        """One dict per pair (:meth:`DiagnosisRow.to_json`)."""
        return [r.to_json() for r in self.rows]

    def payload(self) -> dict[str, Any]:
        return {"rows": self.to_rows()}

    @property
    def failures(self) -> list[tuple[str, str]]:
        """``(name, error)`` of every pair that was not diagnosed, in order."""
        return [(r.name, r.error) for r in self.rows if r.error is not None]


def _check_pairs(pairs) -> list[tuple[str, Any, Any]]:
    if isinstance(pairs, Record | str | os.PathLike):
        raise InputError(
            "diagnose_many: argument 'pairs' must be a sequence of (name, train, valid), got "
            f"one {type(pairs).__name__}; for one pair call lionjax.diagnose(train, valid)."
        )
    out, seen = [], set()
    for i, p in enumerate(pairs):
        if not (isinstance(p, tuple | list) and len(p) == 3 and isinstance(p[0], str)):
            raise InputError(
                f"diagnose_many: pairs[{i}] must be (name, train, valid) with a str name and "
                f"each record a lionjax.Record or a file path, got {p!r:.80}."
            )
        for role, r in zip(("train", "valid"), p[1:], strict=True):
            if not (isinstance(r, Record | str | os.PathLike) or (role == "valid" and r is None)):
                raise InputError(
                    f"diagnose_many: pairs[{i}] ({p[0]!r}): {role} must be a lionjax.Record or "
                    f"a file path (.csv, .npz, .mat), got {type(r).__name__}."
                )
        if p[0] in seen:
            raise InputError(
                f"diagnose_many: the name {p[0]!r} is given to two pairs (pairs[{i}] and an "
                "earlier one); give each pair its own name."
            )
        seen.add(p[0])
        out.append(tuple(p))
    if not out:
        raise InputError("diagnose_many: got no pairs; pass at least one (name, train, valid).")
    return out


def _record(r, load: Mapping[str, Any]) -> Record | None:
    """``r`` itself, or the record read from the file ``r`` (errors name the file)."""
    if r is None or isinstance(r, Record):
        return r
    from .._io import load_record  # a face (layer 4), needed here for pairs given as files

    try:
        return load_record(r, **load)
    except (InputError, OSError) as e:
        msg = (e.strerror or str(e)) if isinstance(e, OSError) else str(e)
        raise InputError(msg if str(r) in msg else f"{r}: {msg}") from None


def _name_files(message: str, train, valid) -> str:
    """The diagnosis' names of its records → the files they were read from."""
    for role, r in (("train", train), ("valid", valid)):
        if isinstance(r, str | os.PathLike):
            message = message.replace(f"(argument '{role}')", f"({r})")
    return message


def diagnose_many(
    pairs: Sequence[tuple[str, Record | str | os.PathLike, Record | str | os.PathLike | None]],
    *,
    candidates: Sequence[AbstractCandidate] = DEFAULT_CANDIDATES,
    progress: bool = False,
    load: Mapping[str, Any] | None = None,
    **diagnose_kwargs: Any,
) -> ManyDiagnoses:
    """Diagnose every (train, valid) pair of a list, one after the other in this process: each
    is :func:`~lionjax.diagnosis.diagnose` ``(train, valid, candidates=candidates,
    **diagnose_kwargs)`` exactly, and pairs of the same padded lengths share its compiled
    programs.

    Arguments:
        pairs: ``(name, train, valid)`` triples of distinct names; ``train``/``valid`` a
            :class:`lionjax.Record` or a file path (``.csv``, ``.npz``, ``.mat``, read by
            :func:`lionjax.load_record` with ``load``); ``valid`` may be None (train validated
            on itself).
        candidates: the effect library of every pair (default :data:`DEFAULT_CANDIDATES`).
        progress: draw a progress bar on stderr, one step per pair.
        load: keyword arguments of :func:`lionjax.load_record` for the pairs given as files
            (``columns``, ``force_scale``, ``resample``, …).
        **diagnose_kwargs: the other arguments of ``diagnose`` (``filter_hz``, ``window_s``,
            ``max_memory_gb``, ``criteria``, thresholds), the same for every pair.

    Returns:
        a :class:`ManyDiagnoses`, row i of ``pairs[i]``. A pair whose file cannot be read or
        whose diagnosis raises :class:`~lionjax.InputError` or
        :class:`~lionjax.IdentificationError` is a row with the reason in ``error`` (naming the
        file), and the other pairs still run. Ctrl-C returns the rows done
        (``complete=False``).

    Raises:
        InputError: for a malformed ``pairs`` (not ``(name, train, valid)`` triples, a repeated
            name, none at all). Any other exception of a diagnosis (a bug) propagates.
    """
    pairs = _check_pairs(pairs)
    load = dict(load or {})
    rows: list[DiagnosisRow] = []

    def run(pair) -> None:
        name, train, valid = pair
        try:
            d = diagnose(
                _record(train, load), _record(valid, load), candidates=candidates, **diagnose_kwargs
            )
        except (InputError, IdentificationError) as e:
            rows.append(DiagnosisRow(name, error=_name_files(str(e), train, valid)))
        else:
            rows.append(DiagnosisRow.of(name, d))

    complete = run_chunks(
        pairs,
        run,
        label="diagnose",
        total=len(pairs),
        progress=progress,
        partial="returning the pairs done (the rest marked not run, complete=False)",
        what="pairs",
    )
    rows += [DiagnosisRow(p[0], error=NOT_RUN) for p in pairs[len(rows) :]]
    return ManyDiagnoses(rows=tuple(rows), complete=complete)
