"""Structured linear operators for mass, stiffness and damping.

The full chain keeps its structure (a diagonal mass, a symmetric tridiagonal stiffness, a handful of
dampers), so applying an operator costs O(n); a reduced model's mass and stiffness are dense r x r
and its dampers stay low rank (``LowRank``, r x p with p the DOFs they touch). A user's matrices
keep theirs: ``SymmetricBanded`` (O(n b)) and ``Sparse`` (O(nnz)). Every operator is an
``AbstractOperator`` (lineax's ``AbstractLinearOperator`` in miniature): ``size``, ``mv``
(matrix-vector product), ``as_matrix`` (dense, only on request), ``project(basis)`` (the Galerkin
product ``basis^T A basis`` of eq. 3.4) and ``abs_row_sums`` (Gershgorin bounds); the main
diagonal is the single-dispatch function ``diagonal(operator)``, in each operator's structure.
"""

import abc
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Basis, Float, Matrix, Vector


class AbstractOperator(eqx.Module):
    """A square linear operator applied in its structure (mass, stiffness or damping)."""

    size: eqx.AbstractVar[int]

    @abc.abstractmethod
    def mv(self, x: Vector) -> Vector:
        """A x."""

    @abc.abstractmethod
    def as_matrix(self) -> Matrix:
        """The dense (size, size) matrix: O(size^2), only on request."""

    @abc.abstractmethod
    def project(self, basis: Basis) -> "AbstractOperator":
        """basis^T A basis (eq. 3.4), (r, r) for an (size, r) basis."""

    @abc.abstractmethod
    def abs_row_sums(self) -> Vector:
        """sum_j |A_ij| per row (Gershgorin bounds)."""


@functools.singledispatch
def diagonal(operator: AbstractOperator) -> Vector:
    """The main diagonal of an operator, in its structure where it has one (the dense matrix's
    otherwise)."""
    if not isinstance(operator, AbstractOperator):
        raise TypeError(f"not an operator: {type(operator).__name__}")
    return jnp.diag(operator.as_matrix())


def diagonal_of(operator: AbstractOperator) -> Vector:
    """The main diagonal of any operator (``diagonal``; the name other modules import)."""
    return diagonal(operator)


def abs_row_sums(operator: AbstractOperator) -> Vector:
    """sum_j |A_ij| per row of any operator, in its structure where it has one."""
    return operator.abs_row_sums()


def dense_abs_row_sums(operator: AbstractOperator) -> Vector:
    """sum_j |A_ij| from the dense matrix (operators with no cheaper structure)."""
    return jnp.sum(jnp.abs(operator.as_matrix()), axis=1)


def project_by_products(operator: AbstractOperator, basis: Basis) -> "Dense":
    """basis^T A basis from r structured products A basis[:, j] (no dense A is formed)."""
    return Dense(basis.T @ jax.vmap(operator.mv, in_axes=1, out_axes=1)(basis))


class Diagonal(AbstractOperator):
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

    def abs_row_sums(self) -> Vector:
        return jnp.abs(self.diagonal)


class SymmetricTridiagonal(AbstractOperator):
    """A symmetric tridiagonal matrix: main diagonal (n,) and off-diagonal (n-1,).

    ``springs`` (optional): the k_i of a fixed-free chain, K = L^T diag(k) L with L the
    difference operator (x_i - x_{i-1}, x_0 = 0). The modal decomposition then uses the SVD of the
    bidiagonal factor diag(sqrt k) L M^-1/2, which keeps every eigenfrequency to full relative
    accuracy; eigh of M^-1/2 K M^-1/2 loses the lowest ones when masses span many decades.

    ``links`` (optional, static, 0-based pairs (i, j) with |i - j| > 1) and ``link_springs``
    (one per link): springs between DOFs that are not neighbours, as in a branched chain. They add
    -k_ij at (i, j) and (j, i); ``diagonal`` already holds their +k_ij. A stencil plus O(links).
    """

    diagonal: Vector
    off_diagonal: Float[Array, " n-1"]
    springs: Vector | None = None
    links: tuple[tuple[int, int], ...] = eqx.field(static=True, default=())
    link_springs: Vector | None = None

    @property
    def size(self) -> int:
        return self.diagonal.shape[0]

    def mv(self, x: Vector) -> Vector:
        y = self.diagonal * x
        if self.size > 1:
            upper = self.off_diagonal * x[1:]
            lower = self.off_diagonal * x[:-1]
            y = y + jnp.pad(upper, (0, 1)) + jnp.pad(lower, (1, 0))
        if self.links:
            i, j = (np.asarray(a) for a in zip(*self.links))
            y = y.at[i].add(-self.link_springs * x[j]).at[j].add(-self.link_springs * x[i])
        return y

    def as_matrix(self) -> Matrix:
        matrix = (jnp.diag(self.diagonal) + jnp.diag(self.off_diagonal, 1)
                  + jnp.diag(self.off_diagonal, -1))
        if self.links:
            i, j = (np.asarray(a) for a in zip(*self.links))
            matrix = matrix.at[i, j].add(-self.link_springs).at[j, i].add(-self.link_springs)
        return matrix

    def abs_row_sums(self) -> Vector:
        off = jnp.abs(self.off_diagonal)
        rows = jnp.abs(self.diagonal) + jnp.pad(off, (0, 1)) + jnp.pad(off, (1, 0))
        if self.links:
            i, j = (np.asarray(a) for a in zip(*self.links))
            rows = rows.at[i].add(jnp.abs(self.link_springs)).at[j].add(jnp.abs(self.link_springs))
        return rows

    def project(self, basis: Basis) -> "Dense":
        return project_by_products(self, basis)


