"""The classic projection bases beside POD: modal truncation, and modal truncation with a static
(residual-flexibility) correction for the damper and load directions.

Both return an (n, r) basis with orthonormal columns, for ``galerkin`` and everything that takes
a ``ReducedModel`` (solvers, objectives, ``jax.grad``), like ``POD.basis``:

* **Modal truncation**: the r lowest undamped modes (``modal_decomposition``; eq. 2.4 for
  Mikota's chain), orthonormalised. Exact for an undamped free vibration that starts in their
  span; a damper couples every mode, so it converges slowly where dampers are strong.
* **Modal + static correction**: the same modes and the static responses K^-1 b of every damper
  direction b (e_j for a grounded damper at DOF j, the two DOFs of a split one, e_i - e_j for a
  relative one) and of the ``loads`` given. span(U_r, K^-1 B) = span(U_r, (K^-1 - U_r
  Omega_r^-2 U_r^T) B), the residual flexibility of Craig & Bampton's method and of the
  mode-acceleration method (Craig & Kurdila, "Fundamentals of Structural Dynamics", 2006,
  ch. 14; Besselink et al., "A comparison of model reduction techniques from structural dynamics,
  numerical mathematics and systems and control", J. Sound Vib. 332 (2013) 4403-4422): the
  damper forces act on the truncated modes through their static part. A hand-built check on
  FastOptimalDamping.jl's n = 801 example took an average-energy trace from 1.3e-2 (100 modes)
  to 1.6e-5 relative with the three damper directions added.

The static solves are O(n) for a chain (tridiagonal K), dense otherwise.
"""

import jax.numpy as jnp
import numpy as np

from ._custom_types import Basis
from ._dampers import Dampers
from ._errors import MARK, as_float
from ._implicit import symmetric_tridiagonal_solve
from ._modal import modal_decomposition
from ._operators import SymmetricTridiagonal
from ._system import SecondOrderSystem

# a static direction whose part outside the kept modes is below this (relative) adds nothing
_DEPENDENT = 1e-10


def _check(system, rank: int) -> None:
    if not isinstance(system, SecondOrderSystem):
        raise ValueError(MARK + f"system must be a SecondOrderSystem, got "
                         f"{type(system).__name__}.")
    if isinstance(rank, bool) or not isinstance(rank, int) or not 1 <= rank <= system.size:
        raise ValueError(MARK + f"rank must be an integer in 1..{system.size}, got {rank!r}.")


def modal_basis(system: SecondOrderSystem, rank: int) -> Basis:
    """The r = ``rank`` lowest undamped modes of ``system`` as an (n, r) orthonormal basis."""
    _check(system, rank)
    _, modes = modal_decomposition(system)
    q, _ = jnp.linalg.qr(modes[:, :rank])
    return q


def damper_directions(system: SecondOrderSystem) -> jnp.ndarray:
    """(n, k) the directions B of the system's dampers (D = B diag(w) B^T): a grounded damper
    gives its one or two DOFs' unit vectors, a relative damper e_i - e_j; (n, 0) without."""
    if not isinstance(system.damping, Dampers):
        return jnp.zeros((system.size, 0))
    dampers, n = system.damping, system.size
    left, right, _, _ = dampers._grounded_weights()
    g, p = left.shape[0], dampers.pair_count
    columns = jnp.arange(2 * g + p)
    b = jnp.zeros((n, 2 * g + p)).at[jnp.concatenate([left, right]), columns[:2 * g]].set(1.0)
    if p:
        b = b.at[dampers.pairs[:, 0], columns[2 * g:]].set(1.0)
        b = b.at[dampers.pairs[:, 1], columns[2 * g:]].add(-1.0)
    return b


def modal_static_basis(system: SecondOrderSystem, rank: int, *, loads=None,
                       dampers: bool = True) -> Basis:
    """The ``rank`` lowest undamped modes and the static responses K^-1 b of the damper
    directions (``dampers=True``) and of ``loads`` ((n,) or (n, s) force directions), as an
    orthonormal (n, r + s') basis: s' the static directions not already in the modes' span (to
    1e-10 relative), so the size can be below rank + s and depends on the values (call it
    outside ``jit``, as POD's rank rule). See the module docstring."""
    _check(system, rank)
    columns = [damper_directions(system)] if dampers else []
    if loads is not None:
        loads = as_float(loads, "loads")
        loads = loads[:, None] if loads.ndim == 1 else loads
        if loads.ndim != 2 or loads.shape[0] != system.size:
            raise ValueError(MARK + f"loads must be (n,) or (n, s) with n = {system.size}, got "
                             f"{loads.shape}.")
        columns.append(loads)
    modes = modal_basis(system, rank)
    if not columns or rank == system.size:
        return modes
    forces = jnp.concatenate(columns, axis=1)
    stiffness = system.stiffness
    if isinstance(stiffness, SymmetricTridiagonal) and not stiffness.links:  # a chain: O(n)
        static = symmetric_tridiagonal_solve(stiffness.diagonal, stiffness.off_diagonal, forces)
    else:
        static = jnp.linalg.solve(stiffness.as_matrix(), forces)
    scale = float(jnp.max(jnp.linalg.norm(static, axis=0)))
    # the part outside the kept modes, twice (classical Gram-Schmidt loses orthogonality once)
    for _ in range(2):
        static = static - modes @ (modes.T @ static)
    q, r = jnp.linalg.qr(static)
    keep = np.flatnonzero(np.abs(np.diag(np.asarray(r))) > _DEPENDENT * scale)
    return jnp.concatenate([modes, q[:, keep]], axis=1)[:, : system.size]
