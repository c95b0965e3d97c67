"""lionjax.diagnose: the flexible-mode candidate: its columns against scipy, exactness on a
noise-free record, the (ω, ζ) search, and its plausibility (collocated, heavy, deflection against
the position noise) on held-out records."""

import math

import diagnosis_blind as blind  # benchmarks/ (tests/conftest.py)
import numpy as np
import pytest

import lionjax as lj

# the slow tier (.ci/run's second step): whole diagnoses of blind-benchmark records
pytestmark = pytest.mark.slow


def test_quantisation_fed_back_is_no_mode():
    """A clean closed-loop record (independent simulator, 1.3 kHz, 4 µm encoder, PD on the
    measured position) whose quantisation the loop feeds back into F: a "mode" at 82 Hz fits
    it (score > threshold) but deflects the axis by a quarter of the position noise, so it is
    not plausible and the verdict is ``none`` (it was ``flexible_mode`` at confidence 1.0).
    Since the (ω, ζ) profile is chosen on validation the look-alike lands at ζ 0.28, above the
    damping bound, and is refused by that rule first; the deflection rule is checked on its own
    in :func:`test_mode_plausible_only_lightly_damped_and_heavy_only_collocated`."""
    train, valid, info = blind.make_case("none", 2001001, source="scipy")
    assert info["closed_loop"] and info["q"] > 3e-6
    d = lj.diagnose(train, valid)
    mode = next(e for e in d.effects if e.name == "flexible_mode")
    assert mode.score > 10 and not mode.plausible and mode.reason.startswith("no flexible mode")
    assert mode.params["deflection"] < 0.5 * d.noise["position_std"]
    assert d.verdict == "none"


def test_mode_signals_and_soft_saturation_against_scipy():
    """h = (s²/D)[·] of the flexible-mode candidate (bucketed batched filter) against scipy's
    lsim (first-order hold of the hold-corrected samples: linear interpolation) and zero-order-
    hold discretisation, 1e-8; the soft input map against tanh."""
    from scipy import signal

    from lionjax.diagnosis._filtering import mode_signals, padded_length
    from lionjax.diagnosis._fit import apply_input

    dt, T = 1 / 997.3, 3000
    t = np.arange(T) * dt
    x = 0.01 * np.sin(2 * np.pi * 3.1 * t) + 0.002 * np.sin(2 * np.pi * 37.0 * t)  # x(0) = 0
    F = np.sign(np.sin(2 * np.pi * 1.3 * t + 0.3))
    w, z = 2 * np.pi * 21.0, 0.07
    num, den = [1.0, 0.0, 0.0], [1.0, 2 * z * w, w * w]
    # x is held first-order after the hold correction xₖ − Δ²xₖ/12 (ends: the neighbour's Δ²)
    d2 = x[2:] - 2 * x[1:-1] + x[:-2]
    xc = x - np.concatenate([d2[:1], d2, d2[-1:]]) / 12
    # (the state sees xc; the feedthrough D·x the samples themselves)
    A, B, C, D = signal.tf2ss(num, den)
    x0_ss = -np.linalg.solve(A, B[:, 0] * xc[0])  # at rest under xc[0], as the filter
    hx_ref = signal.lsim((A, B, C, 0 * D), xc, t, X0=x0_ss, interp=True)[1] + D[0, 0] * x
    A, B, C, D, _ = signal.cont2discrete(signal.tf2ss(num, den), dt, "zoh")
    x0 = np.linalg.solve(np.eye(2) - A, B[:, 0] * F[0])  # at rest under F[0]: h = 0
    hF_ref = signal.dlsim((A, B, C, D, dt), F, t=t, x0=x0)[1][:, 0]
    ((hx, hF),) = mode_signals(x, F, dt, [(w, z)], padded_length(T))
    scale = np.max(np.abs(hx_ref))
    # the last sample's Δ² sees the padding (its own value repeated), not the neighbour's Δ²
    np.testing.assert_allclose(hx[:-1], hx_ref[:-1], atol=1e-8 * scale)
    assert abs(hx[-1] - hx_ref[-1]) < 0.01 * scale
    np.testing.assert_allclose(hF, hF_ref, atol=1e-8 * np.max(np.abs(hF_ref)))
    np.testing.assert_allclose(apply_input(F * 2.0, dt, 0.0, -1.5), 1.5 * np.tanh(F * 2.0 / 1.5))


