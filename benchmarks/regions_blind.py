"""Blind benchmark of the searched regions (``Diagnosis.regions``) on records with planted regions.

Each case draws a setup as ``diagnosis_blind.py`` does (sample rate 250 Hz – 5 kHz, 4–12 s,
a, b, open or closed loop, excitation, encoder, noise; :func:`diagnosis_blind.draw_setup`) and
plants one effect confined to a known region of the validation record, from one of the two
simulators: the lionjax twin, or ``_blind_sim.py`` (numpy/numba, written without lionjax).
``lj.diagnose`` sees ``lj.Record(x, F, dt)`` of each record and nothing else.

Classes, the planted effect and its true region (a mask over the validation samples; p is the
region's share of the clean validation record's samples, uniform in :data:`SHARE`):

    none            no effect                                                 (no region)
    saturation      the command clipped at ±F_max, F_max the clean record's
                    (1 − p)-quantile of |F|                                   |F| > F_max
    dead_zone       the command's dead zone: u = 0 for |F| ≤ d, F − d·sgn F
                    beyond, d the clean record's p-quantile of |F|            |F| < d
    friction_spot   Coulomb friction F_c·sgn ẋ only on [x₁, x₂], a stretch
                    holding p of the clean record's positions               x₁ ≤ x ≤ x₂
    position_step   b changed by the factor 1 + α on one side of a boundary
                    x_b (a = C/M kept), the side holding p                   x > x_b or x < x_b
    payload         a mass μ·M fixed to the axis at t_p = (1 − p)·T on the
                    validation record (train has none): a, b scaled 1/(1+μ)   t ≥ t_p
    drift           a force r·(t − t_r)₊ on the axis from t_r = (1 − p)·T on
                    the validation record (train has none)                    t ≥ t_r

The level that bounds a region (F_max, d, x₁ and x₂, x_b) is set from the quantiles of the
record with the effect, re-anchored twice (an effect moves x and, in closed loop, F), so that the
region holds p of its samples; a draw whose region ends outside :data:`TRUE_SHARE` or whose size
misses the band is drawn again (up to :data:`DRAWS` times, then kept and flagged). Saturation and
the dead zone are hard maps; their size follows from p. The others' strength s (F_c = s·F_rms;
α = ±s; μ = s; r·(T − t_r) = ±s·F_rms) is sized so that the response change
c = ‖v − v₀‖/‖v₀‖ of the validation record (v its true velocity, v₀ the same run without the
effect) lies in :data:`BAND`: drawn from its prior up to four times, then bisected in log s
(eight more tries).

The twin has no time-varying effect and no position-gated friction, so its payload is simulated
in two pieces (the second, with a and b scaled, starting from the true state at t_p; in closed
loop the PD's velocity restarts at 0 there, a one-sample glitch), its drift is a force effect
with a clock state, and its friction spot is a smooth friction F_c·tanh(ẋ/ε)·[x₁ ≤ x ≤ x₂]
(ε = 2 % of the clean RMS velocity). ``_blind_sim`` simulates all of them exactly (switched
friction gated by position, a and b switched at the sample t_p, the drift held per sample).

A reported region covers the samples of the validation record whose variable lies in
[low, high] (read from the JSON alone, ends included). Scores (IoU on the validation samples,
mask against mask):

- hit: some reported region has IoU ≥ 0.5 with the true region (also given: the strongest one
  does);
- the IoU of the best-matching region (0 where none is reported), its median per class;
- the false-region rate: clean records with any region (the calibration: ≤ α expected);
- the added time: per case, t_regions / (t_diagnose − t_regions), the time the region search
  takes inside ``lj.diagnose`` over the diagnosis without it (its median over the cases).

Seeds: case i of class c and source s uses seed0 + 10000·c + 1000·s + i (``CLASSES``,
``SOURCES`` indices). Develop on ``--seed 0``; report once on a fresh range.

    python benchmarks/regions_blind.py --per-class 20 --clean 100 --seed 3000000 --json out.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
import traceback

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _blind_sim as bs  # noqa: E402
import diagnosis_blind as db  # noqa: E402

SOURCES = ("twin", "scipy")
CLASSES = (
    "none",
    "saturation",
    "dead_zone",
    "friction_spot",
    "position_step",
    "payload",
    "drift",
)
#: the variable each class' region lies in
VARIABLE = {
    "saturation": "|F|",
    "dead_zone": "|F|",
    "friction_spot": "x",
    "position_step": "x",
    "payload": "t",
    "drift": "t",
}
#: the true region's share of the clean validation record's samples
SHARE = (0.15, 0.5)
#: the response-change band of the sized classes (diagnosis_blind's band)
BAND = (0.02, 0.80)
#: (prior, hard limits) of the strength s per sized class
PRIOR = {
    "friction_spot": ((0.02, 0.6), (0.002, 3.0)),
    "position_step": ((0.05, 0.8), (0.005, 0.9)),
    "payload": ((0.05, 1.0), (0.005, 5.0)),
    "drift": ((0.05, 1.0), (0.005, 10.0)),
}
HIT_IOU = 0.5


def _logu(rng, lo, hi):
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


# ------------------------------------------------------------------------------------- twin


_TWIN = None


def _twin_classes():
    """The twin's force effects for the friction spot and the drift (built lazily)."""
    global _TWIN
    if _TWIN is not None:
        return _TWIN
    import jax.numpy as jnp

    import lionjax.twin as tw

    class FrictionSpot(tw.AbstractForceEffect):
        """Smooth Coulomb friction on [x₁, x₂] only: −F_c·tanh(ẋ/ε)·[x₁ ≤ x ≤ x₂] [N]."""

        fc: object
        eps: object
        x1: object
        x2: object

        def __init__(self, fc, eps, x1, x2):
            self.fc, self.eps = jnp.asarray(fc), jnp.asarray(eps)
            self.x1, self.x2 = jnp.asarray(x1), jnp.asarray(x2)

        def force(self, x, v, z):
            on = (x >= self.x1) & (x <= self.x2)
            return jnp.where(on, -self.fc * jnp.tanh(v / self.eps), 0.0)

    class Drift(tw.AbstractForceEffect):
        """A force r·(t − t_r)₊ [N]; t is the effect's one state (a clock: ż = 1, z(0) = 0)."""

        n_states = 1
        rate: object
        t_r: object

        def __init__(self, rate, t_r):
            self.rate, self.t_r = jnp.asarray(rate), jnp.asarray(t_r)

        def init_states(self, x0, v0):
            return jnp.zeros(1, jnp.result_type(x0, float))

        def force(self, x, v, z):
            return self.rate * jnp.maximum(z[0] - self.t_r, 0.0)

        def states_rhs(self, x, v, z):
            return jnp.ones_like(z)

    _TWIN = {"friction_spot": FrictionSpot, "drift": Drift}
    return _TWIN


