"""Identify ẍ + aẋ = bF (one region, or several with --regions) from one record or many.

One file: reads CSV (header t,x,F in s, m, N), NPZ or MAT; prints a table; --json writes
{"params": {"a": …, "b": …}, …} (with regions: a_1, b_1, a_2, b_2, … — region 1 the lowest x).

Several files, or a folder (every *.csv, *.npz, *.mat in it, sorted by name; sub-folders are not
searched): every file is read and checked first (a bad file stops the run, naming it; nothing is
skipped), then all records are identified in ONE batched call (different lengths padded and
masked, each record with its own dt) and one row per file is printed; --json OUT.json writes
{"method", "model", "names", …, "rows": [...]}, --csv OUT.csv the table. --method ls is then the
streamed least squares over the samples after the filter transient (= lionjax.least_squares(…,
initial="discard") per file; one file uses initial="estimate"); --method lion is Lion's law with
the exact step (= lionjax.lion per file). A record that cannot be identified (shorter than the
filter transient, not excited) is a row with status "failed"/"not run" and NaN estimates; the
rows are all written, the failed files are named on stderr, and the exit status is 1.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from .._errors import InputError
from .._progress import counted, status, wanted
from .._tables import check_output, write_json
from .._units import unit
from ._common import about, add_units_argument, float_list, format_table

NAME = "identify"
HELP = (
    "identify a, b (per region) from a record, or from many in one batched call, with least "
    "squares or Lion's estimator"
)

UNITS = {"a": "1/s", "b": "1/kg"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "data",
        nargs="+",
        metavar="DATA",
        help="record file(s): .csv (t,x,F), .npz or .mat; or folder(s): every *.csv, *.npz, "
        "*.mat in it, sorted by name, not sub-folders. Several files or a folder: one batched "
        "call, one row per file (list all DATA together, before or after the options)",
    )
    p.add_argument("--regions", help="region bounds in m, sorted, e.g. -0.01,0.01")
    p.add_argument("--method", choices=("ls", "lion"), default="ls", help="default: ls")
    p.add_argument("--json", metavar="OUT.json", help="write the result as JSON")
    p.add_argument(
        "--csv", metavar="OUT.csv", help="write the table as CSV (several files or a folder)"
    )
    g = p.add_argument_group("filter Λ(s)")
    g.add_argument(
        "--poles",
        help="filter poles in rad/s (default -4,-4,-4 = the paper's, for records sampled at "
        "200 Hz or faster; slower: -p,-p,-p with p = 0.02/dt)",
    )
    g.add_argument("--coeffs", help="filter coefficients λ₁,…,λₙ (instead of --poles)")
    g.add_argument(
        "--dc-gain",
        choices=("unit", "raw"),
        default="unit",
        help="unit: λₙ/Λ (default); raw: 1/Λ as in the paper",
    )
    g.add_argument("--x-hold", choices=("foh", "zoh"), default="foh", help="default foh")
    g.add_argument("--F-hold", choices=("foh", "zoh"), default="zoh", help="default zoh")
    g = p.add_argument_group("Lion's estimator (--method lion)")
    g.add_argument(
        "--gain",
        default="auto",
        help="'auto' (G = rate·R⁻¹, default) or a number g for G = g·I (paper: 1e4)",
    )
    g.add_argument("--rate", type=float, default=1.0, help="rate [1/s] of --gain auto")
    g.add_argument("--normalisation", type=float, default=0.0, help="μ of the normalised law")
    g.add_argument("--theta0", help="initial estimate, comma separated (default zeros)")
    g.add_argument(
        "--paper",
        action="store_true",
        help="the paper's settings: λ=(12,48,64) raw DC gain, G = 1e4·I, θ₀ = 0",
    )
    g = p.add_argument_group("input file")
    g.add_argument("--columns", help="map column names, e.g. t=time,x=pos,F=force")
    g.add_argument("--force-scale", type=float, help="multiply F by this (e.g. 1.75, or N/V)")
    g.add_argument("--resample", action="store_true", help="resample a non-uniform record (linear)")
    add_units_argument(g)


def settings(args, dt=None):
    """(model, bank, gain) from the common arguments (the gain as a Module); without --poles or
    --coeffs the filter is the package's sampling-aware default (s + p)³ for records sampled at
    ``dt`` (p = 4 rad/s at 200 Hz or faster)."""
    import lionjax as lj

    from .._validity import default_poles

    if args.regions:
        model = lj.Piecewise(float_list(args.regions, "--regions"), args.x_hold, args.F_hold)
    else:
        model = lj.MassDamper(args.x_hold, args.F_hold)
    unit = args.dc_gain == "unit"
    gain_arg = getattr(args, "gain", "auto")
    if getattr(args, "paper", False):
        if args.poles or args.coeffs:
            raise InputError("--paper fixes the filter; drop --poles/--coeffs.")
        return model, lj.FilterBank.paper(), lj.FixedGain(1e4)
    if args.poles and args.coeffs:
        raise InputError("give either --poles or --coeffs, not both.")
    if args.coeffs:
        bank = lj.FilterBank(float_list(args.coeffs, "--coeffs"), unit_dc_gain=unit)
    elif args.poles:
        bank = lj.FilterBank.from_poles(np.asarray(float_list(args.poles, "--poles")), unit)
    else:
        p = float(default_poles(dt))
        bank = lj.FilterBank.from_poles(np.array([-p, -p, -p]), unit)
    if gain_arg == "auto":
        gain = lj.AutoGain(getattr(args, "rate", 1.0))
    else:
        try:
            g = float(gain_arg)
        except ValueError:
            raise InputError(f"--gain: expected 'auto' or a number, got {gain_arg!r}.") from None
        gain = lj.FixedGain(g)
    return model, bank, gain


def stepper(args):
    """Lion's stepper: the exact step, normalised by --normalisation μ when μ ≠ 0."""
    import lionjax as lj

    mu = float(getattr(args, "normalisation", 0.0) or 0.0)
    return lj.ExactStep(normalisation=mu if mu else None)


