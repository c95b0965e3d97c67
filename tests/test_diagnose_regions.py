"""Where the gap lies: lionjax.diagnosis.find_regions and Region (lionjax/diagnosis/_regions.py).

The search's calibration on autocorrelated noise (its false-region rate against a binomial
bound of alpha), planted regions found on synthetic residuals (IoU ≥ 0.8 with the true mask),
determinism, the JSON fields and the CLI line, bad input, and the regions benchmark's planted
effects in the independent simulator (benchmarks/_blind_sim.py) against closed forms. The JSON
contract on a diagnosis (EMPS) is in test_diagnose.py."""

import json
import math

import _blind_sim as bs  # benchmarks/ (tests/conftest.py)
import numpy as np
import pytest
from scipy.signal import bilinear, lfilter
from scipy.stats import binom, genextreme

import lionjax as lj
from lionjax.diagnosis import Region, find_regions
from lionjax.diagnosis._region_scan import _extreme_p


def _ar(rng, n, phi):
    """A unit-variance AR(1) series: autocorrelation phi^k at lag k."""
    return lfilter([math.sqrt(1 - phi * phi)], [1.0, -phi], rng.standard_normal(n))


def _signals(seed, T=1500, dt=1e-3):
    """Covariates and a residual of pure noise, all autocorrelated, independent of each other."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) * dt
    v = 0.05 * _ar(rng, T, 0.995)
    return {
        "t": t,
        "x": np.cumsum(v) * dt,
        "v": v,
        "F": _ar(rng, T, 0.98),
        "residual_base": _ar(rng, T, 0.8),
    }


def _iou(a, b):
    return np.count_nonzero(a & b) / max(np.count_nonzero(a | b), 1)


@pytest.mark.slow  # 80 searches (~13 s)
def test_false_region_rate_on_autocorrelated_noise():
    # the search's own test (min_explained = 0: no effect-size filter), first step only: the
    # share of noise records with a region at alpha lies within the binomial bound of alpha
    n, alpha = 60, 0.05

    def found(seed, a):
        s = _signals(seed, T=1200)
        return bool(find_regions(s, alpha=a, min_explained=0.0, n_resamples=99, seed=seed))

    assert sum(found(s, alpha) for s in range(n)) <= binom.ppf(0.99, n, alpha)
    # and the test is no dead letter: at alpha = 0.5 a fair share of the records have one
    assert sum(found(s, 0.5) for s in range(20)) >= 3


@pytest.mark.parametrize("k", [0.3, 0.0, -0.2])
def test_tail_law_against_scipy_genextreme(k):
    # the resampled maxima's tail (_extreme_p, L-moments) against the law the draws come from:
    # bounded (k > 0), Gumbel (0) and heavy (k < 0) tails; 20 000 draws, p within 15 % + 2e-4
    law = genextreme(c=k, loc=10.0, scale=2.0)  # scipy's c is Hosking's k
    null = law.rvs(size=(20000, 1), random_state=np.random.default_rng(3))
    x = law.ppf([0.5, 0.9, 0.99, 0.999])
    p = np.array([_extreme_p(np.array([xi]), null)[0] for xi in x])
    np.testing.assert_allclose(p, law.sf(x), rtol=0.15, atol=2e-4)


def _filtered(u, fc=40.0, dt=1e-3):
    """λ³/(s + λ)³ (ε₁'s filter) applied to u: an effect reaches ε₁ through it."""
    lam = 2 * math.pi * fc
    b, a = bilinear([lam**3], [1.0, 3 * lam, 3 * lam**2, lam**3], 1 / dt)
    return lfilter(b, a, u)


def _planted(kind, seed=7):
    s = _signals(seed, T=6000)
    F, x, v, t = s["F"], s["x"], s["v"], s["t"]
    if kind == "clip":  # a force clipped above a level: ε₁ ∝ F − clip(F)
        c = np.quantile(np.abs(F), 0.7)
        mask = np.abs(F) > c
        effect = 20.0 * (F - np.clip(F, -c, c))
    elif kind == "payload":  # the gain on F changes from a moment on
        mask = t >= t[4000]
        effect = 2.0 * F * mask
    else:  # friction on a stretch of rail
        lo, hi = np.quantile(x, [0.4, 0.7])
        mask = (x >= lo) & (x <= hi)
        effect = -2.0 * np.sign(v) * mask
    s["residual_base"] = s["residual_base"] + _filtered(effect)
    return s, mask


@pytest.mark.parametrize(
    ("kind", "variable"), [("clip", "|F|"), ("payload", "t"), ("friction_spot", "x")]
)
def test_planted_region_found(kind, variable):
    s, truth = _planted(kind)
    regions = find_regions(s, n_resamples=99)
    assert regions and regions[0].variable == variable
    assert _iou(regions[0].mask(s), truth) >= 0.8
    assert regions[0].p_value < 0.01
    # the effect's misfit lies in the region: its share of Σε₁² exceeds its share of samples
    assert regions[0].gap_share > regions[0].sample_share


def test_gap_share_is_corrected_for_selection():
    # the region's raw share of Σε₁² less the null's mean excess share: never above the raw
    s, _ = _planted("clip")
    (r, *_) = find_regions(s, n_resamples=99)
    e = s["residual_base"] ** 2
    raw = e[r.mask(s)].sum() / e.sum()
    assert r.gap_share <= raw + 1e-12
    assert r.gap_share > 0.5 * raw


def test_stack_removes_and_simulation_share():
    s, truth = _planted("clip")
    e = s["residual_base"] ** 2
    s["residual_final"] = 0.3 * s["residual_base"]  # a stack that removes 91 % everywhere
    s["sim_base"] = s["residual_base"][:-10]  # whole windows: may be shorter
    (r, *_) = find_regions(s, n_resamples=99)
    assert r.stack_removes == pytest.approx(1 - 0.09)
    m = r.mask(s)[:-10]
    assert r.simulation_share == pytest.approx(e[:-10][m].sum() / e[:-10].sum())
    # a diverged simulation (overflowed) has no share; the regions are the same
    s["sim_base"] = np.where(np.arange(s["sim_base"].size) == 5, np.inf, s["sim_base"])
    (d, *_) = find_regions(s, n_resamples=99)
    assert d.simulation_share is None and (d.low, d.high) == (r.low, r.high)


def test_deterministic_and_pure():
    s, _ = _planted("payload")
    before = {k: v.copy() for k, v in s.items()}
    a = [r.to_json() for r in find_regions(s, n_resamples=99, seed=3)]
    b = [r.to_json() for r in find_regions(s, n_resamples=99, seed=3)]
    assert a == b and a
    assert all(np.array_equal(before[k], s[k]) for k in s)


def test_json_fields():
    s, _ = _planted("clip")
    (r, *_) = find_regions(s, n_resamples=99)
    j = json.loads(json.dumps(r.to_json()))
    assert set(j) >= {
        "variable",
        "low",
        "high",
        "gap_share",
        "sample_share",
        "p_value",
        "stack_removes",
    }
    assert j["variable"] == "|F|" and j["high"] is None and j["low"] > 0
    assert j["units"] == "N" and j["stack_removes"] is None
    assert 0 <= j["sample_share"] <= 1 and 0 <= j["gap_share"] <= 1 and 0 < j["p_value"] < 1


def _region(**kw):
    base = dict(
        variable="|F|",
        low=0.712,
        high=None,
        gap_share=0.68,
        sample_share=0.24,
        p_value=2e-5,
        stack_removes=0.81,
        simulation_share=None,
        statistic=100.0,
    )
    return Region(**{**base, **kw})


def test_cli_line():
    assert _region().describe() == (
        "|F| > 0.712 N: 24 % of samples, 68 % of the gap, p < 0.001; the stack removes 81 % of it"
    )
    line = _region(variable="x", low=0.12, high=0.35, p_value=0.0123, stack_removes=None)
    assert line.describe() == (
        "0.12 ≤ x < 0.35 m: 24 % of samples, 68 % of the gap, p = 0.012; no effect is stacked"
    )
    line = _region(variable="t", low=None, high=2.5, stack_removes=-0.25)
    assert line.describe().startswith("t < 2.5 s: ")
    assert line.describe().endswith("; the stack adds 25 % to it")


def test_rotary_units():
    # a rotary record's regions: the same bounds, their units rewritten (t keeps seconds)
    for variable, linear, rotary in (("x", "m", "rad"), ("|v|", "m/s", "rad/s"), ("F", "N", "N·m")):
        r = _region(variable=variable, units="rotary")
        assert r.to_json()["units"] == rotary and r.to_json()["low"] == 0.712
        assert f"{variable} > 0.712 {rotary}:" in r.describe()
        assert _region(variable=variable).to_json()["units"] == linear
    assert (
        _region(variable="t", high=2.5, low=None, units="rotary").describe().startswith("t < 2.5 s")
    )


def test_bad_input():
    s = _signals(0)
    with pytest.raises(lj.InputError, match="residual_base"):
        find_regions({k: v for k, v in s.items() if k != "residual_base"})
    bad = dict(s, F=s["F"].copy())
    bad["F"][17] = np.nan
    with pytest.raises(lj.InputError, match=r"signals\['F'\].*sample 17"):
        find_regions(bad)
    with pytest.raises(lj.InputError, match="t has 1500"):
        find_regions(dict(s, x=s["x"][:-1]))
    with pytest.raises(lj.InputError, match="alpha"):
        find_regions(s, alpha=1.5)
    with pytest.raises(lj.InputError, match="at least"):
        find_regions({k: v[:50] for k, v in s.items()})
    with pytest.raises(lj.InputError, match="alpha"):
        lj.diagnosis.Criteria(alpha=0.0)
    # the confidence of "none" takes ln(min_size): 0 is refused by name, not a division by zero
    with pytest.raises(lj.InputError, match=r"min_size must be in \(0, 1\).*got 0\.0"):
        lj.diagnosis.Criteria(min_size=0.0)


# ---------------------------------------------------------------- the benchmark's simulator


def _open_loop(effects, fs=1000.0, n=3000, seed=5):
    rng = np.random.default_rng(seed)
    exc = bs.excitation("multisine", rng, n, fs, 2.0, 0.3, 12.0)
    return bs.simulate(bs.Axis(8.0, 1.5, effects), exc, fs), exc


def test_payload_against_closed_form():
    # a, b scaled by κ = 1/(1 + μ) from the first sample at or after t_p: the exact solution of
    # each piece, the second from the first's state at that sample
    fs, mu, kp = 1000.0, 0.6, 1700
    r, exc = _open_loop((bs.Payload(mu, (kp - 0.5) / fs),))
    X1, V1 = bs.exact_mass_damper(8.0, 1.5, exc, 1 / fs)
    k = 1 / (1 + mu)
    X2, V2 = bs.exact_mass_damper(8.0 * k, 1.5 * k, exc[kp:], 1 / fs, x0=X1[kp], v0=V1[kp])
    # the second piece starts with the held command of sample kp (no delay: u = F[k])
    X = np.concatenate([X1[:kp], X2])
    assert np.max(np.abs(r.x_true - X)) <= 1e-6 * np.max(np.abs(X))


def test_device_drift_against_closed_form():
    # a force r·(t − t_r)₊ held per interval at its mid-point value: the clean solution driven
    # by F plus that force
    fs, rate, t_r = 1000.0, 0.8, 1.2
    r, exc = _open_loop((bs.DeviceDrift(rate, t_r),))
    t = np.arange(exc.size) / fs
    X, _ = bs.exact_mass_damper(8.0, 1.5, exc + rate * np.maximum(t + 0.5 / fs - t_r, 0), 1 / fs)
    assert np.max(np.abs(r.x_true - X)) <= 1e-6 * np.max(np.abs(X))


def test_friction_spot_is_friction_inside_and_nothing_outside():
    clean, exc = _open_loop(())
    lo, hi = np.min(clean.x_true), np.max(clean.x_true)
    # outside the spot the axis is the clean mass–damper (its exact solution; the switched
    # kernel still locates each reversal, so not bit for bit)
    away = _open_loop((bs.FrictionSpot(0.3, hi + 1.0, hi + 2.0),))[0]
    X, _ = bs.exact_mass_damper(8.0, 1.5, exc, 1e-3)
    assert np.max(np.abs(away.x_true - X)) <= 1e-6 * np.max(np.abs(X))
    whole = _open_loop((bs.FrictionSpot(0.3, lo - 1.0, hi + 1.0),))[0]
    plain = _open_loop((bs.StribeckFriction(0.3, 0.3, 1.0),))[0]
    assert np.array_equal(whole.x_true, plain.x_true)
    # the step of b: a boundary beyond the travel leaves the clean record
    step = _open_loop((bs.PositionDependence(0.0, 0.5, 1.0, hi + 1.0, "step"),))[0]
    assert np.array_equal(step.x_true, clean.x_true)
