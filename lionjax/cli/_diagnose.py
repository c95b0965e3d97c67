"""Diagnose the sim-to-real gap of ẍ + aẋ = bF: where it is, which effect explains it, how far.

Fits the mass–damper on TRAIN, scores it and every candidate effect (coulomb_friction, offset,
spring, delay, saturation, position_dependent, asymmetric_friction, flexible_mode, and the
force sensor's artefacts force_sensor_line and force_sensor_drift) on VALID, stacks the
significant ones, and prints the verdict and the regions where the gap lies (one line each,
significant at the family-wise level --alpha). --candidates FILE.py:Name[,Name…] adds effects
of one's own (docs/effects.md). --json writes the payload (baseline, where, regions,
effects, stack, verdict, confidence, ambiguous, final, and the decimation applied);
--plot writes a one-page summary (PNG/PDF/SVG by extension). Long records are streamed (the
fits accumulated chunk by chunk, only the raw samples held whole; --streamed on/off/auto);
--decimate R (or auto) diagnoses records at R× the sample interval; --F-hold foh reads a force
sampled at instants (a measured current) as the held force over each interval.

--pairs DIR diagnoses every pair NAME_train.* / NAME_valid.* of a folder (or --pairs FILE.csv,
a manifest with the columns name,train,valid) in one process, sharing the compiled programs
between pairs of the same lengths: one table row per pair (verdict, confidence, stack, shrink,
detection limit, error), written by --json and --csv. The settings apply to every pair.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import warnings

from .._errors import DataWarning, IdentificationError, InputError
from .._plotting import FIGURE_SUFFIXES
from .._progress import wanted
from .._tables import check_output, write_json
from ._common import about, add_units_argument, cli_words, format_table, number

NAME = "diagnose"
HELP = "diagnose the sim-to-real gap: which unmodelled effect, where, how much it explains"
#: Share of validation samples outside the training record's range above which the CLI warns.
OUTSIDE_WARN = 0.05


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.set_defaults(_parser=p)
    p.add_argument(
        "data", metavar="TRAIN", nargs="?", help="training record: .csv (t,x,F), .npz or .mat"
    )
    p.add_argument("--validate", metavar="VALID", help="validation record (default: TRAIN)")
    p.add_argument(
        "--pairs",
        metavar="DIR|FILE.csv",
        help="diagnose many pairs instead of TRAIN: a folder of NAME_train.* and NAME_valid.* "
        "records, or a manifest FILE.csv with the columns name,train,valid",
    )
    p.add_argument("--json", metavar="OUT.json", help="write the diagnosis as JSON")
    p.add_argument("--csv", metavar="OUT.csv", help="write the rows of --pairs as CSV")
    p.add_argument("--plot", metavar="OUT.png", help="write a one-page figure")
    g = p.add_argument_group("settings (defaults adapt to the record)")
    g.add_argument(
        "--filter-hz",
        type=float,
        help="filter corner λ/2π in Hz (default min(fs/25, 40 Hz), raised to a dominant "
        "oscillation's frequency, at most fs/8, where the mass–damper fit is qualitatively wrong)",
    )
    g.add_argument(
        "--window",
        type=float,
        help="restart interval H [s] of the simulation gap (default: from the slowest dynamics "
        "the records show, docs/method.md)",
    )
    g.add_argument(
        "--alpha",
        type=float,
        help="family-wise error rate of the regions where the gap lies (default 0.05)",
    )
    g.add_argument(
        "--candidates",
        metavar="FILE.py:Name[,Name…]",
        help="add candidate effects defined in a Python file (lionjax.diagnosis.ForceEffect "
        "subclasses, docs/effects.md), e.g. examples/custom_effects.py:QuadraticDrag,Cogging",
    )
    g.add_argument(
        "--max-memory-gb",
        type=float,
        help="host memory the diagnosis may take [GB] (default: this machine's memory)",
    )
    g.add_argument(
        "--streamed",
        choices=("auto", "on", "off"),
        default="auto",
        help="accumulate the fits chunk by chunk: only the records' raw samples are held whole "
        "('auto': for records above 2^17 samples, padded; default auto)",
    )
    g.add_argument(
        "--decimate",
        metavar="R",
        type=_factor,
        default=1,
        help="diagnose both records at R× the sample interval (Record.decimate: x sampled, F "
        "averaged over each interval); 'auto': the least R that fits the memory (default 1)",
    )
    g = p.add_argument_group("input files")
    g.add_argument("--columns", help="map column names, e.g. t=time,x=pos,F=force")
    g.add_argument("--force-scale", type=float, help="multiply F by this (e.g. N/V)")
    g.add_argument(
        "--F-hold",
        choices=("zoh", "foh"),
        default="zoh",
        help="F between samples: zoh, held by the drive over each interval (a command; "
        "default); foh, sampled at instants (a measured current or load cell), diagnosed as "
        "the held force (F_k + F_k+1)/2 (Record.hold_force)",
    )
    g.add_argument("--resample", action="store_true", help="resample a non-uniform record (linear)")
    add_units_argument(g)


def _streamed(args) -> bool | None:
    return {"auto": None, "on": True, "off": False}[args.streamed]


def _factor(s: str):
    if s == "auto":
        return s
    try:
        r = int(s)
    except ValueError:
        r = 0
    if r < 1:
        raise argparse.ArgumentTypeError(f"expected an integer ≥ 1 or 'auto', got {s!r}")
    return r


def _load(path, args):
    import lionjax as lj

    columns = lj.extend.parse_columns(args.columns) if args.columns else None
    return lj.load_record(
        path,
        columns=columns,
        force_scale=args.force_scale,
        resample=args.resample,
        units=args.units,
    )


def _name_files(message: str, args) -> str:
    """The diagnosis' names of its records ("(argument 'train')") → the files; options named as
    the command line's."""
    valid = args.validate or args.data
    for old, new in (
        ("(argument 'train')", f"({args.data})"),
        ("(argument 'valid')", f"({valid}" + (", --validate)" if args.validate else ")")),
    ):
        message = message.replace(old, new)
    return cli_words(message)