@pytest.mark.filterwarnings("ignore::scipy.signal.BadCoefficients")  # λ³sʲ⁺¹: trailing zeros
@pytest.mark.parametrize(
    "fs, f_filter, f_mode, zeta",
    [(1003.7, 40.0, 21.0, 0.2), (1003.7, 40.0, 8.0, 0.1), (277.3, 11.0, 60.0, 0.05)],
)
def test_mode_columns_against_scipy(fs, f_filter, f_mode, zeta):
    """The flexible mode's ε₁ columns λ³s⁴/((s + λ)³D)[x] (x under the first-order hold of its
    hold-corrected samples) and λ³s²/((s + λ)³D)[F] (F under a zero-order hold), computed as the
    diagnosis filter's output followed by an exact stage of order 2, against scipy's
    cont2discrete + dlsim of the order-5 transfer functions: 1e-9 once the initial states
    (steady vs scipy's zero) have decayed (25 time constants). A mode below the filter corner,
    a lightly damped one further below, and one above a low sample rate's filter."""
    from scipy import signal

    from lionjax.diagnosis._filtering import hold_corrected, mode_columns
    from lionjax.diagnosis._fit import Regressors

    dt, T = 1 / fs, 12000
    t = np.arange(T) * dt
    rng = np.random.default_rng(3)
    x = sum(1e-3 * np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in (0.7, 3.1, 9.0, 27.0))
    F = np.repeat(rng.standard_normal(T // 10), 10)
    w, z, lam = 2 * np.pi * f_mode, zeta, 2 * np.pi * f_filter
    bank = lj.FilterBank.from_poles(np.full(3, -lam), unit_dc_gain=True)
    regs = Regressors(lj.Record(x, F, dt), bank)
    (cx,), (cF,) = mode_columns(regs, [(w, z)], lam)
    den = np.polymul(np.poly([-lam] * 3), [1.0, 2 * z * w, w * w])
    xc = np.asarray(hold_corrected(x, 1.0))
    tail = slice(int(25 / min(z * w, lam) / dt), T - 1)
    assert tail.start < T // 2
    yF = signal.dlsim(signal.cont2discrete(([lam**3, 0, 0], den), dt, "zoh"), F, t=t)[1][:, 0]
    np.testing.assert_allclose(cF[tail], yF[tail], atol=1e-9 * np.max(np.abs(yF)))
    yx = signal.dlsim(signal.cont2discrete(([lam**3, 0, 0, 0, 0], den), dt, "foh"), xc, t=t)
    np.testing.assert_allclose(cx[tail], yx[1][tail, 0], atol=1e-9 * np.max(np.abs(yx[1])))


def _noise_free_noncollocated_mode(monkeypatch, seed):
    """(train, valid, info) of the independent simulator's open-loop non-collocated flexible
    mode case ``seed``, without encoder quantisation or position noise."""
    import dataclasses

    draw = blind.draw_setup
    monkeypatch.setattr(
        blind, "draw_setup", lambda *a, **k: dataclasses.replace(draw(*a, **k), q=1e-9, noise=0.0)
    )
    train, valid, info = blind.make_case("flexible_mode", seed, source="scipy")
    assert info["shape"] == "noncollocated" and not info["closed_loop"]
    return train, valid, info


def test_noncollocated_mode_is_exact(monkeypatch):
    """A non-collocated flexible mode (independent simulator, noise-free, open loop, 905 Hz,
    17 Hz, ζ = 0.023) obeys ẍ + aẋ − μs²(s²/D)x = b(1 − s²/D)F exactly: the diagnosis' profile
    finds (ω, ζ) and the ε₁ fit returns μ and the input share κ = 1. The two-stage columns (h's
    samples filtered again) returned μ 0.147, κ 0.78, and without the mode's free-response
    columns its initial transient (1/ζω = 0.4 s) left a quarter of the excess error."""
    train, valid, info = _noise_free_noncollocated_mode(monkeypatch, 81000)
    p = info["effects"][0]["params"]
    d = lj.diagnose(train, valid)
    assert d.verdict == "flexible_mode"
    r = next(e for e in d.effects if e.name == "flexible_mode").params
    assert r["f_mode"] == pytest.approx(p["frequency"], rel=MODE_TOL["f"])
    assert r["zeta_mode"] == pytest.approx(p["damping_ratio"], rel=MODE_TOL["zeta"])
    assert r["mass_ratio"] == pytest.approx(p["mass_ratio"], rel=MODE_TOL["mu"])
    assert r["input_share"] == pytest.approx(1.0, abs=MODE_TOL["kappa"])


#: What the profile reaches on the noise-free mode above, the pattern search's resolution
#: (measured: f 0.5 %, ζ 12 %, μ 5 %, κ 0.004; with (ω, ζ) held at the truth μ and κ are exact
#: within 1e-3).
MODE_TOL = {"f": 0.01, "zeta": 0.15, "mu": 0.06, "kappa": 0.01}


def test_collocated_mode_in_closed_loop():
    """A collocated flexible mode in closed loop (independent simulator, 1.48 kHz): the input-
    share column also fits the position noise fed back into F and biased μ by 24 %; the variant
    without it wins on validation and recovers the drawn mode (f 16.61 Hz, μ 0.512)."""
    train, valid, info = blind.make_case("flexible_mode", 81006, source="scipy")
    assert info["closed_loop"] and info["shape"] == "collocated"
    p = info["effects"][0]["params"]
    d = lj.diagnose(train, valid)
    assert d.verdict == "flexible_mode"
    mode = next(e for e in d.effects if e.name == "flexible_mode")
    assert mode.params["input_share"] == 0.0
    assert mode.params["f_mode"] == pytest.approx(p["frequency"], rel=0.03)
    assert mode.params["mass_ratio"] == pytest.approx(p["mass_ratio"], rel=0.15)


def test_mode_search_finds_a_narrow_valley(monkeypatch):
    """A non-collocated flexible mode at 12.9 Hz, ζ = 0.047 (independent simulator, open loop,
    312 Hz, noise-free): its RSS valley in (ω, ζ) is a few per cent wide and falls between the
    coarse grid's points, and the pattern search from the coarse best stopped at an input filter
    (μ ≈ 0 at 14.2 Hz, ζ 0.12, RSS 480× the true mode's): verdict ``unexplained``. The
    equation-error guess (:func:`mode_seed`) lands within 1 % of ω and 5 % of ζ, and the search
    from it recovers the drawn mode (reference: the simulator's parameters)."""
    import math

    from lionjax.diagnosis._filtering import mode_seed, padded_length

    train, valid, info = _noise_free_noncollocated_mode(monkeypatch, 12081004)
    p = info["effects"][0]["params"]
    w, z = 2 * math.pi * p["frequency"], p["damping_ratio"]
    dt = float(train.dt)
    lam = 2 * math.pi * min(1 / dt / 25, 40.0)
    ws, zs = mode_seed(train.x, train.F, dt, lam, padded_length(train.n_samples))
    assert ws == pytest.approx(w, rel=0.01) and zs == pytest.approx(z, rel=0.05)
    d = lj.diagnose(train, valid)
    assert d.verdict == "flexible_mode"
    mode = next(e for e in d.effects if e.name == "flexible_mode").params
    assert mode["f_mode"] == pytest.approx(p["frequency"], rel=1e-3)
    assert mode["zeta_mode"] == pytest.approx(z, rel=0.02)
    assert mode["mass_ratio"] == pytest.approx(p["mass_ratio"], rel=0.01)
    assert mode["input_share"] == pytest.approx(1.0, abs=0.01)


def test_mode_plausible_only_lightly_damped_and_heavy_only_collocated():
    from lionjax.diagnosis import FlexibleModeCandidate, Limits
    from lionjax.diagnosis._mode import MAX_HEAVY_MODE_MASS, MAX_MODE_ZETA

    c, lim = FlexibleModeCandidate(), Limits(F_abs_max=1.0, dt=1e-3)
    base = dict(b=2.0, f_mode=20.0, deflection=1e-3)

    def why(mu, zeta, beta):
        return c.implausible(base | dict(mass_ratio=mu, zeta_mode=zeta, beta=beta), lim)

    assert why(0.5, 0.2, 1.0) == ""  # light, κ free
    # more damped than a resonance peak of 2× (1/(2ζ√(1 − ζ²)) at ζ = 0.2588): refused
    assert 1 / (2 * MAX_MODE_ZETA * math.sqrt(1 - MAX_MODE_ZETA**2)) >= 2.0
    assert "damping ratio" in why(0.5, MAX_MODE_ZETA + 0.01, 1.0)
    assert "damping ratio" in why(0.9, MAX_MODE_ZETA + 0.05, 0.0)  # heavy, damped
    assert why(0.9, 0.1, 0.0) == ""  # heavy, collocated (β ≡ 0), lightly damped
    assert why(0.9, 0.1, 0.004) == ""  # κ = 0.002 fitted free: collocated within the fit
    assert "mass ratio" in why(0.9, 0.1, 2.0)  # heavy with κ = 1: a delay's look-alike
    assert "mass ratio" in why(0.9, 0.1, 0.4)  # heavy with κ = 0.2
    assert "mass ratio" in why(MAX_HEAVY_MODE_MASS + 0.01, 0.1, 0.0)
    # the deflection against the position noise: 2× in closed loop, 1× for a light open-loop mode
    for closed, dfl, bad in ((True, 1.9e-3, True), (True, 2.1e-3, False), (False, 1.1e-3, False)):
        noisy = Limits(F_abs_max=1.0, dt=1e-3, position_noise=1e-3, closed_loop=closed)
        phys = base | dict(mass_ratio=0.5, zeta_mode=0.1, beta=0.0, deflection=dfl)
        assert ("position noise" in c.implausible(phys, noisy)) == bad
    phys = base | dict(mass_ratio=0.5, zeta_mode=0.1, beta=0.0, deflection=0.9e-3)
    assert "position noise" in c.implausible(phys, Limits(1.0, 1e-3, position_noise=1e-3))
    # a mode on the first or last frequency of the search (f_mode = 20 Hz here) was not located
    phys = base | dict(mass_ratio=0.5, zeta_mode=0.1, beta=0.0)
    for band, edge in (((20.0, 80.0), True), ((5.0, 20.0), True), ((19.9, 20.1), False)):
        lim = Limits(F_abs_max=1.0, dt=1e-3, mode_band=band)
        assert ("edge of the searched band" in c.implausible(phys, lim)) == edge
    # within 3× the hold error (ωh)²/12 = 0.0329 at 35 Hz, 350 Hz: the sampling's look-alike
    # (κ = 0), unless the input passes through the mode (κ ≈ 1: non-collocated)
    lim = Limits(F_abs_max=1.0, dt=1 / 350)
    for beta, bad in ((0.0, True), (0.6, True), (1.0, False), (2.0, False)):  # κ = β/b, b = 2
        phys = base | dict(f_mode=35.0, mass_ratio=0.089, zeta_mode=0.18, beta=beta)
        assert ("hold error" in c.implausible(phys, lim)) == bad


def test_open_loop_mode_above_the_noise_is_named():
    """An open-loop twin record (294 Hz) with a collocated mode of μ 0.107 at 13.6 Hz: fitted
    within 2 % of μ and ω (score > 400), it moves the axis by 1.7× the position noise and was
    refused under the closed-loop bound of 2× (there a position loop feeds the quantisation into
    F). In open loop the mode must only stand above the noise."""
    train, valid, info = blind.make_case("flexible_mode", 16080002, source="twin")
    truth = info["effects"][0]["params"]
    d = lj.diagnose(train, valid)
    assert not d.noise["closed_loop"] and d.verdict == "flexible_mode"
    assert d.final["f_mode"] == pytest.approx(truth["frequency"], rel=0.02)
    assert d.final["mass_ratio"] == pytest.approx(truth["mass_ratio"], rel=0.05)
    assert d.noise["position_std"] < d.final["deflection"] < 2 * d.noise["position_std"]


def test_validation_rss_of_a_training_fit_against_numpy():
    """The flexible mode's profile fits each point on train (``rss_with_columns``) and judges
    it on validation (``rss_fixed_with_columns``: the structure's and the mode's coefficients
    held, the filter's initial state and the mode's free response refitted). Against numpy's
    lstsq on the explicit designs ε₁ = V₃ + aV₂ − bQ₁ + Σ cⱼ·colⱼ + N·η (N the filter's free
    response): the training coefficients and RSS, and the validation RSS, to 1e-9 relative."""
    from lionjax._models import Augmented, MassDamper
    from lionjax.diagnosis._fit import Regressors, rss_fixed_with_columns, rss_with_columns

    dt, T, lam = 1 / 997.3, 4000, 2 * np.pi * 30.0
    bank = lj.FilterBank.from_poles(np.full(3, -lam), unit_dc_gain=True)
    model = Augmented(MassDamper(), ())
    rng = np.random.default_rng(11)
    t = np.arange(T) * dt
    regs, designs = [], []
    for _ in range(2):
        F = np.repeat(rng.standard_normal(T // 20), 20)
        x = np.cumsum(np.cumsum(F)) * dt * dt * 0.05 + 1e-6 * rng.standard_normal(T)
        r = Regressors(lj.Record(x, F, dt), bank)
        V = r.filtered({"x": (r.x, "foh"), "F": (r.F, "zoh")})
        Vx, VF = np.asarray(V["x"])[:T], np.asarray(V["F"])[:T]
        regs.append(r)
        designs.append((np.stack([Vx[:, 1], -VF[:, 0]], 1), Vx[:, 2], np.asarray(r.N)[:T]))
    # two sets of K = 4 extra columns per record: 2 held (a mode's), 2 refitted (its free
    # response), smooth enough to be identifiable
    m, K = 2, 4
    cols = [
        np.stack(
            [
                np.stack([np.sin(2 * np.pi * (3 + i + k) * t + j) for k in range(K)])
                for i in range(m)
            ]
        )
        for j in range(2)
    ]
    c, rss, n = rss_with_columns(regs[0], model, cols[0], coef=True)
    W, y, N = designs[0]
    assert n == W.shape[1] + N.shape[1]
    for i in range(m):
        D = np.concatenate([W, N, cols[0][i].T], 1)
        ref, res = np.linalg.lstsq(D, -y, rcond=None)[:2]
        np.testing.assert_allclose(c[i], ref, rtol=1e-9, atol=1e-9 * np.max(np.abs(ref)))
        np.testing.assert_allclose(rss[i], res[0], rtol=1e-9)
    got = rss_fixed_with_columns(regs[1], model, cols[1], c, 2)
    W, y, N = designs[1]
    for i in range(m):
        held = W @ c[i, :2] + y + cols[1][i, :2].T @ c[i, n : n + 2]
        B = np.concatenate([N, cols[1][i, 2:].T], 1)
        eta = np.linalg.lstsq(B, -held, rcond=None)[0]
        np.testing.assert_allclose(got[i], np.sum((held + B @ eta) ** 2), rtol=1e-9)


def test_fits_hold_only_small_arrays_per_structure(monkeypatch):
    """ε₁'s least squares of a structure with an F-dependent column (b(x) = b + b₁ξ: the
    column ξ·u) under input maps u = sat_Fmax(F(t − τ)) — the profile grid's path — and for
    u = F, against numpy's lstsq on the explicit design [V₂(x), −Q₁(u), V₂(g), −Q₁(ξu), N]
    (N the filter's free response), to 1e-9 relative. With the design cached (short record)
    and rebuilt (``BIG`` lowered: a long record), bit for bit the same; and on the long record
    nothing of the record's length is held per structure, only its plan and its Gram."""
    from lionjax._model_effects import PolynomialPosition
    from lionjax._models import Augmented, MassDamper
    from lionjax.diagnosis import _fit
    from lionjax.diagnosis._fit import Regressors, apply_input, fit_batch

    dt, T, lam = 1 / 997.3, 3000, 2 * np.pi * 30.0
    bank = lj.FilterBank.from_poles(np.full(3, -lam), unit_dc_gain=True)
    rng = np.random.default_rng(5)
    F = np.repeat(rng.standard_normal(T // 20), 20)
    x = 0.01 * np.sin(np.arange(T) * dt * 2.1) + 1e-4 * np.cumsum(rng.standard_normal(T)) * dt
    c, ell = float(np.mean(x)), float(np.std(x))
    model = Augmented(MassDamper(), (PolynomialPosition(c, ell, 1),))
    inputs = [(0.0, np.inf), (0.0031, np.inf), (0.0, 0.8), (0.0017, -1.2)]

    def fits(big):
        monkeypatch.setattr(_fit, "BIG", big)
        regs = Regressors(lj.Record(x, F, dt), bank)
        out = [fit_batch(regs, model, [inp])[:2] for inp in inputs[:1]]
        out.append(fit_batch(regs, model, inputs[1:])[:2])
        return regs, out

    regs, cached = fits(1 << 18)
    long_regs, rebuilt = fits(1 << 10)
    for a, b in zip(cached, rebuilt, strict=True):
        assert all(np.array_equal(u, v) for u, v in zip(a, b, strict=True))
    kinds = {k[0] for k in long_regs.cache if isinstance(k, tuple)}
    assert "design" not in kinds and {"plan", "gram"} <= kinds
    for k, v in long_regs.cache.items():
        if isinstance(k, tuple) and k[0] in ("plan", "gram"):
            arrays = [a for a in (v if isinstance(v, tuple) else (v,)) if isinstance(a, np.ndarray)]
            assert arrays and all(a.size <= (_fit.P_MAX + 1) ** 2 for a in arrays), k
    theta = np.concatenate([cached[0][0], cached[1][0]])
    rss = np.concatenate([cached[0][1], cached[1][1]])
    xi = (x - c) / ell
    g = ell * xi**2 / 2
    V = regs.filtered({"x": (x, "foh"), "g": (g, "foh")})
    N = np.asarray(regs.N)[:T]
    for i, (tau, fmax) in enumerate(inputs):
        u = apply_input(F, dt, tau, fmax)
        Q = regs.filtered({f"u{i}": (u, "zoh"), f"xiu{i}": (xi * u, "zoh")})
        D = np.stack([V["x"][:T, 1], -Q[f"u{i}"][:T, 0], V["g"][:T, 1], -Q[f"xiu{i}"][:T, 0]], 1)
        D = np.concatenate([D, N], 1)
        ref, res = np.linalg.lstsq(D, -V["x"][:T, 2], rcond=None)[:2]
        np.testing.assert_allclose(theta[i], ref[:4], rtol=1e-9, atol=1e-9 * np.abs(ref[:4]).max())
        np.testing.assert_allclose(rss[i], res[0], rtol=1e-9)