def load(args):
    import lionjax as lj

    columns = lj.extend.parse_columns(args.columns) if args.columns else None
    return lj.load_record(
        args.data,
        columns=columns,
        force_scale=args.force_scale,
        resample=args.resample,
        units=args.units,
    )


def identify(record, args) -> dict:
    """Run the identification; returns the JSON payload."""
    import lionjax as lj

    model, bank, gain = settings(args, record.dt)
    out = {
        "file": str(args.data),
        "method": args.method,
        "model": type(model).__name__,
        "regions": list(getattr(model, "bounds", ())),
        "n_samples": int(record.n_samples),
        "dt": float(record.dt),
        "filter": {
            "coeffs": np.asarray(bank.coeffs).tolist(),
            "unit_dc_gain": bank.unit_dc_gain,
            "x_hold": args.x_hold,
            "F_hold": args.F_hold,
        },
    }
    if args.method == "ls":
        sol = lj.least_squares(model, record, bank=bank)
        out["params"] = {k: float(v) for k, v in sol.params().items()}
        out["std"] = {n: float(s) for n, s in zip(sol.names, np.asarray(sol.std), strict=True)}
        out["condition"] = float(sol.condition)
        out["rms_equation_error"] = float(sol.rms)
    else:
        theta0 = None
        if args.theta0:
            theta0 = np.asarray(float_list(args.theta0, "--theta0"), float)
        if args.paper and theta0 is None:
            theta0 = np.zeros(len(model.names))
        sol = lj.lion(model, record, bank=bank, gain=gain, stepper=stepper(args), theta0=theta0)
        out["params"] = {k: float(v) for k, v in sol.params().items()}
        out["gain"] = np.asarray(sol.gain).tolist()
        out["final_cost"] = float(sol.J[-1])
        # the convergence time of lionjax (as lion_batched and study): seconds after which
        # every parameter stays within 2 % of the least-squares answer (null: not settled)
        ls = lj.least_squares(model, record, bank=bank, initial="discard")
        out["params_ls"] = {k: float(v) for k, v in ls.params().items()}
        t_conv = float(sol.convergence_time(ls.theta, tolerance=0.02))
        out["convergence_time"] = t_conv if np.isfinite(t_conv) else None
        out["duration"] = float(record.dt) * (int(record.n_samples) - 1)
        out["gain_rule"] = "fixed" if isinstance(gain, lj.FixedGain) else "auto"
        out["gain_rates"] = gain_rates(gain, ls)
        std = lion_std(np.array(list(out["params"].values())), ls)
        out["std"] = dict(zip(out["params"], std.tolist(), strict=True))
        out["std_method"] = STD_AT_LION
    out["units"] = record.units
    out["param_units"] = {n: param_unit(n, record.units) for n in out["params"]}
    return out


def param_unit(name: str, units: str = "linear") -> str:
    """The unit of the identified parameter ``name`` (``b_1`` as ``b``) in ``units``."""
    return unit(UNITS.get(name.split("_")[0], ""), units)


#: How ``identify --method lion`` states its uncertainty (printed and in the JSON).
STD_AT_LION = (
    "least-squares covariance σ²(ΦᵀΦ)⁻¹ (initial='discard') with σ² the residual variance at "
    "Lion's estimate; Lion's law itself gives no covariance"
)


