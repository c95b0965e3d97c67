"""Time `lionjax.diagnose` on a fixed set of records, compiled and warm.

Ten records of the blind generator (diagnosis_blind.py: both sources, open and closed loop, one
or two effects or none; padded lengths 4096–16384 — regression cases of the test suite),
diagnosed twice in one process: the first pass includes every compilation (as a test suite or a
first call sees it), the second runs compiled programs only (as a study of many records of the
same lengths sees it). Prints both times and a fingerprint of the verdicts (verdict, confidence,
stack, scores to 4 digits), so that two checkouts can be compared on the same machine:

    PYTHONPATH=<checkout> python <checkout>/benchmarks/diagnosis_speed.py

(float64, XLA's elemental CPU emitters as the test suite uses them: tests/conftest.py).

``--many`` times many pairs of one length instead (float64, XLA's default emitters, as the
command line runs): N pairs of the blind generator, all ``--duration`` s at ``--rate`` Hz, so
they share one length bucket. It reports

- seconds per pair cold (the first pair in the process, with every compilation) and compiled
  (each later pair of the same shapes);
- the same N pairs, after that warm-up, as a loop of ``lj.diagnose`` calls and as one
  ``lj.diagnosis.diagnose_many`` call, in the same process, alternated ``--repeats`` times (the
  least time of each, and the verdicts of both);
- with ``--cli M``: M pairs written to a temporary folder, diagnosed by one
  ``lionjax diagnose --pairs DIR`` process and by M separate ``lionjax diagnose TRAIN --validate
  VALID`` processes (wall time of each arm, one run, each with a fresh compilation cache
  folder, as a user's first run sees it), and whether the verdicts match; ``--no-cache-arm``
  adds the separate processes without the cache (``LIONJAX_NO_COMPILE_CACHE=1``);
- with ``--blas``: the same loop of ``lj.diagnose`` with the host BLAS on one thread (what the
  diagnosis sets) and on the host's default threads, alternated ``--repeats`` times (the least
  of each), and whether the verdicts match;
- with ``--call-sizes``: the same loop with the filter and mode-stage calls capped at
  ``FILTER_SAMPLES`` and ``MODE_SAMPLES`` (lionjax.diagnosis._streaming: what the diagnosis
  does) and uncapped (up to 32 signals or 4 modes per call whatever the chunk), alternated
  ``--repeats`` times (the least of each), and whether the reports are the same bit for bit
  (the caps bind from a chunk of 32768 samples: ``--duration 10 --rate 4000``).

    PYTHONPATH=<checkout> python benchmarks/diagnosis_speed.py --many [--pairs N] [--cli M]

``--lengths N1,N2,…`` measures time and peak memory against the record's length: for each N, a
fresh process diagnoses a pair of N training samples and max(N/5, 4000) validation samples (a
mass–damper with an offset, exact zero-order-hold samples, band-limited noise input, encoder
steps and position noise; ``--rate`` Hz) and reports its wall time (compilation included, as a
first run sees it), its peak RSS, the diagnosis' memory estimate for the pair, and the
verdict; a pair the diagnosis refuses for memory (its estimate above this machine's memory) is
listed with the reason. ``--streamed on|off`` diagnoses every length streamed or in memory
(default ``auto``: as ``lj.diagnose`` chooses, streamed above 2¹⁷ padded samples).

    PYTHONPATH=<checkout> python benchmarks/diagnosis_speed.py --lengths 1e4,1e5,1e6 [--json F]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

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


#: Classes of the --many pairs, in turn (seed MANY_SEED + i for pair i).
MANY_CLASSES = ("none", "offset", "coulomb_friction", "spring", "delay", "saturation")
MANY_SEED = 4100000


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--passes", type=int, default=2, help="diagnoses of each record (default 2)")
    p.add_argument("--json", help="write the times and verdicts here")
    g = p.add_argument_group("many pairs of one length (--many)")
    g.add_argument("--many", action="store_true", help="time many pairs instead (see above)")
    g.add_argument("--pairs", type=int, default=6, help="pairs timed in process (default 6)")
    g.add_argument("--duration", type=float, default=4.0, help="record length [s] (default 4)")
    g.add_argument("--rate", type=float, default=1000.0, help="sampling rate [Hz] (default 1000)")
    g.add_argument(
        "--repeats", type=int, default=2, help="loop and diagnose_many runs, alternated (2)"
    )
    g.add_argument(
        "--call-sizes",
        action="store_true",
        help="also time the loop with the filter and mode calls capped (the default) and not",
    )
    g.add_argument("--cli", type=int, default=0, help="pairs of the CLI comparison (default 0)")
    g.add_argument(
        "--no-cache-arm",
        action="store_true",
        help="also time the separate processes without the compilation cache",
    )
    g.add_argument(
        "--blas",
        action="store_true",
        help="also time the loop with the host's BLAS threads against one thread",
    )
    p.add_argument(
        "--lengths", help="time and peak RSS against training samples N1,N2,… (see above)"
    )
    p.add_argument(
        "--streamed",
        choices=("auto", "on", "off"),
        default="auto",
        help="--lengths: diagnose streamed, in memory, or as lj.diagnose chooses (default)",
    )
    p.add_argument("--one-length", type=float, help=argparse.SUPPRESS)  # a --lengths child
    args = p.parse_args(argv)
    if args.one_length:
        return _one_length(int(args.one_length), args.rate, args.streamed)
    if args.lengths:
        return lengths(args)
    if args.passes < 1:
        p.error(f"--passes must be >= 1, got {args.passes}")
    if args.many:
        if args.pairs < 2:
            p.error(f"--pairs must be >= 2 (a cold pair and a compiled one), got {args.pairs}")
        return many(args)
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


def _pairs(n: int, duration: float, rate: float) -> list:
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import diagnosis_blind as blind

    return [
        (f"pair{i:03d}", *blind.make_case(cls, MANY_SEED + i, duration, rate=(rate, rate))[:2])
        for i, cls in ((i, MANY_CLASSES[i % len(MANY_CLASSES)]) for i in range(n))
    ]


def _key(verdict, confidence, stack) -> tuple:
    return (verdict, None if confidence is None else round(confidence, 6), list(stack))


def many(args) -> dict:
    """The --many mode (module docstring)."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import lionjax as lj

    pairs = _pairs(args.pairs, args.duration, args.rate)
    per_pair = []
    for name, train, valid in pairs:
        t0 = time.perf_counter()
        lj.diagnose(train, valid)
        per_pair.append(time.perf_counter() - t0)
        print(f"{name}: {per_pair[-1]:.2f} s", flush=True)
    compiled = sorted(per_pair[1:])
    t_loop, t_many = [], []
    for _ in range(args.repeats):  # alternated, the least of each: other work on the core
        t0 = time.perf_counter()
        loop = [lj.diagnose(tr, va) for _, tr, va in pairs]
        t_loop.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        rows = lj.diagnosis.diagnose_many(pairs).rows
        t_many.append(time.perf_counter() - t0)
    t_loop, t_many = min(t_loop), min(t_many)
    same = [_key(d.verdict, d.confidence, d.stack) for d in loop] == [
        _key(r.verdict, r.confidence, r.stack) for r in rows
    ]
    out = {
        "mode": "many",
        "pairs": args.pairs,
        "samples": int(pairs[0][1].n_samples),
        "rate_hz": args.rate,
        "cold_s": per_pair[0],
        "compiled_s_median": compiled[len(compiled) // 2],
        "compiled_s": per_pair[1:],
        "repeats": args.repeats,
        "loop_s": t_loop,
        "many_s": t_many,
        "loop_over_many": t_loop / t_many,
        "same_verdicts": same,
        "verdicts": [_key(r.verdict, r.confidence, r.stack) for r in rows],
        "lionjax": lj.__file__,
        "jax": jax.__version__,
        "cpus": sorted(os.sched_getaffinity(0)),
    }
    print(
        f"{out['samples']} samples per record; per pair: cold {out['cold_s']:.2f} s, compiled "
        f"{out['compiled_s_median']:.2f} s (median of {len(compiled)})\n"
        f"{args.pairs} pairs after a warm-up: loop of lj.diagnose {t_loop:.2f} s, diagnose_many "
        f"{t_many:.2f} s (loop/many {out['loop_over_many']:.2f}), same verdicts: {same}"
    )
    if args.blas:
        out["blas"] = _blas_threads(pairs, lj, args.repeats)
    if args.call_sizes:
        out["call_sizes"] = _call_sizes(pairs, lj, args.repeats)
    if args.cli:
        out["cli"] = _cli(_pairs(args.cli, args.duration, args.rate), lj, args.no_cache_arm)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return out


def _alternated(pairs: list, lj, repeats: int, module, arms: dict) -> tuple[dict, dict]:
    """The compiled loop of ``lj.diagnose`` over ``pairs`` under each arm {name: {attribute:
    value}} of ``module``'s settings, the arms alternated ``repeats`` times (other work on the
    core), the settings restored after each: ({name: the least seconds}, {name: the diagnoses
    of its last loop})."""
    kept = {k: getattr(module, k) for values in arms.values() for k in values}
    times: dict = {name: [] for name in arms}
    last: dict = {}
    for _ in range(repeats):
        for name, values in arms.items():
            for k, v in values.items():
                setattr(module, k, v)
            try:
                t0 = time.perf_counter()
                last[name] = [lj.diagnose(tr, va) for _, tr, va in pairs]
                times[name].append(time.perf_counter() - t0)
            finally:
                for k, v in kept.items():
                    setattr(module, k, v)
    return {name: min(t) for name, t in times.items()}, last


def _blas_threads(pairs: list, lj, repeats: int) -> dict:
    """The compiled loop of ``lj.diagnose`` over ``pairs`` with the host BLAS on one thread (the
    diagnosis' setting, ``lionjax.diagnosis._core.BLAS_THREADS``) and on the host's default,
    alternated ``repeats`` times: the least of each, and whether the verdicts match."""
    from lionjax.diagnosis import _core

    arms = {"one": {"BLAS_THREADS": 1}, "default": {"BLAS_THREADS": None}}
    t, ds = _alternated(pairs, lj, repeats, _core, arms)
    keys = {a: [_key(d.verdict, d.confidence, d.stack) for d in ds[a]] for a in arms}
    out = {
        "one_thread_s": t["one"],
        "default_threads_s": t["default"],
        "same_verdicts": keys["one"] == keys["default"],
    }
    out["default_over_one"] = out["default_threads_s"] / out["one_thread_s"]
    print(
        f"{len(pairs)} pairs, BLAS on one thread {out['one_thread_s']:.2f} s, on the host's "
        f"default {out['default_threads_s']:.2f} s (default/one {out['default_over_one']:.2f}), "
        f"same verdicts: {out['same_verdicts']}"
    )
    return out


def _call_sizes(pairs: list, lj, repeats: int) -> dict:
    """The compiled loop of ``lj.diagnose`` over ``pairs`` with the filter and mode-stage calls
    capped (the diagnosis' setting) and uncapped, alternated ``repeats`` times: the least of
    each, and whether the reports (their whole JSON) are the same bit for bit."""
    from lionjax.diagnosis import _streaming

    capped = {"FILTER_SAMPLES": _streaming.FILTER_SAMPLES, "MODE_SAMPLES": _streaming.MODE_SAMPLES}
    arms = {"capped": capped, "uncapped": dict.fromkeys(capped, 1 << 62)}
    t, ds = _alternated(pairs, lj, repeats, _streaming, arms)
    prints = {
        a: hashlib.sha256(
            json.dumps([d.to_json() for d in ds[a]], sort_keys=True, default=str).encode()
        ).hexdigest()
        for a in arms
    }
    out = {
        "capped_s": t["capped"],
        "uncapped_s": t["uncapped"],
        "same_reports": prints["capped"] == prints["uncapped"],
    }
    out["uncapped_over_capped"] = out["uncapped_s"] / out["capped_s"]
    print(
        f"{len(pairs)} pairs, calls capped {out['capped_s']:.2f} s, uncapped "
        f"{out['uncapped_s']:.2f} s (uncapped/capped {out['uncapped_over_capped']:.2f}), "
        f"the same reports bit for bit: {out['same_reports']}"
    )
    return out


def _cli(pairs: list, lj, no_cache_arm: bool) -> dict:
    """One ``lionjax diagnose --pairs DIR`` process against one process per pair (with the
    compilation cache, fresh; and, with ``no_cache_arm``, without it)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    lionjax = [sys.executable, "-m", "lionjax.cli"]
    out: dict = {"pairs": len(pairs)}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp) / "pairs"
        d.mkdir()
        for name, train, valid in pairs:
            lj.save_record(d / f"{name}_train.npz", train)
            lj.save_record(d / f"{name}_valid.npz", valid)
        env["LIONJAX_CACHE_DIR"] = str(Path(tmp) / "cache_pairs")
        t0 = time.perf_counter()
        cmd = [*lionjax, "diagnose", "--pairs", str(d), "--json", f"{tmp}/rows.json"]
        subprocess.run(cmd, env=env, check=True, capture_output=True)
        out["pairs_process_s"] = time.perf_counter() - t0
        with open(f"{tmp}/rows.json") as f:
            rows = {
                r["name"]: _key(r["verdict"], r["confidence"], r["stack"])
                for r in json.load(f)["rows"]
            }
        print(
            f"{len(pairs)} pairs, one --pairs process: {out['pairs_process_s']:.1f} s", flush=True
        )
        arms = (("separate", {"LIONJAX_CACHE_DIR": str(Path(tmp) / "cache_single")}),)
        if no_cache_arm:
            arms += (("separate_no_cache", {"LIONJAX_NO_COMPILE_CACHE": "1"}),)
        for arm, extra in arms:
            t, single = _separate(pairs, d, tmp, lionjax, {**env, **extra})
            same = rows == single
            out[arm] = {
                "seconds": t,
                "ratio": t / out["pairs_process_s"],
                "same_verdicts": same,
                "mismatches": sorted(k for k in rows if rows[k] != single.get(k)),
            }
            print(
                f"{len(pairs)} separate processes ({arm}): {t:.1f} s; separate/--pairs "
                f"{out[arm]['ratio']:.2f}, same verdicts: {same}",
                flush=True,
            )
    return out


def _separate(pairs, d: Path, tmp: str, lionjax: list, env: dict) -> tuple[float, dict]:
    """Wall time of one ``lionjax diagnose`` process per pair, and their verdicts."""
    single = {}
    t0 = time.perf_counter()
    for name, _, _ in pairs:
        out = f"{tmp}/{name}.json"
        cmd = [*lionjax, "diagnose", str(d / f"{name}_train.npz"), "--validate"]
        cmd += [str(d / f"{name}_valid.npz"), "--json", out]
        subprocess.run(cmd, env=env, check=True, capture_output=True)
        with open(out) as f:
            j = json.load(f)
        single[name] = _key(j["verdict"], j["confidence"], j["stack"])
    return time.perf_counter() - t0, single


def _long_record(n: int, rate: float, seed: int):
    """(x, F, dt) of a mass–damper ẍ + aẋ = b(F + F₀) (a = 8 1/s, b = 2 1/kg, F₀ = 0.3 N),
    sampled exactly under a zero-order hold, driven by noise low-passed at 4 Hz (RMS ≈ 1 N), x
    rounded to 1 µm encoder steps plus 0.3 µm noise."""
    import numpy as np
    from scipy.signal import lfilter

    rng = np.random.default_rng(seed)
    dt, a, b, F0 = 1.0 / rate, 8.0, 2.0, 0.3
    p = np.exp(-2 * np.pi * 4.0 * dt)  # two first-order low-passes at 4 Hz
    F = lfilter([(1 - p) ** 2], [1, -2 * p, p * p], rng.standard_normal(n))
    F *= 1.0 / max(float(np.std(F)), 1e-12)
    e = np.exp(-a * dt)
    u = b * (F + F0)
    v = lfilter([0.0, (1 - e) / a], [1, -e], u)  # v[k+1] = e·v[k] + (1 − e)/a·u[k]
    dx = (1 - e) / a * v + (dt - (1 - e) / a) / a * u  # x[k+1] − x[k]
    x = np.concatenate([[0.0], np.cumsum(dx[:-1])])
    x = np.round(x / 1e-6) * 1e-6 + 0.3e-6 * rng.standard_normal(n)
    return x, F, dt


def _one_length(n: int, rate: float, streamed: str = "auto") -> dict:
    """A --lengths child: diagnose one pair of n training samples; print one JSON line."""
    import resource

    import jax

    jax.config.update("jax_enable_x64", True)
    import lionjax as lj
    from lionjax.diagnosis._statistics import memory_estimate, streamed_by_default

    nv = max(n // 5, 4000)
    train, valid = (lj.Record(*_long_record(k, rate, seed)) for k, seed in ((n, 1), (nv, 2)))
    mode = {"auto": None, "on": True, "off": False}[streamed]
    on = streamed_by_default(n, nv) if mode is None else mode
    out = {"train_samples": n, "valid_samples": nv, "rate_hz": rate, "streamed": on}
    out["memory_estimate_gb"] = memory_estimate(n, nv, streamed=on) / 1e9  # diagnose's check
    t0 = time.perf_counter()
    try:
        d = lj.diagnose(train, valid, streamed=mode)
        out.update(status="ok", verdict=d.verdict, confidence=d.confidence, stack=d.stack)
    except lj.InputError as e:  # refused for memory (the message says by how much)
        out.update(status="refused", reason=str(e))
    out["seconds"] = time.perf_counter() - t0
    out["peak_rss_gb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / 1e9
    print(json.dumps(out), flush=True)
    return out


def lengths(args) -> dict:
    """The --lengths mode (module docstring): one fresh process per length."""
    rows = []
    for text in args.lengths.split(","):
        n = int(float(text))
        cmd = [sys.executable, os.path.abspath(__file__), "--one-length", str(n)]
        cmd += ["--rate", str(args.rate), "--streamed", args.streamed]
        t0 = time.perf_counter()
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            row = {"train_samples": n, "status": "failed", "stderr": r.stderr[-2000:]}
        else:
            row = json.loads(r.stdout.strip().splitlines()[-1])
        row["process_s"] = time.perf_counter() - t0
        rows.append(row)
        print(
            f"N = {n:>9d} ({'streamed' if row.get('streamed') else 'in memory'}): "
            f"{row['status']:8s} diagnose {row.get('seconds', math.nan):7.1f} s, "
            f"process {row['process_s']:7.1f} s, peak RSS {row.get('peak_rss_gb', math.nan):6.2f} "
            f"GB (estimate {row.get('memory_estimate_gb', math.nan):6.2f} GB) "
            f"{row.get('verdict', row.get('reason', ''))[:100]}",
            flush=True,
        )
    out = {"mode": "lengths", "rate_hz": args.rate, "streamed": args.streamed, "rows": rows}
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return out


if __name__ == "__main__":
    main()
