"""The position-periodic look-alike (cogging, out of the library) against independent references:
a Runge–Kutta simulation of a mass–damper with a force periodic in position, and numpy ``lstsq`` on
the public ``Cogging`` candidate (examples/custom_effects.py), a second implementation of the same
model."""

import math

import numpy as np
import pytest

import lionjax as lj

# the slow tier (.ci/run's second step): whole diagnoses of blind-benchmark records
pytestmark = pytest.mark.slow

DT = 1 / 997.3
A, B = 20.0, 2.0


def _record(seed, cog, period, n=6000, noise=1e-6):
    """ẍ + aẋ = b(F + cog·sin(2πx/period + 0.7)), F held between samples: classical RK4 with
    8 steps per sample (written here; its step error, ~(ωh)⁴, is far below the noise)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    F = sum(
        a * np.sin(2 * np.pi * f * t + p)
        for a, f, p in zip(
            rng.uniform(0.5, 1.0, 6), rng.uniform(0.3, 8.0, 6), rng.uniform(0, 6, 6), strict=True
        )
    )
    w = 2 * math.pi / period

    def acc(x, v, f):
        return -A * v + B * (f + cog * math.sin(w * x + 0.7))

    x = np.empty(n)
    xk = vk = 0.0
    h = DT / 8
    for k in range(n):
        x[k] = xk
        f = float(F[k])
        for _ in range(8):
            a1 = acc(xk, vk, f)
            a2 = acc(xk + h / 2 * vk, vk + h / 2 * a1, f)
            a3 = acc(xk + h / 2 * (vk + h / 2 * a1), vk + h / 2 * a2, f)
            a4 = acc(xk + h * (vk + h / 2 * a2), vk + h * a3, f)
            xk, vk = (
                xk + h * vk + h * h / 6 * (a1 + a2 + a3),
                vk + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4),
            )
    return lj.Record(x + noise * rng.standard_normal(n), F, DT)


@pytest.fixture(scope="module")
def cogging():
    period = 0.0023
    return _record(1, 0.08, period), _record(2, 0.08, period), period


def test_periodic_lookalike_against_the_cogging_candidate(cogging):
    """The look-alike's period within 1 % of the drawn one, and its validated mean square equal
    (within 2 %) to that of a second implementation of the same model: the public
    ``Cogging`` candidate of examples/custom_effects.py (sine and cosine of 2πx/p as
    ForceEffect columns, p profiled on its own grid and refined), fitted alone on the baseline."""
    import pathlib
    import sys

    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "examples"))
    from custom_effects import Cogging

    train, valid, period = cogging
    d = lj.diagnose(train, valid)
    look = d.final["periodic_lookalike"]
    assert look["period"] == pytest.approx(period, rel=0.01)
    assert d.stack == []  # the look-alike was fitted on the baseline structure
    ms_look = look["ratio"] * d.final["equation_gap"] ** 2
    lib = lj.diagnosis.DEFAULT_CANDIDATES + (Cogging(),)
    c = next(e for e in lj.diagnose(train, valid, candidates=lib).effects if e.name == "cogging")
    assert c.params["period"] == pytest.approx(period, rel=0.01)
    assert ms_look == pytest.approx(c.equation_gap**2, rel=0.02)


def test_cogging_is_unexplained_with_its_period(cogging):
    """A force periodic in position is not in the library: the record is ``unexplained``, and
    ``where`` names the period (within 1 %). (Clean records stay ``none``: test_diagnose.)"""
    train, valid, period = cogging
    d = lj.diagnose(train, valid)
    assert d.verdict == "unexplained", (d.verdict, d.stack)
    assert d.final["periodic_lookalike"]["significant"]
    found = [w for w in d.where if w["kind"] == "position_period"]
    assert found and found[0]["period"] == pytest.approx(period, rel=0.01)


def test_a_periodic_force_the_stack_left_below_its_own_floor_is_seen():
    """Cogging near the noise floor, closed loop (twin of the blind benchmark, 1.9 kHz, error
    1.34× the floor): Coulomb friction scored 15.5 and lowered the fitted floor to its own
    error, so it left no excess; the periodic look-alike fitted on it scored 193 but took a
    share of nothing, and `coulomb_friction` was named at 0.94. The look-alike's validated fit
    bounds the floor too: the stack is `unexplained`, and the look-alike's period is the
    simulator's within 2 %."""
    import diagnosis_blind as blind  # benchmarks/ (tests/conftest.py)

    train, valid, info = blind.make_case("cogging", 110110016, source="twin")
    d = lj.diagnose(train, valid)
    assert d.verdict == "unexplained", (d.verdict, d.confidence, d.stack)
    look = d.final["periodic_lookalike"]
    assert look["significant"] and look["score"] > 40
    period = info["effects"][0]["params"]["period"]
    assert look["period"] == pytest.approx(period, rel=0.02)


@pytest.mark.parametrize(
    "cls, source, seed, name",
    [
        ("spring_dominant", "twin", 180140001, "spring"),
        ("stiction_dominant", "twin", 180150019, "coulomb_friction"),
    ],
)
def test_a_periodic_remainder_beside_a_dominant_effect_does_not_overrule_it(
    cls, source, seed, name
):
    """A dominant spring (65 Hz above a 40 Hz filter corner, closed loop) and dominant Stribeck
    stiction (open loop): the library's effect removes 99 % and 99.96 % of the excess, and a
    sine in position fitted on what it leaves scored 163 and 51 (above 4× the threshold) but
    held 0.12 and 0.23 of the stack's evidence. They were ``unexplained`` at 0.63 and 0.94; the
    remainder is reported, the effect named (the spring's k within 1 % of the simulator's). With
    the filter corner moved up to a dominant oscillation the spring leaves no periodic remainder
    that scores: only the stiction's is left to weigh."""
    import diagnosis_blind as blind  # benchmarks/ (tests/conftest.py)

    train, valid, info = blind.make_case(cls, seed, source=source)
    d = lj.diagnose(train, valid)
    assert d.verdict == name, (d.verdict, d.confidence, d.stack)
    look = d.final["periodic_lookalike"]
    assert not look["significant"]
    if name == "spring":
        # the spring's remainder, once the filter corner moves up to its frequency, holds no
        # periodic force worth a look-alike: it scores below the threshold, or is not fitted
        # where the stack maps its input (a delay of −¼ sample, which the twin's record does not
        # hold, stacks third here; the look-alike is fitted with no input map)
        assert ("delay" in d.stack and look["score"] is None) or look["score"] < 10
    else:
        # where one scores, it does not overrule the effect
        held = sum(s.score for s in d.steps)
        assert 40 < look["score"] < 0.5 * held
    if name == "spring":
        assert d.final["params"]["k"] == pytest.approx(info["effects"][0]["params"]["k"], rel=0.01)
