"""Internal (structural) damping: Rayleigh's alpha M + beta K, modal damping, a user's matrix D.

Each is differentiable in its parameters. In M-orthonormal modal coordinates (U^T M U = I,
U^T K U = diag(omega^2)) Rayleigh and modal damping are both diagonal:

- Rayleigh: U^T (alpha M + beta K) U = diag(alpha + beta omega_l^2), the ratio of critical
  damping of mode l is zeta_l = alpha / (2 omega_l) + beta omega_l / 2;
- modal: D = 2 zeta M^(1/2) (M^-1/2 K M^-1/2)^(1/2) M^(1/2) = M U diag(2 zeta_l omega_l) U^T M
  (the second form also for a zeta per mode), so U^T D U = diag(2 zeta_l omega_l): mode l has
  exactly the ratio zeta_l.

``InternalDamping`` holds what a system has (a user matrix, a Rayleigh pair, modal ratios); it is
resolved against the system's own M and K whenever they are known, so changing M or K (a
sensitivity, a projection) keeps the specification, not a stale matrix.
"""

import equinox as eqx
import jax.numpy as jnp

from .._custom_types import Array, Float, ScalarLike
from .._errors import MARK, as_float, check
from .operators import (
    AbstractOperator,
    Dense,
    Diagonal,
    LowRank,
    add,
    dense_abs_row_sums,
    diagonal,
)


class Rayleigh(eqx.Module):
    """Rayleigh damping D = alpha M + beta K: ``alpha`` (1 / time) and ``beta`` (time), >= 0.

    Mode l's ratio of critical damping is alpha / (2 omega_l) + beta omega_l / 2. Both are traced,
    so ``jax.grad`` passes through them; they are checked finite and >= 0.
    """

    alpha: Float[Array, ""]
    beta: Float[Array, ""]

    def __init__(self, alpha: ScalarLike = 0.0, beta: ScalarLike = 0.0):
        alpha, beta = as_float(alpha, "alpha"), as_float(beta, "beta")
        if alpha.shape != () or beta.shape != ():
            raise ValueError(MARK + "Rayleigh alpha and beta must be scalars.")
        self.alpha = check(alpha, ~(jnp.isfinite(alpha) & (alpha >= 0)),
                           "Rayleigh alpha must be finite and >= 0.")
        self.beta = check(beta, ~(jnp.isfinite(beta) & (beta >= 0)),
                          "Rayleigh beta must be finite and >= 0.")


class ModalDamping(eqx.Module):
    """Modal damping: ratio ``zeta`` of critical damping in every mode (a scalar), or per mode
    (an (n,) vector, modes in ascending frequency order); finite and >= 0 (1: critical).

    D = 2 M^(1/2) (M^-1/2 K M^-1/2)^(1/2) M^(1/2) for a scalar zeta, built from the generalized
    eigendecomposition (an O(n^3) step; systems with modal damping are solved in modal
    coordinates, where it is diagonal). Traced: ``jax.grad`` passes through zeta.
    """

    zeta: Float[Array, "..."]

    def __init__(self, zeta: ScalarLike | Float[Array, " n"]):
        zeta = as_float(zeta, "zeta")
        if zeta.ndim > 1:
            raise ValueError(MARK + f"zeta must be a scalar or an (n,) vector, got {zeta.shape}.")
        self.zeta = check(zeta, ~jnp.all(jnp.isfinite(zeta) & (zeta >= 0)),
                          "zeta must be finite and >= 0.")


