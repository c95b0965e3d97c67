"""The real-data gallery: `lionjax.diagnose` (defaults) on measured records of real benches.

Each record has a pre-registered expectation, ``benchmarks/real/<name>/EXPECTED.md``, written
from its source's physics before the first run and never changed after (a disagreement goes in
the note column), and a ``PROVENANCE.md`` (source, commit, licence, what was done to the data).
The script diagnoses every record with the default settings and writes one table:

    PYTHONPATH=<checkout> python benchmarks/real_gallery.py [--only NAME,...] [--out DIR]

→ ``DIR/<date>_real_gallery.md`` and ``.json`` (default ``benchmarks/results``): record,
expected, verdict, confidence, stack, baseline a and b, what the final model says (the natural
frequency of a spring, the mode's frequency, the friction level, the position period of a
periodic residual), runtime, outcome (``pass``: the verdict is one the EXPECTED.md accepts)
and a note (the warnings the diagnosis raised, the record's refusal).

Records and where their data is read:

- ``silverbox_multisine``, ``silverbox_arrow``: ``shared/data/silverbox/`` beside the
  checkout (searched in the checkout's parent folders, or ``$LIONJAX_SHARED_DATA``), official
  splits train_val → test_multisine / test_arrow_full.
- ``emps``: ``lionjax.datasets.emps()`` (package data).
- the others: ``<name>/train.npz`` and ``valid.npz`` (keys ``t``, ``x``, ``F``, ``units``) in
  ``$LIONJAX_REAL_DATA``, ``benchmarks/real/`` or ``shared/data/gallery/`` beside the checkout;
  ``benchmarks/real/package.py`` builds them from the source files named in PROVENANCE.md.
  A record whose data is absent is listed as such and not diagnosed.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
import os
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REAL = HERE / "real"


@dataclasses.dataclass(frozen=True)
class Entry:
    """One gallery record: its loader and the verdicts its EXPECTED.md accepts."""

    name: str
    expected: str
    accepted: tuple[str, ...]
    load: Callable[[], tuple]
    #: a "where" finding the EXPECTED.md requires beside the verdict (its ``kind``), or None
    needs: str | None = None


def _shared_data() -> Path | None:
    env = os.environ.get("LIONJAX_SHARED_DATA")
    if env:
        return Path(env)
    for parent in HERE.parents:
        if (parent / "shared" / "data").is_dir():
            return parent / "shared" / "data"
    return None


def _silverbox(split: str):
    import lionjax as lj

    root = _shared_data()
    path = None if root is None else root / "silverbox" / "silverbox_SNLS80mV.npz"
    if path is None or not path.is_file():
        raise FileNotFoundError("shared/data/silverbox/silverbox_SNLS80mV.npz not found")
    d = np.load(path)
    dt = float(d["dt"])

    def part(key):
        a, b = (int(v) for v in d[key])
        return lj.Record(d["position"][a:b], d["force"][a:b], dt, float(d["t"][a]))

    return part("split_train_val"), part(split), "linear"


def _emps():
    import lionjax as lj

    return lj.datasets.emps("estimation"), lj.datasets.emps("validation"), "linear"


def _npz_folder(name: str) -> Path | None:
    roots = [os.environ.get("LIONJAX_REAL_DATA"), REAL]
    shared = _shared_data()
    if shared is not None:
        roots.append(shared / "gallery")
    for root in roots:
        if root and (Path(root) / name / "train.npz").is_file():
            return Path(root) / name
    return None


def load_npz_pair(name: str):
    """(train, valid, units) of a packaged gallery record (FileNotFoundError where absent)."""
    import lionjax as lj

    folder = _npz_folder(name)
    if folder is None:
        raise FileNotFoundError(f"{name}/train.npz not found (see {name}/PROVENANCE.md)")
    out = []
    for split in ("train", "valid"):
        d = np.load(folder / f"{split}.npz")
        units = str(d["units"])
        kw = {"units": units} if "units" in lj.Record.__dataclass_fields__ else {}
        out.append(lj.Record.from_samples(d["t"], d["x"], d["F"], source=f"{name}/{split}", **kw))
    return out[0], out[1], units


#: The payload series' records and their added inertias [kg·m²] (siesta_payload/PROVENANCE.md),
#: and the data sheet's torque constant the series is held to [N·m/mA]
#: (siesta_payload/EXPECTED.md).
PAYLOADS = {"siesta_L0": 0.0, "siesta_L1": 224.5440144e-6, "siesta_L2": 548.4378187e-6,
            "siesta_L4": 772.98e-6}  # fmt: skip
SHEET_K = 3.0 / 2300.0

ENTRIES = (
    Entry("motorbench_motor", "flexible_mode", ("flexible_mode",),
          lambda: load_npz_pair("motorbench_motor")),
    Entry("motorbench_load", "flexible_mode", ("flexible_mode",),
          lambda: load_npz_pair("motorbench_load")),
    Entry("lorenz_friction", "coulomb_friction",
          ("coulomb_friction", "asymmetric_friction", "inconclusive"),
          lambda: load_npz_pair("lorenz_friction")),
    Entry("odrive_cogging", "unexplained (position_period)", ("unexplained", "inconclusive"),
          lambda: load_npz_pair("odrive_cogging"), needs="position_period"),
    Entry("quanser_flexcart", "coulomb_friction", ("coulomb_friction", "asymmetric_friction"),
          lambda: load_npz_pair("quanser_flexcart")),
    Entry("silverbox_multisine", "spring", ("spring",),
          lambda: _silverbox("split_test_multisine")),
    Entry("silverbox_arrow", "spring", ("spring",), lambda: _silverbox("split_test_arrow_full")),
    Entry("emps", "coulomb_friction + offset", ("coulomb_friction", "asymmetric_friction"), _emps),
    *(
        Entry(name, "coulomb_friction", ("coulomb_friction", "asymmetric_friction"),
              lambda name=name: load_npz_pair(name))
        for name in PAYLOADS
    ),
)  # fmt: skip

#: Folders of documents a series of records shares (its EXPECTED.md and PROVENANCE.md), by the
#: records they serve.
FAMILIES = {"siesta_payload": tuple(PAYLOADS)}


def payload_law(rows: list[dict]) -> dict | None:
    """The payload series' law (siesta_payload/EXPECTED.md): 1/b = (J₀ + J_L)/K_τ from the final
    models' b, fitted by least squares; ``pass`` where 1/b increases with J_L, each point lies
    within 20 % of the four 1/b values' range from the line, K_τ = 1/slope is within a factor 2
    of the data sheet's and J₀ > 0. None unless all four records were diagnosed."""
    got = {r["record"]: (r.get("final_params") or {}).get("b") for r in rows}
    if any(got.get(k) is None for k in PAYLOADS):
        return None
    J = np.array(list(PAYLOADS.values()))
    inv = np.array([1.0 / got[k] for k in PAYLOADS])
    slope, icpt = np.polyfit(J, inv, 1)
    spread = float(np.ptp(inv))
    worst = float(np.max(np.abs(inv - (icpt + slope * J)))) / spread if spread > 0 else math.inf
    k_tau = 1.0 / slope if slope > 0 else math.nan
    checks = {
        "increasing": bool(np.all(np.diff(inv) > 0)),
        "on_the_line": worst <= 0.2,
        "k_tau_within_2x": bool(0.5 <= k_tau / SHEET_K <= 2.0),
        "j0_positive": bool(slope > 0 and icpt > 0),
    }
    return {
        "records": list(PAYLOADS),
        "added_inertia": J.tolist(),
        "inv_b": inv.tolist(),
        "slope": float(slope),
        "intercept": float(icpt),
        "worst_off_line": worst,
        "k_tau": k_tau,
        "k_tau_sheet": SHEET_K,
        "j0": float(icpt / slope) if slope > 0 else math.nan,
        "checks": checks,
        "outcome": "pass" if all(checks.values()) else "FAIL",
    }


