"""A stiff solver that keeps the system's structure: Kvaerno's 5/4 ESDIRK with O(n) stage solves.

diffrax's implicit solvers find each stage by Newton iterations on a dense 2n x 2n Jacobian,
factored every step: O(n^3), unusable from n ~ 1000 on. Our system is linear, y = (x, v),
y' = (v, M^-1 (f(t) - D v - K x)), so an implicit stage z = w + s F(t, z) (s = h gamma) is one
linear solve, done exactly. Eliminating x = w_x + s v leaves

    (M + s D + s^2 K) v = M w_v + s (f(t) - K w_x),

a symmetric positive definite n x n system. For a chain it is tridiagonal (diagonal mass and
grounded dampers, tridiagonal K, Rayleigh damping) plus one rank-one term per relative damper or
branched-chain link (Woodbury); in modal coordinates (a reduced model, a non-diagonal mass, modal
damping) it is diagonal plus the low-rank projected dampers. Banded, sparse or dense user
matrices with a diagonal mass fall back to a dense solve per step. Either way a
stage costs O(n) (O(r p) reduced), the method is L-stable and stiffly accurate, and diffrax's
step-size control, dense output, events and adjoints work unchanged around it.
"""

from typing import ClassVar

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from .._model.dampers import Dampers
from .._model.operators import Diagonal, LowRank, SymmetricTridiagonal

_TABLEAU = diffrax.Kvaerno5.tableau


def symmetric_tridiagonal_solve(diagonal, off_diagonal, rhs):
    """Solve a symmetric tridiagonal system for rhs (n,) or (n, p) (no pivoting: it is SPD)."""
    vector = rhs.ndim == 1
    rhs = rhs[:, None] if vector else rhs
    if diagonal.shape[0] == 1:
        out = rhs / diagonal[:, None]
    else:
        lower = jnp.pad(off_diagonal, (1, 0))
        upper = jnp.pad(off_diagonal, (0, 1))
        out = jax.lax.linalg.tridiagonal_solve(lower, diagonal, upper, rhs)
    return out[:, 0] if vector else out


def _woodbury(base_solve, factor, weights):
    """y -> (T + U diag(w) U^T)^-1 y given y -> T^-1 y; no inverse of w (it may be zero)."""
    z = base_solve(factor)  # T^-1 U, (n, p)
    capacitance = jnp.eye(factor.shape[1]) + weights[:, None] * (factor.T @ z)

    def solve(rhs):
        y = base_solve(rhs)
        return y - z @ jnp.linalg.solve(capacitance, weights * (factor.T @ y))

    return solve


def _internal_bands(system, s):
    """s D_internal as (diagonal, off-diagonal, link weights), or None when it is not tridiagonal.

    Rayleigh's alpha M + beta K is as tridiagonal as K (its links scale by beta); a user's
    diagonal or tridiagonal D adds its bands; modal damping is diagonal only in modal coordinates
    (where ``unpack`` has turned it into a ``Diagonal`` matrix already).
    """
    n, internal, stiffness = system.size, system.internal, system.stiffness
    diagonal, off, links = jnp.zeros(n), jnp.zeros(max(n - 1, 0)), None
    if internal is None:
        return diagonal, off, links
    if internal.modal is not None:
        return None
    matrix = internal.matrix
    if isinstance(matrix, Diagonal):
        diagonal = diagonal + s * matrix.diagonal
    elif isinstance(matrix, SymmetricTridiagonal) and not matrix.links:
        diagonal, off = diagonal + s * matrix.diagonal, off + s * matrix.off_diagonal
    elif matrix is not None:
        return None
    if internal.rayleigh is not None:
        mass = system.mass
        if not (physical_mass(mass) and isinstance(stiffness, Diagonal | SymmetricTridiagonal)):
            return None
        alpha, beta = s * internal.rayleigh.alpha, s * internal.rayleigh.beta
        diagonal = diagonal + alpha * mass.diagonal + beta * stiffness.diagonal
        if isinstance(mass, SymmetricTridiagonal):
            off = off + alpha * mass.off_diagonal
        if isinstance(stiffness, SymmetricTridiagonal):
            off = off + beta * stiffness.off_diagonal
            links = None if not stiffness.links else beta * stiffness.link_springs
    return diagonal, off, links


def physical_mass(mass) -> bool:
    """A mass solved in physical coordinates: diagonal, or tridiagonal without links (a
    consistent finite-element mass of a bar, say)."""
    return isinstance(mass, Diagonal) or (isinstance(mass, SymmetricTridiagonal)
                                           and not mass.links)


def dense_shifted_solver(system, s):
    """rhs -> (M + s D + s^2 K)^-1 rhs by one Cholesky factorization per step (it is SPD)."""
    matrix = system.mass.as_matrix() + s**2 * system.stiffness.as_matrix()
    damping = system.damping_operator()
    if damping is not None:
        matrix = matrix + s * damping.as_matrix()
    factor = jax.scipy.linalg.cho_factor((matrix + matrix.T) / 2)
    return lambda rhs: jax.scipy.linalg.cho_solve(factor, rhs)


def _pair_factor(n: int, pairs):
    """(n, p) columns e_i - e_j for 0-based pairs (i, j)."""
    pairs = jnp.asarray(pairs).reshape(-1, 2)
    columns = jnp.arange(pairs.shape[0])
    return jnp.zeros((n, pairs.shape[0])).at[pairs[:, 0], columns].set(1.0).at[
        pairs[:, 1], columns].add(-1.0)


