"""Checks of an effect of one's own (a :class:`~._force_effects.ForceEffect`) when it is loaded
and when its basis and grid are first evaluated: a mistake in it is an
:class:`~lionjax.InputError` naming the candidate, the rule of ``docs/effects.md`` it breaks and
the fix, never an "internal error" of lionjax.

Three moments:

- **loaded** (:func:`check_definitions`, from :func:`~._force_effects.check_library`): the class
  variables (``name``, ``parameters``, ``nonlinear``, ``units``, ``acts_on``), a ``basis`` (or,
  for a measurement effect, a ``record_basis``) of its own, and the basis traced as the
  compiled windowed simulation calls it (arrays of shape (W,), the Module's float fields traced
  too): a tuple of one array of shape (W,) per parameter, no NumPy or Python control flow on
  the arguments;
- **grid** (:func:`checked_grid`, from :meth:`~._force_effects.ForceEffect.profile`): at least
  one Module, each an instance of the candidate's class;
- **basis** (:func:`checked_basis`, from :class:`~._force_effects.ForceColumns`, wherever the basis
  is evaluated on a record): a tuple of one array per parameter, each of the record's shape (or
  a scalar), real and finite on every sample.

The built-in candidates (modules under ``lionjax.``) are trusted: an error in them is lionjax's.
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._errors import InputError
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
}

#: Samples of each traced argument in the first-evaluation probe (a few simulated windows).
PROBE_WINDOWS = 4
#: Classes whose basis has been traced (the probe runs once per class).
_PROBED: set[type] = set()


def is_users(candidate) -> bool:
    """Whether ``candidate`` is a user's (its class defined outside lionjax)."""
    return not type(candidate).__module__.startswith("lionjax.")


def _refuse(candidate, what: str, rule: str, fix: str, prefix: str = "diagnose: ") -> InputError:
    """The InputError naming the candidate, what it did, the rule and the fix (``prefix``: ""
    where :func:`~._stages.check_candidates` adds its own)."""
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
    """The class variables of every ForceEffect of ``effects`` (loaded; ``base``: the ForceEffect
    class, whose ``basis`` a device effect must override), and that no parameter name is
    reserved (``reserved``: the names the diagnosis reports) or another's. The messages start
    with the candidate (the caller names the argument)."""
    seen: dict[str, str] = {}
    for c in effects:
        _check_variables(c, base)
        for p in (*c.parameters, *c.nonlinear):
            if p in reserved:
                raise _refuse(
                    c,
                    f"parameter name {p!r} is one the diagnosis already reports "
                    f"({', '.join(sorted(set(reserved)))})",
                    "names",
                    "rename it",
                    "",
                )
            if p in seen:
                raise _refuse(
                    c, f"parameter name {p!r} is also {seen[p]}'s", "names", "rename one", ""
                )
            seen[p] = type(c).__name__
        if is_users(c):
            _probe(c, "")