def _twin_run(st, a, b, bounds, effects, exc, key, n_sub, x0=0.0, v0=0.0):
    import jax

    import lionjax.twin as tw

    sensors = [tw.EncoderQuantisation(st.q)]
    if st.noise > 0:
        sensors.append(tw.PositionNoise(st.noise))
    plant = tw.Plant(a, b, bounds, [*effects, *sensors])
    loop = tw.CentringPD(*st.pd()) if st.closed else None
    rec = tw.simulate(
        plant,
        exc,
        dt=st.dt,
        key=jax.random.key(key),
        closed_loop=loop,
        n_substeps=n_sub,
        x0=x0,
        v0=v0,
    )
    ex = rec.extras
    return (
        np.asarray(rec.x),
        np.asarray(rec.F),
        np.asarray(ex["x_true"]),
        np.asarray(ex["v_true"]),
    )


def _simulate_twin(st, cls, prm, j):
    import lionjax.twin as tw

    exc, key = st.exc[j], st.noise_seeds[j]
    a, b, bounds, eff, n_sub = st.a, st.b, (), [], 1
    timed = cls in ("payload", "drift")
    if cls == "saturation":
        eff.append(tw.HardSaturation(prm["f_max"]))
    elif cls == "dead_zone":
        eff.append(db._twin_classes()["dead_zone"](prm["d"]))
    elif cls == "friction_spot":
        eff.append(_twin_classes()["friction_spot"](prm["fc"], prm["eps"], prm["x1"], prm["x2"]))
        # the smooth sign's stiffness b·F_c/ε: h·rate ≤ 0.5, at most 32 steps (as diagnosis_blind)
        rate = st.b * prm["fc_max"] / prm["eps"]
        n_sub = max(1, min(int(math.ceil(st.dt * rate / 0.5)), 32))
    elif cls == "position_step":
        lo, hi = (
            (st.b, st.b * (1 + prm["alpha"]))
            if prm["side"] > 0
            else (
                st.b * (1 + prm["alpha"]),
                st.b,
            )
        )
        a, b, bounds = (st.a, st.a), (lo, hi), (prm["x_b"],)
    elif cls == "drift" and j == 1:
        eff.append(_twin_classes()["drift"](prm["rate"], prm["t_r"]))
    if cls == "payload" and j == 1:
        kp = int(math.ceil(prm["t_p"] / st.dt - 1e-9))
        x1, F1, xt1, vt1 = _twin_run(st, a, b, bounds, eff, exc[: kp + 1], key, n_sub)
        k = 1 / (1 + prm["mu"])
        x2, F2, xt2, vt2 = _twin_run(
            st, a * k, b * k, bounds, eff, exc[kp:], key + 1, n_sub, xt1[-1], vt1[-1]
        )
        cat = lambda u, w: np.concatenate([u[:kp], w])  # noqa: E731
        return cat(x1, x2), cat(F1, F2), cat(xt1, xt2), cat(vt1, vt2)
    del timed
    return _twin_run(st, a, b, bounds, eff, exc, key, n_sub)


