"""Records labelled by a grid of record axes for :func:`lionjax.studies.study`: the
:class:`StudyRecords` sequence, and :func:`study_records`, which simulates seeded twin records
for it (optionally over excitations × operating points × noise seeds)."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from .._record import Record

#: Names a record axis of a study may have (``dataset`` for plain lists of records).
RECORD_DIMS = ("dataset", "excitation", "operating_point", "noise_seed")


class StudyRecords(eqx.Module):
    """Records labelled by a grid of record axes (the leading dims of a :func:`study`).

    A sequence of :class:`~lionjax.Record` (``len``, indexing and iteration give the records
    in C order over ``dims``), e.g. from :func:`study_records`.

    Attributes:
        records: the records, ``prod(shape)`` of them, C order over ``dims``.
        dims: record axis names, from :data:`RECORD_DIMS` (``"dataset"``, ``"excitation"``,
            ``"operating_point"``, ``"noise_seed"``), each at most once.
        coords: axis name → list of labels (excitation names; operating points x_ref [m];
            noise seeds; dataset names).
    """

    records: tuple[Record, ...]
    dims: tuple[str, ...] = eqx.field(static=True)
    coords: dict[str, list] = eqx.field(static=True)

    def __check_init__(self):
        if len(set(self.dims)) != len(self.dims) or any(d not in RECORD_DIMS for d in self.dims):
            raise InputError(
                f"StudyRecords: dims must be distinct names from {RECORD_DIMS}, got {self.dims}."
            )
        if set(self.coords) != set(self.dims):
            raise InputError(
                f"StudyRecords: coords must have one list per dim {self.dims}, got keys "
                f"{tuple(self.coords)}."
            )
        n = int(np.prod([len(self.coords[d]) for d in self.dims]))
        if len(self.records) != n or n == 0:
            raise InputError(
                f"StudyRecords: {len(self.records)} records for a grid of shape {self.shape} "
                f"({n} records expected, at least one)."
            )

    @property
    def shape(self) -> tuple[int, ...]:
        """Grid shape, ``len(coords[d])`` for d in ``dims``."""
        return tuple(len(self.coords[d]) for d in self.dims)

    def __len__(self) -> int:
        return len(self.records)

    def __getitem__(self, i: int) -> Record:
        return self.records[i]

    def __iter__(self) -> Iterator[Record]:
        return iter(self.records)

    def labels(self) -> list[dict[str, Any]]:
        """One ``{dim: label}`` dict per record, in the order of ``records``."""
        return [
            {d: self.coords[d][i] for d, i in zip(self.dims, idx, strict=True)}
            for idx in np.ndindex(*self.shape)
        ]


def _labels(values, dim: str) -> tuple[list, list]:
    """(labels, items) of one record axis given as a list or a {label: item} mapping."""
    if isinstance(values, Mapping):
        return [str(k) for k in values], list(values.values())
    items = list(values)
    if not items:
        raise InputError(f"study_records: {dim} must be a non-empty list, got {values!r}.")
    return None, items


def study_records(
    n: int | None = None,
    n_samples: int = 3000,
    dt: float = 1e-3,
    force_noise: float = 0.01,
    seed: int = 0,
    *,
    excitations: Sequence[Any] | Mapping[str, Any] | str | None = None,
    operating_points: Sequence[float] | str | None = None,
    noise_seeds: Sequence[int] | None = None,
    plant: Any | None = None,
) -> StudyRecords:
    """Seeded closed-loop twin records for :func:`study`, labelled (a :class:`StudyRecords`).

    Two forms:

    - ``study_records(n, ...)`` (no grid axes): ``n`` records (default 3, dims ``("dataset",)``,
      labels "0", "1", …) of the paper's region 2 alone (a = 22.0 1/s, b = 1.916 1/kg, one
      region, so records never cross a region bound) under :class:`lionjax.twin.CentringPD`
      (K_p = 200 N/m, K_d = 1 N·s/m, x_ref = 0) with a random-phase multisine (0.7, 2.3, 5.1,
      9.7 Hz, 1 N each; phases from key ``seed + i``) and force-sensor noise from key
      ``1000 + seed + i``.
    - a grid over any of ``excitations`` × ``operating_points`` × ``noise_seeds`` (dims in this
      order, only those given): one record per combination, on ``plant`` (default the paper's
      piecewise device :data:`lionjax.twin.FALCON_PAPER`, eq. (13)) under
      ``CentringPD(x_ref=operating point)``. Defaults for an axis not given: the paper's input 4
      (``twin.PAPER_SINE_SETS[3]``, ±5 mm around the operating point: one region), x_ref = 0,
      noise key ``seed``. The noise seed only changes the noise (key
      ``jax.random.PRNGKey(noise_seed)``), never the excitation.

    Arguments:
        n: number of records of the first form (leave None with grid axes).
        n_samples: samples per record; dt: sample interval [s].
        force_noise: σ [N] of white force-sensor noise (:class:`lionjax.twin.ForceNoise`) added
            to the plant (0: none).
        seed: base seed (first form; default noise key of the grid form).
        excitations: force inputs [N], a list of twin excitations (labels "0", "1", …), a
            ``{label: excitation}`` mapping, or ``"paper"`` (the four
            ``twin.PAPER_SINE_SETS``, labels "input1" … "input4").
        operating_points: x_ref [m] of the centring loop, or ``"paper"`` (−20, 0, +20 mm).
        noise_seeds: integer seeds of the noise (one record per seed).
        plant: a :class:`lionjax.twin.Plant` for the grid form (its effects are kept;
            ``force_noise`` adds a ForceNoise on top).

    Returns:
        a :class:`StudyRecords` (a sequence of :class:`~lionjax.Record`).
    """
    from .. import twin

    grid = excitations is not None or operating_points is not None or noise_seeds is not None
    if not grid:
        if plant is not None:
            raise InputError(
                "study_records: plant is for the grid form; pass excitations=, "
                "operating_points= or noise_seeds= with it (the first form uses region 2)."
            )
        n = 3 if n is None else int(n)
        if n < 1:
            raise InputError(f"study_records: n must be a positive int, got {n!r}.")
        fp = twin.FALCON_PAPER
        base = twin.Plant(a=(fp.a[1],), b=(fp.b[1],), bounds=())
        if force_noise > 0:
            base = base.with_effects(twin.ForceNoise(force_noise))
        out = []
        for i in range(n):
            exc = twin.multisine(
                jnp.array([0.7, 2.3, 5.1, 9.7]), 1.0, key=jax.random.PRNGKey(seed + i)
            )
            out.append(
                twin.simulate(
                    base,
                    exc,
                    n_samples=n_samples,
                    dt=dt,
                    key=jax.random.PRNGKey(1000 + seed + i),
                    closed_loop=twin.CentringPD(),
                )
            )
        return StudyRecords(tuple(out), ("dataset",), {"dataset": [str(i) for i in range(n)]})

    if n is not None:
        raise InputError(
            f"study_records: n={n!r} is for the plain form; with excitations=, "
            "operating_points= or noise_seeds= the grid sets the number of records. Drop n."
        )
    base = twin.FALCON_PAPER if plant is None else plant
    if not isinstance(base, twin.Plant):
        raise InputError(
            f"study_records: plant must be a lionjax.twin.Plant, got {type(base).__name__}."
        )
    if force_noise > 0:
        base = base.with_effects(twin.ForceNoise(force_noise))
    dims: list[str] = []
    coords: dict[str, list] = {}
    axes: list[list] = []
    if excitations is not None:
        if isinstance(excitations, str):
            if excitations != "paper":
                raise InputError(
                    f"study_records: excitations must be a list, a mapping or 'paper', got "
                    f"{excitations!r}."
                )
            excitations = {f"input{i + 1}": e for i, e in enumerate(twin.PAPER_SINE_SETS)}
        labels, items = _labels(excitations, "excitations")
        for e in items:
            if not isinstance(e, twin.AbstractExcitation):
                raise InputError(
                    "study_records: every excitation must be a lionjax.twin excitation "
                    f"(SineSum, multisine(...), Chirp, PRBS …), got {type(e).__name__}."
                )
        dims.append("excitation")
        coords["excitation"] = labels or [str(i) for i in range(len(items))]
        axes.append(items)
    if operating_points is not None:
        if isinstance(operating_points, str):
            if operating_points != "paper":
                raise InputError(
                    "study_records: operating_points must be a list of x_ref [m] or 'paper', "
                    f"got {operating_points!r}."
                )
            operating_points = twin.PAPER_OPERATING_POINTS
        ops = np.atleast_1d(np.asarray(operating_points, float))
        if ops.ndim != 1 or ops.size == 0 or not np.all(np.isfinite(ops)):
            raise InputError(
                "study_records: operating_points must be a non-empty list of finite x_ref [m], "
                f"got {operating_points!r}."
            )
        dims.append("operating_point")
        coords["operating_point"] = ops.tolist()
        axes.append(ops.tolist())
    if noise_seeds is not None:
        seeds = list(noise_seeds)
        if not seeds or not all(isinstance(s, int | np.integer) for s in seeds):
            raise InputError(
                f"study_records: noise_seeds must be a non-empty list of ints, got {noise_seeds!r}."
            )
        dims.append("noise_seed")
        coords["noise_seed"] = [int(s) for s in seeds]
        axes.append([int(s) for s in seeds])
    default = {
        "excitation": twin.PAPER_SINE_SETS[3],
        "operating_point": 0.0,
        "noise_seed": int(seed),
    }
    out = []
    for idx in np.ndindex(*[len(a) for a in axes]):
        pick = dict(default)
        pick.update({d: axes[k][i] for k, (d, i) in enumerate(zip(dims, idx, strict=True))})
        out.append(
            twin.simulate(
                base,
                pick["excitation"],
                n_samples=n_samples,
                dt=dt,
                key=jax.random.PRNGKey(pick["noise_seed"]),
                closed_loop=twin.CentringPD(x_ref=pick["operating_point"]),
                x0=pick["operating_point"],
            )
        )
    return StudyRecords(tuple(out), tuple(dims), coords)