def shifted_solver(system, s):
    """rhs -> (M + s D + s^2 K)^-1 rhs, prepared once per step (s = h gamma), in O(n) structure.

    Structured when M is diagonal or tridiagonal and K (with D's internal part) tridiagonal or
    diagonal: a tridiagonal solve, plus Woodbury for relative dampers, a branched chain's links
    and projected dampers; any other system (banded, sparse or dense matrices) is solved densely.
    """
    mass, stiffness, damping = system.mass, system.stiffness, system.damping
    internal = _internal_bands(system, s)
    structured = (physical_mass(mass) and internal is not None
                  and isinstance(stiffness, Diagonal | SymmetricTridiagonal)
                  and isinstance(damping, Dampers | LowRank | None))
    if not structured:
        return dense_shifted_solver(system, s)
    d_internal, off_internal, link_internal = internal
    diagonal = mass.diagonal + s**2 * stiffness.diagonal + d_internal
    if isinstance(damping, Dampers):
        diagonal = diagonal + s * damping.grounded_diagonal()
    factors, weights = [], []
    tridiagonal = isinstance(stiffness, SymmetricTridiagonal) or isinstance(
        mass, SymmetricTridiagonal)
    if tridiagonal:
        off = off_internal
        if isinstance(mass, SymmetricTridiagonal):
            off = off + mass.off_diagonal
        if isinstance(stiffness, SymmetricTridiagonal):
            off = off + s**2 * stiffness.off_diagonal
        if isinstance(stiffness, SymmetricTridiagonal) and stiffness.links:
            # K's links are -k at (i, j) with +k on the diagonal: k (e_i - e_j)(e_i - e_j)^T
            # taken out of the tridiagonal part and put back by Woodbury
            w = s**2 * stiffness.link_springs + (0.0 if link_internal is None else link_internal)
            i, j = (np.asarray(a) for a in zip(*stiffness.links))
            diagonal = diagonal.at[i].add(-w).at[j].add(-w)
            factors.append(_pair_factor(system.size, stiffness.links))
            weights.append(w)
        solve = lambda rhs: symmetric_tridiagonal_solve(diagonal, off, rhs)  # noqa: E731
    else:
        solve = lambda rhs: rhs / (diagonal if rhs.ndim == 1 else diagonal[:, None])  # noqa: E731
    if isinstance(damping, Dampers) and damping.pair_count:
        factors.append(_pair_factor(system.size, damping.pairs))
        weights.append(s * damping.pair_coefficients)
    elif isinstance(damping, LowRank):
        factors.append(damping.factor)
        weights.append(s * damping.weights)
    if factors:
        solve = _woodbury(solve, jnp.concatenate(factors, axis=1), jnp.concatenate(weights))
    return solve


class StructuredKvaerno5(diffrax.AbstractSolver):
    """Kvaerno's L-stable 5/4 ESDIRK (diffrax's tableau) with exact, structured stage solves.

    Use it as ``solve(..., method=ODE(StructuredKvaerno5()))`` for stiff cases: large n (highest
    eigenfrequency n sqrt(k/m)) or a strong damper. ``ODE`` binds the system and load; a
    stage costs one O(n) tridiagonal solve instead of Newton iterations on a dense Jacobian.
    The methods below are diffrax's ``AbstractSolver`` interface; the state is y = (x, v), (2n,).
    """

    system: object = None
    load: object = None

    term_structure: ClassVar = diffrax.AbstractTerm
    interpolation_cls: ClassVar = diffrax.ThirdOrderHermitePolynomialInterpolation.from_k

    def bind(self, system, load) -> "StructuredKvaerno5":
        """This solver for one system (diagonal-mass coordinates) and load; ``ODE`` binds."""
        return StructuredKvaerno5(system, load)

    def order(self, terms):
        """5, the order of the solution (the embedded error estimate is order 4)."""
        return 5

    def init(self, terms, t0, t1, y0, args):
        """No solver state; raises unless bound to a system."""
        if self.system is None:
            raise ValueError("StructuredKvaerno5 must be bound to a system; use it as "
                             "solve(..., method=ODE(StructuredKvaerno5())).")
        return None

    def func(self, terms, t0, y0, args):
        """The vector field y' = (v, M^-1 (f(t) - D v - K x)) at (t0, y0)."""
        return terms.vf(t0, y0, args)

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        """One ESDIRK step t0 -> t1: (y1, filtered error estimate, dense info, None, result)."""
        del solver_state, made_jump
        tableau, system = _TABLEAU, self.system
        n = system.size
        h = t1 - t0
        s = h * tableau.a_diagonal[1]
        solve = shifted_solver(system, s)

        def stage(w, t):
            """z = w + s F(t, z) (F without the load when t is None): one structured solve."""
            force = -system.stiffness.mv(w[:n])
            if self.load is not None and t is not None:
                force = force + self.load(t)
            v = solve(system.mass.mv(w[n:]) + s * force)
            return jnp.concatenate([w[:n] + s * v, v])

        ks = [terms.vf(t0, y0, args)]
        z = y0
        for a_row, c in zip(tableau.a_lower, tableau.c):
            w = y0 + h * sum(a * k for a, k in zip(a_row, ks) if a != 0)
            t = t0 + c * h
            z = stage(w, t)
            ks.append(terms.vf(t, z, args))
        y1 = z  # stiffly accurate: the last stage is the solution
        error = h * sum(b * k for b, k in zip(tableau.b_error, ks) if b != 0)
        # Filter the estimate through (I - s A)^-1 (Hairer & Wanner, IV.8): unfiltered, the
        # stiff components' k (lambda z, |lambda| up to n sqrt(k/m)) inflate it by |s lambda|
        # and the controller takes explicit-sized steps after all.
        error = stage(error, None)
        dense_info = dict(y0=y0, y1=y1, k=jnp.stack([h * ks[0], h * ks[-1]]))
        return y1, error, dense_info, None, diffrax.RESULTS.successful