def _criteria(args):
    """The diagnosis' Criteria with --alpha, or None (the defaults)."""
    import lionjax as lj

    return None if args.alpha is None else lj.diagnosis.Criteria(alpha=args.alpha)


def _library(args):
    import lionjax as lj

    library = lj.diagnosis.DEFAULT_CANDIDATES
    if args.candidates:
        library = library + lj.diagnosis.load_candidates(args.candidates)
    return library


def run(args) -> int:
    parser = args._parser
    if args.pairs is not None:
        from ._pairs import check_arguments

        check_arguments(args, parser)
        return _run_pairs(args)
    if args.data is None:
        parser.error("one of the arguments TRAIN or --pairs DIR|FILE.csv is required")
    if args.csv:
        parser.error("argument --csv writes the rows of --pairs; for one pair use --json")
    return _run_one(args)


def _run_pairs(args) -> int:
    """Every pair of --pairs through diagnose_many; exit status 1 when some pair failed."""
    import lionjax as lj

    from ._pairs import find_pairs, table

    check_output(args.json, "--json")
    check_output(args.csv, "--csv")
    library = _library(args)
    pairs, orphans = find_pairs(args.pairs)
    columns = lj.extend.parse_columns(args.columns) if args.columns else None
    result = lj.diagnosis.diagnose_many(
        pairs,
        candidates=library,
        progress=wanted(args.quiet),  # the pairs done
        load={
            "columns": columns,
            "force_scale": args.force_scale,
            "resample": args.resample,
            "units": args.units,
        },
        filter_hz=args.filter_hz,
        window_s=args.window,
        max_memory_gb=args.max_memory_gb,
        streamed=_streamed(args),
        criteria=_criteria(args),
    )
    rows = [dataclasses.replace(r, error=cli_words(r.error)) if r.error else r for r in result.rows]
    if orphans:  # a folder's pairs come sorted by name: the unpaired files take their places
        rows += [lj.diagnosis.DiagnosisRow(name, error=why) for name, why in orphans]
        rows.sort(key=lambda r: r.name)
    result = dataclasses.replace(result, rows=tuple(rows))  # a manifest's rows in its order
    print(table(result))
    for path, write in ((args.json, result.to_json), (args.csv, result.to_csv)):
        if path:
            write(path)
            print(f"wrote {path}")
    return 1 if result.failures else 0