def _simulate_scipy(st, cls, prm, j):
    eff = []
    if cls == "saturation":
        eff.append(bs.HardSaturation(prm["f_max"]))
    elif cls == "dead_zone":
        eff.append(bs.DeadZone(prm["d"]))
    elif cls == "friction_spot":
        eff.append(bs.FrictionSpot(prm["fc"], prm["x1"], prm["x2"]))
    elif cls == "position_step":
        eff.append(bs.PositionDependence(0.0, prm["alpha"], float(prm["side"]), prm["x_b"], "step"))
    elif cls == "payload" and j == 1:
        eff.append(bs.Payload(prm["mu"], prm["t_p"]))
    elif cls == "drift" and j == 1:
        eff.append(bs.DeviceDrift(prm["rate"], prm["t_r"]))
    loop = None
    if st.closed:
        kp, kd = st.pd()
        loop = bs.PDLoop(kp, kd, st.fv_loop)
    r = bs.simulate(
        bs.Axis(st.a, st.b, tuple(eff)),
        st.exc[j],
        st.fs,
        loop=loop,
        q=st.q,
        noise_std=st.noise,
        seed=st.noise_seeds[j],
    )
    return r.x, r.F, r.x_true, r.v_true


def simulate(st, cls, prm, j):
    """(x, F, x_true, v_true) of record j (0 train, 1 valid) of class ``cls`` with ``prm``."""
    if cls == "none":
        return db.simulate(st, [], j)
    return (_simulate_twin if st.source == "twin" else _simulate_scipy)(st, cls, prm, j)


# ------------------------------------------------------------------------------------- cases


