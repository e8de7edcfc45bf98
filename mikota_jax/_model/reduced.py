"""Galerkin reduction (eqs. 3.2-3.4): a reduced model is a smaller second-order system plus a basis.

With an orthonormal basis Phi (n x r) of proper orthogonal modes, x ~ Phi q (eq. 3.2) and
Phi^T M Phi q'' + Phi^T D Phi q' + Phi^T K Phi q = Phi^T f (eq. 3.4). The reduced initial state is
q(0) = Phi^T x(0), q'(0) = Phi^T x'(0): the orthogonal projection, exact when x(0) lies in span Phi.
Both that projection and the lift x = Phi q need orthonormal columns, so ``galerkin`` refuses a
basis with max |Phi^T Phi - I| > ORTHONORMALITY: dependent or duplicated columns (a singular reduced
mass), unnormalised ones, or POMs that lost orthogonality (Sirovich's method far below sigma_1).
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Basis, Float, Vector
from .._errors import MARK, array_module, check
from .system import SecondOrderSystem

# The error of the reduced initial state and of the lift is of this order. The bases this package
# builds are orthonormal to ~1e-15 (SVD, QR), or to ~1e-8 after basis enrichment.
ORTHONORMALITY = 1e-6



class ReductionStats(eqx.Module):
    """What a reduction did: ``ReducedModel.stats``, one record for every strategy.

    ``strategy``: the strategy's class name ("POD", "Modal", ...); ``rank``: r, the basis'
    column count. The rest is None where a strategy has no such fact:

    - ``decomposition``: the POD of the snapshot matrix (``POD``, ``EnrichedPOD``): its
      ``singular_values`` (k,), ``modes`` (n, k), ``energy_fraction``, ``rank_for_energy``,
      ``numerical_rank`` and ``basis(r)``; an array leaf, so ``jit`` sees it as data.
    - ``snapshots``: the snapshot count m (the columns of Q; ``EnrichedPOD``: of the enriched Q).
    - ``modes``: the undamped (``ModalStatic``) or held (``CraigBampton``) modes kept; the
      rest of the rank are static directions.
    - ``shifts``, ``iterations``, ``converged``, ``changes``: the interpolation shifts
      (``RationalKrylov``, ``IRKA``), and IRKA's iterations run, whether it settled and its
      relative change per iteration.
    - ``optimality``: ``H2Optimal``'s largest relative mismatch of the first-order H2
      conditions (interpolation at the mirrored poles of the reduced model).
    - ``dropped``: ``SOBT``'s H2 norm of the modes damped below rounding that it left out,
      relative to the full norm (a floor under its error).
    - ``certified``, ``bounds``, ``history``, ``full_solves``: ``Greedy``'s certificate,
      final relative bounds at the training designs, (rank, largest bound, design) per
      iteration, and the full solves taken.
    - ``parts``: ``Union``'s records of its strategies, in order.

    Everything but ``decomposition`` and ``parts`` is static (hashable): a ``ReducedModel``
    stays a pytree that ``jax.jit`` and ``jax.vmap`` take.
    """

    strategy: str = eqx.field(static=True)
    rank: int = eqx.field(static=True)
    decomposition: eqx.Module | None = None  # the POD (mikota_jax._rom.pod), an array leaf
    snapshots: int | None = eqx.field(static=True, default=None)
    modes: int | None = eqx.field(static=True, default=None)
    shifts: tuple[complex, ...] | None = eqx.field(static=True, default=None)
    iterations: int | None = eqx.field(static=True, default=None)
    converged: bool | None = eqx.field(static=True, default=None)
    changes: tuple[float, ...] | None = eqx.field(static=True, default=None)
    certified: bool | None = eqx.field(static=True, default=None)
    bounds: tuple[float, ...] | None = eqx.field(static=True, default=None)
    history: tuple[tuple[int, float, int], ...] | None = eqx.field(static=True, default=None)
    full_solves: int | None = eqx.field(static=True, default=None)
    optimality: float | None = eqx.field(static=True, default=None)
    dropped: float | None = eqx.field(static=True, default=None)
    parts: tuple["ReductionStats", ...] | None = None

    @property
    def singular_values(self) -> Float[Array, " k"] | None:
        """The snapshot matrix' singular values (descending), or None (no POD)."""
        return None if self.decomposition is None else self.decomposition.singular_values


