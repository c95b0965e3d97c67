"""The grid of a study, declared once: one Module per quantity a study varies.

A study grid is the product of its axes: the records (one or several record dims), the gain, the
filter poles and the initial guess. Each :class:`AbstractAxis` is either a grid axis (labelled
values, one per index along its dims) or one value for every grid point; it validates its
values, names its dims and labels, and gives the keyword arguments of
:func:`lionjax.lion_batched` for any set of grid points. :class:`StudyGrid` composes them: the
dims are the axes' dims in order, a grid point is a C-order index over them, and a chunk of
grid points becomes one batched call. A new axis is one more Module here, placed in the
order of :func:`study_grid` (and the argument of :func:`lionjax.studies.study` that feeds it).
"""

from __future__ import annotations

import abc
from collections.abc import Mapping
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._batched import stack_records
from .._errors import InputError
from .._estimators import AbstractGain, AutoGain, FixedGain, default_bank
from .._filters import FilterBank
from .._least_squares import check_identified
from .._models import AbstractModel
from .._record import Record
from .._validity import MAX_POLE_DT, check_duration, check_filter_speed, check_record, pole_dt
from ._records import StudyRecords


class AbstractAxis(eqx.Module):
    """One quantity of a study grid: a grid axis, or one value for every grid point.

    ``dims`` are the grid dims the axis adds (``()`` for one value) and ``coords`` their
    labels; :meth:`arguments` gives the keyword arguments of :func:`lionjax.lion_batched` for
    a set of grid points.
    """

    @property
    @abc.abstractmethod
    def dims(self) -> tuple[str, ...]:
        """The dims this axis adds to the grid, in order (``()``: one value for every point)."""

    @property
    @abc.abstractmethod
    def coords(self) -> dict[str, list]:
        """``{dim: labels}`` of :attr:`dims`."""

    @abc.abstractmethod
    def arguments(self, index: Mapping[str, np.ndarray], n: int, dtype) -> dict[str, Any]:
        """Keyword arguments of :func:`lionjax.lion_batched` for ``n`` grid points whose index
        along each of :attr:`dims` is ``index[dim]`` (integer arrays of length ``n``); arrays
        in ``dtype``, the records'."""


class AbstractValueAxis(AbstractAxis):
    """An axis of labelled values along one dim, or ``values`` None: one value (a default) for
    every grid point. The labels are the values (``values.tolist()``)."""

    values: eqx.AbstractVar[np.ndarray | None]
    dim: eqx.AbstractClassVar[str]

    @property
    def dims(self) -> tuple[str, ...]:
        return () if self.values is None else (self.dim,)

    @property
    def coords(self) -> dict[str, list]:
        return {} if self.values is None else {self.dim: self.values.tolist()}


