"""Second-order systems M x'' + D x' + K x = f, and fixed-free chains (eqs. 2.1-2.3, 3.1).

Chain conventions: DOF i = 1..n (1-based) carries mass m_i and is tied to DOF i-1 by spring k_i;
DOF 0 is the fixed support, DOF n is free. So K = tridiag(-k_i, k_i + k_{i+1}, -k_{i+1}) with
k_{n+1} = 0 (eq. 2.2). Mikota's chain has m_i = m / i and k_i = (n - i + 1) k (eq. 2.3),
eigenfrequencies l * sqrt(k / m) (eq. 2.4).

Units: any consistent set (the paper's are dimensionless): masses, stiffnesses in force per length,
damping coefficients in force * time per length, times, frequencies in rad per unit time.
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
    """A linear second-order system M x'' + D x' + K x = f (eq. 3.1), with structured operators.

    ``mass`` M and ``stiffness`` K (force per length) are n x n operators: diagonal and symmetric
    tridiagonal for a chain (eq. 2.2), dense for a reduced model; ``damping`` D (force * time per
    length) is the dampers' operator (low rank once projected), ``None`` when undamped. Build with
    ``mikota_chain`` or ``chain``; ``simulate`` and ``exact_solve`` solve it.
    """

    mass: Diagonal | Dense
    stiffness: SymmetricTridiagonal | Dense
    damping: Dampers | Dense | None = None

    @property
    def size(self) -> int:
        """n, the number of DOFs."""
        return self.mass.size

    def dense(self):
        """(M, D, K) as dense (n, n) arrays (D is None when undamped): for small systems, checks."""
        damping = None if self.damping is None else self.damping.as_matrix()
        return self.mass.as_matrix(), damping, self.stiffness.as_matrix()

    def project(self, basis) -> "SecondOrderSystem":
        """The r-DOF system (basis^T M basis, basis^T D basis, basis^T K basis) of eq. (3.4).

        ``basis`` is (n, r); the result has dense r x r mass and stiffness and low-rank dampers.
        ``galerkin`` checks the basis and keeps it for the lift (eq. 3.2); prefer it.
        """
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
    """A fixed-free chain (eq. 2.2) from masses m_1..m_n and springs k_1..k_n, each (n,).

    Spring k_i ties DOF i to DOF i - 1 (1-based; k_1 ties DOF 1 to the fixed support), DOF n is
    free; all values finite and > 0 (masses, stiffnesses in force per length; consistent units).
    ``dampers``: ``GroundedDamper``/``RelativeDamper`` instances, or none (then ``damping=None``).
    """
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
    """Mikota's chain (eqs. 2.2-2.3): m_i = m / i, k_i = (n - i + 1) k for DOFs i = 1..n.

    ``m`` is the first mass and ``k`` the last spring's stiffness (force per length), in consistent
    units (the paper: m = k = 1, dimensionless); the undamped chain's eigenfrequencies are
    l sqrt(k/m), l = 1..n (eq. 2.4). ``dampers`` as in ``chain``.
    """
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
