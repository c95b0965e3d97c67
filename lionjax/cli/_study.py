"""Run Lion's estimator over a grid of gains × filter poles (× datasets) in batched calls.

With no DATA it simulates a small seeded set of twin records (the paper's region 2, closed loop,
multisine, force noise). Prints one row per grid point: the final estimates, the convergence
time to within 2 % of least squares, and the final bias vs least squares. --plot draws the
designer's map: heat maps of convergence time and bias over (gain, pole).
"""

from __future__ import annotations

import argparse

import numpy as np

from .._errors import InputError
from ._common import float_list, format_table

NAME = "study"
HELP = "map convergence time and bias of Lion's estimator over gains × filter poles"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("data", nargs="*", help="record files or a folder (default: simulated twin)")
    p.add_argument("--gains", default="1e2,1e3,1e4", help="gains, comma separated")
    p.add_argument(
        "--gain-type",
        choices=("fixed", "auto"),
        default="fixed",
        help="fixed: G = g·I (default); auto: AutoGain rates [1/s]",
    )
    p.add_argument(
        "--poles", default="-4,-4,-4;-8,-8,-8", help="pole sets [rad/s], ';' between sets"
    )
    p.add_argument("--samples", type=int, default=3000, help="samples per simulated record")
    p.add_argument("--n-records", type=int, default=2, help="simulated records (no DATA)")
    p.add_argument("--chunk-size", type=int, help="grid points per batched call")
    p.add_argument("--json", metavar="OUT.json", help="write the grid as JSON")
    p.add_argument("--csv", metavar="OUT.csv", help="write the grid as CSV")
    p.add_argument("--plot", metavar="OUT.png", help="heat maps over (gain, pole)")


def _poles(text: str) -> list[list[float]]:
    sets = [float_list(s, "--poles") for s in text.split(";") if s.strip()]
    if not sets or len({len(s) for s in sets}) != 1:
        raise InputError(
            f"--poles: expected pole sets of equal length separated by ';', got {text!r}."
        )
    return sets


def plot(res, path: str, gain_type: str = "fixed") -> None:
    """Heat maps of median convergence time and bias over (gain, pole), datasets pooled."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    axes = [res.dims.index(d) for d in ("gain", "poles")]
    other = tuple(i for i in range(len(res.dims)) if i not in axes)
    tc = np.moveaxis(res.convergence_time, axes, (-2, -1))
    bias = np.moveaxis(res.bias, axes, (-2, -1))
    tc = np.median(tc.reshape((-1,) + tc.shape[-2:]), axis=0) if other else tc
    bias = np.median(bias.reshape((-1,) + bias.shape[-2:]), axis=0) if other else bias
    gains = res.coords["gain"]
    poles = [",".join(f"{q:g}" for q in P) for P in res.coords["poles"]]
    fig, ax = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    gl = "AutoGain rate [1/s]" if gain_type == "auto" else "gain g [G = g·I]"
    for a, z, title, unit in (
        (ax[0], tc, f"convergence time to within {100 * res.tolerance:g} % of LS (median)", "s"),
        (ax[1], 100 * bias, "final bias vs LS, max over params (median)", "%"),
    ):
        zz = np.where(np.isfinite(z), z, np.nan)
        im = a.imshow(zz.T, origin="lower", aspect="auto", cmap="viridis")
        a.set_xticks(range(len(gains)), [f"{g:g}" for g in gains])
        a.set_yticks(range(len(poles)), poles)
        a.set_xlabel(gl)
        a.set_ylabel("filter poles [rad/s]")
        a.set_title(title, fontsize=10)
        for i in range(zz.shape[0]):
            for j in range(zz.shape[1]):
                v = z[i, j]
                a.text(
                    i,
                    j,
                    "n/s" if np.isinf(v) else f"{v:.3g}",
                    ha="center",
                    va="center",
                    color="w",
                    fontsize=8,
                )
        fig.colorbar(im, ax=a, label=unit)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run(args) -> int:
    import lionjax as lj

    gains = float_list(args.gains, "--gains")
    poles = _poles(args.poles)
    if args.data:
        paths = args.data[0] if len(args.data) == 1 else args.data
        loaded = lj.load_records(paths)
        records = [r for _, r in loaded]
        names = [p.name for p, _ in loaded]
    else:
        records = lj.study_records(args.n_records, n_samples=args.samples)
        names = [f"twin{i}" for i in range(len(records))]
    res = lj.study(
        lj.MassDamper(),
        records,
        gains=gains,
        gain_type=args.gain_type,
        poles=poles,
        unit_dc_gain=True,
        dataset_names=names,
        chunk_size=args.chunk_size,
    )
    rows = [
        [
            r["dataset"],
            r["gain"],
            ",".join(f"{q:g}" for q in r["poles"]),
            r["a"],
            r["b"],
            r["a_ls"],
            r["b_ls"],
            r["convergence_time"],
            100 * r["bias"],
        ]
        for r in res.to_records()
    ]
    print(
        format_table(
            ["dataset", "gain", "poles", "a", "b", "a_LS", "b_LS", "t_conv [s]", "bias [%]"],
            rows,
            f"Lion's estimator over {len(gains)} gains × {len(poles)} pole sets × "
            f"{len(records)} records (t_conv inf: not within {100 * res.tolerance:g} % by the end)",
        )
    )
    if args.json:
        res.to_json(args.json)
        print(f"wrote {args.json}")
    if args.csv:
        res.to_csv(args.csv)
        print(f"wrote {args.csv}")
    if args.plot:
        plot(res, args.plot, args.gain_type)
        print(f"wrote {args.plot}")
    return 0