class Records(AbstractAxis):
    """The records: one record (no dim), a batch or a list (dim ``"dataset"``, padded to the
    longest and masked), or a :class:`StudyRecords` (its dims).

    Attributes:
        batch: the records stacked, ``x``/``F`` ``(D, T)``, ``dt``/``t0`` ``(D,)``.
        lengths: valid samples per record, ``(D,)``.
        names: one label per record, for errors.
    """

    batch: Record
    lengths: np.ndarray
    record_dims: tuple[str, ...] = eqx.field(static=True)
    record_coords: dict[str, list] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)

    def __init__(self, records, dataset_names=None, what: str = "study"):
        dims: tuple[str, ...] = ("dataset",)
        coords: dict[str, list] | None = None
        if isinstance(records, StudyRecords):
            batch, lengths = stack_records(list(records.records))
            dims, coords = records.dims, dict(records.coords)
        elif isinstance(records, Record) and records.x.ndim == 1:
            batch, lengths = stack_records([records])
            dims, coords = (), {}
        elif isinstance(records, Record):
            if records.x.ndim != 2:
                raise InputError(
                    f"{what}: records must be one record (T,) or a batch (D, T), got x of "
                    f"shape {records.x.shape}."
                )
            D, T = records.x.shape
            batch = Record(
                records.x,
                records.F,
                jnp.broadcast_to(records.dt, (D,)),
                jnp.broadcast_to(records.t0, (D,)),
            )
            lengths = np.full(D, T)
        else:
            records = list(records)
            if not records or not all(isinstance(r, Record) for r in records):
                raise InputError(
                    f"{what}: records must be a Record (one or a batch), a non-empty list of "
                    f"Records or a StudyRecords, got {type(records).__name__}."
                )
            batch, lengths = stack_records(records)
        D = batch.x.shape[0]
        if dataset_names is not None:
            if dims != ("dataset",):
                raise InputError(
                    f"{what}: dataset_names labels a plain list of records (dim 'dataset'); "
                    f"these records have dims {dims}. Drop dataset_names."
                )
            coords = {"dataset": [str(s) for s in dataset_names]}
            if len(coords["dataset"]) != D:
                raise InputError(
                    f"{what}: dataset_names has {len(coords['dataset'])} names for {D} datasets."
                )
        elif coords is None:
            coords = {"dataset": [str(i) for i in range(D)]}
        self.batch = batch
        self.lengths = np.asarray(lengths)
        self.record_dims = tuple(dims)
        self.record_coords = coords
        self.names = tuple(
            [", ".join(str(v) for v in lab.values()) for lab in records.labels()]
            if isinstance(records, StudyRecords)
            else coords.get("dataset", [str(i) for i in range(D)])
        )

    @property
    def dims(self) -> tuple[str, ...]:
        return self.record_dims

    @property
    def coords(self) -> dict[str, list]:
        return self.record_coords

    @property
    def common_dt(self) -> bool:
        """Whether every record has the same sampling interval."""
        dt = np.asarray(self.batch.dt)
        return bool(np.all(dt == dt[0]))

    def check(self, model: AbstractModel, banks: list[FilterBank], transient, what: str) -> None:
        """Every record, alone (padding must not lengthen a short record): its data, each
        filter's speed against its dt, a duration beyond each filter's transient, and the model
        identified from its samples after the transient (the rules of lion/least_squares)."""
        b = self.batch
        for i in range(b.x.shape[0]):
            n = self.lengths[i]
            one = Record(b.x[i, :n], b.F[i, :n], b.dt[i], b.t0[i])
            name = f"{what}: record {self.names[i]!r}"
            check_record(one, name)
            for bank in banks:
                rho = pole_dt(bank, one.dt)
                if rho is not None and np.any(rho > MAX_POLE_DT):  # refused: name the record
                    check_filter_speed(bank, one.dt, name, "poles")
                check_duration(one, bank, name, transient)
            # the record identifies the model from its samples after the transient (what a_LS
            # and Lion's law use), and the model explains more than a trace of it
            check_identified(model, one, banks[0], transient, name)

    def arguments(self, index, n, dtype) -> dict[str, Any]:
        shape = tuple(len(self.record_coords[d]) for d in self.record_dims)
        d = (
            np.ravel_multi_index(tuple(index[k] for k in self.record_dims), shape)
            if self.record_dims
            else np.zeros(n, int)
        )
        b = self.batch
        if self.common_dt:  # one dt: the filter is discretised once per pole set
            sub = Record(b.x[d], b.F[d], b.dt[0], b.t0[0])
        else:
            sub = Record(b.x[d], b.F[d], b.dt[d], b.t0[d])
        ln = self.lengths[d]
        full = np.all(ln == b.x.shape[1])
        return {"records": sub, "lengths": None if full else jnp.asarray(ln, jnp.int32)}


def gain_class(gain, what: str) -> type[AbstractGain] | AbstractGain | None:
    """Check a ``gain`` argument of :func:`study` / :func:`lionjax.studies.tune`: a gain Module
    class (called with each grid value) or, for :func:`study`, one gain Module. The old strings
    ``"fixed"``/``"auto"`` are refused with their replacement."""
    if isinstance(gain, str):
        repl = {"fixed": "lionjax.FixedGain", "auto": "lionjax.AutoGain"}.get(gain)
        raise InputError(
            f"{what}: gain={gain!r}: gains are given as Module classes, not strings: "
            + (f"use gain={repl}." if repl else "gain=lionjax.FixedGain or lionjax.AutoGain.")
        )
    if gain is None or isinstance(gain, AbstractGain):
        return gain
    if isinstance(gain, type) and issubclass(gain, AbstractGain):
        return gain
    raise InputError(
        f"{what}: gain must be a gain Module class (lionjax.FixedGain: G = g·I, "
        f"lionjax.AutoGain: G = rate·R⁻¹) or a gain Module, got {gain!r}."
    )


