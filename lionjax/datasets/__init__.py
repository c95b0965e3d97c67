"""Real data sets shipped with lionjax (package data, loaded with ``importlib.resources``).

EMPS — Electro-Mechanical Positioning System (ONERA / LS2N): real measurements of a prismatic
ball-screw drive under a closed-loop position controller, 1 kHz, 24,841 samples per split.
Cite: A. Janot, M. Gautier and M. Brunot, "Data Set and Reference Models of EMPS", 2019 Workshop
on Nonlinear System Identification Benchmarks, Eindhoven. Units, origin, hashes and the
published results are in ``lionjax/datasets/emps/PROVENANCE.md`` (public benchmark data; do not
redistribute outside the project without checking the licence).

Published inverse dynamic model (IDIM): τ = M q̈ + Fv q̇ + Fc sgn(q̇) + offset. In lionjax's form
(docs/method.md, "Effects") ẍ + a ẋ = b (F + F0 − Fc sgn ẋ) with a = Fv/M, b = 1/M and F0 = −offset.

Silverbox — an analogue electronic circuit built as a mass–damper with a hardening spring,
m·ÿ + d·ẏ + (a + b·y²)·y = u, "position" y and "force" u voltages, f_s = 610.35 Hz, 131,072
samples (the SNLS80mV record). Cite: T. Wigren and J. Schoukens, "Three free data sets for
development and benchmarking in nonlinear system identification", ECC 2013, pp. 2933–2938.
Origin, hashes and the benchmark's official splits are in
``lionjax/datasets/silverbox/PROVENANCE.md`` (no licence is stated for the data: public
benchmark data, cite the paper).
"""

from __future__ import annotations

import dataclasses
import importlib.resources

from .._errors import InputError
from .._io import load_record
from .._record import Record

__all__ = ["EMPS_REFERENCE", "EMPSAsymmetricReference", "EMPSReference", "emps", "silverbox"]

_EMPS_FILES = {
    "estimation": "emps_estimation.npz",
    "validation": "emps_validation_pulses.npz",
}


@dataclasses.dataclass(frozen=True)
class EMPSAsymmetricReference:
    """Published IDIM-LS fit with direction-dependent friction (Janot et al. 2019, eq. 12).

    τ = M q̈ + Fv± q̇ + Fc± sgn(q̇) (the + values for q̇ > 0, − for q̇ < 0; no offset column).
    """

    M: float = 95.1540  #: mass [kg]
    Fv_pos: float = 166.7061  #: viscous friction for q̇ > 0 [N·s/m]
    Fc_pos: float = 20.1440  #: Coulomb friction for q̇ > 0 [N]
    Fv_neg: float = 240.4236  #: viscous friction for q̇ < 0 [N·s/m]
    Fc_neg: float = 20.6277  #: Coulomb friction for q̇ < 0 [N]
    relative_error: float = 0.031117  #: ‖τ − Φθ‖ / ‖τ‖ on the estimation set
    condition_number: float = 26.0197


@dataclasses.dataclass(frozen=True)
class EMPSReference:
    """Published IDIM-LS values for EMPS (Janot et al. 2019, sec. 3.4) and lionjax's form.

    Published model τ = M q̈ + Fv q̇ + Fc sgn(q̇) + offset (τ = gτ·ν, the force in N).
    lionjax's form (docs/method.md, "Effects"): ẍ + a ẋ = b (F + F0 − Fc sgn ẋ), so
    ``a = Fv/M`` [1/s], ``b = 1/M`` [1/kg] and ``F0 = −offset`` [N] (the published offset
    −3.1648 N is F0 = +3.1648 N).
    """

    M: float = 95.1089  #: mass [kg]
    Fv: float = 203.5034  #: viscous friction [N·s/m]
    Fc: float = 20.3935  #: Coulomb friction [N]
    offset: float = -3.1648  #: force offset in the published (IDIM) sign convention [N]
    sigma_M: float = 0.1085  #: standard deviation of M [kg]
    sigma_Fv: float = 1.1460  #: standard deviation of Fv [N·s/m]
    sigma_Fc: float = 0.1012  #: standard deviation of Fc [N]
    sigma_offset: float = 0.0444  #: standard deviation of offset [N]
    relative_error: float = 0.040834  #: ‖τ − Φθ‖ / ‖τ‖ on the estimation set
    condition_number: float = 25.9883
    validation_relative_error: float = 0.059824  #: same θ, pulses (validation) set
    gtau: float = 35.15065188248547  #: drive gain, force = gtau · control_voltage [N/V]
    kp: float = 160.18  #: position-loop gain [1/s]
    kv: float = 243.45  #: velocity-loop gain [V/(m/s)]
    dt: float = 1e-3  #: sampling interval [s]
    asymmetric: EMPSAsymmetricReference = EMPSAsymmetricReference()

    @property
    def a(self) -> float:
        """a = Fv/M [1/s]."""
        return self.Fv / self.M

    @property
    def b(self) -> float:
        """b = 1/M [1/kg]."""
        return 1.0 / self.M

    @property
    def F0(self) -> float:
        """Constant force offset in lionjax's sign convention, F0 = −offset [N]."""
        return -self.offset