class InternalDamping(eqx.Module):
    """The damping of a system that is not a discrete damper: a user's matrix (``matrix``, any
    operator), ``rayleigh`` and/or ``modal``; any of them may be None."""

    matrix: AbstractOperator | None = None
    rayleigh: Rayleigh | None = None
    modal: ModalDamping | None = None

    def operator(self, mass, stiffness, modes_of):
        """D as an operator in physical coordinates; ``modes_of()`` -> (omega^2, U) if needed."""
        parts = [self.matrix]
        if self.rayleigh is not None:
            parts += [Scaled(self.rayleigh.alpha, mass), Scaled(self.rayleigh.beta, stiffness)]
        if self.modal is not None:
            omega2, modes = modes_of()
            factor = mass.as_matrix() @ modes if not isinstance(mass, Diagonal) else (
                mass.diagonal[:, None] * modes)
            parts.append(LowRank(factor, self.modal_rates(omega2)))
        return add(*parts)

    def modal_rates(self, omega2):
        """2 zeta_l omega_l, (n,) (modal damping's diagonal in modal coordinates)."""
        omega = jnp.sqrt(jnp.maximum(omega2, 0.0))
        return 2 * jnp.broadcast_to(self.modal.zeta, omega.shape) * omega

    def in_modes(self, omega2, modes):
        """U^T D U for M-orthonormal modes U: diagonal unless a user's matrix is present."""
        diagonal = jnp.zeros_like(omega2)
        if self.rayleigh is not None:
            diagonal = diagonal + self.rayleigh.alpha + self.rayleigh.beta * omega2
        if self.modal is not None:
            diagonal = diagonal + self.modal_rates(omega2)
        if self.matrix is None:
            return Diagonal(diagonal)
        return Dense(jnp.diag(diagonal) + self.matrix.project(modes).as_matrix())

    def project(self, basis, mass, stiffness, modes_of) -> "InternalDamping":
        """The Galerkin projection (eq. 3.4): Rayleigh stays Rayleigh of the projected M and K
        (exactly); a user's and modal damping become one dense r x r matrix."""
        other = InternalDamping(self.matrix, None, self.modal)
        resolved = other.operator(mass, stiffness, modes_of)
        matrix = None if resolved is None else Dense(resolved.project(basis).as_matrix())
        return InternalDamping(matrix, self.rayleigh, None)


class Scaled(AbstractOperator):
    """c A for a scalar c and an operator A (Rayleigh's alpha M and beta K)."""

    scale: Float[Array, ""]
    operator: AbstractOperator

    @property
    def size(self) -> int:
        return self.operator.size

    def mv(self, x):
        return self.scale * self.operator.mv(x)

    def as_matrix(self):
        return self.scale * self.operator.as_matrix()

    def project(self, basis) -> Dense:
        return Dense(self.scale * self.operator.project(basis).as_matrix())

    def abs_row_sums(self):
        return dense_abs_row_sums(self)


@diagonal.register(Scaled)
def _(operator: Scaled):
    return operator.scale * diagonal(operator.operator)


def as_internal(internal_damping, n: int, matrix=None) -> InternalDamping | None:
    """An ``InternalDamping`` from ``Rayleigh``/``ModalDamping`` (or a tuple of both) and a user's
    damping operator (or None); a vector zeta must have n entries."""
    specs = internal_damping
    if specs is None:
        specs = ()
    elif isinstance(specs, Rayleigh | ModalDamping):
        specs = (specs,)
    elif not isinstance(specs, tuple | list):
        raise ValueError(MARK + "internal_damping must be Rayleigh(alpha, beta), "
                         f"ModalDamping(zeta), a tuple of both, or None; got {specs!r}.")
    rayleigh = [s for s in specs if isinstance(s, Rayleigh)]
    modal = [s for s in specs if isinstance(s, ModalDamping)]
    if len(rayleigh) + len(modal) != len(specs) or len(rayleigh) > 1 or len(modal) > 1:
        raise ValueError(MARK + "internal_damping takes at most one Rayleigh and one "
                         f"ModalDamping, got {specs!r}.")
    if modal and modal[0].zeta.ndim == 1 and modal[0].zeta.shape[0] != n:
        raise ValueError(MARK + f"zeta must be a scalar or have n = {n} entries (one per mode), "
                         f"got {modal[0].zeta.shape[0]}.")
    if matrix is None and not specs:
        return None
    return InternalDamping(matrix, rayleigh[0] if rayleigh else None, modal[0] if modal else None)
