"""The state-variable filter bank Λ(s) and its exact discretisation.

Lion's method never differentiates measured data. It passes every signal u through

    Vⱼ = s^(j−1)/Λ(s) · u,   j = 1 … 4,   Λ(s) = sⁿ + λ₁sⁿ⁻¹ + … + λₙ   (n ≥ 3, Hurwitz),

so that the equation of motion ẍ + aẋ = bF becomes the algebraic relation V₃ + aV₂ − bQ₁ = 0
between filtered signals (docs/method.md, "Equation errors"). The paper uses n = 3,
λ = (12, 48, 64) = (s + 4)³.

Data are samples, the method is continuous-time. Each signal is filtered *exactly* at the sample
instants under an intersample assumption chosen per signal
(docs/method.md, "Discretisation"):

- ``"zoh"``: the signal is held between samples (a force commanded by a 1 kHz device loop);
- ``"foh"``: the signal is linear between samples (a smooth measured position).

With state z = (y, ẏ, …, y⁽ⁿ⁻¹⁾), y = u/Λ (controllable canonical form), ż = Az + Bu and over one
sample interval h

    z[k+1] = Φ z[k] + Γ₀ u[k] + Γ₁ (u[k+1] − u[k])      (Γ₁ = 0 for "zoh"),

with Φ = e^{Ah}, Γ₀ = ∫₀ʰ e^{Aσ}dσ B, Γ₁ = (1/h)∫₀ʰ e^{Aσ}(h − σ)dσ B, read off one matrix
exponential of an (n + 2)-square block matrix (the same construction as
``scipy.signal.cont2discrete(..., method="foh")``).
"""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._errors import InputError
from ._linalg import expm

Hold = Literal["zoh", "foh"]
HOLDS = ("zoh", "foh")


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def check_hold(hold: str, argument: str = "hold") -> str:
    if hold not in HOLDS:
        raise InputError(
            f"{argument} must be 'zoh' (held between samples) or 'foh' (linear between "
            f"samples), got {hold!r}."
        )
    return hold


