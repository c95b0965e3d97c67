"""The command line's persistent compilation cache: a second process starts warm.

A ``lionjax`` process spends most of a short run compiling (a diagnosis of one pair of 8-s
records at 5 kHz: about three quarters of its time). JAX can keep the compiled programs on
disk and load them in the next process instead of compiling again; the command line turns that
on, in a per-user folder:

- ``$LIONJAX_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/lionjax/jax``, else
  ``~/.cache/lionjax/jax``;
- off with the option ``lionjax --no-compile-cache …`` or ``LIONJAX_NO_COMPILE_CACHE=1``;
- left alone where JAX's own cache folder is already set (``JAX_COMPILATION_CACHE_DIR`` or
  ``jax.config``): that one is used.

Every program is kept, however fast it compiled or small it is (on CPU most of the diagnosis'
programs compile in well under JAX's default threshold of one second, and together they are
the cold start). The library itself never changes JAX's configuration: only the command line
calls :func:`enable`. A cache hit is the same executable, so results do not depend on it.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping
from pathlib import Path

#: Values of ``LIONJAX_NO_COMPILE_CACHE`` that turn the cache off.
_OFF = ("1", "true", "yes", "on")


def cache_dir(environ: Mapping[str, str] | None = None) -> Path | None:
    """The folder of the cache, or None when ``LIONJAX_NO_COMPILE_CACHE`` turns it off."""
    env = os.environ if environ is None else environ
    if env.get("LIONJAX_NO_COMPILE_CACHE", "").strip().lower() in _OFF:
        return None
    if env.get("LIONJAX_CACHE_DIR"):
        return Path(env["LIONJAX_CACHE_DIR"]).expanduser()
    base = env.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base).expanduser() / "lionjax" / "jax"


def enable(disabled: bool = False) -> Path | None:
    """Turn JAX's persistent compilation cache on in :func:`cache_dir`; returns the folder used,
    or None when off (``disabled``, the environment variable, or a folder that cannot be made:
    then a warning, and the run goes on without it)."""
    import jax

    if disabled:
        return None
    if jax.config.jax_compilation_cache_dir:  # the user's own JAX cache
        return Path(jax.config.jax_compilation_cache_dir)
    folder = cache_dir()
    if folder is None:
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        warnings.warn(
            f"compilation cache {folder}: {e.strerror or e}; running without it (set "
            "LIONJAX_CACHE_DIR to a writable folder, or LIONJAX_NO_COMPILE_CACHE=1)",
            stacklevel=2,
        )
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return folder
