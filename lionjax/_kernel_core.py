"""The per-sample work of the batched kernel, shared by the fused XLA loop
(:func:`lionjax._batched.kernel._kernel`) and the Pallas kernel (:mod:`lionjax._pallas`).

Layer 1 (core). :class:`_Core` holds one step k → k+1 of every record's filter states, θ (Lion's
exact or Euler step) and the output accumulators of :mod:`lionjax._outputs`, written on flat
``(rows,)`` arrays so the same code runs inside an XLA loop and inside a Pallas program. Its
inputs are described by :class:`_Plan` (static: signals, columns, pass) and two
:class:`_Inputs` (values shared by the batch, values per record), and a run returns an
:class:`_Out`. :func:`_maps` and :func:`_midpoint_basis` precompute the filter's linear maps.

Both kernels import this module; neither imports the other's module back (the batched entry
points in :mod:`lionjax._batched` choose a kernel, :mod:`lionjax._pallas` only needs the core).
"""

from __future__ import annotations

import contextlib

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from ._estimators import AbstractSampleStepper
from ._filters import FilterBank
from ._linalg import matmul
from ._outputs import Accumulated, Sample
from ._phi import materialise, real_guard


class _Plan(eqx.Module):
    """Static description of one kernel run: which signals and columns, which pass."""

    signals: tuple[tuple[str, str], ...] = eqx.field(static=True)  # (name, hold)
    columns: tuple[tuple[int, int, float], ...] = eqx.field(static=True)  # (sig, order, sign)
    x_index: int = eqx.field(static=True)
    n: int = eqx.field(static=True)
    masked: bool = eqx.field(static=True)
    block: int = eqx.field(static=True)  # samples per slab
    estimate: bool = eqx.field(static=True, default=False)  # False: the statistics pass
    midpoint: bool = eqx.field(static=True, default=True)  # the stepper's regressors
    save_blocks: int = eqx.field(static=True, default=0)  # 0: no snapshots; else slabs between
    series_terms: int = eqx.field(static=True, default=0)  # 0: closed-form E (phi_sym2)
    # carry the midpoint basis w = λₙ(I + Φ)z/2 instead of z (:func:`_midpoint_basis`)
    aligned: bool = eqx.field(static=True, default=False)


class _Maps(eqx.Module):
    """The linear maps of one signal's filter (:func:`_maps`); (rows, n + 2) each, a trailing
    batch axis when one filter per record."""

    next: Array
    start: Array
    mid: Array
    end: Array


_MODES = ("next", "start", "mid", "end")


class _Filter(eqx.Module):
    """One filter per record, compactly (batch axis last): Φ (n, n), Γ₀, Γ₁ (n,), the
    coefficients of zᵢ in V_{n+1} (λ reversed, (n,)) and the unit-DC-gain scale λₙ (or None).
    The same for every signal (the holds are static); the outputs at the start, midpoint and
    end of a step come from the states z_k and z_{k+1} (:func:`_maps` composes them per
    signal instead: free as scalars, but as per-record arrays they are 5× the values read per
    sample)."""

    Phi: Array
    G0: Array
    G1: Array
    lam_rev: Array
    scale: Array | None


def _filter(bank: FilterBank, dt: Array) -> _Filter:
    """:class:`_Filter` of one filter and interval (vmapped over records by the stream)."""
    Phi, G0, G1 = bank.discretise(dt)
    lam = bank.coeffs.astype(Phi.dtype)
    return _Filter(Phi, G0, G1, lam[::-1], lam[-1] if bank.unit_dc_gain else None)


class _Inputs(eqx.Module):
    """Kernel inputs. Each field is given once: in the ``shared`` instance (values common to the
    batch, scalars in the kernel) or in the ``per`` instance (one per record, batch axis last
    inside the kernel); the other holds None."""

    maps: tuple[_Maps, ...] | _Filter | None = None  # one per signal, or one per record
    h: Array | None = None  # sampling interval [s]
    G: Array | None = None  # gain (p, p)
    length: Array | None = None  # valid samples per record
    z0: Array | None = None  # initial filter states (S, n)
    theta0: Array | None = None  # (p,)
    outputs: tuple | None = None  # per: prepared inputs; shared: the accumulators
    stepper: AbstractSampleStepper | None = None
    one: Array | None = None  # a runtime 1 (see materialise)


class _State(eqx.Module):
    """The kernel's carry from sample to sample (all (Bs,) arrays)."""

    z: list  # S lists of n filter states
    theta: list | None  # θ as complex pairs (θ₀ + iθ₁, …)
    valid: Array | None  # the stepper's per-step validity (steppers that report it)
    outputs: tuple[Accumulated, ...]


class _Out(eqx.Module):
    """What one kernel run returns (batch axis last inside, first outside)."""

    theta: Array | None  # (p, Bs)
    J: Array | None
    valid: Array | None
    outputs: tuple[Accumulated, ...]
    snapshots: Array | None  # (K, p, Bs)