def _run_one(args) -> int:
    import lionjax as lj

    check_output(args.json, "--json")
    check_output(args.plot, "--plot", FIGURE_SUFFIXES)
    library = _library(args)
    with about(args.data):
        train = _load(args.data, args)
    if args.validate:
        with about(args.validate):
            valid = _load(args.validate, args)
    else:
        valid = None
    if args.F_hold == "foh":
        train = train.hold_force()
        valid = valid.hold_force() if valid is not None else None
        print(
            "F sampled at instants (--F-hold foh): diagnosed as the held force "
            f"(F_k + F_k+1)/2 over each interval, {train.n_samples} training samples"
        )
    r = args.decimate
    if r == "auto":
        r = lj.diagnosis.decimation_for(
            train, valid, max_memory_gb=args.max_memory_gb, streamed=_streamed(args)
        )
        if r == 0:
            r = 1  # no factor fits: diagnose refuses the records and says why
    dt0 = float(train.dt)
    if r > 1:
        train = train.decimate(r)
        valid = valid.decimate(r) if valid is not None else None
        print(
            f"decimated by {r}: dt {dt0:.6g} s → {float(train.dt):.6g} s, "
            f"{train.n_samples} training samples (x sampled, F averaged over each interval)"
        )
    try:
        d = lj.diagnose(
            train,
            valid,
            candidates=library,
            filter_hz=args.filter_hz,
            window_s=args.window,
            max_memory_gb=args.max_memory_gb,
            streamed=_streamed(args),
            progress=wanted(args.quiet),
            criteria=_criteria(args),
        )
    except (InputError, IdentificationError) as e:
        raise type(e)(_name_files(str(e), args)) from None
    out = d.to_json()
    out["files"] = {"train": str(args.data), "validate": str(args.validate or args.data)}
    out["decimate"] = {"factor": r, "dt_recorded": dt0}
    out["F_hold"] = args.F_hold
    out["candidates"] = [c.name for c in library]
    base = out["baseline"]
    print(
        f"baseline ẍ + aẋ = bF: a = {number(base['params']['a'], '.6g')} 1/s, b = "
        f"{number(base['params']['b'], '.6g')} {base['units']['b']}; gap "
        f"{number(base['gap'])} {base['gap_units']} (windowed simulation, H = "
        f"{number(out['settings']['window_s'], '.3g')} s), equation error "
        f"{number(base['equation_gap'])} {base['equation_gap_units']} (noise floor "
        f"{number(base['noise_floor'], '.3g')})"
    )
    for why in base.get("qualitatively_wrong", []):
        print(f"  the baseline is qualitatively wrong: {why}")
    rows = [
        [
            e["name"],
            e["score"],
            e["shrink"],
            e["equation_shrink"],
            e["size"],
            "yes" if e["significant"] else "no",
        ]
        for e in out["effects"]
    ]
    print(format_table(["effect", "score", "shrink", "eq. shrink", "size", "significant"], rows))
    print(f"stack: {', '.join(out['stack']) or '(empty)'}")
    tie = f"; near-tie: {', '.join(out['ambiguous'])}" if out["ambiguous"] else ""
    print(f"verdict: {out['verdict']} (confidence {number(out['confidence'], '.2f')}{tie})")
    if out.get("inconclusive"):
        print(f"  the records cannot decide: {out['inconclusive']['reason']}")
        print(f"  record instead: {out['inconclusive']['advice']}")
    if out["verdict"] in out["final"]["measurement"]:
        print(
            f"  {out['verdict']} is an error of the force sensor, not of the device's dynamics: "
            "the measured F carries a term the device did not feel"
        )
    print(
        f"detection limit: {number(out['noise']['detection_limit'], '.2g')} (the least effect "
        "this record would name, as a share of the input's term b·F)"
    )
    alpha = number(out["settings"]["alpha"], "g")
    if d.regions:
        print(f"where the gap lies (regions, family-wise α = {alpha}):")
        for region in d.regions:
            print(f"  {region.describe()}")
    else:
        print(f"where the gap lies: no region is significant at α = {alpha}")
    out_of = {k: v for k, v in base["valid_outside_train"].items() if (v or 0) > OUTSIDE_WARN}
    if out_of:
        warnings.warn(
            "the validation record leaves the training record's range ("
            + ", ".join(f"{k}: {v:.0%} of the samples" for k, v in out_of.items())
            + "); the model extrapolates there — record a training run that covers it",
            DataWarning,
            stacklevel=2,
        )
    fin = out["final"]
    if not fin.get("result", True):
        print("final: no usable model — " + "; ".join(fin["qualitatively_wrong"]))
    print(
        ("final (not a result): " if not fin.get("result", True) else "final: ")
        + ", ".join(
            f"{k} = {number(v, '.6g')} {fin['units'].get(k, '')}".rstrip()
            for k, v in fin["params"].items()
        )
        + f"; gap {number(fin['gap'])} {base['gap_units']}"
        + (
            f" ({fin['shrink']:.0%} of the baseline's removed)"
            if out["stack"] and fin.get("shrink") is not None and math.isfinite(fin["shrink"])
            else ""
        )
    )
    tau = fin["params"].get("tau")
    if tau is not None and tau < 0:
        print(
            f"  τ < 0: the recorded force lags the force acting by {number(-tau, '.3g')} s "
            f"({number(-fin['params'].get('tau_samples', math.nan), '.2g')} samples): a filtered "
            "or late force reading (half a sample: a force sampled at instants, read as held"
            + (": --F-hold foh reads it so)" if args.F_hold == "zoh" else ")")
        )
    if args.json:
        write_json(args.json, out)
        print(f"wrote {args.json}")
    if args.plot:
        from ..diagnosis._plot import plot_diagnosis

        path = plot_diagnosis(d, args.plot)
        print(f"wrote {path}")
    return 0