class FilterBank(eqx.Module):
    """The filter Λ(s) = sⁿ + λ₁sⁿ⁻¹ + … + λₙ and the bank of outputs s^(j−1)/Λ, j = 1…4.

    Attributes:
        coeffs: (λ₁, …, λₙ), shape ``(n,)``, n ≥ 3; Λ must be Hurwitz (checked when concrete).
            A batch of filters — one per record for :func:`lionjax.lion_batched`, e.g. a grid of
            pole sets (:func:`lionjax.studies.stack_banks`) — has ``coeffs`` of shape ``(B, n)``.
        unit_dc_gain: if True every output is multiplied by λₙ, i.e. the bank is λₙ·s^(j−1)/Λ
            and V₁ → u at DC. This only rescales the equation errors (LS is unchanged), but it
            keeps regressors O(signal) whatever the poles, which is what a gain G should see.

    Build from poles with :meth:`from_poles` (differentiable in the poles), or the paper's
    filter with :meth:`paper`.
    """

    coeffs: Float[Array, "*B n"]
    unit_dc_gain: bool = eqx.field(static=True, default=False)

    def __init__(self, coeffs: ArrayLike, unit_dc_gain: bool = False):
        self.coeffs = jnp.asarray(coeffs, dtype=jnp.result_type(float))
        self.unit_dc_gain = bool(unit_dc_gain)

    def __check_init__(self):
        if self.coeffs.ndim not in (1, 2) or self.coeffs.shape[-1] < 3:
            raise InputError(
                "FilterBank: coeffs must be (λ₁, …, λₙ) with n ≥ 3 (a second-order model needs "
                "a filter of relative degree ≥ 3), shape (n,) or (B, n) for one filter per "
                f"record, got shape {self.coeffs.shape}."
            )
        if _is_concrete(self.coeffs):
            for c in np.asarray(self.coeffs, dtype=np.float64).reshape(-1, self.order):
                if not np.all(np.isfinite(c)):
                    raise InputError(f"FilterBank: coeffs must be finite, got {c.tolist()}.")
                roots = np.roots(np.concatenate([[1.0], c]))
                if np.any(roots.real >= 0):
                    raise InputError(
                        "FilterBank: Λ(s) must be Hurwitz (all roots in the open left "
                        f"half-plane), but coeffs {c.tolist()} have roots "
                        f"{np.round(roots, 6).tolist()}. Choose poles with negative real parts, "
                        "e.g. FilterBank.from_poles([-4, -4, -4])."
                    )

    @classmethod
    def from_poles(cls, poles: ArrayLike, unit_dc_gain: bool = False) -> FilterBank:
        """Λ(s) = Π (s − pᵢ) from its poles [rad/s] (real, or complex in conjugate pairs)."""
        p = jnp.asarray(poles)
        if p.ndim != 1 or p.shape[0] < 3:
            raise InputError(
                f"FilterBank.from_poles: need at least 3 poles in a 1-D array, got shape {p.shape}."
            )
        if _is_concrete(p):
            pn = np.asarray(p)
            if np.any(np.real(pn) >= 0):
                raise InputError(
                    f"FilterBank.from_poles: every pole must have a negative real part, got "
                    f"{pn.tolist()}. Λ must be Hurwitz for the filtered signals to be bounded."
                )
            if np.iscomplexobj(pn):
                srt = lambda v: np.sort_complex(v)
                if not np.allclose(srt(pn), srt(np.conj(pn)), rtol=1e-10, atol=1e-12):
                    raise InputError(
                        "FilterBank.from_poles: complex poles must come in conjugate pairs, got "
                        f"{pn.tolist()}."
                    )
        coeffs = jnp.real(jnp.poly(p))[1:]
        return cls(coeffs, unit_dc_gain=unit_dc_gain)

    @classmethod
    def paper(cls) -> FilterBank:
        """The paper's filter Λ = s³ + 12s² + 48s + 64 = (s + 4)³, without DC normalisation."""
        return cls(jnp.array([12.0, 48.0, 64.0]), unit_dc_gain=False)

    @property
    def order(self) -> int:
        """n, the degree of Λ (the last axis of ``coeffs``, also for a batch of banks)."""
        return self.coeffs.shape[-1]

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """``()`` for one filter, ``(B,)`` for one filter per record (``coeffs`` ``(B, n)``)."""
        return tuple(self.coeffs.shape[:-1])

    @property
    def poles(self) -> Array:
        """The roots of Λ (complex) [rad/s]."""
        return jnp.roots(jnp.concatenate([jnp.ones((1,), self.coeffs.dtype), self.coeffs]))

    def state_space(self) -> tuple[Array, Array, Array, Array]:
        """(A, B, C, D) of the bank: ż = Az + Bu, (V₁…V₄) = Cz + Du; C is 4×n."""
        n = self.order
        dtype = self.coeffs.dtype
        A = jnp.zeros((n, n), dtype).at[jnp.arange(n - 1), jnp.arange(1, n)].set(1.0)
        A = A.at[n - 1].set(-self.coeffs[::-1])
        B = jnp.zeros((n,), dtype).at[n - 1].set(1.0)
        # s^j/Λ u = z_j for j < n; sⁿ/Λ u = u − Σ λ z (only needed when n = 3).
        rows = [jnp.zeros((n,), dtype).at[j].set(1.0) for j in range(min(n, 4))]
        D = jnp.zeros((4,), dtype)
        if n == 3:
            rows.append(-self.coeffs[::-1])
            D = D.at[3].set(1.0)
        C = jnp.stack(rows)
        if self.unit_dc_gain:
            C = C * self.coeffs[-1]
            D = D * self.coeffs[-1]
        return A, B, C, D

    def discretise(self, dt: ArrayLike) -> tuple[Array, Array, Array]:
        """(Φ, Γ₀, Γ₁) of the exact sampled filter over one interval ``dt`` [s] (see module doc).

        For a zero-order-hold signal use Φ and Γ₀ only; for a first-order hold add Γ₁.

        The companion matrix is badly scaled for fast poles (its last row holds λₙ ~ ω₀ⁿ), and
        the exponential of the raw block matrix overflows to NaN once ω₀ is a few hundred rad/s
        (a 2 kHz record with a 80 Hz filter). So the exponential is taken of the balanced
        matrix Â = S⁻¹AS, S = diag(1, ω₀, …, ω₀ⁿ⁻¹), ω₀ = λₙ^(1/n) (every entry of Âh is
        O(ω₀h)), with the input scaled by ω₀ⁿ⁻¹, and mapped back: Φ = SΦ̂S⁻¹, Γ = SΓ̂/ω₀ⁿ⁻¹.
        """
        A, B, _, _ = self.state_space()
        n = self.order
        h = jnp.asarray(dt, A.dtype)
        w0 = jnp.abs(self.coeffs[-1]) ** (1.0 / n)
        s = w0 ** jnp.arange(n, dtype=A.dtype)  # S = diag(s)
        A_bal = A * s[None, :] / s[:, None]
        B_bal = B / s * s[-1]  # S⁻¹B·ω₀ⁿ⁻¹ = e_n
        Phi, G0, G1 = sample_hold(A_bal * h, B_bal * h)
        Phi = Phi * s[:, None] / s[None, :]
        return Phi, G0 * s / s[-1], G1 * s / s[-1]

    def steady_state(self, u0: ArrayLike) -> Array:
        """Filter state of a signal held at ``u0`` forever before the record starts."""
        n = self.order
        u0 = jnp.asarray(u0, self.coeffs.dtype)
        return (
            jnp.zeros(jnp.shape(u0) + (n,), self.coeffs.dtype).at[..., 0].set(u0 / self.coeffs[-1])
        )

    def free_response(self, dt: ArrayLike, n_samples: int) -> Float[Array, "T n 4"]:
        """Outputs (V₁…V₄)[k] of the unforced filter started from each unit state eᵢ.

        Any error in a filter's initial state adds to the equation error a combination of
        these (their V₁, V₂ columns), which is how least squares absorbs unknown initial
        conditions exactly instead of discarding a transient.
        """
        Phi, _, _ = self.discretise(dt)
        _, _, C, _ = self.state_space()
        return jnp.einsum("jn,tni->tij", C, powers(Phi, n_samples))

    def __call__(
        self,
        u: Float[Array, " T"],
        dt: ArrayLike,
        hold: Hold = "zoh",
        init: Literal["steady", "zero"] = "steady",
    ) -> Float[Array, "T 4"]:
        """Filter one sampled signal: returns (V₁ … V₄)[k] = s^(j−1)/Λ · u at every sample.

        Arguments:
            u: samples, shape ``(T,)`` (any unit; outputs carry unit·s^(j−1−n), or the unit
                of u times s^(j−1) with ``unit_dc_gain``).
            dt: sampling interval [s].
            hold: intersample assumption, ``"zoh"`` or ``"foh"``.
            init: ``"steady"`` (default): the signal sat at u[0] before the record, so a device
                resting at its first sample produces no filter transient; ``"zero"``: zero state.
        """
        check_hold(hold)
        u = jnp.asarray(u, self.coeffs.dtype)
        Phi, G0, G1 = self.discretise(dt)
        _, _, C, D = self.state_space()
        z0 = self.steady_state(u[0]) if init == "steady" else jnp.zeros((self.order,), u.dtype)
        u_next = jnp.concatenate([u[1:], u[-1:]])
        du = (u_next - u) if hold == "foh" else jnp.zeros_like(u)

        def step(z, inputs):
            uk, duk = inputs
            return Phi @ z + G0 * uk + G1 * duk, z

        _, zs = jax.lax.scan(step, z0, (u, du))
        return zs @ C.T + u[:, None] * D


