"""Undamped modes and the scaled modal coordinates every exact computation works in.

K U = M U diag(omega^2) with U^T M U = I (eq. 2.7); for a fixed-free chain from its bidiagonal
factor to full relative accuracy (O(n^2) ``_chain_modes`` from n = 256, the SVD below), else by
eigh. In the scaled modal
coordinates z = (Omega eta, eta'), x = U eta, the state matrix is A = [[0, Omega], [-Omega,
-U^T D U]] and the energy (x^T K x + x'^T M x') / 2 is |z|^2 / 2: used by ``exact_solve``, the
energies of ``_objectives`` and the optimiser's modal reduced model.
"""

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from .._errors import RESULTS, check
from .._limits import CHAIN_MODES_FROM
from .chain_modes import unchecked_chain_modes
from .operators import Diagonal, SymmetricTridiagonal


def generalized_modes(system):
    """(omega^2, U) of a ``SecondOrderSystem``: K U = M U diag(omega^2), U^T M U = I, ascending;
    omega^2 is not checked."""
    stiffness = system.stiffness
    springs = stiffness.springs if isinstance(stiffness, SymmetricTridiagonal) else None
    if isinstance(system.mass, Diagonal) and springs is not None and springs.shape[0] >= (
            CHAIN_MODES_FROM):
        # a long fixed-free chain, K = L^T diag(k) L (``springs`` is None once links are added):
        # O(n^2) modes to full relative accuracy from the qd form of C = diag(sqrt k) L M^-1/2
        # (``_chain_modes``; the SVD below is O(n^3): 34 s against 1.7 s at n = 3000)
        return unchecked_chain_modes(system.mass.diagonal, springs)
    if isinstance(system.mass, Diagonal) and springs is not None:
        # a short chain: the singular values of C = diag(sqrt k) L M^-1/2 are the omega_l, to
        # full relative accuracy (eigh of M^-1/2 K M^-1/2 only to eps ||K||: the lowest omega of
        # a chain with masses over 12 decades came out 1e-3 off); C^T C = M^-1/2 K M^-1/2. One
        # LAPACK call compiles in a fraction of ``_chain_modes``' loops, and is as fast here.
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


def modal_decomposition(system):
    """Eigenfrequencies and M-orthonormal mode shapes (omega, U) of a system's M and K.

    ``omega``: (n,), ascending, in rad per unit time (l sqrt(k/m) for Mikota's chain, eq. 2.4);
    ``U``: (n, n), column l - 1 is mode l (proportional to u_l of eq. 2.5 for Mikota's chain),
    with U^T M U = I and U^T K U = diag(omega^2) (eq. 2.7). Damping is ignored. For a
    ``SecondOrderSystem``; a stiffness that is not positive definite is a ``ValueError``.
    """
    omega2, modes = generalized_modes(system)
    omega2 = check(omega2, omega2 <= 0, RESULTS[RESULTS.not_definite])
    return jnp.sqrt(omega2), modes


def scaled_modal(system):
    """(omega, U, U^T D U or None, not_definite) of a system with M-orthonormal modes U.

    In the scaled modal coordinates z = (Omega eta, eta'), x = U eta, the state matrix is
    A = [[0, Omega], [-Omega, -U^T D U]] and the energy (x^T K x + x'^T M x') / 2 is |z|^2 / 2.
    """
    omega2, modes = generalized_modes(system)
    not_definite = jnp.any(omega2 <= 0)
    omega = jnp.sqrt(jnp.where(omega2 > 0, omega2, 1.0))  # no NaN below; flagged instead
    damping_modal, damping = None, system.damping_operator()
    if damping is not None:
        damping_modal = modes.T @ jax.vmap(damping.mv, in_axes=1, out_axes=1)(modes)
    return omega, modes, damping_modal, not_definite


def state_matrix(omega, damping_modal):
    """A = [[0, Omega], [-Omega, -D_modal]] of the scaled modal coordinates."""
    n = omega.shape[0]
    damping_modal = jnp.zeros((n, n)) if damping_modal is None else damping_modal
    return jnp.block([[jnp.zeros((n, n)), jnp.diag(omega)], [-jnp.diag(omega), -damping_modal]])


def modal_projection(system, modes):
    """y -> U^T M y: modal coordinates of a physical vector (U^T M U = I)."""
    if isinstance(system.mass, Diagonal):
        return lambda y: modes.T @ (system.mass.diagonal * y)
    mass = system.mass.as_matrix()
    return lambda y: modes.T @ (mass @ y)
