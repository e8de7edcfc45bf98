"""Input validation: eager ``ValueError`` for concrete values, ``eqx.error_if`` for traced ones.

Every message starts with ``MARK`` so that the public entry points can turn equinox's runtime error
(raised when a traced check fails under ``jit``) back into the ``ValueError`` a user expects.
"""

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
    if dtype is None:  # Python numbers, lists, strings: what numpy makes of them
        try:
            x = np.asarray(x)
        except (TypeError, ValueError) as error:  # ragged lists
            raise ValueError(MARK + f"{name} must be real, got {x!r:.60}.") from error
        if not (np.issubdtype(x.dtype, np.number) or x.dtype == np.bool_) or np.issubdtype(
                x.dtype, np.complexfloating):
            raise ValueError(MARK + f"{name} must be real, got {x!r:.60}.")
    if isinstance(x, np.ndarray | np.generic):  # cast on the host: an int array cast on the
        x = x.astype(np.float64)  # device would compile a conversion per shape
    return jnp.asarray(x, dtype=jnp.float64)


def check_lowest(lowest, n: int) -> None:
    """``lowest``: None or the number of lowest modes, an integer in 1..n."""
    if lowest is not None and (isinstance(lowest, bool) or not isinstance(lowest, int)
                               or not 1 <= lowest <= n):
        raise ValueError(MARK + f"lowest must be None or an integer in 1..{n}, got {lowest!r}.")