def sample_hold(
    Ah: Float[Array, "n n"], Bh: Float[Array, " n"]
) -> tuple[Float[Array, "n n"], Float[Array, " n"], Float[Array, " n"]]:
    """(Φ, Γ₀, Γ₁) of ż = Az + Bu sampled exactly over one interval h, given Ah and Bh: with
    u(t) = u_k + Δu_k·(t − t_k)/h on [t_k, t_k + h] (a first-order hold; Δu_k = 0 for a
    zero-order hold), z_{k+1} = Φz_k + Γ₀u_k + Γ₁Δu_k. One block exponential of
    [[Ah, Bh, 0], [0, 0, 1], [0, 0, 0]], whose first rows are (Φ, Γ₀, Γ₁) (Van Loan). Scale A
    and B first where their entries differ by orders of magnitude
    (:meth:`FilterBank.discretise`)."""
    n = Ah.shape[-1]
    M = jnp.zeros((n + 2, n + 2), Ah.dtype)
    M = M.at[:n, :n].set(Ah).at[:n, n].set(Bh).at[n, n + 1].set(1.0)
    E = expm(M)  # elementwise products: exact float32 on a GPU, see lionjax._linalg
    return E[:n, :n], E[:n, n], E[:n, n + 1]


def powers(Phi: Float[Array, "n n"], n_samples: int) -> Float[Array, "T n n"]:
    """Φᵏ for k = 0 … T − 1: the states of the unforced recurrence z[k+1] = Φz[k] started from
    each unit state eᵢ (column i of Φᵏ), by a scan of T matrix products."""

    def step(Z, _):
        return Phi @ Z, Z

    _, Zs = jax.lax.scan(step, jnp.eye(Phi.shape[-1], dtype=Phi.dtype), None, length=n_samples)
    return Zs
