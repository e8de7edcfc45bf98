"""Discrete dampers: grounded (absolute) at a DOF, and relative between two DOFs.

Conventions: DOFs are 1-based as in the paper. A grounded damper's ``position`` is a real number in
[1, n]: at a fractional position p = j + w (j = floor(p), 0 <= w < 1) its coefficient is split
linearly, d*(1-w) grounded at DOF j and d*w grounded at DOF j+1. At integer positions this is
exactly the paper's damper (Section 5); in between it is a different (two-damper) device,
continuous in p with a kink at every integer, where the derivative taken by JAX is the right-sided
one (and the left-sided one at p = n).
"""

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Basis, Float, Int, Matrix, ScalarLike, Vector
from .._errors import MARK, array_module, as_float, check, integer_indices
from .operators import AbstractOperator, LowRank, diagonal


class GroundedDamper(eqx.Module):
    """An absolute damper from a DOF to the ground, as in the paper's Section 5 (d in eq. 5.1).

    ``position``: a scalar in [1, n], 1-based (the paper's damper sits at DOF 7); a fractional
    p = j + w splits the coefficient, d (1 - w) at DOF j and d w at DOF j + 1 (see the module
    docstring). ``coefficient`` d >= 0: a scalar in force * time per length (consistent units).
    Both stay traced arrays, so ``jax.grad`` passes through them; the range is checked when the
    chain is built.
    """

    position: Float[Array, ""]
    coefficient: Float[Array, ""]

    def __init__(self, position: ScalarLike, coefficient: ScalarLike):
        self.position = as_float(position, "position")
        self.coefficient = as_float(coefficient, "coefficient")
        if self.position.shape != () or self.coefficient.shape != ():
            raise ValueError(MARK + "GroundedDamper position and coefficient must be scalars.")


class RelativeDamper(eqx.Module):
    """A relative damper between DOFs i and j: it adds c (e_i - e_j)(e_i - e_j)^T to D (eq. 3.1).

    ``dofs = (i, j)``: 1-based, i != j, static (Python integers). ``coefficient`` c >= 0: a
    scalar in force * time per length (consistent units), traced.
    """

    dofs: tuple[int, int] = eqx.field(static=True)
    coefficient: Float[Array, ""]

    def __init__(self, dofs: tuple[int, int], coefficient: ScalarLike):
        dofs = integer_indices(dofs, "RelativeDamper dofs")
        if len(dofs) != 2 or dofs[0] == dofs[1]:
            raise ValueError(MARK + f"RelativeDamper dofs must be two different DOFs, got {dofs}.")
        self.dofs = dofs
        self.coefficient = as_float(coefficient, "coefficient")
        if self.coefficient.shape != ():
            raise ValueError(MARK + "RelativeDamper coefficient must be a scalar.")


# the ``dampers`` argument of the system builders: one damper alone, or a sequence of them
DamperArgument = GroundedDamper | RelativeDamper | Sequence[GroundedDamper | RelativeDamper]


def _split(position, n: int):
    """0-based left index and weight of the right neighbour for a position in [1, n]."""
    if n == 1:
        return jnp.zeros(position.shape, int), jnp.zeros_like(position)
    j = jnp.clip(jnp.floor(position), 1, n - 1)
    return j.astype(int) - 1, position - j


