"""Blind evaluation of ``lionjax.diagnose`` on twin records with a withheld effect (GUIDE §7).

For each class (none, the six library effects, two two-effect classes, and a flexible mode that is
outside the library) it draws records with a random plant (a ∈ [10, 40] 1/s, b ∈ [0.5, 3] 1/kg),
random excitation (multisine, chirp or PRBS; random amplitude and band), random sensor noise
(encoder quantisation 1–10 µm, position noise 0–3 µm), open or closed loop (centring PD), a random
effect magnitude, and a train and a validation record with different excitation seeds. The
effect's size is reported as the relative change of the velocity response, ‖v − v₀‖/‖v₀‖, with
v₀ the same record simulated without the effect (the draws target roughly 2–80 %).
``diagnose`` sees only (t, x, F). Reported: the confusion matrix, top-1 accuracy on single
effects, two-effect detection, out-of-library → ``unexplained``, false alarms on clean records and
the shrink error against an oracle (the true effect's structure fitted by the same machinery).

    python benchmarks/diagnosis_blind.py --per-class 20 --json blind.json
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import lionjax as lj  # noqa: E402
import lionjax.twin as tw  # noqa: E402
from lionjax._diagnose import DEFAULT_CANDIDATES  # noqa: E402
from lionjax._diagnose._core import _Fitter, settings  # noqa: E402

SINGLE = ("coulomb_friction", "offset", "spring", "delay", "saturation", "position_dependent")
CLASSES = ("none", *SINGLE, "coulomb_friction+offset", "spring+delay", "flexible_mode")
DT = 1e-3


def _excitation(rng, key, amp, duration, two_level_ok=True):
    kinds = ["multisine", "chirp", "prbs"] if two_level_ok else ["multisine", "chirp"]
    kind = rng.choice(kinds)
    if kind == "multisine":
        n = int(rng.integers(4, 10))
        f = np.sort(rng.uniform(0.3, 12.0, n))
        return tw.multisine(f, amp / math.sqrt(n / 2), key=key), kind
    if kind == "chirp":
        return tw.Chirp(amp, rng.uniform(0.2, 1.0), rng.uniform(6.0, 15.0), duration), kind
    return tw.PRBS(amp * 0.7, float(rng.choice([0.02, 0.04, 0.08])), key, order=8), kind


def _effects(cls, rng, a, b, amp, closed):
    M = 1 / b
    out = []
    for name in cls.split("+"):
        if name == "coulomb_friction":
            out.append(tw.CoulombFriction(amp * rng.uniform(0.06, 0.4)))
        elif name == "offset":
            out.append(tw.ForceOffset(amp * rng.uniform(0.08, 0.5) * rng.choice([-1, 1])))
        elif name == "spring":
            k = M * (2 * math.pi * rng.uniform(1.0, 4.0)) ** 2
            out.append(tw.LinearSpring(k, rng.uniform(-0.004, 0.004)))
        elif name == "delay":
            out.append(tw.InputDelay(rng.uniform(3e-3, 15e-3)))
        elif name == "saturation":
            out.append(tw.HardSaturation(amp * rng.uniform(0.45, 0.8)))
        elif name == "position_dependent":
            s = rng.choice([-1, 1], 2)
            out.append(
                tw.PositionDependence(
                    alpha_a=s[0] * rng.uniform(0.2, 0.6),
                    alpha_b=s[1] * rng.uniform(0.2, 0.6),
                    length=0.004 if closed else 0.02,
                )
            )
        elif name == "flexible_mode":
            out.append(
                tw.FlexibleMode(
                    M * rng.uniform(0.2, 0.6), rng.uniform(6.0, 20.0), rng.uniform(0.03, 0.15)
                )
            )
    return out


def make_case(cls: str, seed: int, duration: float = 4.0):
    """(train, valid, info) for one blind record of class ``cls``."""
    rng = np.random.default_rng(seed)
    a, b = rng.uniform(10, 40), rng.uniform(0.5, 3.0)
    closed = bool(rng.random() < 0.5)
    amp = rng.uniform(1.0, 4.0)
    effects = _effects(cls, rng, a, b, amp, closed)
    sensors = [tw.EncoderQuantisation(rng.uniform(1e-6, 10e-6))]
    if rng.random() < 0.5:
        sensors.append(tw.PositionNoise(rng.uniform(0.2e-6, 3e-6)))
    plant0 = tw.Plant(a, b, (), sensors)
    plant = plant0.with_effects(*effects)
    loop = tw.CentringPD(kp=rng.uniform(100, 300) / b / 2, kd=rng.uniform(0.5, 2.0) / b / 2)
    n = int(round(duration / DT)) + 1
    recs, kinds, change = [], [], []
    for j in range(2):
        key = jax.random.key(seed * 7 + j)
        # a two-level open-loop input makes a saturation a mere gain change (unidentifiable)
        exc, kind = _excitation(rng, key, amp, duration, closed or "saturation" not in cls)
        kw = dict(n_samples=n, key=key, closed_loop=loop if closed else None)
        rec = tw.simulate(plant, exc, dt=DT, **kw)
        ref = tw.simulate(plant0, exc, dt=DT, **kw)
        v, v0 = np.asarray(rec.extras["v_true"]), np.asarray(ref.extras["v_true"])
        change.append(float(np.linalg.norm(v - v0) / max(np.linalg.norm(v0), 1e-12)))
        recs.append(lj.Record(rec.x, rec.F, rec.dt))
        kinds.append(kind)
    info = {
        "class": cls,
        "seed": seed,
        "closed_loop": closed,
        "excitation": kinds,
        "a": a,
        "b": b,
        "response_change": change[1],
    }
    return recs[0], recs[1], info


def _oracle_shrink(train, valid, cls):
    """Shrink of the windowed simulation gap when the true effect's structure is fitted."""
    names = [n for n in cls.split("+") if n in SINGLE]
    if not names:
        return None
    st = settings(train)
    f = _Fitter(train, valid, st)
    by = {c.name: c for c in DEFAULT_CANDIDATES}
    base = f.fit([])
    fit = f.fit([by[n] for n in names])
    return 1 - fit.gap / base.gap


