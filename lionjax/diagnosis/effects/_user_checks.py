"""Checks of an effect of one's own (a :class:`~._force_effect.ForceEffect`): a mistake in it is
an :class:`~lionjax.InputError` naming the candidate, the rule of ``docs/effects.md`` it breaks
and the fix, never an internal error of lionjax: when the library is loaded
(:func:`check_definitions`), when its grid is read (:func:`checked_grid`) and wherever its basis
is evaluated on a record (:func:`checked_basis`). Built-in candidates (under ``lionjax.``) are
trusted: an error in them is lionjax's."""

from __future__ import annotations

import numbers
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._errors import InputError
from ..._units import unit
from ._base import AbstractCandidate

#: The rules of docs/effects.md ("Rules for a good candidate", "What a candidate is"), quoted.
RULES = {
    "finite": "Finite everywhere the record goes: the basis is evaluated at every recorded "
    "sample and at every simulated state; avoid 1/x, log |v| and unbounded growth, smooth a "
    "sign with jnp.tanh",
    "jnp": "jax.numpy, elementwise: basis is called on whole records and on single steps "
    "inside the compiled simulation; use jnp functions, no NumPy on the arguments, no Python "
    "if on their values, nothing that reads neighbouring samples",
    "one_each": "Return exactly one array per name in parameters, as a tuple: "
    "return (phi_1, phi_2, …), each of the shape of x",
    "grid": "grid(limits) returns the Modules the profile searches, one per grid point, each a "
    "Module of the candidate's class (e.g. [Cogging(float(p)) for p in periods]), at least one",
    "class_variables": "name, parameters and units are class variables: name a str, "
    "parameters a non-empty tuple of str (one per basis function), units a dict of the unit of "
    "each parameter and nonlinear field",
    "names": "Names of one's own: a parameter name may not be one the diagnosis already "
    "reports, nor another candidate's",
    "physics": "Physics in implausible: return why the fitted parameters are not physical, "
    'as a str ("" or None when they are), and call super().implausible to keep the check '
    "b > 0",
    "fitted": "Nonzero where it is fitted: each basis function is fitted on the training "
    "record, and one that is zero at every training sample leaves its parameter undetermined",
}

#: Samples of each traced argument in the probe of a basis (a few simulated windows).
PROBE_WINDOWS = 4
#: Classes whose basis has been traced (once per class).
_PROBED: set[type] = set()
#: What tracing raises where a basis converts or branches on a traced value.
_TRACER_ERRORS = (
    jax.errors.TracerArrayConversionError,
    jax.errors.TracerBoolConversionError,
    jax.errors.ConcretizationTypeError,
    jax.errors.TracerIntegerConversionError,
)


def is_users(candidate) -> bool:
    """Whether ``candidate`` is a user's (its class defined outside lionjax)."""
    return not type(candidate).__module__.startswith("lionjax.")


def _refuse(candidate, what: str, rule: str, fix: str, prefix: str = "diagnose: ") -> InputError:
    """The InputError naming the candidate, what it did, the rule and the fix (``prefix`` ""
    where :func:`~.._stages.check_candidates` adds its own)."""
    nm = type(candidate).__name__
    name = getattr(candidate, "name", None)
    who = f"candidate {name!r} ({nm})" if isinstance(name, str) else f"candidate {nm}"
    return InputError(f"{prefix}{who}: {what}. Rule (docs/effects.md): {RULES[rule]}. Fix: {fix}.")


def traced(effect):
    """``effect`` with its float fields as arrays, so that a compiled simulation is reused
    across their values (and a Python branch on them is seen when traced)."""
    return jax.tree_util.tree_map(
        lambda a: jnp.asarray(a, jnp.float64) if isinstance(a, float) else a, effect
    )


def check_definitions(effects: Sequence, reserved: Sequence[str], base: type) -> None:
    """The class variables of every ForceEffect of ``effects`` (``base``: the ForceEffect class,
    whose ``basis`` a device effect must override), and that no parameter name is ``reserved``
    (reported by the diagnosis) or another's. The messages start with the candidate (the caller
    names the argument)."""
    seen: dict[str, str] = {}
    for c in effects:
        _check_variables(c, base)
        for p in (*c.parameters, *c.nonlinear):
            if p in reserved:
                what = f"parameter name {p!r} is one the diagnosis already reports"
                raise _refuse(
                    c, f"{what} ({', '.join(sorted(set(reserved)))})", "names", "rename it", ""
                )
            if p in seen:
                raise _refuse(
                    c, f"parameter name {p!r} is also {seen[p]}'s", "names", "rename one", ""
                )
            seen[p] = type(c).__name__
        if is_users(c):
            _probe(c)