class Plant:
    """One case's planted effect: its class, the region's share p, and the level that bounds the
    region (set from the quantiles of a record, :meth:`anchor`), as parameters of a strength s."""

    def __init__(self, cls, rng, st, clean):
        self.cls, self.st = cls, st
        x0, F0, xt0, v0 = clean
        self.p = float(rng.uniform(*SHARE))
        self.F_rms = float(np.sqrt(np.mean(F0**2)))
        self.T = (st.n - 1) * st.dt
        self.q1 = float(rng.uniform(0.03, 0.97 - self.p))  # the friction spot's lower quantile
        self.side = float(rng.choice([-1.0, 1.0]))  # the position step's changed side
        self.sign = float(rng.choice([-1.0, 1.0]))  # the sign of α or of the drift
        self.eps = 0.02 * float(np.sqrt(np.mean(v0**2)))
        self.level = {}
        self.anchor(clean)

    def anchor(self, run) -> None:
        """Set the region's level so that it holds p of ``run``'s samples (valid record)."""
        _, F, xt, _ = run
        p, aF = self.p, np.abs(F)
        if self.cls == "saturation":
            self.level = {"f_max": float(np.quantile(aF, 1 - p))}
        elif self.cls == "dead_zone":
            self.level = {"d": float(np.quantile(aF, p))}
        elif self.cls == "friction_spot":
            x1, x2 = np.quantile(xt, [self.q1, self.q1 + p])
            self.level = {"x1": float(x1), "x2": float(x2)}
        elif self.cls == "position_step":
            self.level = {"x_b": float(np.quantile(xt, 1 - p if self.side > 0 else p))}

    def params(self, s) -> dict:
        c, lv = self.cls, self.level
        if c in ("saturation", "dead_zone"):
            return dict(lv)
        if c == "friction_spot":
            hi = PRIOR[c][1][1] * self.F_rms
            return {"fc": s * self.F_rms, "eps": self.eps, "fc_max": hi, **lv}
        if c == "position_step":
            return {"alpha": self.sign * s, "side": self.side, **lv}
        if c == "payload":
            return {"mu": s, "t_p": (1 - self.p) * self.T}
        if c == "drift":
            t_r = (1 - self.p) * self.T
            return {"rate": self.sign * s * self.F_rms / (self.p * self.T), "t_r": t_r}
        raise ValueError(f"unknown class {c!r}; expected one of {CLASSES}")


def _size(st, plant, rng, v0):
    """The strength s whose validation response change lies in BAND (or the nearest tried),
    the change, the tries, and whether it lies in the band."""
    cls = plant.cls
    (prior, limits), (lo, hi) = PRIOR[cls], BAND
    tried = []

    def attempt(s):
        v = simulate(st, cls, plant.params(s), 1)[3]
        tried.append((s, db._change(v, v0)))
        return lo <= tried[-1][1] <= hi

    ok = any(attempt(_logu(rng, *prior)) for _ in range(4))
    for _ in range(0 if ok else 8):
        below = [s for s, c in tried if c < lo]
        above = [s for s, c in tried if not c <= hi]
        if below and above:
            s = math.sqrt(max(below) * min(above))
        elif below:
            s = min(max(below) * 3.0, limits[1])
        else:
            s = max(min(above) / 3.0, limits[0])
        if any(abs(s - t) <= 1e-12 * s for t, _ in tried):
            break
        if attempt(s):
            ok = True
            break
    if ok:
        return (*tried[-1], len(tried), True)
    mid = math.sqrt(lo * hi)
    s, c = min(tried, key=lambda t: abs(math.log(max(min(t[1], 1e6), 1e-12) / mid)))
    return s, c, len(tried), False


#: draws of a case (its share, level and strength) before one outside the aims is kept
DRAWS = 4
#: re-anchorings of the level on the effect's own record (an effect moves the record's x and,
#: in closed loop, its F, so a level set on the clean record holds another share)
ANCHORS = 2
#: the share of the validation samples the true region must hold (else the case is redrawn):
#: at most half, as a region is the minority regime (lionjax/diagnosis/_regions.py)
TRUE_SHARE = (0.08, 0.5)


def _plant(cls, rng, st, clean):
    """A planted effect sized and anchored: (plant, strength, sizing info, valid run)."""
    for draw in range(DRAWS):
        plant = Plant(cls, rng, st, clean)
        s, info = math.nan, {}
        if cls in PRIOR:
            s, _, tries, ok = _size(st, plant, rng, clean[3])
            info = {"strength": s, "tries": tries}
        run = simulate(st, cls, plant.params(s), 1)
        for _ in range(
            ANCHORS if cls in ("saturation", "dead_zone", "friction_spot", "position_step") else 0
        ):
            plant.anchor(run)
            run = simulate(st, cls, plant.params(s), 1)
        share = float(np.mean(truth_mask(cls, plant.params(s), run, st.dt)))
        change = db._change(run[3], clean[3])
        info.update(draws=draw + 1, size_in_band=bool(BAND[0] <= change <= BAND[1]))
        if info["size_in_band"] and TRUE_SHARE[0] <= share <= TRUE_SHARE[1]:
            break
    return plant, s, info, run