def _check_variables(c, base: type) -> None:
    """One candidate's class variables (:func:`check_definitions`)."""
    refuse = lambda *args: _refuse(*args, prefix="")
    name = getattr(c, "name", None)
    if not isinstance(name, str) or not name:
        raise refuse(c, f"name is {name!r}", "class_variables", 'name: ClassVar[str] = "…"')
    params = getattr(c, "parameters", None)
    if (
        not isinstance(params, tuple)
        or not params
        or not all(isinstance(p, str) and p for p in params)
    ):
        raise refuse(
            c,
            f"parameters is {params!r}",
            "class_variables",
            'parameters: ClassVar[tuple[str, ...]] = ("c1",), one name per basis function',
        )
    if len(set(params)) != len(params):
        dup = sorted({p for p in params if params.count(p) > 1})
        raise refuse(c, f"parameter name(s) {dup} repeat", "names", "name each one once")
    nonlinear = getattr(c, "nonlinear", ())
    if not isinstance(nonlinear, tuple) or not all(isinstance(f, str) for f in nonlinear):
        raise refuse(
            c,
            f"nonlinear is {nonlinear!r}",
            "class_variables",
            'nonlinear: ClassVar[tuple[str, ...]] = ("period",), fields of the Module',
        )
    for f in nonlinear:
        v = getattr(c, f, None)
        if isinstance(v, bool) or not isinstance(v, numbers.Real):
            raise refuse(
                c,
                f"nonlinear parameter {f!r} is {v!r}, not a real field",
                "class_variables",
                f"declare it as a field with a default, e.g. {f}: float = 1e-3",
            )
    units = getattr(c, "units", {})
    if not isinstance(units, Mapping):
        raise refuse(
            c,
            f"units is {units!r}",
            "class_variables",
            'units: ClassVar[dict[str, str]] = {"' + params[0] + '": "N", …} (or leave it out)',
        )
    if c.acts_on not in ("device", "measurement"):
        raise refuse(
            c,
            f"acts_on is {c.acts_on!r}",
            "class_variables",
            "leave it out (an effect on the device) or set it to 'measurement' (an error of the "
            "force sensor)",
        )
    own = lambda m: getattr(type(c), m) is not getattr(base, m)
    if not (own("basis") or own("record_basis")):
        raise refuse(
            c,
            f"it defines no {'basis' if c.acts_on == 'device' else 'record_basis'}",
            "jnp",
            "define basis(self, x, v, F, t) returning one jnp array per parameter",
        )


def checked_grid(candidate, grid) -> list:
    """``candidate.grid(limits)`` as a list, or an InputError: not a sequence, empty, or holding
    something that is not a ForceEffect of the candidate's name (its class, or a class it
    derives from)."""
    cls = type(candidate)
    if not is_users(candidate):
        return list(grid)
    if isinstance(grid, eqx.Module | str | bytes) or not hasattr(grid, "__iter__"):
        raise _refuse(
            candidate,
            f"grid returned a {type(grid).__name__}, not a list of Modules",
            "grid",
            f"return [{cls.__name__}(…) for each grid point]",
        )
    pts = list(grid)
    if not pts:
        raise _refuse(
            candidate,
            "grid returned no Module to search",
            "grid",
            "return at least one point (build the grid from limits, e.g. limits.x_range); "
            "without nonlinear parameters leave grid out",
        )
    same = lambda g: isinstance(g, AbstractCandidate) and g.name == candidate.name
    bad = next((g for g in pts if not same(g)), None)
    if bad is not None:
        field = candidate.nonlinear[0] if candidate.nonlinear else "value"
        raise _refuse(
            candidate,
            f"grid returned a {type(bad).__name__} ({bad!r}) among its {len(pts)} points, "
            f"not a {cls.__name__} (a ForceEffect named {candidate.name!r})",
            "grid",
            f"return Modules, e.g. [{cls.__name__}({field}=float(v)) for v in values]",
        )
    return pts


def _values(candidate, phis, shape: tuple, where: str, prefix: str = "diagnose: ") -> tuple:
    """``phis`` checked: a tuple/list of one real array per parameter, each of ``shape`` or a
    scalar (``where``: how it was evaluated, for the message)."""
    refuse = lambda *args: _refuse(*args, prefix=prefix)
    n = len(candidate.parameters)
    if isinstance(phis, jax.Array | np.ndarray) or not isinstance(phis, tuple | list):
        got = (
            f"an array of shape {tuple(np.shape(phis))}"
            if isinstance(phis, jax.Array | np.ndarray | jax.ShapeDtypeStruct)
            else f"a {type(phis).__name__}"
        )
        raise refuse(
            candidate,
            f"basis returned {got} {where}, not a tuple of {n} array(s)",
            "one_each",
            f"return ({', '.join('phi_' + p for p in candidate.parameters)},)"
            if n == 1
            else f"return ({', '.join('phi_' + p for p in candidate.parameters)})",
        )
    if len(phis) != n:
        raise refuse(
            candidate,
            f"basis returned {len(phis)} array(s) {where} for the {n} parameter(s) "
            f"{candidate.parameters}",
            "one_each",
            "return one array per name in parameters (add a parameter for each extra basis "
            "function, or combine them)",
        )
    for j, phi in enumerate(phis):
        sh = tuple(np.shape(phi))
        dtype = np.dtype(phi.dtype if hasattr(phi, "dtype") else np.result_type(phi))
        if sh not in ((), shape):
            raise refuse(
                candidate,
                f"basis function {j} ({candidate.parameters[j]}) has shape {sh} {where}, "
                f"where x has shape {shape} (elementwise in x, v, F, t)",
                "one_each",
                "return one array of the shape of x per parameter (stacking several makes "
                "one of shape (k, T): return them as separate tuple items)",
            )
        if dtype.kind not in "fiub":
            raise refuse(
                candidate,
                f"basis function {j} ({candidate.parameters[j]}) is of dtype {dtype} {where}",
                "one_each",
                "return a real force per unit of the parameter (jnp.real(...) if complex "
                "arithmetic is meant)",
            )
    return tuple(phis)