class Dense(AbstractOperator):
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

    def abs_row_sums(self) -> Vector:
        return dense_abs_row_sums(self)


class LowRank(AbstractOperator):
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

    def abs_row_sums(self) -> Vector:
        return dense_abs_row_sums(self)


class SymmetricBanded(AbstractOperator):
    """A symmetric banded matrix stored as its upper bands: ``bands[j, i] = A[i, i + j]``.

    ``bands``: (b + 1, n) for half-bandwidth b, zero-padded at the end of band j (its last j
    entries are unused). Applying it costs O(n b).
    """

    bands: Float[Array, "b+1 n"]

    @property
    def size(self) -> int:
        return self.bands.shape[1]

    def mv(self, x: Vector) -> Vector:
        n = self.size
        y = self.bands[0] * x
        for j in range(1, self.bands.shape[0]):
            band = self.bands[j, : n - j]
            y = y + jnp.pad(band * x[j:], (0, j)) + jnp.pad(band * x[: n - j], (j, 0))
        return y

    def as_matrix(self) -> Matrix:
        n = self.size
        matrix = jnp.diag(self.bands[0])
        for j in range(1, self.bands.shape[0]):
            band = self.bands[j, : n - j]
            matrix = matrix + jnp.diag(band, j) + jnp.diag(band, -j)
        return matrix

    def abs_row_sums(self) -> Vector:
        return SymmetricBanded(jnp.abs(self.bands)).mv(jnp.ones(self.size))

    def project(self, basis: Basis) -> "Dense":
        return project_by_products(self, basis)


class Sparse(AbstractOperator):
    """A sparse matrix in coordinate form: entries ``values[k]`` at (``rows[k]``, ``cols[k]``).

    Every stored entry of a symmetric matrix appears (both triangles); 0-based indices. Applying
    it costs O(nnz) (a gather and a segment sum).
    """

    rows: Array
    cols: Array
    values: Vector
    size: int = eqx.field(static=True)

    def mv(self, x: Vector) -> Vector:
        return jax.ops.segment_sum(self.values * x[self.cols], self.rows, num_segments=self.size)

    def as_matrix(self) -> Matrix:
        return jnp.zeros((self.size, self.size)).at[self.rows, self.cols].add(self.values)

    def abs_row_sums(self) -> Vector:
        return jax.ops.segment_sum(jnp.abs(self.values), self.rows, num_segments=self.size)

    def project(self, basis: Basis) -> "Dense":
        return project_by_products(self, basis)


class Sum(AbstractOperator):
    """A sum of operators (a user's damping matrix plus Rayleigh or modal damping, say)."""

    parts: tuple[AbstractOperator, ...]

    @property
    def size(self) -> int:
        return self.parts[0].size

    def mv(self, x: Vector) -> Vector:
        return sum(part.mv(x) for part in self.parts)

    def as_matrix(self) -> Matrix:
        return sum(part.as_matrix() for part in self.parts)

    def project(self, basis: Basis) -> "Dense":
        return Dense(sum(part.project(basis).as_matrix() for part in self.parts))

    def abs_row_sums(self) -> Vector:
        return dense_abs_row_sums(self)


def add(*parts):
    """The sum of the operators that are not None (None when none is)."""
    parts = tuple(p for p in parts if p is not None)
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else Sum(parts)


@diagonal.register(Diagonal)
@diagonal.register(SymmetricTridiagonal)
def _(operator) -> Vector:
    return operator.diagonal


@diagonal.register(SymmetricBanded)
def _(operator) -> Vector:
    return operator.bands[0]


@diagonal.register(Sparse)
def _(operator) -> Vector:
    on = operator.rows == operator.cols
    return jax.ops.segment_sum(jnp.where(on, operator.values, 0.0), operator.rows,
                               num_segments=operator.size)


Operator = Diagonal | SymmetricTridiagonal | SymmetricBanded | Sparse | Dense | LowRank | Sum
