"""One-shot GPU check of lionjax: one command, one run, a table on stdout and a JSON file.

    python benchmarks/gpu_check.py --out gpu_check.json        # on a GPU (≤ 8 min on one H100)
    python benchmarks/gpu_check.py --dry-run --out dry.json    # the same code paths on CPU, tiny

What it measures (the law of ``benchmarks/throughput.py``: mass–damper, Λ = (s + 4)³ with unit
DC gain, x foh / F zoh, midpoint regressors, the exact θ step, one fixed G):

1. agreement of the Pallas kernel with the fused XLA loop (``lj.Execution(kernel=...)``), float32
   and float64: max relative difference of θ over B = 4096 records of T = 8000 samples;
2. throughput (sample-updates/s = B·T / seconds; warm-up, ``block_until_ready``, min of ≥ 5
   repeats) in float32 at B = 4096, 65536 and 262144, T = 8000, of ``lion_batched`` with the Pallas
   kernel and with the XLA loop, against an independent CuPy ``RawKernel`` of the same law (one
   record per thread, ``(T, B)`` layout: ``benchmarks/throughput.py``'s ``CUDA_SRC``). The
   records are given to lionjax as ``(B, T)``, so its time includes the transpose to ``(T, B)``
   that the Pallas kernel reads (timed alone as ``transpose_s``); the CuPy reference gets its
   layout untimed;
3. ``lion_parallel`` against the sequential ``lion_batched`` (default execution, and the Pallas
   kernel) on one record of 10⁶ samples, float32: time ratio and agreement of the final θ;
4. ``pytest`` on the test files that matter on a GPU (test_pallas, test_parallel, test_batched,
   test_gpu_lowering), in a subprocess with the time left.

Acceptance (printed PASS/FAIL): lionjax (Pallas) ≥ 50 % of the CuPy kernel at B = 65536 float32,
and parallel in time ≥ 10× the sequential default on the 10⁶-sample record.

``--dry-run``: the same code paths on the CPU at tiny sizes (Pallas in interpret mode; no CuPy,
its column skipped with the reason; pytest only collects), in well under 30 s; the acceptance
lines read "not measured". The JSON is rewritten after every stage, so a run cut short keeps
what it measured.
"""

from __future__ import annotations

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)  # check the checkout this script lives in
sys.path.insert(0, HERE)

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

GPU_TESTS = (
    "tests/test_pallas.py",
    "tests/test_parallel.py",
    "tests/test_batched.py",
    "tests/test_gpu_lowering.py",
)
TOL = {"float32": 2e-3, "float64": 1e-9}  # relative, as benchmarks/throughput.py
MIN_CUPY_FRACTION = 0.5  # lionjax ≥ 50 % of the CuPy kernel at B = 65536, float32
MIN_PARALLEL_SPEEDUP = 10.0  # parallel in time ≥ 10× sequential on 10⁶ samples


def best_time(fn, repeats: int, budget_s: float | None = None) -> tuple[float, int]:
    """Min over ``repeats`` timed calls after one warm-up call; with ``budget_s``, stop early
    once that many seconds were spent (at least one timed call). Returns (seconds, calls)."""
    fn()
    ts: list[float] = []
    spent = 0.0
    while len(ts) < repeats and (budget_s is None or not ts or spent < budget_s):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
        spent += ts[-1]
    return min(ts), len(ts)