def _check_variables(c, base: type) -> None:
    """One candidate's class variables (:func:`check_definitions`)."""
    refuse = lambda what, fix, rule="class_variables": _refuse(c, what, rule, fix, "")
    name = getattr(c, "name", None)
    if not isinstance(name, str) or not name:
        raise refuse(f"name is {name!r}", 'name: ClassVar[str] = "…"')
    params = getattr(c, "parameters", None)
    if not (isinstance(params, tuple) and params and all(isinstance(p, str) and p for p in params)):
        raise refuse(
            f"parameters is {params!r}",
            'parameters: ClassVar[tuple[str, ...]] = ("c1",), one name per basis function',
        )
    if len(set(params)) != len(params):
        dup = sorted({p for p in params if params.count(p) > 1})
        raise refuse(f"parameter name(s) {dup} repeat", "name each one once", "names")
    nonlinear = getattr(c, "nonlinear", ())
    if not isinstance(nonlinear, tuple) or not all(isinstance(f, str) for f in nonlinear):
        raise refuse(
            f"nonlinear is {nonlinear!r}",
            'nonlinear: ClassVar[tuple[str, ...]] = ("period",), fields of the Module',
        )
    for f in nonlinear:
        v = getattr(c, f, None)
        if isinstance(v, bool) or not isinstance(v, numbers.Real):
            raise refuse(
                f"nonlinear parameter {f!r} is {v!r}, not a real field",
                f"declare it as a field with a default, e.g. {f}: float = 1e-3",
            )
    units = getattr(c, "units", {})
    if not isinstance(units, Mapping):
        fix = 'units: ClassVar[dict[str, str]] = {"' + params[0] + '": "N", …} (or leave it out)'
        raise refuse(f"units is {units!r}", fix)
    if c.acts_on not in ("device", "measurement"):
        raise refuse(
            f"acts_on is {c.acts_on!r}",
            "leave it out (an effect on the device) or set it to 'measurement' (an error of the "
            "force sensor)",
        )
    own = lambda m: getattr(type(c), m) is not getattr(base, m)
    if not (own("basis") or own("record_basis")):
        raise refuse(
            f"it defines no {'basis' if c.acts_on == 'device' else 'record_basis'}",
            "define basis(self, x, v, F, t) returning one jnp array per parameter",
            "jnp",
        )


def checked_grid(candidate, grid) -> list:
    """``candidate.grid(limits)`` as a list, or an InputError: not a sequence, empty, or holding
    something that is not a candidate of the candidate's name."""
    cls = type(candidate).__name__
    if not is_users(candidate):
        return list(grid)
    refuse = lambda what, fix: _refuse(candidate, what, "grid", fix)
    if isinstance(grid, eqx.Module | str | bytes) or not hasattr(grid, "__iter__"):
        what = f"grid returned a {type(grid).__name__}, not a list of Modules"
        raise refuse(what, f"return [{cls}(…) for each grid point]")
    pts = list(grid)
    if not pts:
        raise refuse(
            "grid returned no Module to search",
            "return at least one point (build the grid from limits, e.g. limits.x_range); "
            "without nonlinear parameters leave grid out",
        )
    same = lambda g: isinstance(g, AbstractCandidate) and g.name == candidate.name
    bad = next((g for g in pts if not same(g)), None)
    if bad is not None:
        field = candidate.nonlinear[0] if candidate.nonlinear else "value"
        raise refuse(
            f"grid returned a {type(bad).__name__} ({bad!r}) among its {len(pts)} points, "
            f"not a {cls} (a ForceEffect named {candidate.name!r})",
            f"return Modules, e.g. [{cls}({field}=float(v)) for v in values]",
        )
    return pts


def _values(candidate, phis, shape: tuple, where: str, prefix: str = "diagnose: ") -> tuple:
    """``phis`` checked: a tuple or list of one real array per parameter, each of ``shape`` or a
    scalar (``where``: how it was evaluated, for the message)."""
    refuse = lambda what, fix: _refuse(candidate, what, "one_each", fix, prefix)
    pars, n = candidate.parameters, len(candidate.parameters)
    if not isinstance(phis, tuple | list):
        array = isinstance(phis, jax.Array | np.ndarray | jax.ShapeDtypeStruct)
        got = f"an array of shape {tuple(np.shape(phis))}" if array else f"a {type(phis).__name__}"
        names = ", ".join("phi_" + p for p in pars)
        fix = f"return ({names},)" if n == 1 else f"return ({names})"
        raise refuse(f"basis returned {got} {where}, not a tuple of {n} array(s)", fix)
    if len(phis) != n:
        raise refuse(
            f"basis returned {len(phis)} array(s) {where} for the {n} parameter(s) {pars}",
            "return one array per name in parameters (add a parameter for each extra basis "
            "function, or combine them)",
        )
    for j, phi in enumerate(phis):
        sh = tuple(np.shape(phi))
        dtype = np.dtype(phi.dtype if hasattr(phi, "dtype") else np.result_type(phi))
        if sh not in ((), shape):
            raise refuse(
                f"basis function {j} ({pars[j]}) has shape {sh} {where}, where x has shape "
                f"{shape} (elementwise in x, v, F, t)",
                "return one array of the shape of x per parameter (stacking several makes "
                "one of shape (k, T): return them as separate tuple items)",
            )
        if dtype.kind not in "fiub":
            raise refuse(
                f"basis function {j} ({pars[j]}) is of dtype {dtype} {where}",
                "return a real force per unit of the parameter (jnp.real(...) if complex "
                "arithmetic is meant)",
            )
    return tuple(phis)


