"""What a candidate's search minimises (:class:`Objective`): the training residual sum of
squares of a base structure with the candidate or with new columns, the base's Gram computed
once (lineax's ``init``/``compute`` split: the base is the state, each point a cheap update)."""

from __future__ import annotations

import math

import numpy as np

from ._lstsq import fit_batch, residual, rss_with_columns
from ._regressors import columns_of


class Objective:
    """The searches' objective on ``problem`` for structures that extend ``base`` (a tuple of
    candidates). A point's own signals are dropped once it is scored: memory does not grow with
    a grid."""

    def __init__(self, problem, base: tuple = ()):
        self.problem, self.base = problem, tuple(base)
        self.rtr, self.rva = problem.regressors(self.base)
        self.model = problem.model(self.base)

    def __call__(self, cand) -> float:
        """The training RSS of ``base + (cand,)``: its new columns on the base's Gram where they
        are columns of their own signals, else the whole structure fitted."""
        structure = (*self.base, cand)
        rtr = self.problem.regressors(structure)[0]
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
        """Forget the training record's signals ``names`` (a point's, once scored)."""
        for regs in self.problem.train_regressors():
            regs.drop(names)
