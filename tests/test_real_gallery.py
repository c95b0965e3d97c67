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
    "odrive_cogging": (1_880, "rad", "A", "rotary"),
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