#: The published EMPS reference values (see :class:`EMPSReference`).
EMPS_REFERENCE = EMPSReference()


def emps(split: str = "estimation", *, dtype=None) -> Record:
    """Load one split of the EMPS benchmark as a :class:`~lionjax.Record`.

    Arguments:
        split: ``"estimation"`` (``DATA_EMPS``, the identification/training set) or
            ``"validation"`` (``DATA_EMPS_PULSES``, the cross-test set with 0/5 N force pulses).
        dtype: array dtype (default: JAX's default float; use float64 for identification).

    Returns:
        A record of 24,841 samples, ``dt = 1e-3`` s exactly, ``t0 = 0``: ``x`` = motor position
        on the load side [m], ``F`` = actuator force gτ·ν [N]; ``extras``: ``position_reference``
        [m], ``control_voltage`` [V], and for the validation split ``pulses_N`` [N].

    Raises:
        InputError: for an unknown ``split``.
    """
    if split not in _EMPS_FILES:
        raise InputError(
            f"split: expected one of {', '.join(map(repr, _EMPS_FILES))}, got {split!r}."
        )
    extras = ("position_reference", "control_voltage")
    if split == "validation":
        extras += ("pulses_N",)
    resource = importlib.resources.files(__name__).joinpath("emps", _EMPS_FILES[split])
    with importlib.resources.as_file(resource) as path:
        return load_record(
            path, columns={"x": "position", "F": "force"}, extras=extras, dtype=dtype
        )


#: The Silverbox benchmark's official splits (PROVENANCE.md): sample ranges [start, stop).
SILVERBOX_SPLITS = {
    "train": "split_train_val",
    "test_multisine": "split_test_multisine",
    "test_arrow": "split_test_arrow_full",
}


def silverbox(split: str = "train", *, dtype=None) -> Record:
    """Load one official split of the Silverbox benchmark (module docstring) as a
    :class:`~lionjax.Record`: ``x`` the output voltage y [V] (the "position"), ``F`` the input
    voltage u [V] (the "force"), dt = 2¹⁴/10⁷ s.

    Arguments:
        split: ``"train"`` (the multisine part's first 75 %, samples 40650–105711),
            ``"test_multisine"`` (its last 25 %, 105712–127399) or ``"test_arrow"`` (the filtered
            noise of growing amplitude, 100–40574).
        dtype: array dtype (default: JAX's default float; use float64 for identification).

    Raises:
        InputError: for an unknown ``split``.
    """
    import numpy as np

    if split not in SILVERBOX_SPLITS:
        raise InputError(
            f"split: expected one of {', '.join(map(repr, SILVERBOX_SPLITS))}, got {split!r}."
        )
    resource = importlib.resources.files(__name__).joinpath("silverbox", "silverbox_SNLS80mV.npz")
    with importlib.resources.as_file(resource) as path, np.load(path) as d:
        a, b = (int(v) for v in d[SILVERBOX_SPLITS[split]])
        x = np.asarray(d["position"][a:b], np.float64)
        F = np.asarray(d["force"][a:b], np.float64)
        dt = float(d["dt"])
    t = dt * np.arange(a, b)
    return Record.from_samples(t, x, F, source=f"Silverbox ({split})", dtype=dtype)