def _maps(bank: FilterBank, dt: Array, foh: bool) -> _Maps:
    """Linear maps from (z_k, u_k, u_{k+1}) — columns ``n + 2`` — to the filter's next state and
    outputs, for one signal under its hold (exact discretisation, :meth:`FilterBank.discretise`).

    - ``next`` (n, n+2): z_{k+1} = Φ z_k + Γ₀ u_k + Γ₁ (u_{k+1} − u_k) (Γ₁ only under foh);
    - ``start``, ``mid``, ``end`` (n+1, n+2): the outputs V₁…V_{n+1} (Vⱼ = sʲ⁻¹/Λ u,
      V_{n+1} = u − Σ λ z; times λₙ under unit DC gain) at sample k, at the midpoint (state and
      input averaged over the interval: :class:`lionjax.ExactStep`'s regressors) and at k+1.

    Precomputing them keeps the per-sample work of the kernel to one dot product per output
    (the θ step never recomputes the filter update).
    """
    f = _filter(bank, dt)  # Φ, Γ₀, Γ₁, λ reversed and the scale, as the per-record form
    n = bank.order
    dtype = f.Phi.dtype
    G1 = f.G1 if foh else jnp.zeros_like(f.G1)
    z = jnp.zeros((n, 1), dtype)
    start = jnp.concatenate([jnp.eye(n, dtype=dtype), z, z], -1)
    nxt = jnp.concatenate([f.Phi, (f.G0 - G1)[:, None], G1[:, None]], -1)

    def outputs(state, u_row):
        V = jnp.concatenate([state, (u_row - jnp.sum(f.lam_rev[:, None] * state, 0))[None]], 0)
        return V if f.scale is None else V * f.scale

    unit = lambda a, b: jnp.concatenate([jnp.zeros((n,), dtype), jnp.array([a, b], dtype)])
    return _Maps(
        next=nxt,
        start=outputs(start, unit(1.0, 0.0)),
        mid=outputs(0.5 * (start + nxt), unit(0.5, 0.5)),
        end=outputs(nxt, unit(0.0, 1.0)),
    )


def _midpoint_basis(maps: _Maps, lam_rev: Array) -> tuple[_Maps, Array]:
    """``maps`` (:func:`_maps`, the filter's own states z) in the midpoint basis w = A z, and A.

    A = λₙ(I + Φ)/2 (λₙ → 1 without unit DC gain) is the z-part of the midpoint outputs
    V₁…V_n (``lam_rev``: the filter's λ reversed). A commutes with Φ, so
    w_{k+1} = Φ w_k + AΓ(…) (the same Φ, no rounding from a similarity transform), and the
    midpoint outputs are V_j = w_{j−1} + (input terms) and V_{n+1} = −Σ λ w + (input terms),
    with exact coefficients (1 and the λ's): the θ step reads each of V₁…V_n with two products
    at most instead of n + 2. The outputs at the start and end of a step read w through A⁻¹
    (dense).
    """
    n = maps.next.shape[0]
    A = maps.mid[:n, :n]  # λₙ(I + Φ)/2
    Ainv = jnp.linalg.inv(A)
    in_w = lambda M: jnp.concatenate([matmul(M[:, :n], Ainv), M[:, n:]], -1)
    mid_z = jnp.concatenate([jnp.eye(n, dtype=A.dtype), -lam_rev[None]], 0)
    return (
        _Maps(
            next=jnp.concatenate([maps.next[:, :n], matmul(A, maps.next[:, n:])], -1),
            start=in_w(maps.start),
            mid=jnp.concatenate([mid_z, maps.mid[:, n:]], -1),
            end=in_w(maps.end),
        ),
        A,
    )


def _structural(mode: str, foh: bool, n: int, row: int, col: int, aligned: bool = False) -> bool:
    """Whether entry (row, col) of a :func:`_maps` matrix can be non-zero (static sparsity);
    ``aligned``: the maps of the midpoint basis (:func:`_midpoint_basis`)."""
    if aligned and mode == "mid" and row < n and col < n:  # Vⱼ = w_{j−1} + inputs
        return col == row
    if aligned and mode == "start":  # Vⱼ = (A⁻¹w)_{j−1}·λₙ, dense in w; V_{n+1} also reads u_k
        return col < n or (col == n and row == n)
    if mode == "start":  # Vⱼ = z_{j−1}; V_{n+1} = u_k − Σ λ z
        return col == row if row < n else col <= n
    if col == n + 1 and not foh:  # a zoh state never sees u_{k+1}; V_{n+1} at mid/end does
        return row == n and mode != "next"
    return True


