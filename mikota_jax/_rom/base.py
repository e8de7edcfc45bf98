"""The reduction stage's family: ``AbstractReduction`` (how to build a basis for a problem), the
``ReductionStats`` every reduced model carries, and the snapshot-POD strategy ``POD``
(snapshots of a solve -> POD, eqs. 3.5-3.6 -> rank, eq. 3.7 -> basis, eq. 3.8).

The private ``pod_basis`` is the snapshot-POD step that ``run_scene``, ``SceneFunction`` and the
damper optimiser share, so a window, a rank rule or a POD method means the same everywhere. The
states stay on the device: the window selects rows by index, and only the singular values travel
to the host (the rank is a shape, so it must be a Python integer).

Conventions: ``states`` is (N, n), rows at the N times ``ts`` and columns at all n DOFs (a
``Trajectory``'s ``displacement`` or ``velocity``); the snapshot matrix Q is its windowed rows
transposed, (n, m) (eq. 3.5). ``rank`` is always the final column count of the basis.
"""

import abc

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Basis, Float, Times
from .._errors import MARK, array_module
from .._model.reduced import ReductionStats
from .._model.system import SecondOrderSystem
from .pod import ALL_METHODS, CRITERIA, _check_energy, pod


class AbstractReduction(eqx.Module):
    """How to reduce a problem: a strategy for ``reduce(problem, strategy)``.

    Subclass it and implement ``basis``; ``reduce`` checks the basis (orthonormal to 1e-6,
    (n, r)) and projects the system onto it (eq. 3.4).
    """

    @abc.abstractmethod
    def basis(self, problem) -> tuple[Basis, ReductionStats | None]:
        """(Phi, stats) for ``problem`` (a ``SecondOrderSystem`` or a ``Scene``): Phi (n, r)
        with orthonormal columns; stats a ``ReductionStats`` or None (then ``reduce`` records
        the class name and r)."""


class AbstractIOReduction(eqx.Module):
    """How to reduce an input-output map: a strategy for ``reduce(io_model, strategy)`` that
    builds its reduced model from the inputs and outputs (H2-optimal, balanced), not from a
    one-sided basis. Implement ``reduce_io``; ``reduce`` returns its ``LTIModel``."""

    @abc.abstractmethod
    def reduce_io(self, io):
        """The reduced ``LTIModel`` of the ``IOModel`` ``io`` of a full system."""


class AbstractSnapshotProblem(eqx.Module):
    """A problem that can give snapshots: a system with an excitation and a time grid. ``Scene``
    is the one the package defines (it lives above the reductions, so the reductions know it by
    this base only); ``snapshot_states`` is its full solve at every DOF."""

    system: eqx.AbstractVar[SecondOrderSystem]
    ts: eqx.AbstractVar[Times]

    @abc.abstractmethod
    def snapshot_states(self, velocity: bool) -> Float[Array, "N n"]:
        """(N, n) the full model's displacements (or velocities) at ``ts``, every DOF."""


def problem_system(problem, strategy: str) -> SecondOrderSystem:
    """The ``SecondOrderSystem`` of ``problem`` (a system, or a scene's system)."""
    if isinstance(problem, AbstractSnapshotProblem):
        return problem.system
    if isinstance(problem, SecondOrderSystem):
        return problem
    raise ValueError(MARK + f"problem must be a SecondOrderSystem or a Scene for {strategy}, "
                     f"got {type(problem).__name__}.")


def problem_scene(problem, strategy: str) -> AbstractSnapshotProblem:
    """``problem`` as a ``Scene`` (snapshot strategies need its excitation and time grid)."""
    if not isinstance(problem, AbstractSnapshotProblem):
        raise ValueError(MARK + f"problem must be a Scene for {strategy} (its snapshots need an "
                         f"excitation and a time grid), got {type(problem).__name__}.")
    return problem


