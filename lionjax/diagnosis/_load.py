"""Candidates from a user's Python file: ``FILE.py:Name[,Name…]`` (``--candidates``)."""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import os
import sys

from .._errors import InputError
from .effects import AbstractCandidate

#: Prefix of the module names the user's candidate files run as (errors inside them are the
#: user's: the command line names the file and line, :func:`lionjax.cli.describe`).
USER_MODULE = "lionjax_user_candidates_"


def _is_candidate_class(v) -> bool:
    return inspect.isclass(v) and issubclass(v, AbstractCandidate)


def load_candidates(spec: str) -> tuple[AbstractCandidate, ...]:
    """The candidates ``Name…`` defined in the Python file ``FILE.py``.

    Arguments:
        spec: ``"FILE.py:Name[,Name…]"``; each name is a candidate class (instantiated with no
            arguments) or a candidate instance defined at the file's top level.

    Returns:
        the instances, in the order named; pass them as
        ``candidates=lionjax.diagnosis.DEFAULT_CANDIDATES + load_candidates(spec)``.

    Raises:
        InputError: naming the file or the name when the file cannot be read or run, or a name
            is missing or not a candidate.
    """
    path, sep, names = str(spec).rpartition(":")
    if not sep or not path or not names.strip():
        raise InputError(
            f"--candidates: expected FILE.py:Name[,Name…] (e.g. "
            f"examples/custom_effects.py:QuadraticDrag,Cogging), got {spec!r}."
        )
    if not os.path.isfile(path):
        raise InputError(f"--candidates: file {path!r} not found (from {spec!r}).")
    mod_name = USER_MODULE + hashlib.sha1(os.path.abspath(path).encode()).hexdigest()[:12]
    module = sys.modules.get(mod_name)
    if module is None:
        loader = importlib.util.spec_from_file_location(mod_name, path)
        if loader is None or loader.loader is None:
            raise InputError(f"--candidates: {path!r} is not a Python file.")
        module = importlib.util.module_from_spec(loader)
        try:
            loader.loader.exec_module(module)
        except Exception as e:
            raise InputError(
                f"--candidates: running {path!r} failed: {type(e).__name__}: {e}"
            ) from None
        sys.modules[mod_name] = module
    out = []
    for name in (n.strip() for n in names.split(",")):
        if not hasattr(module, name):
            have = sorted(
                k
                for k, v in vars(module).items()
                if (_is_candidate_class(v) and not inspect.isabstract(v))
                or isinstance(v, AbstractCandidate)
            )
            raise InputError(
                f"--candidates: {path!r} defines no {name!r}; candidates there: "
                f"{', '.join(have) or 'none'}."
            )
        obj = getattr(module, name)
        if _is_candidate_class(obj):
            try:
                obj = obj()
            except Exception as e:
                raise InputError(
                    f"--candidates: {name} in {path!r} could not be made with no arguments: "
                    f"{type(e).__name__}: {e}"
                ) from None
        if not isinstance(obj, AbstractCandidate):
            raise InputError(
                f"--candidates: {name} in {path!r} is a {type(obj).__name__}, not a "
                "lionjax.diagnosis candidate (subclass lionjax.diagnosis.ForceEffect)."
            )
        out.append(obj)
    return tuple(out)
