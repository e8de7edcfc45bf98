"""Solves with the quadratic pencil sigma^2 M + sigma D + K in M-orthonormal modal coordinates.

With K U = M U Omega^2, U^T M U = I (``modal``), U^T (sigma^2 M + sigma D + K) U = sigma^2 I +
sigma C + Omega^2, where C = U^T D U is a diagonal internal damping (Rayleigh, modal; zeros
without) plus the dampers G W G^T of rank k (G = U^T of the dampers' directions). Woodbury on
that diagonal-plus-rank-k matrix costs O(n k^2) per shift once the right-hand side is in modal
coordinates; a user's dense damping makes it a dense O(n^3) solve. The modes are O(n^2) for a
chain (``chain_modes``), O(n^3) otherwise, and are made once for any number of shifts: the
interpolatory bases (shifted responses) and the transfer functions of ``IOModel`` both use it.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .dampers import Dampers
from .modal import modal_decomposition
from .operators import Diagonal, LowRank, SymmetricTridiagonal


def _complex(a):
    return a.astype(jnp.complex128)  # strict promotion: no mixing of real and complex


class ModalPencil(eqx.Module):
    """sigma -> (sigma^2 I + sigma C + Omega^2)^-1 in modal coordinates, C = diag(c) + G W G^T
    (or dense); ``modal_pencil`` builds it from a system."""

    omega: jax.Array
    modes: jax.Array
    diagonal: jax.Array  # the internal damping's modal diagonal (zeros without)
    factor: jax.Array  # G = U^T B of the dampers, (n, k)
    weights: jax.Array  # W, (k,)
    dense: jax.Array | None  # a user's internal damping in modes, (n, n), or None

    def solve_modal(self, sigma, rhs):
        """(sigma^2 I + sigma C + Omega^2)^-1 rhs for modal right-hand sides (n, p), complex."""
        sigma, rhs = _complex(jnp.asarray(sigma)), _complex(rhs)
        delta = sigma**2 + _complex(self.omega**2) + sigma * _complex(self.diagonal)
        g, w = _complex(self.factor), _complex(self.weights)
        if self.dense is not None:
            matrix = jnp.diag(delta) + sigma * (_complex(self.dense) + (g * w[None, :]) @ g.T)
            return jnp.linalg.solve(matrix, rhs)
        # Woodbury on Delta + sigma G W G^T, no W^-1 (a split damper has a zero weight)
        y = rhs / delta[:, None]
        scaled = g / delta[:, None]
        inner = jnp.eye(g.shape[1], dtype=jnp.complex128) + sigma * (g.T @ scaled) * w[None, :]
        return y - scaled @ (sigma * w[:, None] * jnp.linalg.solve(inner, g.T @ y))

    def damping_modal(self, z):
        """C z for modal vectors z (n, p): the damping in modal coordinates."""
        g, w = _complex(self.factor), _complex(self.weights)
        out = _complex(self.diagonal)[:, None] * z + g @ (w[:, None] * (g.T @ z))
        return out if self.dense is None else out + _complex(self.dense) @ z

    def __call__(self, sigma, forces):
        """X(sigma) = (sigma^2 M + sigma D + K)^-1 F = U (...)^-1 U^T F, physical (n, m)."""
        return _complex(self.modes) @ self.solve_modal(sigma, self.modes.T @ forces)


def modal_pencil(system) -> ModalPencil:
    """The ``ModalPencil`` of a ``SecondOrderSystem`` (its undamped modes, made once)."""
    omega, modes = modal_decomposition(system)
    n = omega.shape[0]
    damping = system.damping
    factor, weights, diagonal, dense = jnp.zeros((n, 0)), jnp.zeros(0), jnp.zeros(n), None
    if isinstance(damping, Dampers | LowRank):  # a chain's dampers, or a reduced model's
        projected = damping.project(modes)
        factor, weights = projected.factor, projected.weights
    elif damping is not None:  # a user's damping operator: dense in the modes
        dense = modes.T @ jax.vmap(damping.mv, in_axes=1, out_axes=1)(modes)
    if system.internal is not None:
        internal = system.internal.in_modes(omega**2, modes)
        if isinstance(internal, Diagonal):
            diagonal = internal.diagonal
        else:
            dense = internal.as_matrix() + (0 if dense is None else dense)
    return ModalPencil(omega, modes, diagonal, factor, weights, dense)


def symmetric_tridiagonal_solve(diagonal, off_diagonal, rhs):
    """Solve a (complex) symmetric tridiagonal system for rhs (n,) or (n, p): LAPACK's gtsv on
    the CPU, with partial pivoting (an indefinite K - omega^2 M needs it)."""
    vector = rhs.ndim == 1
    rhs = rhs[:, None] if vector else rhs
    dtype = jnp.result_type(diagonal, off_diagonal, rhs)
    diagonal, off_diagonal, rhs = (a.astype(dtype) for a in (diagonal, off_diagonal, rhs))
    if diagonal.shape[0] == 1:
        out = rhs / diagonal[:, None]
    else:
        lower = jnp.pad(off_diagonal, (1, 0))
        upper = jnp.pad(off_diagonal, (0, 1))
        out = jax.lax.linalg.tridiagonal_solve(lower, diagonal, upper, rhs)
    return out[:, 0] if vector else out


def _woodbury(base_solve, factor, weights):
    """y -> (T + U diag(w) U^T)^-1 y given y -> T^-1 y; no inverse of w (it may be zero)."""
    factor = factor.astype(weights.dtype)
    z = base_solve(factor)  # T^-1 U, (n, p)
    capacitance = jnp.eye(factor.shape[1], dtype=weights.dtype) + weights[:, None] * (factor.T @ z)

    def solve(rhs):
        y = base_solve(rhs.astype(weights.dtype))
        w = weights if y.ndim == 1 else weights[:, None]
        return y - z @ jnp.linalg.solve(capacitance, w * (factor.T @ y))

    return solve


def physical_mass(mass) -> bool:
    """A mass solved in physical coordinates: diagonal, or tridiagonal without links (a
    consistent finite-element mass of a bar, say)."""
    return isinstance(mass, Diagonal) or (isinstance(mass, SymmetricTridiagonal)
                                           and not mass.links)


def _internal_bands(system, b):
    """b D_internal as (diagonal, off-diagonal, link weights), or None when it is not tridiagonal.

    Rayleigh's alpha M + beta K is as tridiagonal as K (its links scale by beta); a user's
    diagonal or tridiagonal D adds its bands; modal damping is diagonal only in modal coordinates
    (where ``unpack`` has turned it into a ``Diagonal`` matrix already).
    """
    n, internal, stiffness = system.size, system.internal, system.stiffness
    diagonal, off, links = jnp.zeros(n, b.dtype), jnp.zeros(max(n - 1, 0), b.dtype), None
    if internal is None:
        return diagonal, off, links
    if internal.modal is not None:
        return None
    matrix = internal.matrix
    if isinstance(matrix, Diagonal):
        diagonal = diagonal + _times(b, matrix.diagonal)
    elif isinstance(matrix, SymmetricTridiagonal) and not matrix.links:
        diagonal = diagonal + _times(b, matrix.diagonal)
        off = off + _times(b, matrix.off_diagonal)
    elif matrix is not None:
        return None
    if internal.rayleigh is not None:
        mass = system.mass
        if not (physical_mass(mass) and isinstance(stiffness, Diagonal | SymmetricTridiagonal)):
            return None
        alpha, beta = _times(b, internal.rayleigh.alpha), _times(b, internal.rayleigh.beta)
        diagonal = diagonal + _times(alpha, mass.diagonal) + _times(beta, stiffness.diagonal)
        if isinstance(mass, SymmetricTridiagonal):
            off = off + _times(alpha, mass.off_diagonal)
        if isinstance(stiffness, SymmetricTridiagonal):
            off = off + _times(beta, stiffness.off_diagonal)
            links = None if not stiffness.links else _times(beta, stiffness.link_springs)
    return diagonal, off, links


def _pair_factor(n: int, pairs):
    """(n, p) columns e_i - e_j for 0-based pairs (i, j)."""
    pairs = jnp.asarray(pairs).reshape(-1, 2)
    columns = jnp.arange(pairs.shape[0])
    return jnp.zeros((n, pairs.shape[0])).at[pairs[:, 0], columns].set(1.0).at[
        pairs[:, 1], columns].add(-1.0)


def _coefficients(a, b, c):
    """a, b, c as arrays of one dtype: complex128 if any is complex, else float64."""
    values = [jnp.asarray(v) for v in (a, b, c)]
    complex_ = any(jnp.iscomplexobj(v) for v in values)
    return tuple(v.astype(jnp.complex128 if complex_ else jnp.float64) for v in values)


def _times(coefficient, array):
    """coefficient * array in the coefficient's dtype (strict promotion: no mixing)."""
    return coefficient * jnp.asarray(array).astype(coefficient.dtype)


