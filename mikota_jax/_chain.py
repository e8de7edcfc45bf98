"""Second-order systems M x'' + D x' + K x = f, and fixed-free chains (eqs. 2.1-2.3, 3.1).

Chain conventions: DOF i = 1..n (1-based) carries mass m_i and is tied to DOF i-1 by spring k_i;
DOF 0 is the fixed support, DOF n is free. So K = tridiag(-k_i, k_i + k_{i+1}, -k_{i+1}) with
k_{n+1} = 0 (eq. 2.2). Mikota's chain has m_i = m / i and k_i = (n - i + 1) k (eq. 2.3),
eigenfrequencies l * sqrt(k / m) (eq. 2.4).
"""

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from ._custom_types import ScalarLike, Vector
from ._dampers import Dampers, GroundedDamper, RelativeDamper
from ._errors import MARK, as_float, check, positive_scalar
from ._operators import Dense, Diagonal, Operator, SymmetricTridiagonal


class SecondOrderSystem(eqx.Module):
    """M x'' + D x' + K x = f with structured operators; ``damping is None`` when undamped."""

    mass: Diagonal | Dense
    stiffness: SymmetricTridiagonal | Dense
    damping: Dampers | Dense | None = None

    @property
    def size(self) -> int:
        return self.mass.size

    def dense(self):
        """(M, D, K) as dense matrices (D is None when undamped): for small systems and checks."""
        damping = None if self.damping is None else self.damping.as_matrix()
        return self.mass.as_matrix(), damping, self.stiffness.as_matrix()

    def project(self, basis) -> "SecondOrderSystem":
        """Galerkin projection basis^T (M, D, K) basis (eq. 3.4)."""
        damping = None if self.damping is None else self.damping.project(basis)
        return SecondOrderSystem(self.mass.project(basis), self.stiffness.project(basis), damping)


def _damping(n: int, dampers) -> Dampers | None:
    dampers = tuple(dampers)
    for d in dampers:
        if not isinstance(d, GroundedDamper | RelativeDamper):
            raise ValueError(MARK + f"dampers must be GroundedDamper or RelativeDamper, got {d!r}.")
    return Dampers(n, dampers) if dampers else None


def chain(masses: Sequence[float] | Vector, springs: Sequence[float] | Vector,
          dampers: Sequence[GroundedDamper | RelativeDamper] = ()) -> SecondOrderSystem:
    """A fixed-free chain from positive masses m_1..m_n and springs k_1..k_n (k_1 to the ground)."""
    masses = as_float(masses, "masses")
    springs = as_float(springs, "springs")
    if masses.ndim != 1 or masses.shape[0] < 1:
        raise ValueError(MARK + f"masses must be a 1-d array of length n >= 1, got {masses.shape}.")
    if springs.shape != masses.shape:
        raise ValueError(MARK + f"springs must have the shape of masses {masses.shape}, "
                         f"got {springs.shape}.")
    masses = check(masses, ~(jnp.isfinite(masses) & (masses > 0)), "masses must be finite and > 0.")
    springs = check(springs, ~(jnp.isfinite(springs) & (springs > 0)),
                    "springs must be finite and > 0.")
    n = masses.shape[0]
    next_springs = jnp.concatenate([springs[1:], jnp.zeros(1)])  # k_{i+1}, with k_{n+1} = 0
    stiffness = SymmetricTridiagonal(springs + next_springs, -springs[1:], springs)
    return SecondOrderSystem(Diagonal(masses), stiffness, _damping(n, dampers))


def mikota_chain(n: int, m: ScalarLike = 1.0, k: ScalarLike = 1.0,
                 dampers: Sequence[GroundedDamper | RelativeDamper] = ()) -> SecondOrderSystem:
    """Mikota's chain: m_i = m / i, k_i = (n - i + 1) k for i = 1..n (eq. 2.3)."""
    if isinstance(n, bool) or not isinstance(n, int | jnp.integer) or n < 1:
        raise ValueError(MARK + f"n must be an integer >= 1, got {n!r}.")
    n = int(n)
    m, k = positive_scalar(m, "m"), positive_scalar(k, "k")
    i = jnp.arange(1, n + 1, dtype=jnp.float64)
    return chain(m / i, (n - i + 1) * k, dampers)


def generalized_modes(system: SecondOrderSystem):
    """(omega^2, U): K U = M U diag(omega^2), U^T M U = I, ascending; omega^2 is not checked."""
    springs = getattr(system.stiffness, "springs", None)
    if isinstance(system.mass, Diagonal) and springs is not None:
        # K = L^T diag(k) L: the singular values of C = diag(sqrt k) L M^-1/2 are the omega_l, to
        # full relative accuracy (eigh of M^-1/2 K M^-1/2 only to eps ||K||: the lowest omega of
        # a chain with masses over 12 decades came out 1e-3 off); C^T C = M^-1/2 K M^-1/2.
        scale = 1 / jnp.sqrt(system.mass.diagonal)
        n = scale.shape[0]
        factor = jnp.sqrt(springs)[:, None] * (jnp.eye(n) - jnp.eye(n, k=-1)) * scale[None, :]
        _, sigma, vectors_t = jnp.linalg.svd(factor)
        return sigma[::-1] ** 2, scale[:, None] * vectors_t[::-1].T
    if isinstance(system.mass, Diagonal):
        scale = 1 / jnp.sqrt(system.mass.diagonal)
        symmetric = scale[:, None] * system.stiffness.as_matrix() * scale[None, :]
        omega2, vectors = jnp.linalg.eigh(symmetric)
        modes = scale[:, None] * vectors
    else:
        lower = jnp.linalg.cholesky(system.mass.as_matrix())
        inv_k = jsl.solve_triangular(lower, system.stiffness.as_matrix(), lower=True)
        symmetric = jsl.solve_triangular(lower, inv_k.T, lower=True)
        omega2, vectors = jnp.linalg.eigh((symmetric + symmetric.T) / 2)
        modes = jsl.solve_triangular(lower.T, vectors, lower=False)
    return omega2, modes


def as_operator(x) -> Operator:
    return x if isinstance(x, Diagonal | SymmetricTridiagonal | Dense) else Dense(x)
