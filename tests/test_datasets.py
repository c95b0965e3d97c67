"""The shipped EMPS data: loads as published, and an independent IDIM-LS fit reproduces M, Fv."""

import importlib.resources

import numpy as np
import pytest
import scipy.signal

from lionjax import InputError, Record
from lionjax.datasets import EMPS_REFERENCE, emps

T = 24_841


@pytest.fixture(scope="module")
def estimation():
    return emps("estimation")


def test_package_data_present():
    folder = importlib.resources.files("lionjax.datasets").joinpath("emps")
    names = {p.name for p in folder.iterdir()}
    assert {"emps_estimation.npz", "emps_validation_pulses.npz", "PROVENANCE.md"} <= names


def test_emps_estimation_loads(estimation):
    r = estimation
    assert isinstance(r, Record)
    assert r.n_samples == T and r.x.shape == (T,) and r.F.shape == (T,)
    assert float(r.dt) == 1e-3  # the stored dt, checked against t, used exactly (no resampling)
    assert float(r.t0) == 0.0
    assert r.x.dtype == np.float64
    assert set(r.extras) == {"position_reference", "control_voltage"}
    # Ranges from PROVENANCE.md: qm −2.2e-5 … 0.24638 m; force −152 … 145 N.
    assert -3e-5 < float(r.x.min()) < 0 and 0.2463 < float(r.x.max()) < 0.2465
    assert -153 < float(r.F.min()) < -151 and 144 < float(r.F.max()) < 146
    # F = gτ·ν.
    np.testing.assert_allclose(
        np.asarray(r.F), EMPS_REFERENCE.gtau * np.asarray(r.extras["control_voltage"]), rtol=1e-12
    )


def test_emps_validation_loads():
    r = emps("validation")
    assert r.n_samples == T and float(r.dt) == 1e-3
    assert set(r.extras) == {"position_reference", "control_voltage", "pulses_N"}
    assert set(np.unique(np.asarray(r.extras["pulses_N"]))) == {0.0, 5.0}


def test_emps_unknown_split():
    with pytest.raises(InputError, match=r"split.*'estimation'.*'validation'.*'test'"):
        emps("test")


def test_reference_values_and_lionjax_form():
    R = EMPS_REFERENCE
    assert (R.M, R.Fv, R.Fc, R.offset) == (95.1089, 203.5034, 20.3935, -3.1648)
    assert (R.sigma_M, R.sigma_Fv, R.sigma_Fc, R.sigma_offset) == (0.1085, 1.1460, 0.1012, 0.0444)
    assert R.a == pytest.approx(2.1397, rel=1e-4)  # Fv/M [1/s]
    assert R.b == pytest.approx(0.010514, rel=1e-4)  # 1/M [1/kg]
    assert R.F0 == 3.1648  # docs/method.md, Effects: offset −3.1648 N is F0 = +3.1648 N
    A = R.asymmetric
    assert (A.M, A.Fv_pos, A.Fc_pos, A.Fv_neg, A.Fc_neg) == (
        95.1540,
        166.7061,
        20.1440,
        240.4236,
        20.6277,
    )
    with pytest.raises(AttributeError):
        R.M = 1.0  # frozen


def test_independent_idim_ls_reproduces_published(estimation):
    """numpy/scipy OLS of τ = M q̈ + Fv q̇ + Fc sgn q̇ + offset, as in the EMPS paper (sec. 3)."""
    r = estimation
    dt = float(r.dt)
    b, a = scipy.signal.butter(4, 100.0, fs=1.0 / dt)  # 4th order, 100 Hz
    q = scipy.signal.filtfilt(b, a, np.asarray(r.x))
    qd = (q[2:] - q[:-2]) / (2 * dt)
    qdd = (q[2:] - 2 * q[1:-1] + q[:-2]) / dt**2
    tau = np.asarray(r.F)[1:-1]
    keep = slice(49, -49)  # drop the filter borders
    Phi = np.column_stack([qdd, qd, np.sign(qd), np.ones_like(qd)])[keep]
    theta, *_ = np.linalg.lstsq(Phi, tau[keep], rcond=None)
    M, Fv, Fc, offset = theta
    R = EMPS_REFERENCE
    assert M == pytest.approx(R.M, rel=0.01)
    assert Fv == pytest.approx(R.Fv, rel=0.01)
    assert Fc == pytest.approx(R.Fc, rel=0.03)
    assert offset == pytest.approx(R.offset, rel=0.05)
    # lionjax's form: a = Fv/M, b = 1/M, F0 = −offset (> 0).
    assert Fv / M == pytest.approx(R.a, rel=0.01)
    assert 1 / M == pytest.approx(R.b, rel=0.01)
    assert -offset == pytest.approx(R.F0, rel=0.05) and -offset > 0
    rel_err = np.linalg.norm(tau[keep] - Phi @ theta) / np.linalg.norm(tau[keep])
    assert 0.03 < rel_err < 0.06  # published 4.08 % (decimated); 4.5 % without decimation
