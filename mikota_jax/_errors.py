"""Input validation: eager ``ValueError`` for concrete values, ``eqx.error_if`` for traced ones.

Every message starts with ``MARK`` so that the public entry points can turn equinox's runtime error
(raised when a traced check fails under ``jit``) back into the ``ValueError`` a user expects.
"""

import contextlib
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

MARK = "mikota_jax: "


def check_x64() -> None:
    """Refuse to run with float64 disabled: results would silently be float32."""
    if not jax.config.read("jax_enable_x64"):
        raise ValueError(
            MARK + "jax_enable_x64 is off; mikota_jax computes in float64 only. "
            "Re-enable it with jax.config.update('jax_enable_x64', True)."
        )


def as_float(x, name: str) -> jax.Array:
    """Convert to a float64 array; float32/float16 input is an error, never a silent cast."""
    check_x64()
    dtype = getattr(x, "dtype", None)
    if dtype is not None and jnp.issubdtype(dtype, jnp.floating) and dtype != jnp.float64:
        raise ValueError(MARK + f"{name} must be float64, got {dtype}; pass float64 arrays.")
    if dtype is not None and jnp.issubdtype(dtype, jnp.complexfloating):
        raise ValueError(MARK + f"{name} must be real, got {dtype}.")
    return jnp.asarray(x, dtype=jnp.float64)


def is_traced(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def check(x, bad, message: str):
    """Return ``x``; fail with ``message`` where ``bad`` holds (eagerly or under jit)."""
    if not is_traced(bad) and not any(is_traced(leaf) for leaf in jax.tree.leaves(x)):
        if bool(np.any(np.asarray(bad))):
            raise ValueError(MARK + message)
        return x
    return eqx.error_if(x, bad, MARK + message)


def raise_failures(out, failures, messages):
    """Return ``out``, failing with the message of the first flag in ``failures`` that holds.

    Compiled solvers return their failure flags instead of raising inside: with concrete flags the
    error is a plain ``ValueError`` raised here, so the compiled executable holds no host callback
    (and JAX's persistent compilation cache can store it); with traced flags (the caller's own
    ``jit`` or ``vmap``) each becomes an ``eqx.error_if``.
    """
    if not any(is_traced(f) for f in failures):
        for flag, message in zip(failures, messages):
            if bool(np.any(np.asarray(flag))):
                raise ValueError(MARK + message)
        return out
    for flag, message in zip(failures, messages):
        out = eqx.error_if(out, flag, MARK + message)
    return out


@contextlib.contextmanager
def callback_free_checks():
    """Trace diffrax's own runtime checks as NaN-poisoning instead of host callbacks.

    diffrax checks ``SaveAt(ts)`` with ``eqx.error_if``, which compiles to a host callback, and
    JAX's persistent cache refuses executables holding one. Our solvers validate ``ts`` before
    tracing and flag non-finite results themselves, so inside them equinox's ``"nan"`` mode loses
    nothing: a failed check there yields NaN, which the non-finite flag reports. Only the module
    default is switched, only while the solver is traced; with another equinox layout it is a no-op.
    """
    from equinox import _errors as equinox_errors

    previous = getattr(equinox_errors, "EQX_ON_ERROR", None)
    if previous != "raise":  # the user chose a mode (or the layout changed): leave it
        yield
        return
    equinox_errors.EQX_ON_ERROR = "nan"
    try:
        yield
    finally:
        equinox_errors.EQX_ON_ERROR = previous


def positive_scalar(x, name: str):
    """``x`` as float64, checked finite and > 0 (eagerly, or under jit via ``eqx.error_if``)."""
    x = as_float(x, name)
    return check(x, ~(jnp.isfinite(x) & (x > 0)), f"{name} must be finite and > 0.")


def raises_value_error(fn):
    """Re-raise a failed traced check of ours as ``ValueError`` (its message names the argument)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except eqx.EquinoxRuntimeError as error:
            text = str(error)
            if MARK in text:
                start = text.index(MARK)
                line = text[start:].splitlines()[0]
                raise ValueError(line) from None
            raise

    return wrapper


def _available_bytes() -> float | None:
    """Memory the default device can still use: its allocator limit, or the host's available RAM."""
    try:
        stats = jax.devices()[0].memory_stats() or {}
    except Exception:  # a backend without memory statistics
        stats = {}
    if "bytes_limit" in stats:
        return float(stats["bytes_limit"] - stats.get("bytes_in_use", 0))
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def check_dense_memory(size: int, matrices: float, what: str) -> None:
    """Refuse a dense O(size^2) computation that cannot fit in memory, before it is attempted.

    ``matrices`` is how many float64 size x size arrays the computation holds at its peak (counted
    for the method, generously); the error names the size and the O(n) alternatives.
    """
    need = matrices * size * size * 8.0
    available = _available_bytes()
    if available is not None and need > available:
        raise ValueError(
            MARK + f"{what} works with dense matrices: at n = {size} it needs about "
            f"{need / 2**30:.1f} GiB, more than the {available / 2**30:.1f} GiB available. Use "
            "simulate(..., solver='kvaerno5') or integrated_energy(..., method='ode') (O(n) "
            "memory), or a reduced model.")