def _probe(candidate, prefix: str = "diagnose: ") -> None:
    """Trace ``candidate.basis`` as the compiled simulation calls it, once per class (no record
    needed: when loaded)."""
    cls = type(candidate)
    if cls in _PROBED or candidate.acts_on != "device":
        return
    arg = jax.ShapeDtypeStruct((PROBE_WINDOWS,), jnp.float64)
    try:
        out = eqx.filter_eval_shape(
            lambda e, x, v, F, t: e.basis(x, v, F, t), traced(candidate), arg, arg, arg, arg
        )
    except (
        jax.errors.TracerArrayConversionError,
        jax.errors.TracerBoolConversionError,
        jax.errors.ConcretizationTypeError,
        jax.errors.TracerIntegerConversionError,
    ) as e:
        kind = (
            "converts a traced argument to NumPy (np.… on x, v, F or t)"
            if isinstance(e, jax.errors.TracerArrayConversionError)
            else "branches in Python on the value of an argument or field (if/while/bool(), "
            "int(), float())"
        )
        raise _refuse(
            candidate,
            f"basis {kind}, which the compiled simulation cannot run ({type(e).__name__})",
            "jnp",
            "write it with jnp functions; a branch as jnp.where(cond, a, b), a sign as "
            "jnp.tanh(v / v_eps)",
            prefix,
        ) from None
    except Exception as e:  # noqa: BLE001 - the user's code failed: say so, with its error
        if "truth value" in str(e):  # a Python `if` on a traced array of several values
            raise _refuse(
                candidate,
                "basis branches in Python on the value of an argument (if/while on an array)",
                "jnp",
                "write the branch as jnp.where(cond, a, b) (a sign as jnp.tanh(v / v_eps))",
                prefix,
            ) from None
        raise _refuse(
            candidate,
            f"basis failed when traced as the simulation calls it (arrays of shape "
            f"({PROBE_WINDOWS},)): {type(e).__name__}: {e}",
            "jnp",
            "make basis work on jnp arrays of any length, elementwise",
            prefix,
        ) from None
    _values(candidate, out, (PROBE_WINDOWS,), "in the simulation", prefix)
    _PROBED.add(cls)


def checked_basis(candidate, record, v) -> tuple:
    """``candidate.record_basis(record, v)`` checked (module docstring)."""
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
    for j, phi in enumerate(phis):
        a = np.asarray(phi, np.float64)
        bad = np.flatnonzero(~np.isfinite(np.broadcast_to(a, record.x.shape)))
        if bad.size:
            k = int(bad[0])
            x = float(np.asarray(record.x)[k])
            raise _refuse(
                candidate,
                f"basis function {j} ({candidate.parameters[j]}) is not finite at "
                f"{bad.size} of the record's {record.n_samples} samples (the first: sample "
                f"{k}, x = {x:.6g} m, value {float(np.broadcast_to(a, record.x.shape)[k])})",
                "finite",
                "bound it (e.g. x / (x² + ε²) for 1/x, jnp.log(jnp.abs(v) + ε)), or leave the "
                "effect out",
            )
    return phis
