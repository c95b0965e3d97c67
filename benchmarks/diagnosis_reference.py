"""Reference diagnoses: a fixed set of development records, their verdicts kept and compared.

A change of the diagnosis' structure must leave its answers where they were. This script
diagnoses a fixed list of development records and writes, per record, the part of the JSON
that states the answer (verdict, confidence, stack, ambiguous, weights, rivals, every
candidate's score, the steps and the final model's parameters); ``--compare REF.json``
checks a run against a stored one:

- verdict, stack and ambiguous equal;
- confidence within ``--tol`` (absolute, default 1e-6);
- every other number within ``--rtol`` relative (default 1e-6) or ``--tol`` absolute,
  reported (the largest deviations listed) but not failing unless ``--strict``.

The records: one case per class and source of ``diagnosis_blind.py``'s development seeds
(``--seed``, default 0: 20 classes × 2 simulators), the ten timed records of
``diagnosis_speed.py`` (the diagnosis tests' cases) and three 8-s pairs at 5 kHz
(``diagnosis_speed.py --many``'s first three).

    PYTHONPATH=<checkout> python benchmarks/diagnosis_reference.py --json out.json
    PYTHONPATH=<checkout> python benchmarks/diagnosis_reference.py --json new.json --compare out.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def cases(seed0: int) -> list[tuple[str, str, dict]]:
    """(name, kind, spec) of every reference record."""
    import diagnosis_blind as blind
    import diagnosis_speed as speed

    out = []
    for cls in blind.CLASSES:
        ci = blind.CLASSES.index(cls)
        for src in blind.SOURCES:
            seed = seed0 + 10000 * ci + 1000 * blind.SOURCES.index(src)
            out.append((f"{cls}/{src}/{seed}", "blind", {"cls": cls, "seed": seed, "src": src}))
    for cls, seed, src in speed.CASES:
        out.append((f"{cls}/{src}/{seed}", "blind", {"cls": cls, "seed": seed, "src": src}))
    for i in range(3):
        cls = speed.MANY_CLASSES[i % len(speed.MANY_CLASSES)]
        seed = speed.MANY_SEED + i
        spec = {"cls": cls, "seed": seed, "src": "twin", "duration": 8.0, "rate": 5000.0}
        out.append((f"pair{i:03d}/{cls}/{seed}", "pair", spec))
    return list({name: (name, kind, spec) for name, kind, spec in out}.values())


def records(spec: dict):
    import diagnosis_blind as blind

    if "rate" in spec:
        r = spec["rate"]
        return blind.make_case(spec["cls"], spec["seed"], spec["duration"], rate=(r, r))[:2]
    return blind.make_case(spec["cls"], spec["seed"], source=spec["src"])[:2]


def answer(d) -> dict:
    """The part of a diagnosis' JSON that states its answer."""
    j = d.to_json()
    return {
        "verdict": j["verdict"],
        "confidence": j["confidence"],
        "stack": j["stack"],
        "ambiguous": j["ambiguous"],
        "weights": j["weights"],
        "rivals": j["rivals"],
        "effects": {
            e["name"]: {
                "score": e["score"],
                "share": e["share"],
                "significant": e["significant"],
                "plausible": e["plausible"],
                "params": e["params"],
            }
            for e in j["effects"]
        },
        "steps": [[s["name"], s["score"]] for s in j["steps"]],
        "final": {k: j["final"]["params"][k] for k in sorted(j["final"]["params"])},
        "baseline": j["baseline"]["params"],
        "gap": j["baseline"]["gap"],
    }


def _numbers(a, b, path=""):
    """(path, x, y) of every pair of numbers at the same place in two answers."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted((set(a) | set(b)) - {"seconds"}):
            if k in a and k in b:
                yield from _numbers(a[k], b[k], f"{path}.{k}")
            else:
                yield f"{path}.{k}", a.get(k), b.get(k)
    elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            yield from _numbers(x, y, f"{path}[{i}]")
    elif isinstance(a, int | float) and isinstance(b, int | float) and not isinstance(a, bool):
        yield path, float(a), float(b)
    elif a != b:
        yield path, a, b


def compare(new: dict, ref: dict, tol: float, rtol: float) -> dict:
    """Differences of two runs (see the module docstring)."""
    failures, deviations = [], []
    for name in ref:
        if name not in new:
            failures.append(f"{name}: missing")
            continue
        a, b = new[name], ref[name]
        for k in ("verdict", "stack", "ambiguous"):
            if a[k] != b[k]:
                failures.append(f"{name}: {k} {a[k]!r} against {b[k]!r}")
        if not math.isclose(a["confidence"] or 0.0, b["confidence"] or 0.0, abs_tol=tol):
            failures.append(f"{name}: confidence {a['confidence']} against {b['confidence']}")
        for path, x, y in _numbers(a, b):
            if isinstance(x, float) and isinstance(y, float):
                if math.isnan(x) and math.isnan(y):
                    continue
                dev = abs(x - y) / max(abs(y), 1e-300)
                if not math.isclose(x, y, rel_tol=rtol, abs_tol=tol):
                    deviations.append((dev, f"{name}{path}", x, y))
            else:
                deviations.append((math.inf, f"{name}{path}", x, y))
    deviations.sort(key=lambda t: -t[0])
    return {"failures": failures, "deviations": deviations}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", required=True, help="write the answers here")
    p.add_argument("--seed", type=int, default=0, help="blind benchmark seed0 (default 0)")
    p.add_argument("--compare", help="a stored run to compare with")
    p.add_argument("--tol", type=float, default=1e-6)
    p.add_argument("--rtol", type=float, default=1e-6)
    p.add_argument("--strict", action="store_true", help="fail on any number beyond tolerance")
    p.add_argument("--only", help="comma list of substrings of case names to run")
    args = p.parse_args(argv)
    import lionjax as lj

    todo = cases(args.seed)
    if args.only:
        keys = args.only.split(",")
        todo = [c for c in todo if any(k in c[0] for k in keys)]
    out, t0 = {}, time.perf_counter()
    for i, (name, _, spec) in enumerate(todo):
        train, valid = records(spec)
        t1 = time.perf_counter()
        d = lj.diagnose(train, valid)
        out[name] = answer(d) | {"seconds": time.perf_counter() - t1}
        print(
            f"[{i + 1}/{len(todo)}] {name}: {d.verdict} {d.confidence:.4f} {list(d.stack)} "
            f"({out[name]['seconds']:.1f} s)",
            file=sys.stderr,
            flush=True,
        )
    with open(args.json, "w") as f:
        json.dump(lj._tables.jsonable(out), f, indent=1, sort_keys=True)
    print(f"{len(out)} diagnoses in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    if not args.compare:
        return 0
    with open(args.compare) as f:
        ref = json.load(f)
    with open(args.json) as f:
        new = json.load(f)
    if args.only:
        ref = {k: v for k, v in ref.items() if k in new}
    res = compare(new, ref, args.tol, args.rtol)
    for msg in res["failures"]:
        print("FAIL", msg)
    for dev, path, x, y in res["deviations"][:25]:
        print(f"dev {dev:.3g} {path}: {x} against {y}")
    n_dev = len(res["deviations"])
    print(f"{len(res['failures'])} failures, {n_dev} numbers beyond tolerance")
    return 1 if res["failures"] or (args.strict and n_dev) else 0


if __name__ == "__main__":
    sys.exit(main())
