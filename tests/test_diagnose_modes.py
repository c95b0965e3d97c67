"""lionjax.diagnose: the flexible-mode candidate: exactness on a noise-free record, the (ω, ζ)
search, and its plausibility (collocated, heavy, deflection against the position noise) on
held-out records. (Its columns against scipy and its profile's least squares against numpy:
test_diagnose_kernels.py.)"""

import math

import diagnosis_blind as blind  # benchmarks/ (tests/conftest.py)
import pytest

import lionjax as lj

# the slow tier (.ci/run's second step): whole diagnoses of blind-benchmark records
pytestmark = pytest.mark.slow


def test_quantisation_fed_back_is_no_mode():
    """A clean closed-loop record (independent simulator, 1.3 kHz, 4 µm encoder, PD on the
    measured position) whose quantisation the loop feeds back into F: a "mode" that fits it
    (score > threshold) deflects the axis by less than the closed-loop bound of twice the
    position noise, so it is not plausible, and nothing is named (it was ``flexible_mode`` at
    1.0).
    Since the (ω, ζ) profile is chosen on validation the look-alike lands at ζ 0.4, above the
    damping bound, and is refused by that rule first; the deflection rule is checked on its own
    in :func:`test_mode_plausible_only_lightly_damped_and_heavy_only_collocated`."""
    train, valid, info = blind.make_case("none", 2001001, source="scipy")
    assert info["closed_loop"] and info["q"] > 3e-6
    d = lj.diagnose(train, valid)
    mode = next(e for e in d.effects if e.name == "flexible_mode")
    if mode.score > 10:  # a look-alike that fits is refused
        assert not mode.plausible and mode.reason.startswith("no flexible mode")
        assert mode.params["deflection"] < 2 * d.noise["position_std"]  # the closed-loop bound
    # nothing named; the diagnosis does not see the loop here (its feedback test on F), so the
    # damped look-alike (ζ at the search's limit, a broadband lag) counts as a rival of "no
    # effect": unexplained, with no confidence
    assert d.stack == [] and (d.verdict == "none" or d.confidence == 0.0), d.verdict


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
    # the windowed simulation steps the mode with the axis, its unknown initial state fitted:
    # the noise-free record's gap nearly vanishes (shrink 0.998 measured; 0.51 with the load's
    # filters started at rest, whose error decays over 1/ζω = 0.4 s)
    assert d.final["shrink"] >= SHRINK_MODE


#: The least shrink of the simulated gap on that record.
SHRINK_MODE = 0.99

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
    (μ ≈ 0 at 14.2 Hz, ζ 0.12, RSS 480× the true mode's): verdict ``unexplained``. The search
    from the equation-error guess of the mode (within 1 % of ω and 5 % of ζ here,
    test_diagnose_kernels.py) recovers the drawn mode (reference: the simulator's
    parameters)."""
    train, valid, info = _noise_free_noncollocated_mode(monkeypatch, 12081004)
    p = info["effects"][0]["params"]
    z = p["damping_ratio"]
    d = lj.diagnose(train, valid)
    assert d.verdict == "flexible_mode"
    mode = next(e for e in d.effects if e.name == "flexible_mode").params
    assert mode["f_mode"] == pytest.approx(p["frequency"], rel=1e-3)
    assert mode["zeta_mode"] == pytest.approx(z, rel=0.02)
    assert mode["mass_ratio"] == pytest.approx(p["mass_ratio"], rel=0.01)
    assert mode["input_share"] == pytest.approx(1.0, abs=0.01)


#: The flexible mode's plausibility bounds (docs/method.md): ζ ≤ 0.25, a resonance peak
#: 1/(2ζ√(1 − ζ²)) of at least 2×; a mass ratio up to 0.6, up to 0.95 for a collocated mode.
MAX_MODE_ZETA, MAX_HEAVY_MODE_MASS = 0.25, 0.95


def test_mode_plausible_only_lightly_damped_and_heavy_only_collocated():
    from lionjax.diagnosis import FlexibleModeCandidate, Limits

    c, lim = FlexibleModeCandidate(), Limits(F_abs_max=1.0, dt=1e-3)
    base = dict(b=2.0, f_mode=20.0, deflection=1e-3)

    def why(mu, zeta, beta):
        return c.implausible(base | dict(mass_ratio=mu, zeta_mode=zeta, beta=beta), lim)

    assert why(0.5, 0.2, 1.0) == ""  # light, κ free
    # more damped than a resonance peak of 2× (1/(2ζ√(1 − ζ²)) at ζ = 0.2588): refused
    assert 1 / (2 * MAX_MODE_ZETA * math.sqrt(1 - MAX_MODE_ZETA**2)) >= 2.0
    assert why(0.5, MAX_MODE_ZETA, 1.0) == ""  # on the bound
    assert "damping ratio" in why(0.5, MAX_MODE_ZETA + 0.01, 1.0)
    assert "damping ratio" in why(0.9, MAX_MODE_ZETA + 0.05, 0.0)  # heavy, damped
    assert why(0.9, 0.1, 0.0) == ""  # heavy, collocated (β ≡ 0), lightly damped
    assert why(0.9, 0.1, 0.004) == ""  # κ = 0.002 fitted free: collocated within the fit
    assert "mass ratio" in why(0.9, 0.1, 2.0)  # heavy with κ = 1: a delay's look-alike
    assert "mass ratio" in why(0.9, 0.1, 0.4)  # heavy with κ = 0.2
    assert why(MAX_HEAVY_MODE_MASS, 0.1, 0.0) == ""  # on the bound
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
    within 2 % of ω and 8 % of μ (score > 400; the pattern search ends on the valley's flat floor,
    where μ moves by a few per cent with the grid it starts from), it moves the axis by 1.7× the
    position noise and was refused under the closed-loop bound of 2× (there a position loop
    feeds the quantisation into F). In open loop the mode must only stand above the noise."""
    train, valid, info = blind.make_case("flexible_mode", 16080002, source="twin")
    truth = info["effects"][0]["params"]
    d = lj.diagnose(train, valid)
    assert not d.noise["closed_loop"] and d.verdict == "flexible_mode"
    assert d.final["f_mode"] == pytest.approx(truth["frequency"], rel=0.02)
    assert d.final["mass_ratio"] == pytest.approx(truth["mass_ratio"], rel=0.08)
    assert d.noise["position_std"] < d.final["deflection"] < 2 * d.noise["position_std"]
