"""The real-data gallery's files: every record has a pre-registered EXPECTED.md naming a verdict
and a PROVENANCE.md, and every packaged record loads with its documented keys, units and lengths.
No verdict is asserted here (benchmarks/real_gallery.py runs the diagnosis)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import real_gallery as gallery  # benchmarks/ (tests/conftest.py)

REAL = Path(gallery.__file__).resolve().parent / "real"
#: Names a pre-registration may expect: the diagnosis' verdicts and effect names, and
#: ``inconclusive`` for a record that cannot decide.
VERDICTS = {
    "none",
    "unexplained",
    "inconclusive",
    "offset",
    "coulomb_friction",
    "asymmetric_friction",
    "spring",
    "delay",
    "saturation",
    "position_dependent",
    "flexible_mode",
}
#: (samples per split, x unit, F unit, units) that each PROVENANCE.md states.
PACKAGED = {
    "motorbench_motor": (12_500, "rad", "A", "rotary"),
    "motorbench_load": (12_500, "rad", "A", "rotary"),
    "lorenz_friction": (10_000, "rad", "N·m", "rotary"),
    "odrive_cogging": (1_879, "rad", "A", "rotary"),
    "quanser_flexcart": (8_001, "m", "V", "linear"),
}
NAMES = [e.name for e in gallery.ENTRIES]


def test_every_folder_is_a_gallery_entry():
    folders = sorted(p.name for p in REAL.iterdir() if p.is_dir() and not p.name.startswith("_"))
    assert folders == sorted([*NAMES, *gallery.FAMILIES])
    assert set(PACKAGED) <= set(NAMES)
    for family, records in gallery.FAMILIES.items():  # a series' shared documents
        assert set(records) <= set(NAMES)
        assert re.search(r"\*\*Expected verdict", (REAL / family / "EXPECTED.md").read_text())
        assert len((REAL / family / "PROVENANCE.md").read_text()) > 200


@pytest.mark.parametrize("name", NAMES)
def test_expected_and_provenance(name):
    text = (REAL / name / "EXPECTED.md").read_text()
    m = re.search(r"\*\*Expected verdict: `([a-z_]+)`", text)
    assert m, f"{name}/EXPECTED.md states no '**Expected verdict: `…`'"
    assert m.group(1) in VERDICTS
    entry = next(e for e in gallery.ENTRIES if e.name == name)
    assert m.group(1) in entry.accepted  # the script scores what the file pre-registered
    prov = (REAL / name / "PROVENANCE.md").read_text()
    assert len(prov) > 200


@pytest.mark.parametrize("name", sorted(PACKAGED))
def test_packaged_record(name):
    folder = gallery._npz_folder(name)
    if folder is None:
        pytest.skip(f"{name}: data not present (built by benchmarks/real/package.py)")
    n, x_unit, F_unit, units = PACKAGED[name]
    for split in ("train", "valid"):
        path = folder / f"{split}.npz"
        assert path.stat().st_size < 400_000  # packaged small
        d = np.load(path)
        assert set(d.files) == {"t", "x", "F", "x_unit", "F_unit", "units"}
        assert (str(d["x_unit"]), str(d["F_unit"]), str(d["units"])) == (x_unit, F_unit, units)
        t, x, F = d["t"], d["x"], d["F"]
        assert t.shape == x.shape == F.shape == (n,)
        assert all(a.dtype == np.float64 and np.all(np.isfinite(a)) for a in (t, x, F))
        step = np.diff(t)
        assert np.all(step > 0) and np.ptp(step) < 1e-6 * step.mean()
    train, valid, got = gallery.load_npz_pair(name)
    assert got == units and train.units == valid.units == units
    assert float(train.dt) == pytest.approx(float(valid.dt), rel=1e-9)


def test_binned_holds_the_force_from_each_sample():
    """package.py's binning of an irregular log, against closed forms on x = F = t: x_k is the
    mean over the bin centred on t_k (= t_k), F_k the mean over [t_k, t_k + dt) (= t_k + dt/2,
    the force held from sample k); a logging gap's empty bins are counted."""
    import sys

    sys.path.insert(0, str(REAL))
    from package import _binned

    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0.0, 1.0, 20_000))
    t = t[(t < 0.3) | (t > 0.31)]  # a logging gap of 10 ms: bins 120–123 of x hold no sample
    dt, nb = 2.5e-3, 398
    tc, x, F, empty = _binned(t, t, t, dt, nb)
    np.testing.assert_allclose(tc, (np.arange(nb) + 0.5) * dt, rtol=0, atol=1e-15)
    assert empty == 4
    # a bin's mean of ~50 uniform draws on a line is its centre, to the draws' scatter
    # (σ ≈ 0.04·dt; 0.25·dt is 6σ and half the shift told apart); the bins the gap cuts are
    # left out
    whole = (tc + dt < 0.3) | (tc - dt > 0.31)
    np.testing.assert_allclose(x[whole], tc[whole], rtol=0, atol=0.25 * dt)
    np.testing.assert_allclose(F[whole], tc[whole] + dt / 2, rtol=0, atol=0.25 * dt)