def refuse_gain_type(gain_type, what: str) -> None:
    """The removed ``gain_type=`` argument: an error naming its replacement."""
    if gain_type is not None:
        repl = {"fixed": "lionjax.FixedGain", "auto": "lionjax.AutoGain"}.get(gain_type)
        raise InputError(
            f"{what}: gain_type={gain_type!r} was replaced by the gain Module class: "
            + (f"pass gain={repl}." if repl else "gain=lionjax.FixedGain or lionjax.AutoGain.")
        )


class Gains(AbstractValueAxis):
    """The gain: a grid of values (dim ``"gain"``), each passed to a gain Module class (G = g·I
    for :class:`lionjax.FixedGain`, the default with a grid; rates [1/s] for
    :class:`lionjax.AutoGain`), or one gain Module for every grid point (default
    ``AutoGain(1.0)``)."""

    values: np.ndarray | None
    gain: type[AbstractGain] | AbstractGain
    dim: ClassVar[str] = "gain"

    def __init__(self, values, gain, what: str = "study"):
        gain = gain_class(gain, what)
        if values is not None and isinstance(gain, AbstractGain):
            raise InputError(
                f"{what}: gains= is a grid of values for a gain class, but gain is the Module "
                f"{gain!r}; pass gain={type(gain).__name__} (the class) with gains=[...], or "
                "drop gains."
            )
        if values is None:
            gain = AutoGain() if gain is None or isinstance(gain, type) else gain
            if gain.batch_shape:
                raise InputError(
                    f"{what}: gain must be one gain for every grid point, got a batch of "
                    f"{gain.batch_shape[0]}; give the values as gains=[...]."
                )
        else:
            gain = FixedGain if gain is None else gain
            g = np.atleast_1d(np.asarray(values, float))
            if g.ndim != 1 or g.size == 0 or not np.all(g > 0):
                raise InputError(
                    f"{what}: gains must be a non-empty list of positive numbers, got {values!r}."
                )
            values = g
        self.values = values
        self.gain = gain

    @property
    def class_name(self) -> str:
        """The gain Module class of the axis, or of the one gain."""
        return self.gain.__name__ if isinstance(self.gain, type) else type(self.gain).__name__

    def arguments(self, index, n, dtype) -> dict[str, Any]:
        if self.values is None:
            return {"gain": self.gain}
        # one gain per element: the class called with a (batch,) value
        return {"gain": self.gain(jnp.asarray(self.values[index["gain"]], dtype))}


def stack_banks(pole_sets: ArrayLike, unit_dc_gain: bool = True) -> FilterBank:
    """A batched :class:`FilterBank` (``coeffs`` of shape ``(K, n)``) from K pole sets.

    Each set is checked (Hurwitz, conjugate pairs) by :meth:`FilterBank.from_poles`; with one
    set per record it is what :func:`lionjax.lion_batched` takes as one filter per record
    (index it with ``jax.tree.map(lambda c: c[idx], bank)`` to give every batch element its
    filter).
    """
    banks = [FilterBank.from_poles(np.asarray(P), unit_dc_gain) for P in pole_sets]
    return FilterBank(jnp.stack([b.coeffs for b in banks]), unit_dc_gain)


