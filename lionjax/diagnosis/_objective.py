"""What a candidate's search minimises (:class:`Objective`): the training residual sum of
squares of a base structure with the candidate, or with new columns, the base's Gram computed
once and kept (the ``init``/``compute`` split of lineax's solvers: the base is the state, each
point a cheap update); and a fit of new columns scored on the validation record."""

from __future__ import annotations

import math

import numpy as np

from ._lstsq import fit_batch, residual, rss_fixed_with_columns, rss_with_columns
from ._regressors import columns_of


class Objective:
    """The searches' objective on ``problem`` for structures that extend ``base`` (a tuple of
    candidates): :meth:`__call__` a candidate (the training RSS of ``base + (candidate,)``, as a
    :class:`~.effects.ForceEffect`'s ``profile`` takes it), :meth:`rss_with` / :meth:`fit_with`
    new columns on the training record, :meth:`validate_with` those columns' fit held on the
    validation record. Signals of a point's own are dropped once it is scored, so that memory
    does not grow with a grid."""

    def __init__(self, problem, base: tuple = ()):
        self.problem, self.base = problem, tuple(base)
        self.rtr, self.rva = problem.regressors_of(self.base)
        self.model = problem.model(self.base)

    @property
    def train_signals(self):
        """The training record as the effects read it (:class:`~._regressors.RecordSignals`)."""
        return self.problem.signals("train")

    @property
    def force_mask(self):
        """The base structure's force mask on the training record (None: none)."""
        return self.rtr.force_mask

    def __call__(self, cand) -> float:
        """The training RSS of the base with ``cand``: its new columns on the base's Gram where
        they are columns of their own signals, else the whole structure fitted."""
        structure = (*self.base, cand)
        rtr = self.problem.regressors_of(structure)[0]
        model = self.problem.model(structure)
        own = {c.signal for c in columns_of(model)} - {c.signal for c in columns_of(self.model)}
        try:
            cols = rtr.added_columns(model, self.model)
            if cols is None:
                return float(fit_batch(rtr, model, [(0.0, math.inf)])[1][0])
            return float(rss_with_columns(rtr, self.model, cols)[0])
        finally:
            rtr.drop(own)

    def base_residual(self) -> np.ndarray:
        """ε₁ (T,) of the base structure fitted on the training record."""
        inp = (0.0, math.inf)
        theta = fit_batch(self.rtr, self.model, [inp])[0][0]
        return residual(self.rtr, self.model, theta, inp)

    def drop(self, names) -> None:
        """Forget the training record's signals ``names`` (a grid point's, once scored)."""
        for regs in self.problem.train_regressors():
            regs.drop(names)

    def rss_with(self, cols) -> np.ndarray:
        """Training RSS (m,) of the base with each of m sets of columns ``cols``."""
        return rss_with_columns(self.rtr, self.model, cols)

    def fit_with(self, cols):
        """(coefficients (m, n + K), RSS (m,), n) of the base with each set of ``cols`` on the
        training record (n: the base's columns and initial-state columns)."""
        return rss_with_columns(self.rtr, self.model, cols, coef=True)

    def validate_with(self, cols, coef, n_fixed: int) -> np.ndarray:
        """Validation RSS (m,) of the base with ``cols`` (computed on the validation record),
        the base's columns and the first ``n_fixed`` new ones held at ``coef``."""
        return rss_fixed_with_columns(self.rva, self.model, cols, coef, n_fixed)
