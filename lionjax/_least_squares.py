"""Batch least squares on Lion's regressors (docs/method.md, "Batch least squares").

    θ_LS = argmin_θ Σₖ wₖ ‖Wₖθ + W₀ₖ + Nₖη‖²,

solved by :func:`linear_lstsq` — the package's one linear least-squares solve: the singular
value decomposition of the column-normalised regressor matrix, which gives the estimate, the
covariance, the condition number and the least excited direction from one factorisation (the
diagnosis uses the same function). This is the point Lion's law converges to on rich excitation.

Rows: each sample contributes the two equation errors ε₁ = V₃ + aV₂ − bQ₁ + … and ε₂ = dε₁/dt
(``rows=(0, 1)``, the paper's pair). ``rows=(0,)`` fits ε₁ alone: ε₂ weights the fit by
frequency, which on real data with unmodelled fast dynamics biases the viscous term (EMPS with a
40 Hz filter: F_v +86 % with both rows, +0.7 % with ε₁).

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

import dataclasses
import warnings

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._errors import RESULTS, DataWarning, InputError, result_codes
from ._estimators import default_bank, regressor_moments
from ._filters import FilterBank
from ._models import AbstractModel
from ._record import Record
from ._solution_tools import by_name, finish, is_traced, transient_mask
from ._validity import (
    check_duration,
    check_filter_speed,
    check_record,
    column_reference,
    dead_columns,
    explain_unexcited,
    unexcited,
    warn_poor_fit,
)


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
        unexcited: True for each parameter the record does not identify, ``(p,)`` (a column
            not excited, or a large share of a direction beyond ``max_condition``; see
            :mod:`lionjax._validity`).
        unexplained: RSS/‖y‖², the share of the filtered response (V₃, V₄ over the used
            samples) that the fitted model leaves unexplained; near 1 the model explains
            nothing (swapped columns, a force column that is not the applied force).
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
    unexcited: Bool[Array, " p"] | None = None
    unexplained: Float[Array, ""] | None = None

    def params(self) -> dict[str, Array]:
        return by_name(self.names, self.theta)


def _explain(sol: LSSolution) -> str:
    named = explain_unexcited(sol)
    if named:
        return named
    v = np.abs(np.asarray(sol.weakest))
    cond = np.asarray(sol.condition)
    if v.ndim > 1:
        return "Inspect solution.weakest per batch element to see which parameters are unexcited."
    names = [n for n, w in zip(sol.names, v, strict=True) if w > 0.3] or list(sol.names)
    return (
        f"Condition number {float(cond):.3g}. The least excited parameter direction involves "
        f"{', '.join(names)}."
    )


class LinearFit(eqx.Module):
    """The answer of :func:`linear_lstsq`: c = argmin ‖Φc + y‖² (note the sign: Φc ≈ −y).

    Attributes:
        coef: c, shape ``(q,)``.
        gram_inverse: (ΦᵀΦ)⁻¹ (pseudo-inverse on unexcited directions: ``inf`` there),
            shape ``(q, q)``.
        rss: ‖Φc + y‖²; condition: σ_max/σ_min of the column-normalised Φ (``inf`` when a
            column is flat); weakest: right singular vector of σ_min, in the normalised
            coordinates, shape ``(q,)``.
    """

    coef: Float[Array, " q"]
    gram_inverse: Float[Array, "q q"]
    rss: Float[Array, ""]
    condition: Float[Array, ""]
    weakest: Float[Array, " q"]


def linear_lstsq(Phi: Float[Array, "N q"], y: Float[Array, " N"]) -> LinearFit:
    """The package's one linear least-squares solve: min_c ‖Φc + y‖².

    Columns are normalised to unit length, Φₙ = UΣVᵀ (thin SVD), cₙ = −VΣ⁻¹Uᵀy, c = cₙ/‖Φ·ⱼ‖.
    Singular values below σ_max·N·ε (float ε) are treated as zero (the minimum-norm answer on
    that direction; the condition number then reports it). Jit- and vmap-safe. The streamed
    statistics (:class:`lionjax.LSStatistics`) solve through the same spectral step from ΦᵀΦ
    (:func:`gram_lstsq`).
    """
    norms = jnp.sqrt(jnp.sum(Phi * Phi, axis=0))
    tiny = jnp.finfo(Phi.dtype).tiny
    scale = jnp.where(norms > tiny, norms, 1.0)
    Phin = Phi / scale
    U, sv, Vt = jnp.linalg.svd(Phin, full_matrices=False)

    def rss(cn):
        res = Phin @ cn + y
        return jnp.sum(res * res)

    return _spectral_fit(Vt.T, sv, U.T @ y, scale, Phi.shape[0], rss)


def gram_lstsq(
    gram: Float[Array, "q q"], cross: Float[Array, " q"], yy: Float[Array, ""], n_rows
) -> LinearFit:
    """:func:`linear_lstsq` from the normal-equation statistics A = ΦᵀΦ, b = Φᵀy, yᵀy of
    ``n_rows`` rows (what a streamed pass keeps instead of Φ).

    The column-normalised Gram Aₙ = ΦₙᵀΦₙ = VΣ²Vᵀ, so its eigen-decomposition gives the same V and
    Σ as the thin SVD of Φₙ, and Uᵀy = Σ⁻¹Vᵀ(Φₙᵀy); the answer is then built by the same spectral
    step as :func:`linear_lstsq`. Negative eigenvalues (rounding on a flat record) count as zero
    singular values: condition ``inf``. RSS = cₙᵀAₙcₙ + 2cₙᵀbₙ + yᵀy (cancels: a few 1e-4
    relative on noise-free data), clipped at 0. Jit-safe; vmap it over a batch.
    """
    tiny = jnp.finfo(gram.dtype).tiny
    scale = jnp.sqrt(jnp.clip(jnp.diagonal(gram), tiny, None))
    An = gram / scale[:, None] / scale[None, :]
    bn = cross / scale
    ev, V = jnp.linalg.eigh(An)
    ev, V = ev[::-1], V[:, ::-1]  # descending, as the SVD's
    sv = jnp.sqrt(jnp.clip(ev, 0.0, None))
    Uty = jnp.where(sv > 0, (V.T @ bn) / jnp.where(sv > 0, sv, 1.0), 0.0)

    def rss(cn):
        return jnp.clip(cn @ An @ cn + 2 * cn @ bn + yy, 0.0, None)

    return _spectral_fit(V, sv, Uty, scale, n_rows, rss)


def _spectral_fit(V, sv, Uty, scale, n_rows, rss) -> LinearFit:
    """The one solve step, from Φₙ = UΣVᵀ: V (columns, σ descending), Σ, Uᵀy, the column
    norms, the row count (for the cut σ_max·N·ε) and the RSS of a normalised answer cₙ."""
    cut = sv[0] * n_rows * jnp.finfo(sv.dtype).eps
    keep = sv > cut
    inv = jnp.where(keep, 1.0 / jnp.where(keep, sv, 1.0), 0.0)
    cn = -(V * inv) @ Uty
    inv_sv2 = jnp.where(sv > 0, 1.0 / jnp.where(sv > 0, sv, 1.0) ** 2, jnp.inf)
    gram_inv_n = (V * inv_sv2) @ V.T
    condition = jnp.where(sv[-1] > 0, sv[0] / sv[-1], jnp.inf)
    return LinearFit(
        coef=cn / scale,
        gram_inverse=gram_inv_n / scale[:, None] / scale[None, :],
        rss=rss(cn),
        condition=condition,
        weakest=V[:, -1],
    )


def _check_rows(rows) -> tuple[int, ...]:
    rows = tuple(int(r) for r in rows)
    if not rows or len(set(rows)) != len(rows) or any(r not in (0, 1) for r in rows):
        raise InputError(
            f"least_squares: rows must name equation errors 0 (ε₁) and/or 1 (ε₂ = dε₁/dt) once "
            f"each, e.g. (0, 1) or (0,), got {rows!r}."
        )
    return rows


def least_squares(
    model: AbstractModel,
    record: Record,
    *,
    bank: FilterBank | None = None,
    initial: str = "estimate",
    transient: float | Array | None = None,
    rows: tuple[int, ...] = (0, 1),
    max_condition: float = 1e7,
    throw: bool = True,
) -> LSSolution:
    """Batch least squares θ_LS on the same regressors Lion's law uses.

    Arguments:
        model, record, bank: as for :func:`lionjax.lion` (same default filter).
        initial: ``"estimate"`` (default: fit the filters' initial-state error as n nuisance
            parameters, use every sample) or ``"discard"`` (skip ``transient`` seconds).
        transient: seconds skipped at the start with ``initial="discard"`` (default
            3·λₙ₋₁/λₙ); with ``"estimate"`` it defaults to 0.
        rows: which equation errors enter the fit: ``(0, 1)`` (default, ε₁ and ε₂ = dε₁/dt) or
            ``(0,)`` (ε₁ alone; see the module docstring).
        max_condition: condition number of the column-normalised regressors above which the
            record is declared not to excite the parameters (``RESULTS.unidentifiable``); a
            column that is not excited at all (:mod:`lionjax._validity`) is a failure too.
        throw: raise on failure (naming every unexcited parameter); ``False`` under ``vmap``.

    The validity layer (:mod:`lionjax._validity`) runs first: a filter too fast for the
    sampling warns or is refused, a record shorter than the transient or with non-finite or
    out-of-range samples is an :class:`InputError`.
    """
    if not isinstance(model, AbstractModel):
        raise InputError(f"least_squares: model must be a lionjax model, got {type(model)}.")
    if not isinstance(record, Record):
        raise InputError(f"least_squares: record must be a Record, got {type(record)}.")
    bank = default_bank(record.dt) if bank is None else bank
    if not isinstance(bank, FilterBank) or bank.batch_shape:
        raise InputError(
            "least_squares: bank must be one FilterBank (coeffs of shape (n,)), got "
            f"{type(bank).__name__}"
            + (f" with coeffs of shape {bank.coeffs.shape}" if isinstance(bank, FilterBank) else "")
            + "; use lionjax.least_squares_batched for one filter per record."
        )
    check_filter_speed(bank, record.dt, "least_squares")
    check_duration(record, bank, "least_squares")
    check_record(record, "least_squares")
    if initial not in ("estimate", "discard"):
        raise InputError(
            f"least_squares: initial must be 'estimate' or 'discard', got {initial!r}."
        )
    rows = _check_rows(rows)
    if initial == "estimate" and transient is None:
        transient = 0.0
    sol = _least_squares(model, record, bank, initial == "estimate", transient, rows, max_condition)
    sol = finish(sol, throw, what="least squares", explain=_explain)
    warn_poor_fit(sol.unexplained, "least_squares")
    args = (bank, initial == "estimate", transient, rows, max_condition)
    warn_intersample(model, record, sol, lambda m: _least_squares(m, record, *args))
    return sol


#: The force's power above NYQUIST_BAND·(f_s/2) over its whole power (mean removed) from which
#: :func:`warn_intersample` refits under the other hold of F: a quarter, where the excitation
#: itself reaches Nyquist (a force drawn anew every sample: 80 %). A closed loop's answer to its
#: encoder's steps puts 5–13 % there on the paper's twin records (its PD differentiates the
#: counts), with the held answer right to 0.1–1 %: the drive holds what the controller computes.
NYQUIST_BAND = 0.2
NYQUIST_SHARE = 0.25
#: Relative change of a parameter between the two holds of F from which it warns.
INTERSAMPLE_TOL = 0.02


def high_band_share(F) -> float:
    """The share of the power of ``F`` (mean removed) above :data:`NYQUIST_BAND` of the
    Nyquist frequency (a periodogram)."""
    f = np.asarray(F, np.float64)
    P = np.abs(np.fft.rfft(f - np.mean(f))) ** 2
    total = float(np.sum(P))
    if not total > 0:
        return 0.0
    return float(np.sum(P[int(np.ceil(NYQUIST_BAND * (P.size - 1))) :]) / total)


def warn_intersample(model, record: Record, sol: LSSolution, refit) -> None:
    """Warn (:class:`~lionjax.solutions.DataWarning`) where the estimate depends on how F moves
    between samples: where at least :data:`NYQUIST_SHARE` of the force's power lies above
    :data:`NYQUIST_BAND` of the Nyquist frequency, the record is refitted (``refit(model)``)
    with the other hold of F (``"zoh"`` ↔ ``"foh"``); a parameter that moves by more than
    :data:`INTERSAMPLE_TOL` (relative) and three standard deviations is named, with both
    values: the difference is the measured bound of the intersample assumption's bias.

    The filters are exact for the assumed hold; what the device did between samples, the
    samples cannot tell. A force held by the drive (its default, ``F_hold="zoh"``) is then
    identified without bias (a noise-free 1 Hz record of a = 0.2 1/s, b = 0.02 1/kg under a
    force changing every sample: a = 0.19999); the same samples of a force that moved linearly
    between them (a = 0.2218, 11 % high under the held assumption) need ``F_hold="foh"``.
    Host side, for models with an ``F_hold`` (``MassDamper``, ``Piecewise``)."""
    hold = getattr(model, "F_hold", None)
    if hold is None or is_traced((record.F, sol.theta)) or np.ndim(sol.theta) != 1:
        return
    share = high_band_share(record.F)
    if share < NYQUIST_SHARE or result_codes(sol.result) != 0:
        return
    other = "foh" if hold == "zoh" else "zoh"
    alt = refit(dataclasses.replace(model, F_hold=other))
    th, th2 = np.asarray(sol.theta, np.float64), np.asarray(alt.theta, np.float64)
    std = np.asarray(sol.std, np.float64)
    rel = np.abs(th2 - th) / np.maximum(np.abs(th), np.finfo(np.float64).tiny)
    moved = (rel > INTERSAMPLE_TOL) & (np.abs(th2 - th) > 3 * std)
    if not np.any(moved):
        return
    named = ", ".join(
        f"{n} = {a:.6g} ({hold}) or {b:.6g} ({other}), {r:.1%} apart"
        for n, a, b, r, m in zip(sol.names, th, th2, rel, moved, strict=True)
        if m
    )
    warnings.warn(
        f"least_squares: {share:.0%} of the force's power lies above {NYQUIST_BAND:g} of the "
        f"Nyquist frequency, where the estimate depends on how F moved between samples: "
        f"{named}. The bias of the assumed hold ({hold!r}: F "
        f"{'held' if hold == 'zoh' else 'linear'} between samples) is up to that difference. "
        f"Sample faster or excite below f_s/10; or, if the drive "
        f"{'interpolates' if hold == 'zoh' else 'holds'} F, pass F_hold={other!r} to the model "
        "(--F-hold on the command line).",
        DataWarning,
        stacklevel=3,
    )


def check_identified(model, record: Record, bank: FilterBank, transient, what: str) -> None:
    """Refuse (:class:`~lionjax.IdentificationError`, prefixed with ``what``) a record whose
    samples after the transient do not identify ``model`` — the data a streamed estimator uses
    (``least_squares(initial="discard")``, Lion's law after its transient, a study's a_LS) —
    and warn (:class:`~lionjax.solutions.DataWarning`) where the fit explains next to nothing
    (:func:`lionjax._validity.warn_poor_fit`). For callers that batch records and check each
    one on the host first (:func:`lionjax.study`)."""
    with warnings.catch_warnings():  # the caller has already warned about the record itself
        warnings.simplefilter("ignore", DataWarning)
        sol = least_squares(
            model, record, bank=bank, initial="discard", transient=transient, throw=False
        )
    finish(sol, True, what=what, explain=_explain)
    warn_poor_fit(sol.unexplained, what)


def nuisance_columns(bank: FilterBank, dt, T: int, rows: tuple[int, ...]) -> Array:
    """The n free responses of the filter (initial-state error), shape ``(T, len(rows), n)``."""
    N = bank.free_response(dt, T)[:, :, :2]  # (T, n, 2): V₁, V₂ of each unit initial state
    return jnp.swapaxes(N, 1, 2)[:, jnp.asarray(rows), :]


@eqx.filter_jit
def _least_squares(model, record, bank, nuisance, transient, rows, max_condition) -> LSSolution:
    regs = model.regressors(record, bank)
    T, _, p = regs.W.shape
    W = regs.W[:, rows, :]
    if nuisance:
        W = jnp.concatenate([W, nuisance_columns(bank, record.dt, T, rows).astype(W.dtype)], -1)
    q = W.shape[-1]
    r = len(rows)
    w = transient_mask(record, bank, transient)
    Phi = (W * w[:, None, None]).reshape(r * T, q)
    y = (regs.W0[:, rows] * w[:, None]).reshape(r * T)
    fit = linear_lstsq(Phi, y)
    # the validity layer: every column excited (R over the weighted samples, all rows of W),
    # and which parameters an ill-conditioned fit leaves unidentified (R's scale: cond(Φ)²)
    R = regressor_moments(regs, w)
    ref = column_reference(model, record, bank).astype(W.dtype)
    bad = unexcited(R, ref, max_condition**2)
    ok = (fit.condition < max_condition) & ~jnp.any(dead_columns(R, ref))
    if not nuisance:
        # after the transient the filter's free response (its initial-state error) is still in
        # the signals: a parameter excited only through it is not identified by the record
        # (a step response whose own transient ended before the filter's: only b/a remains)
        N = nuisance_columns(bank, record.dt, T, rows).astype(W.dtype) * w[:, None, None]
        aug = linear_lstsq(jnp.concatenate([Phi, N.reshape(r * T, -1)], -1), y)
        aug_ok = aug.condition < max_condition
        ok = ok & aug_ok
        bad = bad | (~aug_ok & (jnp.abs(aug.weakest[:p]) > 0.3))
    theta = fit.coef[:p]
    n_used = jnp.sum(w)
    sigma2 = fit.rss / jnp.maximum(r * n_used - q, 1.0)
    cov = sigma2 * fit.gram_inverse[:p, :p]
    result = RESULTS.where(ok, RESULTS.successful, RESULTS.unidentifiable)
    finite = jnp.all(jnp.isfinite(theta))
    result = RESULTS.where(finite | ~ok, result, RESULTS.nonfinite)
    return LSSolution(
        theta=theta,
        covariance=cov,
        std=jnp.sqrt(jnp.diagonal(cov)),
        sigma2=sigma2,
        condition=fit.condition,
        weakest=fit.weakest[:p],
        rms=jnp.sqrt(fit.rss / jnp.maximum(r * n_used, 1.0)),
        n_used=n_used,
        names=regs.names,
        result=result,
        unexcited=bad,
        unexplained=fit.rss / jnp.maximum(jnp.sum(y * y), jnp.finfo(y.dtype).tiny),
    )


def equation_error(
    model: AbstractModel,
    record: Record,
    theta: Float[Array, " p"],
    *,
    bank: FilterBank | None = None,
    rows: tuple[int, ...] = (0,),
) -> Float[Array, "T r"]:
    """The equation errors ε = Wθ + W₀ + Nη of ``record`` for a fixed θ (validation data).

    Only the filter's initial-state nuisance coefficients η are fitted on this record (by
    :func:`linear_lstsq`), since the record's initial filter state is unknown. Shape
    ``(T, len(rows))``.
    """
    bank = default_bank() if bank is None else bank
    return _equation_error(model, record, jnp.asarray(theta), bank, _check_rows(rows))


@eqx.filter_jit
def _equation_error(model, record, theta, bank, rows):
    regs = model.regressors(record, bank)
    T = regs.W.shape[0]
    r0 = jnp.einsum("trp,p->tr", regs.W[:, rows, :], theta) + regs.W0[:, rows]
    N = nuisance_columns(bank, record.dt, T, rows)
    fit = linear_lstsq(N.reshape(T * len(rows), -1), r0.reshape(-1))
    return r0 + jnp.einsum("trn,n->tr", N, fit.coef)