def final_says(d) -> str:
    """The final model's figures that carry its physics, in words."""
    p = d.final.get("params", {})
    u = d.final.get("units", {})
    out = []
    if "k" in p and p.get("b") is not None and p["k"] is not None and p["b"] * p["k"] > 0:
        out.append(f"spring f_n = {math.sqrt(p['b'] * p['k']) / (2 * math.pi):.4g} Hz")
    for k in (
        "f_mode",
        "zeta_mode",
        "mass_ratio",
        "Fc",
        "Fc_pos",
        "Fc_neg",
        "F0",
        "tau",
        "tau_samples",
    ):
        if p.get(k) is not None:
            out.append(f"{k} = {p[k]:.4g} {u.get(k, '')}".rstrip())
    for w in d.where:
        if w.get("kind") == "position_period":
            out.append(f"position period {w.get('band')}")
    return "; ".join(out)


def findings(d) -> list[str]:
    """What the diagnosis saw, in words, for the note column: the residual's spectral peak, the
    best-scoring candidate that was refused and why, the detection limit, closed loop."""
    out = [f"residual peak {w['band']}" for w in d.where if w.get("kind") == "frequency_peak"]
    refused = [e for e in d.effects if not e.significant and e.score > 10]
    if refused:
        e = refused[0]
        out.append(f"best refused: {e.name} (score {e.score:.3g}; {e.reason})")
    out.append(f"detection limit {d.noise.get('detection_limit', float('nan')):.3g}")
    if d.noise.get("closed_loop"):
        out.append("closed loop")
    return out


