"""Time `lionjax.diagnose` on a fixed set of records, compiled and warm.

Ten records of the blind generator (diagnosis_blind.py: both sources, open and closed loop, one
or two effects or none; padded lengths 4096–16384 — regression cases of the test suite),
diagnosed twice in one process: the first pass includes every compilation (as a test suite or a
first call sees it), the second runs compiled programs only (as a study of many records of the
same lengths sees it). Prints both times and a fingerprint of the verdicts (verdict, confidence,
stack, scores to 4 digits), so that two checkouts can be compared on the same machine:

    PYTHONPATH=<checkout> python <checkout>/benchmarks/diagnosis_speed.py

(float64, XLA's elemental CPU emitters as the test suite uses them: tests/conftest.py).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time

#: (class, seed, source) of the timed records (test cases of tests/test_diagnose_*.py).
CASES = (
    ("coulomb_friction", 2011002, "scipy"),
    ("saturation", 4061003, "scipy"),
    ("none", 6001004, "scipy"),
    ("delay", 16051000, "scipy"),
    ("flexible_mode", 15081000, "scipy"),
    ("spring+delay", 6100003, "twin"),
    ("asymmetric_friction", 8020001, "twin"),
    ("flexible_mode", 12080000, "twin"),
    ("position_dependent", 771017, "scipy"),
    ("coulomb_friction+offset", 14090009, "twin"),
)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--passes", type=int, default=2, help="diagnoses of each record (default 2)")
    p.add_argument("--json", help="write the times and verdicts here")
    args = p.parse_args(argv)
    if args.passes < 1:
        p.error(f"--passes must be >= 1, got {args.passes}")
    flag = "--xla_cpu_use_fusion_emitters=false"
    if flag not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + flag).strip()
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import jax

    jax.config.update("jax_enable_x64", True)
    import diagnosis_blind as blind

    import lionjax as lj

    records = [blind.make_case(c, s, source=src) for c, s, src in CASES]
    times, verdicts = [], []
    for k in range(args.passes):
        t0 = time.perf_counter()
        verdicts = []
        for train, valid, _ in records:
            d = lj.diagnose(train, valid)
            scores = [round(e.score, 4) for e in d.effects]
            verdicts.append((d.verdict, round(d.confidence, 6), list(d.stack), scores))
        times.append(time.perf_counter() - t0)
        print(f"pass {k + 1}: {times[-1]:.1f} s", flush=True)
    fp = hashlib.sha256(json.dumps(verdicts).encode()).hexdigest()[:16]
    print(f"lionjax {lj.__file__}\nverdicts fingerprint {fp}")
    for (c, s, src), v in zip(CASES, verdicts, strict=True):
        print(f"  {src:5s} {c:24s} {s:9d}: {v[0]} ({v[1]:.3f}) stack {v[2]}")
    out = {"seconds": times, "fingerprint": fp, "verdicts": verdicts, "lionjax": lj.__file__}
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return out


if __name__ == "__main__":
    main()
