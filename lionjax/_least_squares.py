"""Batch least squares on Lion's regressors (docs/method.md, "Batch least squares").

    θ_LS = argmin_θ Σₖ wₖ ‖Wₖθ + W₀ₖ + Nₖη‖²,

solved with ``optimistix.least_squares`` (Gauss–Newton with a QR linear solve, on
column-normalised regressors). This is the point Lion's law converges to on rich excitation.

Initial conditions: the filters start from an assumed state (the signal held at its first
sample), which is wrong whenever the device was not at rest under that force. Any such error
adds to ε a combination of the n free responses of the filter (``FilterBank.free_response``),
so by default (``initial="estimate"``) n nuisance columns N with coefficients η are fitted
alongside θ and no data need be discarded (wₖ = 1). With ``initial="discard"`` the nuisance
columns are dropped and the first ``transient`` seconds get wₖ = 0 instead.

Reported with it: the nominal covariance σ²(ΦᵀΦ)⁻¹ (σ² = RSS/(N − p); the rows are filtered
and therefore correlated, so treat it as a lower bound), the condition number of the
column-normalised regressor matrix, and — instead of a garbage answer — an identifiability
failure naming the parameters the record does not excite (condition number above
``max_condition``).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float

from ._errors import RESULTS, InputError
from ._estimators import default_bank
from ._filters import FilterBank
from ._models import AbstractModel
from ._record import Record
from ._solution import check_duration, finish, transient_mask


class LSSolution(eqx.Module):
    """Batch least-squares answer.

    Attributes:
        theta: estimate, shape ``(p,)``.
        covariance: σ²(ΦᵀΦ)⁻¹, shape ``(p, p)``; std: its diagonal's square root, ``(p,)``.
        sigma2: residual variance RSS/(N − p) of the equation error.
        condition: condition number of the column-normalised regressor matrix Φ (2N × p).
        weakest: the right singular vector of the smallest singular value of the normalised Φ,
            shape ``(p,)`` — the least excited parameter combination.
        rms: root-mean-square equation error over the used samples.
        n_used: number of samples used (after the transient).
        names: parameter names; result: :class:`RESULTS` code.
    """

    theta: Float[Array, " p"]
    covariance: Float[Array, "p p"]
    std: Float[Array, " p"]
    sigma2: Float[Array, ""]
    condition: Float[Array, ""]
    weakest: Float[Array, " p"]
    rms: Float[Array, ""]
    n_used: Float[Array, ""]
    names: tuple[str, ...] = eqx.field(static=True)
    result: RESULTS

    def params(self) -> dict[str, Array]:
        return {n: self.theta[..., i] for i, n in enumerate(self.names)}


def _explain(sol: LSSolution) -> str:
    v = np.abs(np.asarray(sol.weakest))
    cond = np.asarray(sol.condition)
    if v.ndim > 1:
        return "Inspect solution.weakest per batch element to see which parameters are unexcited."
    names = [n for n, w in zip(sol.names, v, strict=True) if w > 0.3] or list(sol.names)
    return (
        f"Condition number {float(cond):.3g}. The least excited parameter direction involves "
        f"{', '.join(names)}."
    )


def least_squares(
    model: AbstractModel,
    record: Record,
    *,
    bank: FilterBank | None = None,
    initial: str = "estimate",
    transient: float | Array | None = None,
    max_condition: float = 1e7,
    rtol: float = 1e-10,
    atol: float = 1e-12,
    throw: bool = True,
) -> LSSolution:
    """Batch least squares θ_LS on the same regressors Lion's law uses.

    Arguments:
        model, record, bank: as for :func:`lionjax.lion` (same default filter).
        initial: ``"estimate"`` (default: fit the filters' initial-state error as n nuisance
            parameters, use every sample) or ``"discard"`` (skip ``transient`` seconds).
        transient: seconds skipped at the start with ``initial="discard"`` (default
            3·λₙ₋₁/λₙ); with ``"estimate"`` it defaults to 0.
        max_condition: condition number of the column-normalised regressors above which the
            record is declared not to excite the parameters (``RESULTS.unidentifiable``).
        rtol, atol: optimistix tolerances.
        throw: raise on failure (naming the unexcited parameters); ``False`` under ``vmap``.
    """
    bank = default_bank() if bank is None else bank
    if not isinstance(model, AbstractModel):
        raise InputError(f"least_squares: model must be a lionjax model, got {type(model)}.")
    if not isinstance(record, Record):
        raise InputError(f"least_squares: record must be a Record, got {type(record)}.")
    check_duration(record, bank, "least_squares")
    if initial not in ("estimate", "discard"):
        raise InputError(
            f"least_squares: initial must be 'estimate' or 'discard', got {initial!r}."
        )
    if initial == "estimate" and transient is None:
        transient = 0.0
    sol = _least_squares(
        model, record, bank, initial == "estimate", transient, max_condition, rtol, atol
    )
    return finish(sol, throw, what="least squares", explain=_explain)


@eqx.filter_jit
def _least_squares(
    model, record, bank, nuisance, transient, max_condition, rtol, atol
) -> LSSolution:
    regs = model.regressors(record, bank)
    T, _, p = regs.W.shape
    W = regs.W
    if nuisance:
        N = bank.free_response(record.dt, T)[:, :, :2]  # (T, n, 2)
        W = jnp.concatenate([W, jnp.swapaxes(N, 1, 2).astype(W.dtype)], axis=-1)
    q = W.shape[-1]
    w = transient_mask(record, bank, transient)
    Phi = (W * w[:, None, None]).reshape(2 * T, q)
    y = (regs.W0 * w[:, None]).reshape(2 * T)
    norms = jnp.sqrt(jnp.sum(Phi * Phi, axis=0))
    tiny = jnp.finfo(Phi.dtype).tiny
    scale = jnp.where(norms > tiny, norms, 1.0)
    Phin = Phi / scale
    sv, Vt = jnp.linalg.svd(Phin, full_matrices=False)[1:]
    condition = jnp.where(sv[-1] > 0, sv[0] / sv[-1], jnp.inf)
    ok = condition < max_condition

    def residual(phi, args):
        return Phin @ phi + y

    solver = optx.GaussNewton(rtol=rtol, atol=atol, linear_solver=lx.QR())
    out = optx.least_squares(
        residual, solver, jnp.zeros((q,), Phi.dtype), max_steps=16, throw=False
    )
    theta = (out.value / scale)[:p]
    res = Phin @ out.value + y
    n_used = jnp.sum(w)
    rss = jnp.sum(res * res)
    sigma2 = rss / jnp.maximum(2 * n_used - q, 1.0)
    inv_sv2 = jnp.where(sv > 0, 1.0 / jnp.where(sv > 0, sv, 1.0) ** 2, jnp.inf)
    cov_n = (Vt.T * inv_sv2) @ Vt
    cov = (sigma2 * cov_n / scale[:, None] / scale[None, :])[:p, :p]
    result = RESULTS.where(ok, RESULTS.successful, RESULTS.unidentifiable)
    finite = jnp.all(jnp.isfinite(theta))
    result = RESULTS.where(finite | ~ok, result, RESULTS.nonfinite)
    return LSSolution(
        theta=theta,
        covariance=cov,
        std=jnp.sqrt(jnp.diagonal(cov)),
        sigma2=sigma2,
        condition=condition,
        weakest=Vt[-1, :p],
        rms=jnp.sqrt(rss / jnp.maximum(2 * n_used, 1.0)),
        n_used=n_used,
        names=regs.names,
        result=result,
    )