def outcome(e: Entry, d) -> str:
    """``pass`` when the verdict is one the EXPECTED.md accepts (and its required finding is
    there), else ``FAIL`` with what is missing."""
    if d.verdict not in e.accepted:
        return "FAIL"
    if e.needs and not any(w.get("kind") == e.needs for w in d.where):
        return f"FAIL (no {e.needs} finding)"
    return "pass"


def run_entry(e: Entry) -> dict:
    import lionjax as lj

    row = {"record": e.name, "expected": e.expected, "accepted": list(e.accepted)}
    try:
        train, valid, units = e.load()
    except FileNotFoundError as err:
        return {**row, "outcome": "no data", "note": str(err)}
    row["units"] = units
    row["samples"] = [int(train.n_samples), int(valid.n_samples)]
    row["dt"] = float(train.dt)
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            d = lj.diagnose(train, valid)
        except lj.InputError as err:
            row.update(outcome="refused", note=str(err), runtime_s=time.perf_counter() - start)
            return row
    row["runtime_s"] = time.perf_counter() - start
    base = d.baseline["params"]
    row.update(
        verdict=d.verdict,
        confidence=float(d.confidence),
        stack=list(d.stack),
        ambiguous=list(d.ambiguous),
        baseline_a=base.get("a"),
        baseline_b=base.get("b"),
        final_params=d.final.get("params", {}),
        final_units=d.final.get("units", {}),
        final_says=final_says(d),
        shrink=d.final.get("shrink"),
        outcome=outcome(e, d),
        findings=findings(d),
        warnings=sorted({str(w.message)[:200] for w in caught}),
        diagnosis=d.to_json(),
    )
    return row


def _bare(r, s=slice(None), F=None):
    """``r``'s x and F (or ``F``) over the rows ``s``, without its extra signals."""
    import lionjax as lj

    F = np.asarray(r.F if F is None else F)[s]
    return lj.Record(np.asarray(r.x)[s], F, r.dt, 0.0, units=r.units)