class ReducedModel(eqx.Module):
    """A Galerkin reduced model (eqs. 3.2-3.4): an r-DOF system plus the basis that lifts it.

    ``system``: the projected ``SecondOrderSystem`` M_red, D_red, K_red of eq. (3.4) (dense r x r
    mass and stiffness, low-rank dampers); ``basis``: Phi, (n, r) with orthonormal columns
    (eq. 3.8). ``solve`` takes it like a full system: initial states and
    loads in full coordinates, outputs lifted back to the 1-based full DOFs; ``stats``: what the
    reduction did (``ReductionStats``: the strategy, the rank, and its facts, e.g. a POD's
    singular values; None for a model built by hand). Build with ``reduce``.
    """

    system: SecondOrderSystem
    basis: Basis
    stats: ReductionStats | None = None

    @property
    def size(self) -> int:
        """n, the number of full DOFs."""
        return self.basis.shape[0]

    @property
    def rank(self) -> int:
        """r, the number of reduced coordinates."""
        return self.basis.shape[1]

    def reduce_state(self, x: Vector) -> Vector:
        """q = Phi^T x: (n,) full coordinates to (r,) reduced ones (exact if x is in span Phi)."""
        return self.basis.T @ x

    def lift(self, q):
        """x = Phi q (eq. 3.2): (r,) or (..., r) reduced coordinates to (n,) or (..., n)."""
        return q @ self.basis.T


def galerkin(system: SecondOrderSystem, basis: Basis, stats=None) -> ReducedModel:
    """The reduced model of ``system`` on ``basis``: M, D, K projected as in eq. (3.4).

    ``basis``: Phi, (n, r) float64 with orthonormal columns (e.g. a POD basis, eq. 3.8);
    x ~ Phi q (eq. 3.2). A basis that is not orthonormal to ``ORTHONORMALITY`` (1e-6, in
    max |basis^T basis - I|) is a ``ValueError`` (under ``jit`` an ``eqx.error_if``); the check
    costs O(n r^2).
    """
    if not isinstance(system, SecondOrderSystem):
        raise ValueError(MARK + f"system must be a SecondOrderSystem, got {type(system).__name__}.")
    basis = check_basis(basis, system.size)
    return ReducedModel(_project(system, basis), basis, stats)


@eqx.filter_jit
def _project(system, basis):
    """eq. (3.4) as one compiled function (eagerly, its dozen small products would each compile)."""
    return system.project(basis)


def check_basis(basis, n: int):
    """``basis`` as a checked (n, r) float64 array with orthonormal columns (``galerkin``'s rule,
    ``ORTHONORMALITY``); a ``ValueError`` eagerly, an ``eqx.error_if`` under ``jit``."""
    basis = jnp.asarray(basis)
    if basis.dtype != jnp.float64:
        raise ValueError(MARK + f"basis must be float64, got {basis.dtype}.")
    if basis.ndim != 2 or basis.shape[0] != n or not 1 <= basis.shape[1] <= n:
        raise ValueError(MARK + f"basis must have shape (n, r) with n = {n} and "
                         f"1 <= r <= n, got {basis.shape}.")
    xp = array_module(basis)  # numpy on a concrete basis: the checks compile nothing
    values = np.asarray(basis) if xp is np else basis
    basis = check(basis, ~xp.all(xp.isfinite(values)), "basis must be finite.")
    gram_error = xp.max(xp.abs(values.T @ values - xp.eye(basis.shape[1])))
    basis = check(basis, ~(gram_error <= ORTHONORMALITY),
                  f"basis must have orthonormal columns (max |basis^T basis - I| <= "
                  f"{ORTHONORMALITY:g}); orthonormalise it (QR, or the POD modes), or drop "
                  "dependent columns (a smaller rank).")
    return basis
