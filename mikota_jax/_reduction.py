"""The reduction stage: snapshots of a solve -> POD (eqs. 3.5-3.6) -> rank (eq. 3.7) -> basis.

One function, ``reduce``, used by ``run_scene``, ``SceneFunction`` and the damper optimiser, so a
window, a rank rule or a POD method means the same everywhere. The states stay on the device: the
window selects rows by index, and only the singular values travel to the host (the rank is a
shape, so it must be a Python integer).

Conventions: ``states`` is (N, n), rows at the N times ``ts`` and columns at all n DOFs (a
``Trajectory``'s ``displacement`` or ``velocity``); the snapshot matrix Q is its windowed rows
transposed, (n, m) (eq. 3.5).
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._custom_types import Array, Basis, Float, Times
from ._errors import MARK, array_module
from ._pod import POD, pod


class Reduction(eqx.Module):
    """How to reduce: the snapshot window (t0, t1), the snapshot quantity, and the rank rule.

    ``rank`` (when given) wins over ``energy`` (the pseudo-energy fraction of eq. 3.7 under
    ``criterion``: "squared" or "paper"); ``method`` is the POD's (``pod``). ``quantity``:
    "displacement" (the paper's choice) or "velocity".
    """

    window: tuple[float, float]
    quantity: str = "displacement"
    energy: float | None = None
    rank: int | None = None
    criterion: str = "squared"
    method: str = "svd"


class ReducedBasis(eqx.Module):
    """What ``reduce`` returns: the ``pod`` of the snapshots, the chosen ``rank`` r, the (n, r)
    ``basis`` Phi (eq. 3.8) and the number of ``snapshots`` m in the window."""

    pod: POD
    basis: Basis
    rank: int = eqx.field(static=True)
    snapshots: int = eqx.field(static=True)


def snapshot_window(ts: Times, window: tuple[float, float]) -> np.ndarray:
    """(N,) boolean mask of the times inside ``window`` (t0, t1), to 1e-9 relative of the grid."""
    t = np.asarray(ts)
    tol = 1e-9 * max(1.0, float(np.max(np.abs(t))))
    mask = (t >= window[0] - tol) & (t <= window[1] + tol)
    if not mask.any():
        raise ValueError(MARK + f"[reduction] snapshots window {tuple(window)} holds no time of "
                         "the grid.")
    return mask


def reduce(states: Float[Array, "N n"], ts: Times, reduction: Reduction, *,
           cap_rank: bool = False) -> ReducedBasis:
    """POD basis of the snapshots ``states`` (N, n) at ``ts`` (N,) inside ``reduction.window``.

    The rank is ``reduction.rank`` if given (with ``cap_rank``: at most the numerical rank, as the
    optimiser's bases are), else the smallest rank whose pseudo-energy fraction reaches
    ``reduction.energy`` (eq. 3.7).
    """
    mask = snapshot_window(ts, reduction.window)
    rows = np.flatnonzero(mask)
    # (n, m), eq. (3.5): a concrete selection in numpy (an eager gather would compile)
    snapshots = (jnp.asarray(np.asarray(states)[rows].T) if array_module(states) is np
                 else jnp.asarray(states)[rows].T)
    decomposition = pod(snapshots, method=reduction.method)
    if reduction.rank is not None:
        rank = reduction.rank
        if cap_rank:
            rank = min(rank, decomposition.numerical_rank())
    else:
        rank = decomposition.rank_for_energy(reduction.energy, reduction.criterion)
    return ReducedBasis(decomposition, decomposition.basis(rank), int(rank), int(mask.sum()))