def lion_std(theta, ls) -> np.ndarray:
    """Standard deviations for Lion's estimate ``theta``: the least-squares covariance
    σ²(ΦᵀΦ)⁻¹ of ``ls`` (an :class:`~lionjax.LSSolution`, rows ε₁ and ε₂) with σ² the residual
    variance at ``theta`` instead of at θ_LS. Least squares' residual is orthogonal to Φ, so
    RSS(θ) = RSS(θ_LS) + δᵀΦᵀΦδ with δ = θ − θ_LS and ΦᵀΦ = σ²_LS·cov⁻¹: the covariance scales
    by 1 + δᵀcov⁻¹δ/(N_rows − p)."""
    cov = np.asarray(ls.covariance, np.float64)
    delta = np.asarray(theta, np.float64) - np.asarray(ls.theta, np.float64)
    p = delta.size
    dof = max(2.0 * float(ls.n_used) - p, 1.0)
    try:
        q = float(delta @ np.linalg.solve(cov, delta))
    except np.linalg.LinAlgError:
        return np.sqrt(np.diagonal(cov))
    return np.sqrt(np.diagonal(cov) * (1.0 + max(q, 0.0) / dof))


def print_result(out: dict) -> None:
    lion = out["method"] == "lion"
    rows = []
    for name, value in out["params"].items():
        std = out.get("std", {}).get(name)
        rows.append([name, value, std, out["param_units"][name]])
    title = (
        f"{out['file']}: {out['model']} by {out['method']}, {out['n_samples']} samples at "
        f"{1 / out['dt']:.6g} Hz"
    )
    print(format_table(["param", "estimate", "std*" if lion else "std", "unit"], rows, title))
    if "condition" in out:
        print(
            f"condition number {out['condition']:.4g}; rms equation error "
            f"{out['rms_equation_error']:.4g}"
        )
    if lion:
        print(f"* std: {out['std_method']}.")
        print(convergence_sentence(out))


#: Time constants a record must hold at Lion's slowest rate for θ to settle (e^−5 < 1 %).
SETTLE_TIME_CONSTANTS = 5.0


def gain_rates(gain, ls) -> list[float]:
    """[slowest, fastest] rate [1/s] at which Lion's law converges under ``gain``: the extreme
    eigenvalues of G·R, R = ΦᵀΦ/n the mean regressor moment (from the least-squares answer
    ``ls``: ΦᵀΦ = σ²·cov⁻¹); AutoGain's rate for both under AutoGain (G = rate·R⁻¹)."""
    import lionjax as lj

    if not isinstance(gain, lj.FixedGain):
        return [float(gain.rate)] * 2
    try:
        R = float(ls.sigma2) * np.linalg.inv(np.asarray(ls.covariance, np.float64))
    except np.linalg.LinAlgError:
        return [float("nan")] * 2
    R = R / max(float(ls.n_used), 1.0)
    G = np.asarray(gain.matrix, np.float64)
    GR = (G if G.ndim == 2 else float(G) * np.eye(len(R))) @ R
    ev = np.sort(np.abs(np.linalg.eigvals(GR)))
    return [float(ev[0]), float(ev[-1])]


def convergence_sentence(out: dict, tolerance: float = 0.02) -> str:
    """Plain English: when Lion's estimate settles within the band of least squares, and, when
    it did not, which way to move the gain: up where the slowest rate leaves fewer than
    :data:`SETTLE_TIME_CONSTANTS` time constants in the record, down where it leaves more (θ
    then follows the equation error's noise instead of settling)."""
    st = out["convergence_time"]
    band = f"within {100 * tolerance:g} % of least squares"
    if st is not None:
        return f"Lion's estimate settles {band} after {st:.3g} s."
    flag = "--rate" if out.get("gain_rule", "auto") == "auto" else "--gain"
    slow, fast = out.get("gain_rates", [float("nan")] * 2)
    if np.isfinite(slow) and slow * out["duration"] >= SETTLE_TIME_CONSTANTS:
        fix = (
            f"lower {flag}: its slowest rate, {slow:.3g} 1/s (fastest {fast:.3g} 1/s), already "
            f"fits {slow * out['duration']:.3g} time constants in the record, so θ follows the "
            "noise of the equation error instead of settling"
        )
    else:
        fix = f"raise {flag} or use a longer record"
    return (
        f"Lion's estimate did not settle {band} by the end of the record "
        f"({out['duration']:.3g} s); {fix}."
    )


def run(args) -> int:
    if len(args.data) > 1 or Path(args.data[0]).is_dir():
        return run_many(args)
    if args.csv:
        raise InputError(
            "--csv writes the table of several records (several files or a folder); for one "
            "file use --json, or pass the folder that holds it."
        )
    check_output(args.json, "--json")
    settings(args)  # bad options fail before the file is read
    args.data = args.data[0]  # one file: the single-record path below, unchanged
    with about(args.data):
        record = load(args)
        out = identify(record, args)
    print_result(out)
    if args.json:
        write_json(args.json, out)
        print(f"wrote {args.json}")
    return 0


