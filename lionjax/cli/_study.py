"""Run Lion's estimator over a grid of gains × filter poles (× records) in batched calls.

With no DATA it simulates a small seeded set of twin records (default: the paper's region 2,
closed loop, multisine, force noise; with --operating-points / --noise-seeds a grid of records
of the paper's device, labelled by operating point and noise seed). Prints one row per grid
point: the final estimates, the convergence time to within 2 % of least squares ("inf": not
converged by the end), the final bias vs least squares and the noise amplification (std of θ(t)
over the last quarter of the record / |θ_LS|). --plot draws the designer's map: heat maps of the
three over (gain, pole), records pooled by the median, never-converged cells marked "n.c.".

--tune also tunes the gain and a triple filter pole by gradient descent (lj.studies.tune: BFGS on
J = mean over records of [T_out + κ·Σᵢ (σᵢ/(tol·|θ_LS,i|))²] seconds, T_out the smooth
surrogate of the time outside the tolerance band), from the grid's centre or --tune-start,
prints the tuned gain and pole and stars them on the map (with a fourth panel: J on the grid).
With --tune the study runs with the objective's fixed transient and softness, so the map of J
is the function the tuning minimises.
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from .._errors import IdentificationError, InputError, result_message
from .._plotting import FIGURE_SUFFIXES, save_figure
from .._progress import wanted
from .._tables import check_output, write_json
from ._common import add_units_argument, float_list, format_table

NAME = "study"
HELP = "map convergence time, bias and noise of Lion's estimator over gains × filter poles"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data", nargs="*", help="record files or a folder (default: simulated twin)")
    p.add_argument("--gains", default="1e2,1e3,1e4", help="gains, comma separated")
    p.add_argument(
        "--gain-type",
        choices=("fixed", "auto"),
        default="fixed",
        help="fixed: G = g·I (default); auto: AutoGain rates [1/s], G = g·R⁻¹",
    )
    p.add_argument(
        "--poles",
        default="-4,-4,-4;-8,-8,-8",
        help="pole sets [rad/s], ';' between sets; one number per set is a triple pole "
        "(e.g. '-4;-8;-16')",
    )
    p.add_argument("--samples", type=int, default=3000, help="samples per simulated record")
    p.add_argument("--n-records", type=int, default=2, help="simulated records (no DATA)")
    p.add_argument(
        "--operating-points",
        help="simulate the paper's device at these x_ref [m] (comma separated, or 'paper')",
    )
    p.add_argument("--noise-seeds", help="simulate one record per noise seed (comma separated)")
    p.add_argument("--transient", type=float, help="LS window start [s] (default per filter)")
    p.add_argument("--chunk-size", type=int, help="grid points per batched call")
    p.add_argument("--json", metavar="OUT.json", help="write the grid (and the tuning) as JSON")
    p.add_argument("--csv", metavar="OUT.csv", help="write the grid as CSV")
    p.add_argument("--plot", metavar="OUT.png", help="heat maps over (gain, pole)")
    p.add_argument(
        "--tune",
        action="store_true",
        help="tune the gain and a triple filter pole by gradient descent (lj.studies.tune)",
    )
    p.add_argument(
        "--tune-start",
        metavar="G,P",
        help="start of the tuning: gain, pole magnitude p [rad/s] (default: the grid's centre)",
    )
    p.add_argument("--kappa", type=float, default=1.0, help="price of noise κ [s] (default 1)")
    add_units_argument(p)
    p.add_argument(
        "--tune-transient",
        type=float,
        default=0.5,
        help="fixed LS window start [s] of the tuning objective (default 0.5)",
    )


def _poles(text: str) -> list[list[float]]:
    parts = text.split(";")
    empty = [i + 1 for i, s in enumerate(parts) if not s.strip()]
    if empty and len(parts) > 1:
        raise InputError(
            f"--poles: pole set {empty[0]} of {len(parts)} in {text!r} is empty (two ';' in a "
            'row, or one at an end); give each set its poles, e.g. "-4;-8".'
        )
    sets = [float_list(s, "--poles") for s in parts if s.strip()]
    sets = [s * 3 if len(s) == 1 else s for s in sets]
    if not sets or len({len(s) for s in sets}) != 1:
        raise InputError(
            f"--poles: expected pole sets of equal length separated by ';', got {text!r}."
        )
    return sets


def plot(res, path: str, gain, objective=None, tuned=None) -> None:
    """Write the designer's map (:func:`lionjax.studies.study_figure`) to ``path``; ``gain``: the
    gain Module class the study ran."""
    from ..studies._plot import study_figure

    fig = study_figure(res, gain=gain, objective=objective, tuned=tuned)
    save_figure(fig, path, dpi=110)


def _records(args):
    import lionjax as lj

    if args.data:
        if args.operating_points or args.noise_seeds:
            raise InputError(
                "--operating-points/--noise-seeds simulate twin records; they cannot be combined "
                "with DATA files. Drop one or the other."
            )
        paths = args.data[0] if len(args.data) == 1 else args.data
        loaded = lj.load_records(paths, units=args.units)
        return [r for _, r in loaded], [p.name for p, _ in loaded]
    if args.operating_points or args.noise_seeds:
        ops = None
        if args.operating_points:
            ops = (
                "paper"
                if args.operating_points.strip() == "paper"
                else float_list(args.operating_points, "--operating-points")
            )
        seeds = None
        if args.noise_seeds:
            seeds = [int(v) for v in float_list(args.noise_seeds, "--noise-seeds")]
        return (
            lj.studies.study_records(
                operating_points=ops, noise_seeds=seeds, n_samples=args.samples
            ),
            None,
        )
    records = lj.studies.study_records(args.n_records, n_samples=args.samples)
    return records, [f"twin{i}" for i in range(len(records))]


def _start(args, gains: list[float], poles: list[list[float]]) -> tuple[float, float]:
    if args.tune_start:
        v = float_list(args.tune_start, "--tune-start")
        if len(v) != 2 or not all(isinstance(x, float) and x > 0 for x in v):
            raise InputError(
                f"--tune-start: expected 'gain,pole' (two positive numbers, pole magnitude p in "
                f"rad/s), got {args.tune_start!r}."
            )
        return v[0], v[1]
    g = math.exp(0.5 * (math.log(min(gains)) + math.log(max(gains))))
    mags = [float(np.mean(np.abs(P))) for P in poles]
    p = math.exp(0.5 * (math.log(min(mags)) + math.log(max(mags))))
    return g, p


def run(args) -> int:
    import lionjax as lj

    check_output(args.json, "--json")
    check_output(args.csv, "--csv")
    check_output(args.plot, "--plot", FIGURE_SUFFIXES)
    gains = float_list(args.gains, "--gains")
    poles = _poles(args.poles)
    records, names = _records(args)
    kw = {}
    spec = None
    if args.tune:
        spec = lj.studies.TuneObjective(kappa=args.kappa, transient=args.tune_transient)
        kw = dict(tolerance=spec.tolerance, softness=spec.softness, transient=spec.transient)
        if args.transient is not None:
            raise InputError(
                "--transient: with --tune the study uses the objective's fixed window "
                "(--tune-transient); drop --transient."
            )
    elif args.transient is not None:
        kw["transient"] = args.transient
    gain = {"fixed": lj.FixedGain, "auto": lj.AutoGain}[args.gain_type]
    res = lj.study(
        lj.MassDamper(),
        records,
        gains=gains,
        gain=gain,
        poles=poles,
        unit_dc_gain=True,
        dataset_names=names,
        chunk_size=args.chunk_size,
        progress=wanted(args.quiet),
        **kw,
    )
    rec_dims = [d for d in res.dims if d not in ("gain", "poles")]
    failed = _failures(res, rec_dims)
    rows = [
        [", ".join(f"{r[d]:g}" if isinstance(r[d], float) else str(r[d]) for d in rec_dims)]
        + [
            r["gain"],
            ",".join(f"{q:g}" for q in r["poles"]),
            r["a"],
            r["b"],
            r["a_ls"],
            r["b_ls"],
            "not settled" if r["convergence_time"] == np.inf else r["convergence_time"],
            100 * r["bias"],
            100 * r["noise_amplification"],
        ]
        + (["ok" if r["result"] == 0 else "failed"] if failed else [])
        for r in res.to_rows()
    ]
    n_rec = int(np.prod([len(res.coords[d]) for d in rec_dims])) if rec_dims else 1
    print(
        format_table(
            [
                "/".join(rec_dims) or "record",
                "gain",
                "poles",
                "a",
                "b",
                "a_LS",
                "b_LS",
                "t_conv [s]",
                "bias [%]",
                "noise [%]",
            ]
            + (["status"] if failed else []),
            rows,
            f"Lion's estimator over {len(gains)} gains × {len(poles)} pole sets × "
            f"{n_rec} records (t_conv: seconds until within {100 * res.tolerance:g} % of LS to "
            "the end, 'not settled' if never (n.c. on the map); noise: std of θ over the last "
            "quarter / |θ_LS|)",
        )
    )
    if failed:
        print(
            f"lionjax study: {len(failed)} of {res.result.size} grid points failed (shown as "
            "'failed', — where no value exists):\n"
            + "\n".join(f"  {where}: {why}" for where, why in failed[:20])
            + (f"\n  ... and {len(failed) - 20} more" if len(failed) > 20 else ""),
            file=sys.stderr,
        )
    tuned = None
    J_map = None
    if args.tune:
        g0, p0 = _start(args, gains, poles)
        tuned = lj.studies.tune(
            lj.MassDamper(),
            records,
            objective=spec,
            gain=gain,
            init_gain=g0,
            init_pole=p0,
            throw=False,
        )
        J_map = spec.on_study(res)
        J_map = J_map if J_map.ndim == 2 else None
        status = "" if tuned.success else f" (solver: {tuned.message})"
        unit = " [1/s]" if args.gain_type == "auto" else ""
        print(
            f"tuned (BFGS from gain {g0:.4g}, pole {p0:.4g} rad/s, {tuned.n_steps} steps){status}: "
            f"gain {tuned.gain:.4g}{unit}, filter poles 3 × −{tuned.pole:.4g} rad/s, "
            f"J = {tuned.objective:.4g} s (κ = {spec.kappa:g} s)"
        )
        if J_map is not None:
            i, j = np.unravel_index(np.nanargmin(J_map), J_map.shape)
            print(
                f"grid minimum of J: gain {gains[i]:.4g}, poles {poles[j]} "
                f"(J = {J_map[i, j]:.4g} s)"
            )
    if args.json:
        payload = res.payload()
        if tuned is not None:
            payload["tune"] = tuned.to_dict()
        write_json(args.json, payload)
        print(f"wrote {args.json}")
    if args.csv:
        res.to_csv(args.csv)
        print(f"wrote {args.csv}")
    if args.plot:
        plot(res, args.plot, gain, objective=J_map, tuned=tuned)
        print(f"wrote {args.plot}")
    return 1 if failed else 0


def _failures(res, rec_dims: list[str]) -> list[tuple[str, str]]:
    """(grid point, reason) of every failed grid point; an :class:`IdentificationError` when a
    record failed at every grid point (it cannot be studied: the same refusal as identify)."""
    codes = np.asarray(res.result)
    out = []
    for idx in np.ndindex(*codes.shape):
        c = int(codes[idx])
        if c > 0:
            where = ", ".join(f"{d} {res.coords[d][i]}" for d, i in zip(res.dims, idx, strict=True))
            out.append((where, result_message(c)))
    n_rec = len(rec_dims)
    for ridx in np.ndindex(*codes.shape[:n_rec]):
        sub = codes[ridx].reshape(-1)
        if sub.size and np.all(sub > 0):
            label = (
                ", ".join(str(res.coords[d][i]) for d, i in zip(rec_dims, ridx, strict=True))
                or "the record"
            )
            raise IdentificationError(
                f"{label}: study failed at every grid point: {result_message(int(sub[0]))}"
            )
    return out