def rel_diff(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-12)))


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", metavar="PATH", help="write the results as JSON")
    ap.add_argument("--dry-run", action="store_true", help="CPU, tiny sizes, interpret mode")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--budget", type=float, default=450.0, help="seconds for the whole run")
    args = ap.parse_args(argv)
    start = time.perf_counter()
    dry = args.dry_run
    if dry:
        os.environ.setdefault("JAX_PLATFORMS", "cpu")

    import jax

    jax.config.update("jax_enable_x64", True)  # float64 agreement; float32 arrays stay float32
    import jax.numpy as jnp
    from throughput import build_cuda, make_data

    import lionjax as lj

    gpu = jax.default_backend() == "gpu"
    if not dry and not gpu:
        raise SystemExit(
            f"gpu_check: no GPU (JAX backend {jax.default_backend()!r}); use --dry-run on CPU."
        )
    dev = jax.devices()[0]
    # records must outlast the filter transient 9/p: 2.25 s for the benchmark's (s+4)³ at 1 kHz;
    # the dry run's (s+40)³ (max|pole|·dt = 0.04) settles in 0.225 s, so its records are short
    T = 600 if dry else 8000
    B_AGREE = 8 if dry else 4096
    BATCHES = (8,) if dry else (4096, 65536, 262144)
    B_CRIT = 8 if dry else 65536
    T_LONG = 1000 if dry else 1_000_000
    dt = 1e-3
    model = lj.MassDamper()
    bank = lj.FilterBank.from_poles([-40.0] * 3, unit_dc_gain=True) if dry else lj.default_bank()
    if dry:
        args.repeats = min(args.repeats, 2)

    out: dict = {
        "dry_run": dry,
        "environment": {
            "device": getattr(dev, "device_kind", str(dev)),
            "platform": dev.platform,
            "devices": len(jax.devices()),
            "python": platform.python_version(),
            "jax": jax.__version__,
            "jaxlib": _version("jaxlib"),
            "numpy": np.__version__,
            "cupy": _cupy_version(),
            "lionjax_kernel_params": _triton_params(),
        },
        "config": {
            "law": f"exact step, {'(s+40)^3' if dry else '(s+4)^3'} unit DC gain, x foh / F zoh, "
            "midpoint, fixed G",
            "samples": T,
            "repeats": args.repeats,
            "tolerance_rel": TOL,
        },
    }

    stages: dict = {}
    out["stage_s"] = stages
    mark = [time.perf_counter()]

    def save(stage: str | None = None):
        now = time.perf_counter()
        if stage:
            stages[stage] = now - mark[0]
            mark[0] = now
        out["elapsed_s"] = now - start
        if args.out:
            with open(args.out, "w") as f:
                json.dump(out, f, indent=2)

    # --- data and the fixed gain: benchmarks/throughput.py's records and G (AutoGain(2) of the
    # first record); larger batches repeat the first 4096 records (the work does not depend on
    # the values)
    base_x, base_F = make_data(min(max(BATCHES), 4096), T, dt)
    xg, Fg = make_data(1, max(T, 4000), dt)
    rec0 = lj.Record(jnp.asarray(xg[0]), jnp.asarray(Fg[0]), jnp.asarray(dt))
    G = np.asarray(lj.lion(model, rec0, gain=lj.AutoGain(2.0), save_every=xg.shape[1]).gain)
    G = 0.5 * (G + G.T)
    out["config"]["gain"] = G.tolist()
    save("setup")

    def records(B, dtype):
        reps = -(-B // base_x.shape[0])
        x = jnp.tile(jnp.asarray(base_x, dtype), (reps, 1))[:B]
        F = jnp.tile(jnp.asarray(base_F, dtype), (reps, 1))[:B]
        return lj.Record(x, F, jnp.asarray(dt, dtype))

    def runner(rec, kernel):
        gain = lj.FixedGain(jnp.asarray(G, rec.x.dtype))
        ex = lj.Execution(kernel=kernel, shard=False)
        return lambda: lj.lion_batched(
            model, rec, bank=bank, gain=gain, execution=ex, throw=False
        ).theta.block_until_ready()

    # --- 1. agreement, Pallas vs XLA
    print(f"device: {out['environment']['device']} ({dev.platform}), jax {jax.__version__}")
    print("\nagreement of the Pallas kernel with the XLA loop (max relative difference of θ)")
    out["agreement"] = {}
    for name in ("float32", "float64"):
        rec = records(B_AGREE, np.dtype(name))
        th_p = np.asarray(runner(rec, "pallas")())
        th_x = np.asarray(runner(rec, "xla")())
        err = rel_diff(th_p, th_x)
        ok = bool(np.all(np.isfinite(th_x)) and err <= TOL[name])
        out["agreement"][name] = {
            "batch": B_AGREE,
            "samples": T,
            "max_rel_diff": err,
            "tolerance": TOL[name],
            "dtype": str(th_p.dtype),
            "pass": ok,
        }
        print(f"  {name}: {err:.2e} (tolerance {TOL[name]:g}) {'PASS' if ok else 'FAIL'}")
        del rec
    save("agreement")

    # --- 2. throughput, float32
    cupy_reason = None
    cuda_run = cp = None
    if dry:
        cupy_reason = "dry run (CPU): the CuPy kernel needs a GPU"
    else:
        try:
            import cupy as cp

            cuda_run = build_cuda("float32")
        except Exception as e:  # ImportError, or no CUDA compiler for CuPy
            cupy_reason = f"CuPy unavailable: {type(e).__name__}: {e}"
    Phi, Gam0, Gam1 = (np.asarray(a, np.float32) for a in bank.discretise(jnp.asarray(dt)))
    lam = np.asarray(bank.coeffs, np.float32)
    params = np.concatenate(
        [Phi.ravel(), Gam0, Gam1, lam, [lam[2]], G.astype(np.float32).ravel(), [dt]]
    ).astype(np.float32)
    out["throughput"] = []
    print(
        f"\nthroughput, float32, T = {T} (G sample-updates/s; min of {args.repeats} after warm-up)"
    )
    print(f"  {'B':>8} {'pallas':>8} {'xla':>8} {'cupy':>8} {'pallas/cupy':>11} {'transpose':>10}")
    transpose = jax.jit(lambda x, F: (x.T, F.T))
    for B in BATCHES:
        rec = records(B, np.float32)
        N = B * T
        row: dict = {"batch": B, "samples": T}
        thetas = {}
        for kernel in ("pallas", "xla"):
            fn = runner(rec, kernel)
            t0 = time.perf_counter()
            thetas[kernel] = np.asarray(fn())
            first = time.perf_counter() - t0
            secs, n = best_time(fn, args.repeats)
            row[kernel] = {
                "seconds": secs,
                "gsps": N / secs / 1e9,
                "compile_s": max(first - secs, 0.0),
                "repeats": n,
            }
        secs, _ = best_time(lambda r=rec: jax.block_until_ready(transpose(r.x, r.F)), args.repeats)
        row["transpose_s"] = secs
        row["pallas"]["max_rel_diff_vs_xla"] = rel_diff(thetas["pallas"], thetas["xla"])
        if cuda_run is not None:
            xt, Ft = transpose(rec.x, rec.F)
            xt, Ft = cp.from_dlpack(xt), cp.from_dlpack(Ft)
            th_c = cp.zeros((B, 2), np.float32)
            pc = cp.asarray(params)
            fn = lambda a=(xt, Ft, pc, th_c): cuda_run(*a)
            t0 = time.perf_counter()
            fn()
            first = time.perf_counter() - t0
            secs, n = best_time(fn, args.repeats)
            row["cupy"] = {
                "seconds": secs,
                "gsps": N / secs / 1e9,
                "compile_s": max(first - secs, 0.0),
                "repeats": n,
                "max_rel_diff_vs_pallas": rel_diff(cp.asnumpy(th_c), thetas["pallas"]),
            }
            row["pallas_over_cupy"] = row["pallas"]["gsps"] / row["cupy"]["gsps"]
            del xt, Ft, th_c
        else:
            row["cupy"] = {"skipped": cupy_reason}
        out["throughput"].append(row)
        cup = row["cupy"].get("gsps")
        cup_s = f"{cup:.3g}" if cup else "—"
        frac_s = f"{row['pallas_over_cupy']:.0%}" if cup else "—"
        print(
            f"  {B:>8} {row['pallas']['gsps']:>8.3g} {row['xla']['gsps']:>8.3g} {cup_s:>8} "
            f"{frac_s:>11} {row['transpose_s'] * 1e3:>8.2f}ms"
        )
        del rec
        save("throughput")
    if cupy_reason:
        print(f"  cupy: skipped ({cupy_reason})")

    # --- 3. parallel in time vs sequential, one long record, float32
    xl, Fl = make_data(1, T_LONG, dt, seed=1)
    rl = lj.Record(jnp.asarray(xl[0], np.float32), jnp.asarray(Fl[0], np.float32), jnp.float32(dt))
    rb = jax.tree.map(lambda a: a[None] if a.ndim else a, rl)
    Gj = jnp.asarray(G, np.float32)
    fp = lambda: lj.lion_parallel(model, rl, Gj, bank=bank).theta_final.block_until_ready()
    th_par = np.asarray(fp())
    t_par, n_par = best_time(fp, args.repeats)
    par: dict = {"samples": T_LONG, "parallel_s": t_par, "parallel_repeats": n_par}
    seq = [("sequential", "auto")] + ([] if dry else [("sequential_pallas", "pallas")])
    if dry:  # the Pallas kernel's path is the agreement stage's; one compile less
        par["sequential_pallas"] = {"skipped": "dry run (the kernel is checked above)"}
    for name, kernel in seq:
        fs = lambda k=kernel: runner(rb, k)()
        th_seq = np.asarray(fs())[0]
        # the sequential XLA loop is slow on a GPU (a launch per step): at most ~40 s of repeats
        secs, n = best_time(fs, args.repeats, budget_s=None if dry else 40.0)
        par[name] = {
            "seconds": secs,
            "repeats": n,
            "kernel": kernel,
            "speedup_of_parallel": secs / t_par,
            "max_rel_diff_parallel_vs_this": rel_diff(th_par, th_seq),
        }
    par["speedup"] = par["sequential"]["speedup_of_parallel"]
    par["max_rel_diff"] = par["sequential"]["max_rel_diff_parallel_vs_this"]
    par["agrees"] = bool(par["max_rel_diff"] <= TOL["float32"])
    out["parallel_in_time"] = par
    print(f"\nparallel in time, one record of {T_LONG} samples, float32")
    print(
        f"  lion_parallel {t_par * 1e3:.1f} ms; sequential (default) "
        f"{par['sequential']['seconds'] * 1e3:.1f} ms → {par['speedup']:.1f}×; "
        + (
            ""
            if dry
            else f"sequential (pallas) {par['sequential_pallas']['seconds'] * 1e3:.1f} ms → "
            f"{par['sequential_pallas']['speedup_of_parallel']:.1f}×; "
        )
        + f"max rel diff {par['max_rel_diff']:.2e} {'PASS' if par['agrees'] else 'FAIL'}"
    )
    save("parallel_in_time")

    # --- 4. the GPU test files, with the time left
    files = [f for f in GPU_TESTS if os.path.exists(os.path.join(ROOT, f))]
    if dry:  # collect one file only: the command line works (the suite runs these files on CPU)
        files = files[-1:]
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *files]
    left = args.budget - (time.perf_counter() - start) - 10.0
    env = dict(os.environ, XLA_PYTHON_CLIENT_PREALLOCATE="false")  # beside this process
    if dry:
        cmd.append("--collect-only")  # the command line and the files, not the tests
    else:
        env["LIONJAX_REQUIRE_GPU_LOWERING"] = "0"
    py: dict = {"command": " ".join(cmd[1:]), "files": files}
    if not dry and left < 30:
        py.update(status="not run", reason=f"only {left:.0f} s left of --budget")
    else:
        t0 = time.perf_counter()
        try:
            res = subprocess.run(
                cmd,
                cwd=ROOT,
                env=env,
                capture_output=True,
                text=True,
                timeout=max(left, 30.0),
            )
            last = (res.stdout.strip().splitlines() or [""])[-1]
            status = "passed" if res.returncode == 0 else "failed"
            if dry:
                status = "collected" if res.returncode == 0 else "failed"
            py.update(status=status, returncode=res.returncode, summary=last)
            if res.returncode:
                py["tail"] = (res.stdout + res.stderr)[-3000:] or (
                    "no output: the process ended before pytest reported (run the command by "
                    "hand with -s to see what killed it)"
                )
        except subprocess.TimeoutExpired:
            py.update(status="timeout", reason=f"over {max(left, 30.0):.0f} s")
        py["seconds"] = time.perf_counter() - t0
    out["pytest"] = py
    save("pytest")
    print(f"\npytest {' '.join(files)}: {py['status'].upper()} {py.get('summary', '')}")

    # --- acceptance
    crit: dict = {}
    if dry:
        crit["cupy_fraction"] = {"status": "not measured", "reason": "dry run"}
        crit["parallel_speedup"] = {"status": "not measured", "reason": "dry run"}
    else:
        row = next(r for r in out["throughput"] if r["batch"] == B_CRIT)
        if "pallas_over_cupy" in row:
            frac = row["pallas_over_cupy"]
            crit["cupy_fraction"] = {
                "value": frac,
                "threshold": MIN_CUPY_FRACTION,
                "status": "PASS" if frac >= MIN_CUPY_FRACTION else "FAIL",
            }
        else:
            crit["cupy_fraction"] = {"status": "not measured", "reason": cupy_reason}
        crit["parallel_speedup"] = {
            "value": par["speedup"],
            "threshold": MIN_PARALLEL_SPEEDUP,
            "status": "PASS" if par["speedup"] >= MIN_PARALLEL_SPEEDUP else "FAIL",
        }
    out["criteria"] = crit
    c1, c2 = crit["cupy_fraction"], crit["parallel_speedup"]
    print(
        f"\nACCEPTANCE lionjax (pallas) ≥ {MIN_CUPY_FRACTION:.0%} of CuPy at B = {B_CRIT}: "
        f"{c1['status']}" + (f" ({c1['value']:.0%})" if "value" in c1 else "")
    )
    print(
        f"ACCEPTANCE parallel in time ≥ {MIN_PARALLEL_SPEEDUP:g}× sequential on {T_LONG} samples: "
        f"{c2['status']}" + (f" ({c2['value']:.1f}×)" if "value" in c2 else "")
    )
    save()
    print(f"elapsed {out['elapsed_s']:.1f} s" + (f"; wrote {args.out}" if args.out else ""))
    return out


def _version(dist: str) -> str | None:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def _cupy_version() -> str | None:
    """CuPy's version, whichever wheel holds it (``cupy``, ``cupy-cuda12x``, ``cupy-cuda13x`` …)."""
    from importlib import metadata

    for d in metadata.distributions():
        name = (d.metadata["Name"] or "").lower()
        if name == "cupy" or name.startswith("cupy-cuda"):
            return f"{name} {d.version}"
    return None


def _triton_params() -> dict:
    from lionjax import _pallas

    p = _pallas.TRITON_PARAMS
    return {"num_warps": p.num_warps, "num_stages": p.num_stages, "rows": _pallas.ROWS_GPU}


if __name__ == "__main__":
    main()
    sys.exit(0)
