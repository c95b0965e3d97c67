"""Package the gallery's measured records small: ``<name>/train.npz`` and ``<name>/valid.npz``.

Each file holds ``t`` [s], ``x`` [rad or m], ``F`` [the input's own unit] (float64, uniform
``t``) and the strings ``x_unit``, ``F_unit`` and ``units`` (``"rotary"`` or ``"linear"``).
What is done to each source (splits, unit conversion, decimation) is stated here and in the
record's PROVENANCE.md; the source files themselves come from the repositories and commits
that PROVENANCE.md names (they are not part of this repository).

Usage::

    python benchmarks/real/package.py NAME SOURCE_DIR [--out benchmarks/real]

``SOURCE_DIR`` holds the source files under the names PROVENANCE.md gives.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def _save(out: Path, name: str, split: str, t, x, F, *, x_unit, F_unit, units) -> None:
    t = np.asarray(t, dtype=np.float64)
    d = np.diff(t)
    if not np.all(d > 0) or np.max(np.abs(d - d.mean())) > 1e-6 * d.mean():
        raise ValueError(f"{name}/{split}: t is not uniform")
    folder = out / name
    folder.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        folder / f"{split}.npz",
        t=t,
        x=np.asarray(x, dtype=np.float64),
        F=np.asarray(F, dtype=np.float64),
        x_unit=np.str_(x_unit),
        F_unit=np.str_(F_unit),
        units=np.str_(units),
    )


def _hold_decimate(x, F, r: int):
    """x sampled at the block starts, F averaged over each block (the held input)."""
    n = len(x) // r
    return np.asarray(x)[: n * r : r], np.asarray(F)[: n * r].reshape(n, r).mean(axis=1)


def _binned(t, x, F, dt: float, nb: int):
    """(t_k, x_k, F_k, empty) of ``nb`` uniform samples from an irregular log (t ≥ 0): x_k the
    mean of x over [t_k − dt/2, t_k + dt/2), a point sample of a smooth position at the bin's
    centre t_k = (k + ½)·dt; F_k the mean of F over [t_k, t_k + dt), the force held from t_k
    to the next sample (the zero-order hold the method reads F with: a force averaged over the
    same bin as x would reach the model half a sample late). A bin without a sample takes the
    straight line between its neighbours; ``empty`` counts such bins."""
    tc = (np.arange(nb) + 0.5) * dt
    out, empty = [], 0
    for sig, shift in ((x, 0.0), (F, 0.5)):
        k = np.floor(t / dt - shift).astype(np.int64)
        ok = (k >= 0) & (k < nb)
        cnt = np.bincount(k[ok], minlength=nb)
        full = cnt > 0
        m = np.bincount(k[ok], np.asarray(sig, np.float64)[ok], nb)[full] / cnt[full]
        out.append(np.interp(tc, tc[full], m))
        empty = max(empty, int(np.sum(~full)))
    return tc, out[0], out[1], empty


def motorbench(src: Path, out: Path, side: str) -> None:
    """FdiTools motor bench: MultisineTypeA.mat → train, MultisineTypeB.mat → valid.

    fs = 2500 Hz, 20 periods of 2500 samples; the first period (transient) is dropped and the
    next 10 are kept, then x is sampled and iq averaged over pairs (1250 Hz). side "motor": x =
    theta_mx; side "load": x = −theta_my (the sign the source's own scripts use).
    """
    import scipy.io as sio

    name = f"motorbench_{side}"
    for split, fname in (("train", "MultisineTypeA.mat"), ("valid", "MultisineTypeB.mat")):
        d = sio.loadmat(src / fname, squeeze_me=True)
        fs, n = int(d["fs"]), int(d["nrofs"])
        keep = slice(n, 11 * n)
        x = d["theta_mx"][keep] if side == "motor" else -d["theta_my"][keep]
        x, F = _hold_decimate(x.astype(float), d["iq_adx"][keep].astype(float), 2)
        t = np.arange(x.size) * (2.0 / fs)
        _save(out, name, split, t, x, F, x_unit="rad", F_unit="A", units="rotary")


def lorenz(src: Path, out: Path) -> None:
    """Lorenz rotary axis, 1 kHz: Lorenz_Jm_1.txt → train, Lorenz_Fc_1.txt → valid.

    Columns: Pos [rad], Vel [rad/s], PosCmd [rad], VelCmd [rad/s], TorCtrl [N·m]; all 10 000
    samples kept.
    """
    for split, fname in (("train", "Lorenz_Jm_1.txt"), ("valid", "Lorenz_Fc_1.txt")):
        d = np.loadtxt(src / fname)
        t = np.arange(d.shape[0]) * 1e-3
        _save(
            out,
            "lorenz_friction",
            split,
            t,
            d[:, 0],
            d[:, 4],
            x_unit="rad",
            F_unit="N·m",
            units="rotary",
        )


def odrive(src: Path, out: Path) -> None:
    """ODrive slow-velocity runs without anti-cogging: nocomp_0.npy → train, nocomp_1.npy →
    valid.

    Rows: host time [s] (polled, 1.7–4.7 ms apart), encoder.pos_estimate [counts, 8192 per
    revolution], Iq_measured [A]. Kept: 0.5 s ≤ t < 9.9 s (nocomp_1 starts with the previous
    run's end position and a jump to zero); binned by :func:`_binned` over 5 ms; x in rad =
    counts·2π/8192.
    """
    for split, fname in (("train", "nocomp_0.npy"), ("valid", "nocomp_1.npy")):
        t, pos, iq = np.load(src / fname)
        nb = int(round((9.9 - 0.5) / 5e-3)) - 1
        tc, x, F, empty = _binned(t - 0.5, pos, iq, 5e-3, nb)
        if empty:
            raise ValueError(f"odrive/{split}: {empty} empty 5 ms bins")
        x = x * (2 * np.pi / 8192)
        _save(
            out, "odrive_cogging", split, tc + 0.5, x, F, x_unit="rad", F_unit="A", units="rotary"
        )


def quanser_flexcart(src: Path, out: Path) -> None:
    """Quanser two-cart flexible drive, driven cart: velocity_response_1_5.mat → train,
    velocity_response_2.mat → valid.

    1 kHz, 8001 samples: u [V] (square wave ±1.5 or ±2 V), v1 [mm/s] (encoder counts per
    sample × 4.6592 mm/s). x = running sum of v1·dt in m (the count itself), F = u; all kept.
    """
    import scipy.io as sio

    for split, fname in (
        ("train", "velocity_response_1_5.mat"),
        ("valid", "velocity_response_2.mat"),
    ):
        d = sio.loadmat(src / fname, squeeze_me=True)
        t = np.asarray(d["t"], dtype=float)
        dt = float(np.mean(np.diff(t)))
        x = np.cumsum(np.asarray(d["v1"], dtype=float)) * dt * 1e-3
        _save(out, "quanser_flexcart", split, t, x, d["u"], x_unit="m", F_unit="V", units="linear")


#: siesta's step records per payload: (train, valid) file names (see siesta_payload/PROVENANCE.md)
SIESTA = {
    "L0": ("23-03-22--14-44-20_800Hz-L0-step.csv", "23-03-23--15-15-23_800Hz-L0-step.csv"),
    "L1": ("23-03-22--14-43-27_800Hz-L1-step.csv", "23-03-23--15-14-43_800Hz-L1-step.csv"),
    "L2": ("23-03-22--14-42-59_800Hz-L2-step.csv", "23-03-23--15-13-42_800Hz-L2-step.csv"),
    "L4": ("23-03-22--14-41-10_800Hz-L4-step.csv", "23-03-23--15-12-14_800Hz-L4-step.csv"),
}
#: siesta's uniform bins [s]
SIESTA_BIN = 2.5e-3


def siesta(src: Path, out: Path) -> None:
    """Dynamixel XM430-W210 under four payloads: each payload's step record of 2023-03-22 →
    train, of 2023-03-23 → valid.

    Columns: time [ms on 03-22, s on 03-23], setpoint [rad], position [rad], velocity [rad/s],
    current [mA], three derived columns (unused). Logged at about 800 Hz with irregular
    intervals (median 1.26 ms, at most 13 ms): binned by :func:`_binned` over 2.5 ms from the
    first sample; a bin without a sample (a logging gap) takes the straight line between its
    neighbours, and the count of such bins is printed.
    """
    for load, files in SIESTA.items():
        for split, fname in zip(("train", "valid"), files, strict=True):
            path = src / fname
            with open(path) as f:
                ms = f.readline().split(",")[0].strip() == "time[ms]"
            d = np.loadtxt(path, delimiter=",", skiprows=1)
            t = d[:, 0] * (1e-3 if ms else 1.0)
            t = t - t[0]
            nb = int(t[-1] // SIESTA_BIN) - 1
            tc, x, F, empty = _binned(t, d[:, 2], d[:, 4], SIESTA_BIN, nb)
            print(f"siesta_{load}/{split}: {nb} bins, {empty} interpolated")
            _save(
                out, f"siesta_{load}", split, tc, x, F,
                x_unit="rad", F_unit="mA", units="rotary",
            )  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "name",
        choices=["motorbench", "lorenz_friction", "odrive_cogging", "quanser_flexcart", "siesta"],
    )
    p.add_argument("source", type=Path)
    p.add_argument("--out", type=Path, default=Path(__file__).parent)
    a = p.parse_args()
    if a.name == "motorbench":
        motorbench(a.source, a.out, "motor")
        motorbench(a.source, a.out, "load")
    elif a.name == "lorenz_friction":
        lorenz(a.source, a.out)
    elif a.name == "quanser_flexcart":
        quanser_flexcart(a.source, a.out)
    elif a.name == "siesta":
        siesta(a.source, a.out)
    else:
        odrive(a.source, a.out)


if __name__ == "__main__":
    main()