def run(per_class: int = 20, seed0: int = 0, classes=CLASSES, duration: float = 4.0) -> dict:
    rows = []
    for ci, cls in enumerate(classes):
        for i in range(per_class):
            seed = seed0 + 1000 * ci + i
            train, valid, info = make_case(cls, seed, duration)
            t0 = time.perf_counter()
            d = lj.diagnose(train, valid)
            info["seconds"] = time.perf_counter() - t0
            info.update(verdict=d.verdict, stack=d.stack, shrink=d.final["shrink"])
            info["oracle_shrink"] = _oracle_shrink(train, valid, cls)
            rows.append(info)
    return summarise(rows, classes)


def summarise(rows, classes=CLASSES) -> dict:
    labels = ["none", *SINGLE, "unexplained"]
    conf = {c: {lab: 0 for lab in labels} for c in classes}
    for r in rows:
        conf[r["class"]][r["verdict"] if r["verdict"] in labels else "unexplained"] += 1
    single = [r for r in rows if r["class"] in SINGLE]
    top1 = np.mean([r["verdict"] == r["class"] for r in single]) if single else math.nan
    two = [r for r in rows if "+" in r["class"]]
    both = np.mean([set(r["class"].split("+")) <= set(r["stack"]) for r in two]) if two else None
    ool = [r for r in rows if r["class"] == "flexible_mode"]
    ool_ok = np.mean([r["verdict"] == "unexplained" for r in ool]) if ool else None
    clean = [r for r in rows if r["class"] == "none"]
    fa = np.mean([r["verdict"] != "none" for r in clean]) if clean else None
    err = [abs(r["shrink"] - r["oracle_shrink"]) for r in rows if r["oracle_shrink"] is not None]
    return {
        "confusion": conf,
        "top1_single": float(top1),
        "two_effect_both_named": None if both is None else float(both),
        "out_of_library_unexplained": None if ool_ok is None else float(ool_ok),
        "false_alarm_clean": None if fa is None else float(fa),
        "shrink_error_vs_oracle": {
            "median": float(np.median(err)) if err else None,
            "max": float(np.max(err)) if err else None,
        },
        "response_change": {
            c: [
                float(np.min([r["response_change"] for r in rows if r["class"] == c])),
                float(np.max([r["response_change"] for r in rows if r["class"] == c])),
            ]
            for c in classes
            if c != "none" and any(r["class"] == c for r in rows)
        },
        "seconds_per_record": float(np.mean([r["seconds"] for r in rows])),
        "records": rows,
        "versions": {
            "jax": jax.__version__,
            "python": platform.python_version(),
            "machine": platform.machine(),
        },
    }


def print_summary(out: dict) -> None:
    conf = out["confusion"]
    labels = list(next(iter(conf.values())))
    short = {lab: lab[:6] for lab in labels}
    print("true \\ verdict".ljust(26) + " ".join(short[lab].rjust(7) for lab in labels))
    for c, row in conf.items():
        print(c.ljust(26) + " ".join(str(row[lab]).rjust(7) for lab in labels))
    for k in (
        "top1_single",
        "two_effect_both_named",
        "out_of_library_unexplained",
        "false_alarm_clean",
        "shrink_error_vs_oracle",
        "seconds_per_record",
    ):
        print(f"{k}: {out[k]}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--per-class", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=4.0, help="record length [s]")
    p.add_argument("--json", help="write the results here")
    args = p.parse_args()
    out = run(args.per_class, args.seed, duration=args.duration)
    print_summary(out)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1, default=float)


if __name__ == "__main__":
    main()