def _split(v: list, p: int):
    """(W1, W2, y1, y2) from the flat list W1 + W2 + [y1, y2]."""
    return v[:p], v[p : 2 * p], v[2 * p], v[2 * p + 1]


def _nested(a, scalars: bool):
    """An input as the per-sample code indexes it: nested lists over every axis but the batch
    (``scalars`` False: per-record values, batch last) or over every axis (``scalars`` True:
    values shared by the batch), each entry indexed at once (``a[i, j]``). Applied to every
    array of a pytree; lists (already unstacked, e.g. by the Pallas kernel from its refs) and
    None pass through."""

    def one(v):
        if isinstance(v, list) or not hasattr(v, "ndim"):
            return v
        stop = v.ndim if scalars else v.ndim - 1
        if stop <= 0:
            return v

        def rec(idx):
            if len(idx) == stop:
                return v[idx]
            return [rec(idx + (i,)) for i in range(v.shape[len(idx)])]

        return rec(())

    return jax.tree.map(one, a, is_leaf=lambda v: isinstance(v, list))


class _Core:
    """The per-sample work of the kernel, shared by the fused XLA loop (:func:`_kernel`) and the
    Pallas kernel (:mod:`lionjax._pallas`): the initial carry, one step k → k+1, and θ(T), J.

    ``shared``/``per`` as :class:`_Inputs` (one of each field set), their ``maps``, ``G``,
    ``z0``, ``theta0`` arrays or nested lists (:func:`_nested`); ``pairs``: carry θ as complex
    pairs (the XLA:CPU fusion trick, :func:`lionjax._phi.materialise`) or as p real arrays (the
    Pallas kernel: GPU kernels have no complex numbers)."""

    def __init__(self, plan: _Plan, shared: _Inputs, per: _Inputs, dtype, pairs: bool = True):
        self.plan, self.dtype, self.pairs = plan, dtype, pairs
        n, p = plan.n, len(plan.columns)
        self.n, self.p, self.S = n, p, len(plan.signals)

        def get(name):
            v = getattr(per, name)
            return _nested(v, False) if v is not None else _nested(getattr(shared, name), True)

        maps = get("maps")
        self.filt = maps if isinstance(maps, _Filter) else None  # one filter per record
        if self.filt is None:
            self.maps = [{k: getattr(m, k) for k in _MODES} for m in maps]
        self.h = get("h")
        self.one = shared.one
        self.foh = [hold == "foh" for _, hold in plan.signals]
        self.outputs, self.inputs = shared.outputs, per.outputs
        self.stepper = shared.stepper
        self.G = get("G") if plan.estimate else None
        self.length = per.length if plan.masked else None
        self.z0 = _nested(per.z0, False)
        self.theta0 = _nested(per.theta0, False) if plan.estimate else None

    def lin(self, s, mode, row, z, uk, uk1):
        if self.filt is not None:
            return self.compact(s, mode, row, z, uk, uk1)
        M = self.maps[s][mode][row]
        n = self.n
        al = self.plan.aligned
        terms = [
            (z[c] if al and mode == "mid" and row < n else M[c] * z[c])  # coefficient 1
            if c < n
            else M[c] * (uk if c == n else uk1)
            for c in range(n + 2)
            if _structural(mode, self.foh[s], n, row, c, al)
        ]
        return sum(terms[1:], terms[0])

    def compact(self, s, mode, row, z, uk, uk1):
        """:meth:`lin` from a :class:`_Filter` (per-record coefficients): the next state's
        entry ``row``, or output V_{row+1} at the step's start, midpoint or end."""
        f, n = self.filt, self.n

        def nxt(i):
            v = sum((f.Phi[i][j] * z[j] for j in range(1, n)), f.Phi[i][0] * z[0]) + f.G0[i] * uk
            return v + f.G1[i] * (uk1 - uk) if self.foh[s] else v

        if mode == "next":
            return nxt(row)

        def state(i):
            if mode == "start":
                return z[i]
            return nxt(i) if mode == "end" else 0.5 * (z[i] + nxt(i))

        if row < n:
            v = state(row)
        else:
            u = uk if mode == "start" else uk1 if mode == "end" else 0.5 * (uk + uk1)
            v = u - sum((f.lam_rev[i] * state(i) for i in range(1, n)), f.lam_rev[0] * state(0))
        return v if f.scale is None else v * f.scale

    def regressors(self, mode, z, uk, uk1):
        """W rows (W1, W2) and W₀ = (y1, y2) from the maps, elementwise."""
        cache: dict = {}
        plan = self.plan

        def V(s, j):  # j = 1…4
            if (s, j) not in cache:
                cache[s, j] = self.lin(s, mode, j - 1, z[s], uk[s], uk1[s])
            return cache[s, j]

        W1 = [sign * V(s, order + 1) for s, order, sign in plan.columns]
        W2 = [sign * V(s, order + 2) for s, order, sign in plan.columns]
        return W1, W2, V(plan.x_index, 3), V(plan.x_index, 4)

    # θ is carried as complex pairs (θ₀ + iθ₁, …): the update of a pair is one fusion

    def to_pairs(self, th):
        if not self.pairs:
            return list(th)
        th = list(th) + ([jnp.zeros_like(th[0])] if self.p % 2 else [])
        return [jax.lax.complex(a, b) for a, b in zip(th[::2], th[1::2], strict=True)]

    def from_pairs(self, tc):
        if not self.pairs:
            return list(tc)
        return [f(v) for v in tc for f in (jnp.real, jnp.imag)][: self.p]

    def init(self, zero) -> _State:
        """The carry before the first step; ``zero`` a (Bs,) array of zeros of the dtype."""
        plan, p = self.plan, self.p
        th0 = [self.theta0[i] for i in range(p)] if plan.estimate else None
        return _State(
            z=[[self.z0[s][i] for i in range(self.n)] for s in range(self.S)],
            theta=self.to_pairs(th0) if plan.estimate else None,
            valid=(
                jnp.ones(zero.shape, bool)
                if plan.estimate and self.stepper.reports_stability
                else None
            ),
            outputs=tuple(
                o.init(inp, p, th0, zero) for o, inp in zip(self.outputs, self.inputs, strict=True)
            ),
        )

    def step(self, c: _State, k, uk, uk1, partial):
        """Sample k → k+1 (``partial``: this slab's sums, added to the totals per slab)."""
        plan, n, p, S = self.plan, self.n, self.p, self.S
        lin, one = self.lin, self.one
        z = c.z
        zn = [[lin(s, "next", i, z[s], uk[s], uk1[s]) for i in range(n)] for s in range(S)]
        act = None
        if plan.masked:
            act = (k + 1) < self.length
            zn = [
                [jnp.where(act, a, b) for a, b in zip(zs, zo, strict=True)]
                for zs, zo in zip(zn, z, strict=True)
            ]

        def end():  # regressors at sample k+1, materialised once (LS statistics)
            W1, W2, y1, y2 = self.regressors("end", z, uk, uk1)
            return _split(materialise(W1 + W2 + [y1, y2], one), p)

        theta, valid, theta_new = c.theta, c.valid, None
        if plan.estimate:
            W1, W2, y1, y2 = self.regressors("mid" if plan.midpoint else "start", z, uk, uk1)
            # the increments feed the θ pairs only (one fusion): the guard (a runtime 1, NaN past
            # the series bound) multiplies them as reals; where accumulators read θ too they are
            # divided by it as complex pairs (that keeps the step from being duplicated into
            # every consumer)
            cheap = real_guard() if not self.outputs else contextlib.nullcontext()
            with cheap:
                d, ok = self.stepper.increment(
                    self.from_pairs(c.theta),
                    W1,
                    W2,
                    y1,
                    y2,
                    self.G,
                    self.h,
                    series=plan.series_terms,
                    one=one,
                )
            tc = [t - v for t, v in zip(c.theta, self.to_pairs(d), strict=True)]
            if act is not None:
                tc = [jnp.where(act, a, b) for a, b in zip(tc, c.theta, strict=True)]
                ok = None if ok is None else ok | ~act
            theta = tc
            if valid is not None:
                valid = valid & ok
            theta_new = lambda: self.from_pairs(tc)
        sample = Sample(k, act, self.h, self.dtype, end, theta_new)
        outs, part = [], []
        for o, st, sm, inp in zip(self.outputs, c.outputs, partial, self.inputs, strict=True):
            new = o.update(Accumulated(st.carry, sm), sample, inp)
            outs.append(Accumulated(new.carry, st.sums))
            part.append(new.sums)
        return _State(zn, theta, valid, tuple(outs)), tuple(part)

    @staticmethod
    def zero_sums(c: _State) -> tuple:
        return tuple(jax.tree.map(jnp.zeros_like, st.sums) for st in c.outputs)

    @staticmethod
    def add_sums(c: _State, part) -> _State:
        outs = tuple(
            Accumulated(st.carry, jax.tree.map(lambda a, b: a + b, st.sums, sm))
            for st, sm in zip(c.outputs, part, strict=True)
        )
        return _State(c.z, c.theta, c.valid, outs)

    def final(self, c: _State, u_end):
        """(θ(T) as p arrays, J = ½εᵀε at each record's last sample); ``u_end``: the S signals
        at that sample."""
        W1, W2, y1, y2 = self.regressors("start", c.z, u_end, u_end)
        th = self.from_pairs(c.theta)
        e1 = sum(a * b for a, b in zip(W1, th, strict=True)) + y1
        e2 = sum(a * b for a, b in zip(W2, th, strict=True)) + y2
        return th, 0.5 * (e1 * e1 + e2 * e2)