def dense_pencil_solver(system, a, b, c):
    """rhs -> (a M + b D + c K)^-1 rhs by one dense factorization: Cholesky for real
    coefficients (the matrix is then symmetric positive definite: a, b, c >= 0), else LU."""
    a, b, c = _coefficients(a, b, c)
    matrix = _times(a, system.mass.as_matrix()) + _times(c, system.stiffness.as_matrix())
    damping = system.damping_operator()
    if damping is not None:
        matrix = matrix + _times(b, damping.as_matrix())
    if jnp.iscomplexobj(matrix):
        factor = jax.scipy.linalg.lu_factor(matrix)
        return lambda rhs: jax.scipy.linalg.lu_solve(factor, rhs.astype(matrix.dtype))
    factor = jax.scipy.linalg.cho_factor((matrix + matrix.T) / 2)
    return lambda rhs: jax.scipy.linalg.cho_solve(factor, rhs)


def pencil_solver(system, a, b, c):
    """rhs -> (a M + b D + c K)^-1 rhs in O(n) structure, prepared once (a, b, c real or complex).

    Structured when M is diagonal or tridiagonal and K (with D's internal part) tridiagonal or
    diagonal: a pivoted tridiagonal solve (grounded dampers sit on its diagonal), plus Woodbury
    for relative dampers, a branched chain's links and projected dampers; any other system
    (banded, sparse or dense matrices, a reduced model) is solved densely. Woodbury is exact but
    loses digits where the tridiagonal part alone is nearly singular (a frequency at an
    eigenfrequency of the chain without its relative dampers).
    """
    a, b, c = _coefficients(a, b, c)
    mass, stiffness, damping = system.mass, system.stiffness, system.damping
    internal = _internal_bands(system, b)
    structured = (physical_mass(mass) and internal is not None
                  and isinstance(stiffness, Diagonal | SymmetricTridiagonal)
                  and isinstance(damping, Dampers | LowRank | None))
    if not structured:
        return dense_pencil_solver(system, a, b, c)
    d_internal, off_internal, link_internal = internal
    diagonal = _times(a, mass.diagonal) + _times(c, stiffness.diagonal) + d_internal
    if isinstance(damping, Dampers):
        diagonal = diagonal + _times(b, damping.grounded_diagonal())
    factors, weights = [], []
    tridiagonal = isinstance(stiffness, SymmetricTridiagonal) or isinstance(
        mass, SymmetricTridiagonal)
    if tridiagonal:
        off = off_internal
        if isinstance(mass, SymmetricTridiagonal):
            off = off + _times(a, mass.off_diagonal)
        if isinstance(stiffness, SymmetricTridiagonal):
            off = off + _times(c, stiffness.off_diagonal)
        if isinstance(stiffness, SymmetricTridiagonal) and stiffness.links:
            # K's links are -k at (i, j) with +k on the diagonal: k (e_i - e_j)(e_i - e_j)^T
            # taken out of the tridiagonal part and put back by Woodbury
            w = _times(c, stiffness.link_springs) + (0.0 if link_internal is None
                                                     else link_internal)
            i, j = (np.asarray(v) for v in zip(*stiffness.links))
            diagonal = diagonal.at[i].add(-w).at[j].add(-w)
            factors.append(_pair_factor(system.size, stiffness.links))
            weights.append(w)
        solve = lambda rhs: symmetric_tridiagonal_solve(diagonal, off, rhs)  # noqa: E731
    else:
        solve = lambda rhs: rhs / (diagonal if rhs.ndim == 1 else diagonal[:, None])  # noqa: E731
    if isinstance(damping, Dampers) and damping.pair_count:
        factors.append(_pair_factor(system.size, damping.pairs))
        weights.append(_times(b, damping.pair_coefficients))
    elif isinstance(damping, LowRank):
        factors.append(damping.factor)
        weights.append(_times(b, damping.weights))
    if factors:
        solve = _woodbury(solve, jnp.concatenate(factors, axis=1), jnp.concatenate(weights))
    return solve


def shifted_solver(system, s):
    """rhs -> (M + s D + s^2 K)^-1 rhs: the stage solve of ``StructuredKvaerno5`` (s = h gamma)."""
    return pencil_solver(system, 1.0, s, s**2)


def dense_shifted_solver(system, s):
    """``shifted_solver`` by one dense Cholesky factorization (a check of the structured one)."""
    return dense_pencil_solver(system, 1.0, s, s**2)