def _probe(candidate) -> None:
    """Trace ``candidate.basis`` as the compiled simulation calls it, once per class (no record
    needed: when loaded; the message starts with the candidate)."""
    cls = type(candidate)
    if cls in _PROBED or candidate.acts_on != "device":
        return
    arg = jax.ShapeDtypeStruct((PROBE_WINDOWS,), jnp.float64)
    refuse = lambda what, fix: _refuse(candidate, what, "jnp", fix, "")
    try:
        out = eqx.filter_eval_shape(
            lambda e, x, v, F, t: e.basis(x, v, F, t), traced(candidate), arg, arg, arg, arg
        )
    except _TRACER_ERRORS as e:
        kind = (
            "converts a traced argument to NumPy (np.… on x, v, F or t)"
            if isinstance(e, jax.errors.TracerArrayConversionError)
            else "branches in Python on the value of an argument or field (if/while/bool(), "
            "int(), float())"
        )
        what = f"basis {kind}, which the compiled simulation cannot run ({type(e).__name__})"
        fix = "write it with jnp functions; a branch as jnp.where(cond, a, b), a sign as "
        raise refuse(what, fix + "jnp.tanh(v / v_eps)") from None
    except Exception as e:  # noqa: BLE001 - the user's code failed: say so, with its error
        if "truth value" in str(e):  # a Python `if` on a traced array of several values
            what = "basis branches in Python on the value of an argument (if/while on an array)"
            fix = "write the branch as jnp.where(cond, a, b) (a sign as jnp.tanh(v / v_eps))"
            raise refuse(what, fix) from None
        raise refuse(
            f"basis failed when traced as the simulation calls it (arrays of shape "
            f"({PROBE_WINDOWS},)): {type(e).__name__}: {e}",
            "make basis work on jnp arrays of any length, elementwise",
        ) from None
    _values(candidate, out, (PROBE_WINDOWS,), "in the simulation", "")
    _PROBED.add(cls)


def checked_reason(candidate, why):
    """What a user's ``implausible`` returned, if a reason (a str, or None for none: ""), else
    the InputError of the rule (a bool would read as a reason "True")."""
    if why is None or isinstance(why, str):
        return why or ""
    raise _refuse(
        candidate,
        f"implausible returned {why!r} (a {type(why).__name__}), not a reason",
        "physics",
        'return a str saying what is not physical, e.g. "drag would push along the motion" '
        'if not phys["c2"] > 0, and super().implausible(phys, limits) otherwise',
    )


def checked_basis(candidate, record, v, *, fitted: bool = False) -> tuple:
    """``candidate.record_basis(record, v)``, checked as :func:`_values` and finite; on the
    record its parameters are ``fitted`` on (the training record), not zero throughout either
    (its column would be zero: no value of the parameter fits better than another)."""
    if not is_users(candidate):
        return tuple(candidate.record_basis(record, v))
    try:
        phis = candidate.record_basis(record, v)
    except Exception as e:  # noqa: BLE001 - the user's code failed: say so, with its error
        raise _refuse(
            candidate,
            f"basis failed on the record (arrays of shape {tuple(record.x.shape)}): "
            f"{type(e).__name__}: {e}",
            "jnp",
            "make basis work on jnp arrays elementwise (no Python if on their values: jnp.where)",
        ) from None
    phis = _values(candidate, phis, tuple(record.x.shape), "on the record")
    m = unit("m", record.units)
    for j, phi in enumerate(phis):
        a = np.broadcast_to(np.asarray(phi, np.float64), record.x.shape)
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            k = int(bad[0])
            raise _refuse(
                candidate,
                f"basis function {j} ({candidate.parameters[j]}) is not finite at "
                f"{bad.size} of the record's {record.n_samples} samples (the first: sample "
                f"{k}, x = {float(np.asarray(record.x)[k]):.6g} {m}, value {float(a[k])})",
                "finite",
                "bound it (e.g. x / (x² + ε²) for 1/x, jnp.log(jnp.abs(v) + ε)), or leave the "
                "effect out",
            )
        if fitted and not np.any(a):
            raise _refuse(
                candidate,
                f"basis function {j} ({candidate.parameters[j]}) is zero at every one of the "
                f"training record's {record.n_samples} samples (x from "
                f"{float(np.min(record.x)):.6g} to {float(np.max(record.x)):.6g} {m}), so "
                f"{candidate.parameters[j]} cannot be fitted",
                "fitted",
                "record training data where the effect acts (a region the training record "
                "visits, a force or speed it reaches), or leave the effect out",
            )
    return phis
