"""U C for a fixed-free chain without U: the modes made a chunk at a time (``_chain_modes``),
each chunk's contribution U[rows, chunk] C[chunk] summed in a ``lax.scan``. The spectral
response of a large chain (``_spectral_solve``) maps its modal coordinates to the DOFs with it:
O(n^2) for the modes and O(n^2 p) for the product, O(n (chunk + p)) memory (U at n = 30000 is
7.2 GB). Differentiable in the masses, springs and C (custom JVP from ``_tangents``; reverse
mode recomputes each chunk).
"""

import jax
import jax.numpy as jnp

from .._limits import chunk as work_chunk
from .chain_modes import _chunked, _eigenvalues, _modes_of, _tangents


def _coefficient_chunks(coefficients, size: int):
    """C (n, p) zero-padded to (count, size, p): the padded modes (copies of the last) add 0."""
    n = coefficients.shape[0]
    count = -(-n // size)
    padding = jnp.zeros((count * size - n,) + coefficients.shape[1:], coefficients.dtype)
    return jnp.concatenate([coefficients, padding]).reshape((count, size) + coefficients.shape[1:])


@jax.custom_jvp
def _combine(masses, springs, rows, coefficients, size):
    omega2 = _eigenvalues(masses, springs)

    @jax.checkpoint
    def step(total, chunk):
        lam, c = chunk
        modes, _ = _modes_of(masses, springs, lam)
        return total + modes[rows] @ c, None

    zero = jnp.zeros((rows.shape[0], coefficients.shape[1]), coefficients.dtype)
    chunks = (_chunked(omega2, size.shape[0]), _coefficient_chunks(coefficients, size.shape[0]))
    return jax.lax.scan(step, zero, chunks)[0]


@_combine.defjvp
def _combine_jvp(primals, tangents):
    (masses, springs, rows, coefficients, size), (dmasses, dsprings, _, dcoefficients, _) = (
        primals, tangents)
    omega2 = _eigenvalues(masses, springs)

    @jax.checkpoint
    def step(carry, chunk):
        total, dtotal = carry
        lam, c, dc = chunk
        modes, twisted = _modes_of(masses, springs, lam)
        _, dmodes = _tangents(masses, springs, lam, modes, twisted, dmasses, dsprings)
        picked = modes[rows]
        return (total + picked @ c, dtotal + dmodes[rows] @ c + picked @ dc), None

    zero = jnp.zeros((rows.shape[0], coefficients.shape[1]), coefficients.dtype)
    chunks = (_chunked(omega2, size.shape[0]),
              _coefficient_chunks(coefficients, size.shape[0]),
              _coefficient_chunks(dcoefficients, size.shape[0]))
    (total, dtotal), _ = jax.lax.scan(step, (zero, zero), chunks)
    return total, dtotal


def chain_mode_combination(masses, springs, rows, coefficients, chunk: int | None = None):
    """(U C)[rows]: (s, p) for C (n, p) and 0-based ``rows`` (s,), U the chain's M-orthonormal
    modes (``chain_modes``' order and sign rule), without U. Unchecked (a system's masses and
    springs were checked when it was built); ``chunk``: modes per chunk (default ~2^24 / n, a
    128 MB work array)."""
    n = masses.shape[0]
    chunk = work_chunk(n, 64) if chunk is None else chunk
    return _combine(masses, springs, jnp.asarray(rows), coefficients,
                    jnp.zeros((min(chunk, n), 0)))
