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
import jax.numpy as jnp

from .._model.pencil import (  # noqa: F401  (re-exported: the stage solves live with the pencil)
    dense_shifted_solver,
    physical_mass,
    shifted_solver,
    symmetric_tridiagonal_solve,
)

_TABLEAU = diffrax.Kvaerno5.tableau


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