def _half(r, k: int):
    T = int(r.n_samples)
    return _bare(r, slice(0, T // 2) if k == 0 else slice(T // 2, T))


def _late(r):
    """The force read at the sample instants of a force held over each interval: the mean of
    the two intervals beside it, (Fₖ₋₁ + Fₖ)/2, half a sample late."""
    F = np.asarray(r.F, np.float64)
    return _bare(r, F=0.5 * (F + np.concatenate([F[:1], F[:-1]])))


def _averaged(r, k: int):
    """x and F each the mean over the same bins of ``k`` samples, stamped at the bin's start (a
    record decimated by averaging both signals): F is then the held input lionjax reads, and x
    is low-passed and late by (k − 1)/(2k) of the new interval."""
    import lionjax as lj

    n = int(r.n_samples) // k * k
    x, F = (np.asarray(s, np.float64)[:n].reshape(-1, k).mean(1) for s in (r.x, r.F))
    return lj.Record(x, F, r.dt * k, 0.0, units=r.units)


#: What a similar record of the same bench might bring, each applied to both records: their
#: roles swapped, decimated by 2 and 4 (F averaged, x kept at the new instants: Record.decimate),
#: the first and the second half, a force read half a sample late, and both signals averaged
#: over bins of 4 (x then lags the held force by 3/8 of a sample).
PERTURBATIONS = {
    "swapped": lambda tr, va: (va, tr),
    "decimated ×2": lambda tr, va: (_bare(tr).decimate(2), _bare(va).decimate(2)),
    "decimated ×4": lambda tr, va: (_bare(tr).decimate(4), _bare(va).decimate(4)),
    "first half": lambda tr, va: (_half(tr, 0), _half(va, 0)),
    "second half": lambda tr, va: (_half(tr, 1), _half(va, 1)),
    "F half a sample late": lambda tr, va: (_late(tr), _late(va)),
    "x and F averaged ×4": lambda tr, va: (_averaged(tr, 4), _averaged(va, 4)),
}


def perturbed(e: Entry) -> dict:
    """{perturbation: "verdict (confidence)", marked ✓ where the EXPECTED.md accepts it}."""
    import lionjax as lj

    try:
        train, valid, _ = e.load()
    except FileNotFoundError:
        return {}
    out = {}
    for name, make in PERTURBATIONS.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                d = lj.diagnose(*make(train, valid))
                ok = " ✓" if d.verdict in e.accepted else ""
                out[name] = f"{d.verdict} ({d.confidence:.2f}){ok}"
            except lj.InputError as err:
                out[name] = f"refused: {str(err)[:80]}"
    return out


def _fmt(v, spec=".4g") -> str:
    return "—" if v is None else format(v, spec)


def markdown(rows: list[dict], meta: dict) -> str:
    lines = [
        "# Real-data gallery",
        "",
        f"{meta['date']}, commit {meta['commit']}, `lj.diagnose` with default settings, "
        f"{meta['cpus']} CPU(s). Expected verdicts: `benchmarks/real/<record>/EXPECTED.md` "
        "(pre-registered). Produced by `benchmarks/real_gallery.py`.",
        "",
        "| record | expected | verdict | confidence | stack | gap shrink | baseline a [1/s] "
        "| baseline b | final model says | runtime [s] | outcome | note |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        note = "; ".join([*r.get("findings", []), *r.get("warnings", []), r.get("note", "")])
        note = note.strip("; ")
        lines.append(
            f"| {r['record']} | {r['expected']} | {r.get('verdict', '—')} | "
            f"{_fmt(r.get('confidence'), '.2f')} | {', '.join(r.get('stack', [])) or '—'} | "
            f"{_fmt(r.get('shrink') if r.get('stack') else None, '.2f')} | "
            f"{_fmt(r.get('baseline_a'))} | {_fmt(r.get('baseline_b'))} | "
            f"{r.get('final_says', '') or '—'} | {_fmt(r.get('runtime_s'), '.0f')} | "
            f"{r['outcome']} | {note.replace('|', '/') or '—'} |"
        )
    law = meta.get("payload_law")
    if law:
        c = law["checks"]
        pts = ", ".join(
            f"{r.removeprefix('siesta_')} {v:.4g}"
            for r, v in zip(law["records"], law["inv_b"], strict=True)
        )
        lines += [
            "",
            "## The payload law (siesta, `benchmarks/real/siesta_payload/EXPECTED.md`)",
            "",
            f"1/b [s²·mA/rad]: {pts}. Line 1/b = (J₀ + J_L)/K_τ: K_τ = {law['k_tau']:.4g} N·m/mA "
            f"(data sheet {law['k_tau_sheet']:.4g}), J₀ = {law['j0']:.4g} kg·m², the farthest "
            f"point {law['worst_off_line']:.1%} of the range off the line. Increasing: "
            f"{c['increasing']}; on the line (≤ 20 %): {c['on_the_line']}; K_τ within 2×: "
            f"{c['k_tau_within_2x']}; J₀ > 0: {c['j0_positive']}. **{law['outcome']}**.",
        ]
    return "\n".join(lines) + "\n"


def _meta() -> dict:
    import subprocess

    commit = subprocess.run(
        ["git", "-C", str(HERE), "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    return {"date": datetime.date.today().isoformat(), "commit": commit, "cpus": os.cpu_count()}


def _main_perturbed(entries: list[Entry], out: Path) -> int:
    rows = {}
    for e in entries:
        rows[e.name] = perturbed(e)
        print(f"{e.name}: {rows[e.name]}", flush=True)
    meta = _meta()
    heads = list(PERTURBATIONS)
    lines = [
        "# Real-data gallery, perturbed",
        "",
        f"{meta['date']}, commit {meta['commit']}, `lj.diagnose` with default settings. Each "
        "record diagnosed under `PERTURBATIONS` (`benchmarks/real_gallery.py --perturb`); ✓: a "
        "verdict its pre-registered EXPECTED.md accepts.",
        "",
        "| record | " + " | ".join(heads) + " |",
        "|---|" + "---|" * len(heads),
    ]
    for name, r in rows.items():
        lines.append(f"| {name} | " + " | ".join(r.get(h, "no data") for h in heads) + " |")
    out.mkdir(parents=True, exist_ok=True)
    stem = out / f"{meta['date']}_real_gallery_perturbed"
    stem.with_suffix(".json").write_text(json.dumps({**meta, "rows": rows}, indent=1))
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {stem}.md and .json", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", help="comma-separated record names (default: all)")
    p.add_argument("--out", type=Path, default=HERE / "results")
    p.add_argument(
        "--perturb",
        action="store_true",
        help="diagnose each record under PERTURBATIONS instead (→ <date>_real_gallery_perturbed)",
    )
    a = p.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    names = None if a.only is None else set(a.only.split(","))
    entries = [e for e in ENTRIES if names is None or e.name in names]
    if names is not None and len(entries) != len(names):
        known = ", ".join(e.name for e in ENTRIES)
        p.error(f"--only: unknown record(s) {sorted(names - {e.name for e in entries})}; {known}")
    if a.perturb:
        return _main_perturbed(entries, a.out)
    rows = []
    for e in entries:
        row = run_entry(e)
        rows.append(row)
        print(
            f"{e.name}: {row.get('verdict', row['outcome'])} "
            f"({_fmt(row.get('confidence'), '.2f')}) {row['outcome']}",
            flush=True,
        )
    meta = _meta()
    law = payload_law(rows)
    if law is not None:
        meta["payload_law"] = law
        print(f"payload law: {law['outcome']} {law['checks']}", flush=True)
    a.out.mkdir(parents=True, exist_ok=True)
    stem = a.out / f"{meta['date']}_real_gallery"
    from lionjax._tables import jsonable

    stem.with_suffix(".json").write_text(json.dumps(jsonable({**meta, "rows": rows}), indent=1))
    stem.with_suffix(".md").write_text(markdown(rows, meta))
    print(f"wrote {stem}.md and .json", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