def truth_mask(cls, prm, valid_sim, dt):
    """The true region over the validation samples (bool, shape (T,)), or None (clean)."""
    x, F, xt, _ = valid_sim
    t = np.arange(x.size) * dt
    if cls == "none":
        return None
    if cls == "saturation":
        return np.abs(F) > prm["f_max"]
    if cls == "dead_zone":
        return np.abs(F) < prm["d"]
    if cls == "friction_spot":
        return (xt >= prm["x1"]) & (xt <= prm["x2"])
    if cls == "position_step":
        return xt > prm["x_b"] if prm["side"] > 0 else xt < prm["x_b"]
    if cls == "payload":
        return t >= prm["t_p"] - 1e-9 * dt
    return t >= prm["t_r"]


def make_case(cls, seed, *, source="twin", rate=(250.0, 5000.0), durations=(4.0, 12.0)):
    """(train, valid, info, truth mask over the validation samples or None)."""
    import lionjax as lj

    rng = np.random.default_rng(seed)
    st = db.draw_setup(rng, source, rate, durations)
    clean = simulate(st, "none", None, 1)
    info = {"class": cls, "source": source, "seed": seed, "fs": st.fs, "dt": st.dt}
    info.update(n_samples=st.n, duration=(st.n - 1) * st.dt, closed_loop=st.closed)
    info.update(a=st.a, b=st.b, q=st.q, noise_std=st.noise, excitation=list(st.exc_info))
    prm, valid = None, clean
    if cls != "none":
        plant, s, sized, valid = _plant(cls, rng, st, clean)
        prm = plant.params(s)
        info.update(share_drawn=plant.p, params=prm, **sized)
    runs = [simulate(st, cls, prm, 0), valid]
    for r in runs:
        if not (np.all(np.isfinite(r[0])) and np.all(np.isfinite(r[1]))):
            raise FloatingPointError("simulation blew up (non-finite record)")
    info["response_change"] = db._change(runs[1][3], clean[3])
    mask = truth_mask(cls, prm, runs[1], st.dt)
    if mask is not None:
        info["true_share"] = float(np.mean(mask))
    recs = [lj.Record(x, F, st.dt) for x, F, _, _ in runs]
    return recs[0], recs[1], info, mask


# ------------------------------------------------------------------------------------- scoring


def region_mask(region, series) -> np.ndarray:
    """The validation samples a reported region covers (its variable within [low, high])."""
    z = _variable(region["variable"], series)
    lo = -np.inf if region["low"] is None else region["low"]
    hi = np.inf if region["high"] is None else region["high"]
    return (z >= lo) & (z <= hi)


def _variable(name, s):
    return {
        "x": s["x"],
        "v": s["v"],
        "|v|": np.abs(s["v"]),
        "F": s["F"],
        "|F|": np.abs(s["F"]),
        "t": s["t"],
    }[name]


def iou(a, b) -> float:
    u = np.count_nonzero(a | b)
    return float(np.count_nonzero(a & b) / u) if u else 0.0


def score_regions(regions, series, mask):
    """IoU of each reported region with the true one, the best, and whether they hit."""
    ious = [iou(region_mask(r, series), mask) for r in regions] if mask is not None else []
    best = max(ious, default=0.0)
    return {
        "ious": ious,
        "best_iou": best,
        "hit": bool(best >= HIT_IOU),
        "hit_first": bool(ious and ious[0] >= HIT_IOU),
    }


