"""The spectral path's entry from a ``SecondOrderSystem``: whether it applies, the modal data
(undamped modes, modal damper factor, internal damping rates) and the damped modes, frozen or
carrying the implicit derivative (``_spectral`` holds the iteration itself)."""

import equinox as eqx
import jax
import jax.numpy as jnp

from ._chain_modes import unchecked_chain_modes
from ._dampers import Dampers
from ._errors import MARK, RESULTS, check, check_x64
from ._modal import generalized_modes
from ._operators import Diagonal, SymmetricTridiagonal
from ._spectral import DEFECTIVE_SEPARATION, DampedModes, differentiable_roots, modal_damped_modes


def spectral_applies(system) -> str | None:
    """None if the spectral path takes ``system``, else why not (one line)."""
    if system.damping is None:
        return ("the spectral path needs discrete dampers (GroundedDamper, RelativeDamper); the "
                "system has none")
    if not isinstance(system.damping, Dampers):
        return ("the spectral path needs discrete dampers (GroundedDamper, RelativeDamper), got "
                f"{type(system.damping).__name__}")
    if system.internal is not None and system.internal.matrix is not None:
        return ("the spectral path takes internal damping that is diagonal in modal coordinates "
                "(Rayleigh, modal), not a user's damping matrix")
    return None


def modal_data(system):
    """(omega, U, F, d, gamma or None) of a ``SecondOrderSystem`` the spectral path takes."""
    why = spectral_applies(system)
    if why is not None:
        raise ValueError(MARK + f"system: {why}.")
    stiffness = system.stiffness
    springs = (stiffness.springs if isinstance(stiffness, SymmetricTridiagonal)
               and not stiffness.links else None)
    if isinstance(system.mass, Diagonal) and springs is not None:
        # a fixed-free chain: O(n^2) modes, no dense decomposition (``_chain_modes``); masses
        # and springs were checked when the system was built, and omega^2 > 0 for any such
        # chain, so no check here (none in the optimiser's compiled certification)
        omega2, modes = unchecked_chain_modes(system.mass.diagonal, springs)
    else:
        omega2, modes = generalized_modes(system)
        omega2 = check(omega2, omega2 <= 0, RESULTS[RESULTS.not_definite])
    low_rank = system.damping.project(modes)
    gamma = None
    if system.internal is not None:
        gamma = system.internal.in_modes(omega2, modes).diagonal
    return jnp.sqrt(omega2), modes, low_rank.factor, low_rank.weights, gamma


def damped_modes(system) -> DampedModes:
    """The damped modes of a ``SecondOrderSystem`` with dampers (and internal damping diagonal
    in modal coordinates: Rayleigh, modal).

    All 2n eigenvalues lambda of lambda^2 M + lambda D + K in the layout of ``DampedModes``
    (modal eigenvectors by ``.vectors()``, x = U y). Roots of a mode no damper touches are that
    mode's own two poles. Check ``converged`` and ``separation``: the iteration reports, and
    never hides, roots it did not find or pairs that nearly coincide (critical damping).
    """
    check_x64()
    omega, _, factor, weights, gamma = modal_data(system)
    return modal_damped_modes(omega, factor, weights, gamma)


def live_modes(system):
    """(differentiable ``DampedModes``, U, ok): the roots found without derivatives, then
    carrying the implicit derivative of the secular equation; ok: converged and no two
    interacting roots nearly coincide."""
    omega, modes_u, factor, weights, gamma = modal_data(system)
    frozen = modal_damped_modes(*jax.lax.stop_gradient((omega, factor, weights, gamma)))
    live = frozen if gamma is None else eqx.tree_at(lambda m: m.gamma, frozen, gamma)
    modes = differentiable_roots(eqx.tree_at(lambda m: (m.omega, m.factor, m.weights), live,
                                              (omega, factor, weights)))
    ok = frozen.converged & (frozen.separation > DEFECTIVE_SEPARATION)
    return modes, modes_u, ok