def is_traced(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def array_module(*xs):
    """``numpy`` when every leaf of ``xs`` is concrete, else ``jax.numpy``: host-side checks and
    index arithmetic on concrete inputs then compile nothing (each eager ``jnp`` op compiles once
    per shape, ~40 ms on a 2-core CPU: a scene's cold start paid ~3 s for about 100 of them).
    Convert with ``np.asarray`` before indexing or slicing: under a caller's trace even a
    concrete jax array's ``x[0]`` is staged into the trace (a tracer numpy cannot take)."""
    return jnp if any(is_traced(leaf) for x in xs for leaf in jax.tree.leaves(x)) else np


def check(x, bad, message: str):
    """Return ``x``; fail with ``message`` where ``bad`` holds (eagerly or under jit)."""
    if not is_traced(bad) and not any(is_traced(leaf) for leaf in jax.tree.leaves(x)):
        if bool(np.any(np.asarray(bad))):
            raise ValueError(MARK + message)
        return x
    return eqx.error_if(x, bad, MARK + message)


class RESULTS(eqx.Enumeration):
    """Why a compiled computation failed, as diffrax's ``RESULTS``: an integer code carried
    through ``jit`` and ``vmap`` and turned into one ``ValueError`` at the boundary
    (``raise_result``). Messages may name ``{max_steps}``, filled in there."""

    successful = ""
    not_definite = ("stiffness must be positive definite (a fixed-free chain with positive "
                    "springs is).")
    max_steps_reached = (
        "the integration stopped: max_steps = {max_steps} reached before ts[-1]. Increase "
        "max_steps, loosen rtol/atol, or for a stiff case (large n, strong damper) use the "
        "structured implicit solver (method=ODE(StructuredKvaerno5())) or an exact method "
        "(Spectral(), DenseExponential()).")
    solver_failed = ("the integration failed inside diffrax (step size collapsed or the "
                     "implicit solve diverged); check the inputs for non-finite values, or try "
                     "another solver.")
    non_finite_states = ("the integration produced non-finite states; check the inputs and "
                         "tolerances, or use the stiff solver StructuredKvaerno5().")
    exact_not_finite = (
        "the exact solution produced non-finite values; check the inputs for huge or non-finite "
        "values (a rate ||A|| h beyond ~1e20 is out of the matrix exponential's range: use "
        "solve(..., method=ODE(StructuredKvaerno5()))).")
    pulse_too_short = (
        "DenseExponential(): the pulse duration is too short for the piecewise-constant "
        "formula, which loses digits as eps / (omega_1 duration) (more than 1e-6 here); use its "
        "Dirac limit v0 = M^-1 (amplitude duration) e_dof, or method=ODE().")
    out_of_range = (
        "Energy: the fastest rate times the horizon (||A|| T) exceeds 4.5e11, beyond "
        "which the dense (Van Loan) energy loses more than ~1e-5 to rounding (or the result is "
        "not finite); a full system with discrete dampers takes the spectral path "
        "(method=Auto()), which has no such limit; else shorten the horizon, or model a DOF "
        "that a strong damper pins as fixed.")
    not_damped = (
        "AverageEnergy: some mode is undamped (the Lyapunov solution does not exist); "
        "place a damper where every mode moves, or restrict Z with lowest=s (called outside jit, "
        "the refusal names the undamped modes).")
    spectral_failed = (
        "the spectral path did not hold here (a root did not converge, or roots nearly "
        "coincide beyond a critically damped pair); use method=DenseExponential().")


# every failure, in the order a batch reports them (the first that holds anywhere wins)
FAILURES = (RESULTS.not_definite, RESULTS.max_steps_reached, RESULTS.solver_failed,
            RESULTS.non_finite_states, RESULTS.exact_not_finite, RESULTS.pulse_too_short,
            RESULTS.out_of_range, RESULTS.not_damped, RESULTS.spectral_failed)


def first_failure(*cases) -> RESULTS:
    """The result of the first ``(flag, code)`` whose flag holds; successful when none does."""
    result = RESULTS.successful
    for flag, code in reversed(cases):
        result = RESULTS.where(jnp.any(flag), code, result)
    return result


def raise_result(out, result: RESULTS, **context):
    """Return ``out``, failing with ``result``'s message unless it is ``successful``.

    Compiled solvers return a ``RESULTS`` code instead of raising inside: a concrete code becomes
    a plain ``ValueError`` here, so the compiled executable holds no host callback of ours; a
    traced one (the caller's own ``jit`` or ``vmap``) becomes one ``eqx.branched_error_if``
    (a batch reports its first failure in ``FAILURES`` order). ``context`` fills the messages'
    fields (``max_steps``).
    """

    def message(code):
        text = MARK + RESULTS[code]
        for key, value in context.items():
            text = text.replace("{" + key + "}", str(value))
        return text

    if not any(is_traced(leaf) for leaf in jax.tree.leaves(result)):
        for code in FAILURES:
            if bool(np.any(np.asarray(result == code))):
                raise ValueError(message(code))
        return out
    # index i names ranked[i]: the batch's largest index is its first failure in FAILURES order
    ranked = FAILURES[::-1]
    index = sum(jnp.where(result == code, i, 0) for i, code in enumerate(ranked))
    return eqx.branched_error_if(out, result != RESULTS.successful, index,
                                 [message(code) for code in ranked])


def positive_scalar(x, name: str):
    """``x`` as float64, checked finite and > 0 (eagerly, or under jit via ``eqx.error_if``)."""
    x = as_float(x, name)
    xp = array_module(x)
    value = np.asarray(x) if xp is np else x  # a concrete jax array's ">" would compile
    return check(x, ~(xp.isfinite(value) & (value > 0)), f"{name} must be finite and > 0.")


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


def available_bytes() -> float | None:
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


def fits_in_memory(size: int, matrices: float) -> bool:
    """Whether ``matrices`` float64 size x size arrays fit in the memory available now."""
    available = available_bytes()
    return available is None or matrices * size * size * 8.0 <= available


def check_dense_memory(size: int, matrices: float, what: str) -> None:
    """Refuse a dense O(size^2) computation that cannot fit in memory, before it is attempted.

    ``matrices`` is how many float64 size x size arrays the computation holds at its peak (counted
    for the method, generously); the error names the size and the O(n) alternatives.
    """
    if not fits_in_memory(size, matrices):
        need, available = matrices * size * size * 8.0, available_bytes()
        raise ValueError(
            MARK + f"{what} works with dense matrices: at n = {size} it needs about "
            f"{need / 2**30:.1f} GiB, more than the {available / 2**30:.1f} GiB available. Use "
            "solve(..., method=ODE(StructuredKvaerno5())) or Energy(..., method=ODE()) (O(n) "
            "memory), or a reduced model.")


BYTES_PER_DOF = 8 * 200  # float64 vectors of length n a solve holds, generously


def check_chain_size(n: int, name: str = "n") -> None:
    """Refuse a chain of n DOFs whose O(n) solver vectors alone cannot fit in memory (n = 10^9
    aborted inside XLA after 80 s before)."""
    available = available_bytes()
    if available is not None and BYTES_PER_DOF * n > available:
        raise ValueError(MARK + f"{name} = {n} needs about {BYTES_PER_DOF * n / 2**30:.0f} GiB "
                         f"for the O(n) solvers' vectors, more than the "
                         f"{available / 2**30:.1f} GiB available.")


def check_output_memory(count: int, width: int, what: str) -> None:
    """Refuse ``count`` output times of ``width`` float64 values each (outputs and their
    per-time work arrays) that cannot fit in the memory available now, before compiling."""
    need, available = 8.0 * count * width, available_bytes()
    if available is not None and need > available:
        raise ValueError(
            MARK + f"{what}: {count} output times x {width} values need about "
            f"{need / 2**30:.1f} GiB, more than the {available / 2**30:.1f} GiB available; ask "
            "for fewer times (ts) or fewer dofs.")


def integer_indices(values, name: str) -> tuple[int, ...]:
    """``values`` (a scalar or a sequence) as Python ints; a non-integer (2.5, True, "3", a
    complex) is refused by name, never rounded."""
    try:
        array = np.atleast_1d(np.asarray(values))
    except (TypeError, ValueError):
        raise ValueError(MARK + f"{name} must be integers, got {values!r}.") from None
    kind = array.dtype.kind
    if kind == "f" and np.all(np.isfinite(array)) and np.all(array == np.round(array)):
        return tuple(int(v) for v in array.ravel())
    if kind not in "iu":
        raise ValueError(MARK + f"{name} must be integers, got {values!r}.")
    return tuple(int(v) for v in array.ravel())