class POD(AbstractReduction):
    """Snapshot POD (eqs. 3.5-3.8): the (n, m) snapshots of the scene's full solve in ``window``
    (t0, t1) (None: the whole grid), of ``quantity`` ("displacement", the paper's choice, or
    "velocity"); the rank is ``rank`` if given (it wins over ``energy``), else the smallest
    whose pseudo-energy fraction (eq. 3.7, under ``criterion``: "squared" or "paper") reaches
    ``energy``; ``method``: "svd", "snapshots" (eigenvectors of the smaller Gram matrix) or
    "randomized" (needs ``rank``). A ``Scene``'s ``reduction`` is one.

    A rank above the snapshots' numerical rank is a ``ValueError``. Stats: ``decomposition``
    (the POD, its singular values) and ``snapshots`` (m).
    """

    window: tuple[float, float] | None = None
    quantity: str = "displacement"
    energy: float | None = None
    rank: int | None = None
    criterion: str = "squared"
    method: str = "svd"

    def __check_init__(self):
        if self.window is not None and (len(self.window) != 2
                                        or not self.window[0] <= self.window[1]):
            raise ValueError(MARK + f"window must be None or (t0, t1) with t0 <= t1, got "
                             f"{self.window!r}.")
        if self.quantity not in ("displacement", "velocity"):
            raise ValueError(MARK + f"quantity must be 'displacement' or 'velocity', got "
                             f"{self.quantity!r}.")
        if self.criterion not in CRITERIA:
            raise ValueError(MARK + f"criterion must be one of {CRITERIA}, got "
                             f"{self.criterion!r}.")
        if self.method not in ALL_METHODS:
            raise ValueError(MARK + f"method must be one of {ALL_METHODS}, got {self.method!r}.")
        if self.rank is None and self.energy is None:
            raise ValueError(MARK + "POD needs rank (the column count) or energy (a fraction "
                             "in (0, 1], eq. 3.7).")
        if self.rank is not None and (isinstance(self.rank, bool)
                                      or not isinstance(self.rank, int | np.integer)
                                      or self.rank < 1):
            raise ValueError(MARK + f"rank must be an integer >= 1, got {self.rank!r}.")
        if self.energy is not None:
            _check_energy(self.energy)
        if self.method == "randomized" and self.rank is None:
            raise ValueError(MARK + "method='randomized' needs rank (it computes only the "
                             "leading modes).")

    def basis(self, problem):
        """(n, r) the first r POMs of the scene's (n, m) snapshot matrix (eq. 3.8), and the
        stats (``decomposition``, ``snapshots``)."""
        scene = problem_scene(problem, "POD")
        return pod_basis(scene.snapshot_states(self.quantity == "velocity"), scene.ts, self)


def snapshot_window(ts: Times, window: tuple[float, float] | None) -> np.ndarray:
    """(N,) boolean mask of the times inside ``window`` (t0, t1) (None: all), to 1e-9 relative
    of the grid."""
    t = np.asarray(ts)
    if window is None:
        return np.ones(t.shape, dtype=bool)
    tol = 1e-9 * max(1.0, float(np.max(np.abs(t))))
    mask = (t >= window[0] - tol) & (t <= window[1] + tol)
    if not mask.any():
        raise ValueError(MARK + f"[reduction] snapshots window {tuple(window)} holds no time of "
                         "the grid.")
    return mask


def pod_basis(states: Float[Array, "N n"], ts: Times, strategy: POD, *,
              cap_rank: bool = False) -> tuple[Basis, ReductionStats]:
    """(basis, stats): the POD basis of the snapshots ``states`` (N, n) at ``ts`` (N,) inside
    ``strategy.window``, the snapshot-POD step every caller shares.

    The rank is ``strategy.rank`` if given (with ``cap_rank``: at most the numerical rank, as the
    optimiser's bases are), else the smallest rank whose pseudo-energy fraction reaches
    ``strategy.energy`` (eq. 3.7).
    """
    mask = snapshot_window(ts, strategy.window)
    rows = np.flatnonzero(mask)
    # (n, m), eq. (3.5): a concrete selection in numpy (an eager gather would compile)
    snapshots = (jnp.asarray(np.asarray(states)[rows].T) if array_module(states) is np
                 else jnp.asarray(states)[rows].T)
    if strategy.method == "randomized":
        decomposition = pod(snapshots, method="randomized", rank=strategy.rank)
    else:
        decomposition = pod(snapshots, method=strategy.method)
    if strategy.rank is not None:
        rank = strategy.rank
        if cap_rank:
            rank = min(rank, decomposition.numerical_rank())
    else:
        rank = decomposition.rank_for_energy(strategy.energy, strategy.criterion)
    basis = decomposition.basis(int(rank))
    return basis, ReductionStats("POD", int(rank), decomposition, snapshots=int(mask.sum()))