class Dampers(AbstractOperator):
    """The damping operator D of a set of dampers; applying it costs O(n + number of dampers)."""

    size: int = eqx.field(static=True)
    positions: Float[Array, " g"]
    coefficients: Float[Array, " g"]
    pairs: Int[Array, "p 2"]  # 0-based DOFs of the relative dampers, traced (a search moves them)
    pair_coefficients: Float[Array, " p"]

    def __init__(self, n: int, dampers):
        grounded = [d for d in dampers if isinstance(d, GroundedDamper)]
        relative = [d for d in dampers if isinstance(d, RelativeDamper)]
        if len(grounded) + len(relative) != len(dampers):
            raise ValueError(MARK + "dampers must be GroundedDamper or RelativeDamper instances.")
        self.size = n
        # concrete values: stacked and checked in numpy (nothing compiled), stored as jax arrays
        xp = array_module(*dampers)
        positions = xp.stack([d.position for d in grounded]) if grounded else xp.zeros(0)
        coefficients = xp.stack([d.coefficient for d in grounded]) if grounded else xp.zeros(0)
        self.positions = jnp.asarray(check(
            positions, ~((positions >= 1) & (positions <= n)),
            f"damper position must lie in [1, {n}] (1-based DOFs of a chain with n = {n})."))
        self.coefficients = jnp.asarray(check(
            coefficients, ~(xp.isfinite(coefficients) & (coefficients >= 0)),
            "damper coefficient must be finite and >= 0."))
        for d in relative:
            if not all(1 <= i <= n for i in d.dofs):
                raise ValueError(MARK + f"relative damper dofs {d.dofs} must lie in 1..{n}.")
        self.pairs = jnp.asarray(np.asarray([(d.dofs[0] - 1, d.dofs[1] - 1) for d in relative],
                                            dtype=int).reshape(len(relative), 2))
        pair_coefficients = (xp.stack([d.coefficient for d in relative]) if relative
                             else xp.zeros(0))
        self.pair_coefficients = jnp.asarray(check(
            pair_coefficients, ~(xp.isfinite(pair_coefficients) & (pair_coefficients >= 0)),
            "damper coefficient must be finite and >= 0."))

    @property
    def pair_count(self) -> int:
        """How many relative dampers there are (static: it sets shapes)."""
        return self.pairs.shape[0]

    def _grounded_weights(self):
        left, w = _split(self.positions, self.size)
        right = jnp.minimum(left + 1, self.size - 1)
        return left, right, self.coefficients * (1 - w), self.coefficients * w

    def grounded_diagonal(self) -> Vector:
        """The grounded dampers' part of D, which is diagonal: built once, applied as a product."""
        left, right, c_left, c_right = self._grounded_weights()
        return jnp.zeros(self.size).at[left].add(c_left).at[right].add(c_right)

    def mv_relative(self, v: Vector) -> Vector:
        """The relative dampers' part of D v (zero when there are none)."""
        out = jnp.zeros_like(v)
        if self.pair_count:
            i, j = self.pairs[:, 0], self.pairs[:, 1]
            f = self.pair_coefficients * (v[i] - v[j])
            out = out.at[i].add(f).at[j].add(-f)
        return out

    def mv(self, v: Vector) -> Vector:
        return self.grounded_diagonal() * v + self.mv_relative(v)

    def as_matrix(self) -> Matrix:
        return jax.vmap(self.mv, in_axes=1, out_axes=1)(jnp.eye(self.size))

    def touched(self) -> Array:
        """The 0-based DOFs whose basis rows ``project`` reads, in its order: each grounded
        damper's left and right neighbour, then each relative damper's two DOFs."""
        left, right, _, _ = self._grounded_weights()
        return jnp.concatenate([left, right, self.pairs[:, 0], self.pairs[:, 1]])

    def project_rows(self, rows) -> LowRank:
        """``project`` from the basis rows ``basis[self.touched()]`` alone (no n x r basis:
        a chain's modes at those rows come from ``chain_mode_data``)."""
        g, p = self.positions.shape[0], self.pair_count
        _, _, c_left, c_right = self._grounded_weights()
        columns, weights = [rows[:g], rows[g:2 * g]], [c_left, c_right]
        if p:
            columns.append(rows[2 * g:2 * g + p] - rows[2 * g + p:])
            weights.append(self.pair_coefficients)
        return LowRank(jnp.concatenate(columns).T, jnp.concatenate(weights))

    def project(self, basis: Basis) -> LowRank:
        """``basis^T D basis`` as B diag(w) B^T, B = the basis rows the dampers touch."""
        return self.project_rows(basis[self.touched()])

    def abs_row_sums(self) -> Vector:
        """sum_j |D_ij| per row: the grounded diagonal, plus 2 c at both DOFs of each pair."""
        rows = self.grounded_diagonal()  # coefficients are >= 0
        c = 2 * self.pair_coefficients
        return rows.at[self.pairs[:, 0]].add(c).at[self.pairs[:, 1]].add(c)


@diagonal.register(Dampers)
def _(operator: Dampers) -> Vector:
    c = operator.pair_coefficients
    return operator.grounded_diagonal().at[operator.pairs[:, 0]].add(c).at[
        operator.pairs[:, 1]].add(c)