class Poles(AbstractValueAxis):
    """The filter: a grid of pole sets [rad/s] (dim ``"poles"``, one filter per batch element:
    a bank with ``coeffs`` ``(batch, n)``, tested equal to one call per pole set), or one bank
    for every grid point (default :func:`lionjax.default_bank` of the records' dt)."""

    values: np.ndarray | None
    stacked: FilterBank
    unit_dc_gain: bool = eqx.field(static=True)
    dim: ClassVar[str] = "poles"

    def __init__(self, values, unit_dc_gain: bool, dt, what: str = "study"):
        self.unit_dc_gain = unit_dc_gain
        if values is None:
            self.values = None
            self.stacked = default_bank(dt)
            return
        P = np.asarray(values, float)
        if P.ndim != 2 or P.shape[1] < 3 or np.any(P >= 0):
            raise InputError(
                f"{what}: poles must be a list of pole sets of equal length ≥ 3, all negative "
                f"(rad/s), e.g. [(-4, -4, -4), (-8, -8, -8)]; got {values!r}."
            )
        self.values = P
        self.stacked = stack_banks(P.tolist(), unit_dc_gain)

    def banks(self) -> list[FilterBank]:
        """Every filter of the axis, one bank each (the one bank without a grid)."""
        if self.values is None:
            return [self.stacked]
        return [FilterBank.from_poles(np.asarray(P), self.unit_dc_gain) for P in self.values]

    def arguments(self, index, n, dtype) -> dict[str, Any]:
        if self.values is None:
            return {"bank": self.stacked}
        return {"bank": jax.tree.map(lambda c: c[index["poles"]], self.stacked)}


class InitialGuesses(AbstractValueAxis):
    """The initial estimate θ₀: a grid of guesses, each ``(p,)`` (dim ``"theta0"``), or zeros
    for every grid point."""

    values: np.ndarray | None
    dim: ClassVar[str] = "theta0"

    def __init__(self, values, model: AbstractModel, what: str = "study"):
        if values is not None:
            p = len(model.names)
            values = np.asarray(values, float)
            if values.ndim != 2 or values.shape[1] != p:
                raise InputError(
                    f"{what}: theta0s must be a list of initial estimates of length p={p} "
                    f"({', '.join(model.names)}), got shape {values.shape}."
                )
        self.values = values

    def arguments(self, index, n, dtype) -> dict[str, Any]:
        if self.values is None:
            return {}
        return {"theta0": jnp.asarray(self.values[index["theta0"]], dtype)}


class StudyGrid(eqx.Module):
    """The product of a study's axes (records first): dims, labels, shape, and the keyword
    arguments of :func:`lionjax.lion_batched` for any grid points (flat C-order indices)."""

    records: Records
    axes: tuple[AbstractAxis, ...]

    @property
    def all_axes(self) -> tuple[AbstractAxis, ...]:
        return (self.records, *self.axes)

    @property
    def dims(self) -> tuple[str, ...]:
        return tuple(d for a in self.all_axes for d in a.dims)

    @property
    def coords(self) -> dict[str, list]:
        return {k: v for a in self.all_axes for k, v in a.coords.items()}

    @property
    def shape(self) -> tuple[int, ...]:
        coords = self.coords
        return tuple(len(coords[d]) for d in self.dims)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape)) if self.shape else 1

    def axis(self, kind: type[AbstractAxis]) -> AbstractAxis:
        """The axis of type ``kind``."""
        return next(a for a in self.all_axes if isinstance(a, kind))

    def arguments(self, points: np.ndarray) -> dict[str, Any]:
        """Keyword arguments of :func:`lionjax.lion_batched` for the flat grid ``points``."""
        points = np.asarray(points)
        index = (
            dict(zip(self.dims, np.unravel_index(points, self.shape), strict=True))
            if self.dims
            else {}
        )
        dtype = self.records.batch.x.dtype
        kw: dict[str, Any] = {}
        for a in self.all_axes:
            kw.update(a.arguments({d: index[d] for d in a.dims}, points.size, dtype))
        return kw


def study_grid(
    model: AbstractModel,
    records,
    *,
    gains=None,
    gain=None,
    poles=None,
    unit_dc_gain: bool = True,
    theta0s=None,
    dataset_names=None,
    what: str = "study",
) -> StudyGrid:
    """The grid of :func:`lionjax.studies.study`'s arguments (each validated by its axis):
    records × gains × poles × initial guesses, dims in this order, only those given."""
    recs = Records(records, dataset_names, what)
    axes = (
        Gains(gains, gain, what),
        Poles(poles, unit_dc_gain, recs.batch.dt, what),
        InitialGuesses(theta0s, model, what),
    )
    return StudyGrid(recs, axes)
