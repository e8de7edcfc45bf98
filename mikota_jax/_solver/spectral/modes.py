"""The spectral path's entry from a ``SecondOrderSystem``: whether it applies, the modal data
(undamped modes, modal damper factor, internal damping rates) and the damped modes, frozen or
carrying the implicit derivative (``_spectral`` holds the iteration itself)."""

import equinox as eqx
import jax
import jax.numpy as jnp

from ..._errors import MARK, RESULTS, check, check_x64
from ..._limits import ROWS_ABOVE
from ..._model.chain_modes import unchecked_chain_mode_data, unchecked_chain_modes
from ..._model.dampers import Dampers
from ..._model.modal import generalized_modes
from ..._model.operators import Diagonal, SymmetricTridiagonal
from .roots import DampedModes, differentiable_roots, modal_damped_modes


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


def _chain_springs(system):
    """The springs of a fixed-free chain with a diagonal mass (O(n^2) modes), else None."""
    stiffness = system.stiffness
    if (isinstance(system.mass, Diagonal) and isinstance(stiffness, SymmetricTridiagonal)
            and not stiffness.links):
        return stiffness.springs
    return None




def uses_rows(system) -> bool:
    """Whether the energy takes the O(n)-memory path (``modal_rows``, the roots a block at a
    time): a fixed-free chain with dampers alone, larger than ``ROWS_ABOVE``."""
    return (system.size > ROWS_ABOVE and system.internal is None
            and _chain_springs(system) is not None)


def modal_rows(system, vectors, dofs=None):
    """(omega, F, d, U^T M vectors, U[dofs]) of a chain (``uses_rows``) without U: its modes a
    chunk at a time (``chain_mode_data``), keeping the rows the dampers touch
    (``Dampers.touched``), the rows ``dofs`` (0-based, (d,); None: none, and None returned) and
    the projections of ``vectors`` (n, p). O(n^2) time, O(n (p + d + dampers)) memory (U at
    n = 30000 is 7.2 GB)."""
    masses = system.mass.diagonal
    touched = system.damping.touched()
    wanted = touched if dofs is None else jnp.concatenate([touched, dofs])
    omega2, rows, projected = unchecked_chain_mode_data(
        masses, _chain_springs(system), wanted, masses[:, None] * vectors)
    low_rank = system.damping.project_rows(rows[:touched.shape[0]])
    picked = None if dofs is None else rows[touched.shape[0]:]
    return jnp.sqrt(omega2), low_rank.factor, low_rank.weights, projected, picked


def modal_data(system):
    """(omega, U, F, d, gamma or None) of a ``SecondOrderSystem`` the spectral path takes."""
    why = spectral_applies(system)
    if why is not None:
        raise ValueError(MARK + f"system: {why}.")
    springs = _chain_springs(system)
    if springs is not None:
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


def damped_modes(system, start=None) -> DampedModes:
    """The damped modes of a ``SecondOrderSystem`` with dampers (and internal damping diagonal
    in modal coordinates: Rayleigh, modal).

    All 2n eigenvalues lambda of lambda^2 M + lambda D + K in the layout of ``DampedModes``
    (modal eigenvectors by ``.vectors()``, x = U y). Roots of a mode no damper touches are that
    mode's own two poles. Check ``converged`` and ``separation``: the iteration reports, and
    never hides, roots it did not find or pairs that nearly coincide (critical damping).
    ``start``: where the sweeps start (``RootStart``, e.g. a nearby design's ``.start``), None
    for the arc starts.
    """
    check_x64()
    omega, _, factor, weights, gamma = modal_data(system)
    return modal_damped_modes(omega, factor, weights, gamma, start=start)


def live_modes(system, block: int | None = None, start=None):
    """(differentiable ``DampedModes``, U, ok): the roots found without derivatives, then
    carrying the implicit derivative of the secular equation; ok: converged and no two
    interacting roots nearly coincide outside a cluster (``_spectral_clusters``). ``block``,
    ``start``: as ``modal_damped_modes``."""
    omega, modes_u, factor, weights, gamma = modal_data(system)
    modes, ok = live_modal_modes(omega, factor, weights, gamma, block, start)
    return modes, modes_u, ok


def live_rows(system, vectors, block: int | None = None, dofs=None, start=None):
    """(differentiable ``DampedModes``, U^T M vectors, ok, U[dofs]) of a chain that
    ``uses_rows``: ``live_modes`` in O(n) memory (``block``, ``start``: as
    ``modal_damped_modes``; ``dofs``: as ``modal_rows``)."""
    why = spectral_applies(system)
    if why is not None:
        raise ValueError(MARK + f"system: {why}.")
    omega, factor, weights, projected, picked = modal_rows(system, vectors, dofs)
    modes, ok = live_modal_modes(omega, factor, weights, None, block, start)
    return modes, projected, ok, picked


def live_modal_modes(omega, factor, weights, gamma, block=None, start=None):
    """(differentiable ``DampedModes``, ok) of modal data: frequencies ``omega`` (n,), the
    dampers' modal factor F (n, k) and weights d (k,), internal rates ``gamma`` (n,) or None;
    ``ok`` as ``live_modes``'s. Any modal system takes it: a chain's, or a Galerkin model's in
    its own modal coordinates. ``start``: as ``modal_damped_modes``."""
    frozen = modal_damped_modes(*jax.lax.stop_gradient((omega, factor, weights, gamma)),
                                block=block, start=start)
    live = frozen if gamma is None else eqx.tree_at(lambda m: m.gamma, frozen, gamma)
    modes = differentiable_roots(eqx.tree_at(lambda m: (m.omega, m.factor, m.weights), live,
                                              (omega, factor, weights)), block)
    ok = frozen.converged & frozen.clusters.ok
    return modes, ok
