"""Structured linear operators for mass, stiffness and damping.

The full chain keeps its structure (a diagonal mass, a symmetric tridiagonal stiffness, a handful of
dampers), so applying an operator costs O(n); a reduced model's mass and stiffness are dense r x r
and its dampers stay low rank (``LowRank``, r x p with p the DOFs they touch). Every operator
offers ``mv`` (matrix-vector product), ``as_matrix`` (dense, only on request) and
``project(basis)`` (the Galerkin product ``basis^T A basis`` of eq. 3.4).
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from ._custom_types import Array, Basis, Float, Matrix, Vector


class Diagonal(eqx.Module):
    """A diagonal matrix stored as its diagonal."""

    diagonal: Vector

    @property
    def size(self) -> int:
        return self.diagonal.shape[0]

    def mv(self, x: Vector) -> Vector:
        return self.diagonal * x

    def solve(self, y: Vector) -> Vector:
        return y / self.diagonal

    def as_matrix(self) -> Matrix:
        return jnp.diag(self.diagonal)

    def project(self, basis: Basis) -> "Dense":
        return Dense(basis.T @ (self.diagonal[:, None] * basis))


class SymmetricTridiagonal(eqx.Module):
    """A symmetric tridiagonal matrix: main diagonal (n,) and off-diagonal (n-1,).

    ``springs`` (optional): the k_i of a fixed-free chain, K = L^T diag(k) L with L the
    difference operator (x_i - x_{i-1}, x_0 = 0). The modal decomposition then uses the SVD of the
    bidiagonal factor diag(sqrt k) L M^-1/2, which keeps every eigenfrequency to full relative
    accuracy; eigh of M^-1/2 K M^-1/2 loses the lowest ones when masses span many decades.
    """

    diagonal: Vector
    off_diagonal: Float[Array, " n-1"]
    springs: Vector | None = None

    @property
    def size(self) -> int:
        return self.diagonal.shape[0]

    def mv(self, x: Vector) -> Vector:
        y = self.diagonal * x
        if self.size == 1:
            return y
        upper = self.off_diagonal * x[1:]
        lower = self.off_diagonal * x[:-1]
        return y + jnp.pad(upper, (0, 1)) + jnp.pad(lower, (1, 0))

    def as_matrix(self) -> Matrix:
        return (jnp.diag(self.diagonal) + jnp.diag(self.off_diagonal, 1)
                + jnp.diag(self.off_diagonal, -1))

    def project(self, basis: Basis) -> "Dense":
        return Dense(basis.T @ jax.vmap(self.mv, in_axes=1, out_axes=1)(basis))


class Dense(eqx.Module):
    """A dense matrix (a reduced model's operators, or a user's dense matrix)."""

    matrix: Matrix

    @property
    def size(self) -> int:
        return self.matrix.shape[0]

    def mv(self, x: Vector) -> Vector:
        return self.matrix @ x

    def as_matrix(self) -> Matrix:
        return self.matrix

    def project(self, basis: Basis) -> "Dense":
        return Dense(basis.T @ self.matrix @ basis)


class LowRank(eqx.Module):
    """B diag(w) B^T: projected dampers, which touch only a few DOFs (p = the DOFs touched)."""

    factor: Float[Array, "r p"]
    weights: Float[Array, " p"]

    @property
    def size(self) -> int:
        return self.factor.shape[0]

    def mv(self, x: Vector) -> Vector:
        return self.factor @ (self.weights * (self.factor.T @ x))

    def as_matrix(self) -> Matrix:
        return (self.factor * self.weights[None, :]) @ self.factor.T

    def project(self, basis: Basis) -> "LowRank":
        return LowRank(basis.T @ self.factor, self.weights)


Operator = Diagonal | SymmetricTridiagonal | Dense | LowRank
