"""JAX's persistent compilation cache, turned on in one call.

Compiling is most of a short script's time: each `simulate` configuration (scene, solver,
options, shapes) compiles once per process, about a second for a plain run and several for
`jax.jacfwd` through it. JAX can keep the compiled programs on disk and load them in the
next process instead of compiling again; `enable_compilation_cache()` sets that up, and
`grazejax reproduce` calls it. The cache is keyed by the program and the JAX, jaxlib and
XLA versions (not by source locations), so a scene built afresh in a new process that gives
the same program is loaded, and an upgrade simply recompiles.
"""

import os
from pathlib import Path

import jax
from jax.experimental.compilation_cache import compilation_cache

# A folder, or one of `_OFF`: where `grazejax reproduce` (and `enable_compilation_cache()`
# without a path) keeps compiled programs.
CACHE_ENV = "GRAZEJAX_COMPILATION_CACHE"
_OFF = ("", "0", "off", "none", "false")
# JAX stores only programs that took at least this long to compile (its default is 1 s).
# A plain `simulate` of a small scene compiles in about a second, on either side of JAX's
# threshold from one machine to the next, and loads from disk in a small part of that.
MIN_COMPILE_SECONDS = 0.5
_MIN_COMPILE_ENV = "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"


def default_cache_dir() -> Path:
    """`$XDG_CACHE_HOME/grazejax/jax`, or `~/.cache/grazejax/jax` without it."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "grazejax" / "jax"


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path | None:
    """Turn on JAX's persistent compilation cache, so that a script run again loads its
    compiled programs from disk instead of compiling them.

    Call it once, best before the first simulation. It sets JAX's
    `jax_compilation_cache_dir`, and `jax_persistent_cache_min_compile_time_secs` to 0.5 s
    (programs that compile faster are not stored; JAX's default is 1 s) unless
    `$JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS` sets it. It changes JAX's configuration for
    the whole process, as `jax.config.update` does.

    **Arguments:**

    - `path`: the cache folder (created when the first program is stored). Without it:
        nothing is turned on (and the call returns None) if `$GRAZEJAX_COMPILATION_CACHE`
        is `off` (or `0`, `none`, `false`, empty); else a folder JAX was already given
        (`$JAX_COMPILATION_CACHE_DIR`, or `jax.config.update("jax_compilation_cache_dir",
        ...)`) is kept; else the folder in `$GRAZEJAX_COMPILATION_CACHE` if set; else
        `$XDG_CACHE_HOME/grazejax/jax` (by default `~/.cache/grazejax/jax`).

    **Returns:** the folder the cache uses, or None when `$GRAZEJAX_COMPILATION_CACHE` turned
    it off.

    ```python
    import grazejax as gj

    gj.enable_compilation_cache()  # before the first simulation
    ```
    """
    if path is None:
        value = os.environ.get(CACHE_ENV)
        if value is not None and value.strip().lower() in _OFF:
            return None
        current = jax.config.jax_compilation_cache_dir
        if current:
            path = current
        elif value is not None:
            path = value
        else:
            path = default_cache_dir()
    path = Path(path).expanduser().absolute()
    current = jax.config.jax_compilation_cache_dir
    if current and Path(current).expanduser().absolute() != path:
        # JAX opens its cache at the first compile after a folder is set, and keeps that
        # folder for the process: a new one takes effect only after a reset.
        compilation_cache.reset_cache()
    jax.config.update("jax_compilation_cache_dir", str(path))
    if _MIN_COMPILE_ENV not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    return path