def run_case(spec) -> dict:
    """One case: simulate, diagnose, time the regions, score. Never raises."""
    cls, source, seed, kw, dump = spec
    row = {"class": cls, "source": source, "seed": seed}
    t0 = time.perf_counter()
    try:
        train, valid, info, mask = make_case(cls, seed, source=source, **kw)
    except Exception as e:  # a benchmark bug: listed, not scored
        row.update(sim_error=f"{type(e).__name__}: {e}", traceback=traceback.format_exc(limit=4))
        return row
    row.update(info)
    row["seconds_simulate"] = time.perf_counter() - t0
    import lionjax as lj
    from lionjax.diagnosis import find_regions

    t1 = time.perf_counter()
    try:
        d = lj.diagnose(train, valid)
    except Exception as e:
        row.update(crash=f"{type(e).__name__}: {str(e)[:400]}", hit=False, best_iou=0.0)
        row["traceback"] = traceback.format_exc(limit=6)
        return row
    row["seconds"] = time.perf_counter() - t1
    s = d.series
    if mask is not None and mask.size != s["x"].size:
        row.update(sim_error=f"truth mask of {mask.size} samples, series of {s['x'].size}")
        return row
    # the search's own time (it runs inside diagnose: the same inputs, the same work)
    t2 = time.perf_counter()
    final = {"residual_final": s["residual_final"] if d.stack else None}
    again = find_regions(
        {**s, **final}, alpha=d.settings["alpha"], filter_hz=d.settings["filter_hz"]
    )
    row["seconds_regions"] = time.perf_counter() - t2
    regions = d.to_json()["regions"]
    row["regions_repeat_equal"] = [r.to_json() for r in again] == regions
    row["regions"] = regions
    row["verdict"], row["confidence"] = str(d.verdict), float(d.confidence)
    row.update(score_regions(regions, s, mask))
    row["crash"] = None
    if dump:
        keep = {k: np.asarray(s[k]) for k in ("t", "x", "v", "F", "residual_base")}
        keep.update(residual_final=np.asarray(s["residual_final"]))
        keep.update(sim_base=np.asarray(s["sim_base"]), sim_final=np.asarray(s["sim_final"]))
        keep["mask"] = mask if mask is not None else np.zeros(0, bool)
        np.savez_compressed(os.path.join(dump, f"{cls}_{source}_{seed}.npz"), **keep)
    return row


def case_specs(per_class, clean, seed0, classes, sources, kw, dump=None):
    specs = []
    for cls in classes:
        ci = CLASSES.index(cls)
        n = clean if cls == "none" else per_class
        for src in sources:
            si = SOURCES.index(src)
            m = n // len(sources) + (1 if SOURCES.index(src) < n % len(sources) else 0)
            if cls != "none":
                m = n
            for i in range(m):
                specs.append((cls, src, seed0 + 10000 * ci + 1000 * si + i, kw, dump))
    return specs


def _median(v):
    return float(np.median(v)) if len(v) else None


def summarise(rows, classes, alpha) -> dict:
    scored = [r for r in rows if "sim_error" not in r]
    per = {}
    for c in classes:
        rs = [r for r in scored if r["class"] == c]
        if c == "none":
            any_region = [r for r in rs if r.get("crash") is None and r["regions"]]
            n = len(rs)
            k = len(any_region)
            # the one-sided 95 % binomial bound of the count at the level α: k above it says the
            # false-region rate exceeds α
            from scipy.stats import binom

            per[c] = {
                "n": n,
                "with_any_region": k,
                "false_region_rate": k / n if n else None,
                "binomial_95_bound_at_alpha": int(binom.ppf(0.95, n, alpha)) if n else None,
            }
            continue
        by_src = {}
        for src in SOURCES:
            sub = [r for r in rs if r["source"] == src]
            by_src[src] = {"n": len(sub), "hits": int(sum(r["hit"] for r in sub))}
        per[c] = {
            "n": len(rs),
            "hits": int(sum(r["hit"] for r in rs)),
            "hit_rate": float(np.mean([r["hit"] for r in rs])) if rs else None,
            "hit_first_rate": float(np.mean([r.get("hit_first", False) for r in rs]))
            if rs
            else None,
            "median_iou": _median([r["best_iou"] for r in rs]),
            "by_source": by_src,
            "crashes": int(sum(r.get("crash") is not None for r in rs)),
            "size_in_band": int(sum(r.get("size_in_band", True) for r in rs)),
        }
    planted = [r for r in scored if r["class"] != "none"]
    ratio = [
        r["seconds_regions"] / max(r["seconds"] - r["seconds_regions"], 1e-9)
        for r in scored
        if r.get("seconds_regions") is not None
    ]
    extra = [sum(1 for u in r["ious"] if u < HIT_IOU and u < 0.1) for r in planted if r.get("ious")]
    return {
        "per_class": per,
        "median_iou_planted": _median([r["best_iou"] for r in planted]),
        "median_iou_hits": _median([r["best_iou"] for r in planted if r["hit"]]),
        "planted_with_unrelated_region": int(sum(e > 0 for e in extra)),
        "added_time_median": _median(ratio),
        "added_time_p90": float(np.quantile(ratio, 0.9)) if ratio else None,
        "seconds_regions_median": _median(
            [r["seconds_regions"] for r in scored if "seconds_regions" in r]
        ),
        "seconds_diagnose_median": _median([r["seconds"] for r in scored if "seconds" in r]),
        "deterministic": bool(all(r.get("regions_repeat_equal", True) for r in scored)),
        "sim_errors": [
            {k: r[k] for k in ("class", "source", "seed", "sim_error")}
            for r in rows
            if "sim_error" in r
        ],
        "crashes": [
            {k: r[k] for k in ("class", "source", "seed", "crash")}
            for r in scored
            if r.get("crash")
        ],
    }


