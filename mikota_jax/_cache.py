"""JAX's persistent compilation cache, switched on by the command line and on request.

Compiling a solve (1-5 s) costs far more than running it (0.01-0.3 s). With the cache on, a second
process loads the compiled executables from disk instead. Only executables without host callbacks
can be stored: the solvers therefore return a ``RESULTS`` code and raise outside the compiled code
(the ``ODE`` method's executable still holds diffrax's own check of ``SaveAt(ts)``, so it is
recompiled in each process).
Importing mikota_jax changes no global setting; the CLI calls ``enable_compilation_cache`` unless
``MIKOTA_JAX_CACHE=0``.
"""

import os
from pathlib import Path

import jax

ENV_DIR = "MIKOTA_JAX_CACHE_DIR"


def default_cache_dir() -> Path:
    """``$MIKOTA_JAX_CACHE_DIR``, else ``$XDG_CACHE_HOME/mikota_jax/xla`` (``~/.cache/...``)."""
    if os.environ.get(ENV_DIR):
        return Path(os.environ[ENV_DIR]).expanduser()
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "mikota_jax" / "xla"


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path:
    """Turn on JAX's persistent compilation cache in ``path``; returns that directory.

    Default: ``$MIKOTA_JAX_CACHE_DIR``, else ``$XDG_CACHE_HOME/mikota_jax/xla`` (``~/.cache/...``).
    Changes JAX's global configuration for this process; every executable is stored, however short
    its compile time. An ``OSError`` (nothing changed) where the folder cannot be used.
    """
    path = Path(path).expanduser() if path is not None else default_cache_dir()
    if path.exists() and not path.is_dir():
        raise OSError(f"{path} is not a folder")
    path.mkdir(parents=True, exist_ok=True)
    if not os.access(path, os.W_OK | os.X_OK):
        raise OSError(f"{path} is not writable")
    jax.config.update("jax_compilation_cache_dir", str(path))
    # Every solve is worth caching: the default threshold (1 s) would skip the smaller ones.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path