# --------------------------------------------------------------------------- many files


def data_files(data: list[str]) -> list[Path]:
    """The files named by DATA: files as given, folders expanded (sorted, not recursive)."""
    from .._io import record_files

    paths: list[Path] = []
    for d in data:
        p = Path(d)
        paths.extend(record_files(p) if p.is_dir() else [p])
    seen: dict[Path, Path] = {}
    for p in paths:
        key = p.resolve()
        if key in seen:
            raise InputError(
                f"{p}: named twice in DATA (also as {seen[key]}); give each file once (a folder "
                "already includes every record file in it)."
            )
        seen[key] = p
    return paths


def load_many(paths: list[Path], args) -> list:
    """Read and check every file before anything is computed; one error lists every bad file."""
    import lionjax as lj

    columns = lj.extend.parse_columns(args.columns) if args.columns else None
    records, errors = [], []
    for p in counted(paths, "reading", "files"):
        try:
            records.append(
                lj.load_record(
                    p,
                    columns=columns,
                    force_scale=args.force_scale,
                    resample=args.resample,
                    units=args.units,
                )
            )
        except InputError as e:
            errors.append(str(e))
    if errors:
        raise InputError(
            f"{len(errors)} of {len(paths)} files cannot be used (nothing was identified):\n"
            + "\n".join(f"  {e}" for e in errors)
        )
    return records


def run_many(args) -> int:

    check_output(args.json, "--json")
    check_output(args.csv, "--csv")
    settings(args)  # bad options fail before any file is read
    paths = data_files(args.data)
    with status("identify", enabled=wanted(args.quiet)) as st:
        records = load_many(paths, args)
        st.stage(f"identifying the {len(records)} records in one batched call")
        res = _identify_many(records, paths, args)
    return report_many(res, records, args)


def _identify_many(records, paths, args):
    """The batched identification of ``records`` (``identify_batch``) under the options."""
    import lionjax as lj

    model, bank, gain = settings(args, np.array([float(r.dt) for r in records]))
    theta0 = None
    if args.method == "lion":
        if args.theta0:
            theta0 = np.asarray(float_list(args.theta0, "--theta0"), float)
        elif args.paper:
            theta0 = np.zeros(len(model.names))
    if args.method == "ls":
        method = lj.LeastSquares()
    else:
        method = lj.Lion(gain=gain, stepper=stepper(args), theta0=theta0)
    return lj.identify_batch(
        model, records, method=method, labels=[str(p) for p in paths], bank=bank
    )


def report_many(res, records, args) -> int:
    """Print and write the rows of a batch; exit status 1 when some record failed."""
    print_many(res, args.units)
    if args.json:
        res.to_json(args.json)
        print(f"wrote {args.json}")
    if args.csv:
        res.to_csv(args.csv)
        print(f"wrote {args.csv}")
    failed = res.failures()
    if failed:
        print(
            f"lionjax identify: {len(failed)} of {len(records)} records not identified "
            "(rows written with NaN estimates):\n"
            + "\n".join(f"  {label}: {why}" for label, why in failed),
            file=sys.stderr,
        )
        return 1
    return 0


def print_many(res, units: str = "linear") -> None:
    names = list(res.names)
    headers = ["file", "samples", "dt [s]", *names]
    if res.method == "lion":
        headers += [f"{n}_LS" for n in names] + ["t_conv [s]"]
    headers += ["condition"] + (["rms"] if res.rms is not None else []) + ["status"]
    rows = []
    for r in res.to_rows():
        row = [r["record"], r["n_samples"], r["dt"], *(r[n] for n in names)]
        if res.method == "lion":
            t = r["convergence_time"]  # inf: not within the band by the end of the record
            row += [r[f"{n}_ls"] for n in names] + ["not settled" if t == np.inf else t]
        row += [r["condition"]] + ([r["rms"]] if res.rms is not None else []) + [r["status"]]
        rows.append(["inf" if v == np.inf else v for v in row])  # format_table prints nan
    how = (
        "least squares over the samples after the filter transient (= least_squares(initial="
        "'discard') per file)"
        if res.method == "ls"
        else f"Lion's estimator (exact step; t_conv: within {100 * res.tolerance:g} % of LS)"
    )
    stated = ", ".join(f"{n} [{param_unit(n, units)}]" for n in names)
    print(
        format_table(
            headers,
            rows,
            f"{len(rows)} records: {res.model} by {how}, in one batched call; {stated}",
        )
    )