def _progress(k, n, r):
    head = f"[{k}/{n}] {r['source']:5s} {r['class']:14s} seed={r['seed']}"
    if "sim_error" in r:
        print(f"{head} SIMULATION FAILED: {r['sim_error']}", file=sys.stderr, flush=True)
        return
    if r.get("crash"):
        print(f"{head} CRASH {r['crash'][:100]}", file=sys.stderr, flush=True)
        return
    regs = "; ".join(
        f"{g['variable']} [{g['low']}, {g['high']}] {100 * g['sample_share']:.0f}%"
        for g in r["regions"][:3]
    )
    print(
        f"{head} fs={r['fs']:7.1f} {'closed' if r['closed_loop'] else 'open  '} "
        f"Δv={100 * r['response_change']:5.1f}% share={100 * r.get('true_share', 0):4.1f}% "
        f"IoU={r['best_iou']:.2f} {'HIT' if r['hit'] else '   '} "
        f"({r['seconds']:.1f}s, regions {r['seconds_regions']:.2f}s) {regs}",
        file=sys.stderr,
        flush=True,
    )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--per-class", type=int, default=3, help="cases per planted class and source")
    ap.add_argument("--clean", type=int, default=10, help="clean records (split over sources)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--classes", default=",".join(CLASSES))
    ap.add_argument("--sources", default=",".join(SOURCES))
    ap.add_argument("--json", default=None)
    ap.add_argument("--dump", default=None, help="folder: save each case's series (.npz)")
    args = ap.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    classes = [c for c in args.classes.split(",") if c]
    sources = [s for s in args.sources.split(",") if s]
    for c in classes:
        if c not in CLASSES:
            ap.error(f"unknown class {c!r}; expected some of {CLASSES}")
    if args.dump:
        os.makedirs(args.dump, exist_ok=True)
    kw = {"rate": (250.0, 5000.0), "durations": (4.0, 12.0)}
    specs = case_specs(args.per_class, args.clean, args.seed, classes, sources, kw, args.dump)
    rows, t0 = [], time.perf_counter()
    for k, sp in enumerate(specs, 1):
        rows.append(run_case(sp))
        _progress(k, len(specs), rows[-1])
    import lionjax as lj

    alpha = lj.diagnosis.Criteria().alpha
    out = summarise(rows, classes, alpha)
    out["config"] = {
        "per_class": args.per_class,
        "clean": args.clean,
        "seed0": args.seed,
        "classes": classes,
        "sources": sources,
        "alpha": alpha,
        "band": list(BAND),
        "share": list(SHARE),
        "wall_s": time.perf_counter() - t0,
        "python": platform.python_version(),
        "machine": platform.machine(),
    }
    out["rows"] = rows
    print(json.dumps({k: v for k, v in out.items() if k != "rows"}, indent=1, default=str))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1, default=str)


if __name__ == "__main__":
    main()
