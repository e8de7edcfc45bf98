"""One basis for a whole design space: POD-greedy driven by the a posteriori bound, and a rank
rule that tracks the bound rather than the snapshots' energy.

``greedy_reduce`` (Haasdonk & Ohlberger, M2AN 42 (2008) 277-302, "POD-greedy"): start from a
basis (the scene's POD, or the one given); evaluate the bound of ``error_bound`` on |J - J_r| / J
at every training design (``mj.sweep``: no full solve); where it is largest, solve the full
model once (``exact_solve``), take the POD of that trajectory's part outside the basis over the
scene's snapshot window, and append its ``step`` leading modes; repeat until every training
design is certified to ``tolerance`` or the basis reaches ``max_rank``. The full solves are one
per iteration, at the designs the bound picks; a design outside the training set is certified
by evaluating the bound there (``bound_function``).

``rank_for_bound``: the smallest rank r of a POD whose bound at the scene's design is within a
requested relative accuracy in J (bisection on r; the bound is evaluated, never the full model).
"""

import sys
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import MARK
from .._model.reduced import ReductionStats, check_basis
from .._rom.base import AbstractReduction, problem_scene, snapshot_window
from .._rom.pod import _Decomposition
from .._scenes.scene import Scene
from .._scenes.sensitivity import SceneFunction, _scene_basis, parameters_at
from .._solver.exact import exact_solve
from .._sweep import sweep
from .estimator import HierarchicalEstimator, _bound


class BoundFunction(eqx.Module):
    """parameters -> (J_r, bound on |J - J_r|, bound on the state error) of ``scene``'s free
    vibration on the reduced model of ``basis``: a pure function for ``mj.sweep`` (the scene's
    values where a name is missing, as ``SceneFunction``)."""

    function: SceneFunction
    basis: jax.Array

    def __init__(self, scene: Scene, basis):
        _check_scene(scene)
        self.function = SceneFunction(scene, "energy")
        self.basis = check_basis(basis, scene.size)

    def __call__(self, parameters: dict) -> jax.Array:
        system, horizon, x0, v0 = _free_vibration(self.function, parameters)
        b = _bound(system, self.basis, horizon, x0, v0)
        return jnp.stack([b.value, b.energy, b.state])


def _free_vibration(function: SceneFunction, parameters: dict):
    """(system, horizon, x0, v0) of the scene's free vibration at ``parameters`` (zero where the
    scene gives no start)."""
    scene = function.scene
    n = scene.size
    x0, v0, _ = function.excitation(parameters)
    x0 = jnp.zeros(n) if x0 is None else x0
    v0 = jnp.zeros(n) if v0 is None else v0
    return function.system(parameters), scene.ts[-1] - scene.ts[0], x0, v0


def _check_scene(scene) -> None:
    if not isinstance(scene, Scene):
        raise ValueError(MARK + f"scene must be a Scene (see mj.app.load_scene), got "
                         f"{type(scene).__name__}.")
    if scene.load is not None:
        raise ValueError(MARK + "scene: the error bound covers free vibration only (no [load]).")
    if scene.reduction is None:
        raise ValueError(MARK + "scene: a reduced basis needs a [reduction] table.")


def relative_bounds(values: np.ndarray) -> np.ndarray:
    """bound / (J_r - bound) per row (J_r, bound, ...) of an estimate or bound sweep; inf where
    not positive."""
    value, energy = values[:, 0], values[:, 1]
    floor = value - energy
    return np.where(floor > 0, energy / np.where(floor > 0, floor, 1.0), np.inf)


@dataclass(frozen=True)
class GreedyBasis:
    """What ``greedy_reduce`` returns.

    ``basis``: (n, r) orthonormal; ``rank``: r; ``certified``: whether every training design's
    relative bound is <= ``tolerance``; ``bounds``: (S,) the final relative bounds on |J - J_r| /
    J at the training designs; ``history``: per iteration (rank, largest relative bound, index of
    that design in the training set); ``full_solves``: the full-model solves taken.
    """

    basis: jax.Array
    rank: int
    certified: bool
    tolerance: float
    bounds: np.ndarray
    history: tuple[tuple[int, float, int], ...]
    full_solves: int


def _training(scene: Scene, training: dict) -> tuple[dict, int]:
    if not isinstance(training, dict) or not training:
        raise ValueError(MARK + "training must be a dict of parameter name -> (S, ...) arrays "
                         "(see mj.grid).")
    nominal = parameters_at(scene, tuple(training))
    points = {}
    for name, values in training.items():
        values = np.asarray(values, dtype=np.float64)
        if values.ndim == 0 or values.shape[1:] != tuple(np.shape(nominal[name])):
            raise ValueError(MARK + f"training[{name!r}] must have shape (S, "
                             f"*{np.shape(nominal[name])}), got {values.shape}.")
        points[name] = values
    counts = {v.shape[0] for v in points.values()}
    if len(counts) != 1:
        raise ValueError(MARK + f"training arrays must share their length S, got {sorted(counts)}.")
    return points, counts.pop()


def _new_directions(scene: Scene, basis, parameters: dict, step: int):
    """The ``step`` leading POD modes of the full trajectory's part outside ``basis``."""
    function = SceneFunction(scene, "energy")
    x0, v0, _ = function.excitation(parameters)
    velocity = scene.reduction.quantity == "velocity"
    solution = exact_solve(function.system(parameters), scene.ts, x0, v0,
                           displacement=not velocity, velocity=velocity)
    states = np.asarray(solution.velocity if velocity else solution.displacement)
    snapshots = states[snapshot_window(scene.ts, scene.reduction.window)].T
    b = np.asarray(basis)
    outside = snapshots - b @ (b.T @ snapshots)
    outside = outside - b @ (b.T @ outside)  # twice: Gram-Schmidt's lost orthogonality
    u, s, _ = np.linalg.svd(outside, full_matrices=False)
    keep = s > 1e-12 * max(np.linalg.norm(snapshots, 2), 1e-300)
    u = u[:, keep][:, :step]
    u = u - b @ (b.T @ u)
    q, _ = np.linalg.qr(u)
    return q


def greedy_reduce(scene: Scene, training: dict, tolerance: float = 1e-4, *, basis=None,
                  step: int = 10, max_rank: int | None = None, hierarchical: dict | None = None,
                  progress: bool = False) -> GreedyBasis:
    """One basis for ``scene`` certified over the designs ``training`` (module docstring).

    ``training``: parameter name -> (S, ...) arrays of S designs (``mj.grid``; names as in
    ``sensitivities``); ``tolerance``: the relative bound on |J - J_r| / J to reach at every
    training design; ``basis``: the starting (n, r0) orthonormal basis (default the scene's own
    POD); ``step``: modes appended per iteration; ``max_rank``: stop there (default n);
    ``progress``: one line per iteration on stderr. Each iteration costs one bound per
    training design (O(n r^2 + r^3), no full solve) and one full solve.

    ``hierarchical``: None (default) drives the greedy by the rigorous ``error_bound``; a dict
    drives it by the hierarchical estimate instead, ``HierarchicalEstimator(scene.system, basis,
    **hierarchical)`` rebuilt per iteration (e.g. ``{"modes": 80, "basis_moments": 2}``: the
    reduced model is then the basis plus two damper moments of each design, and the result's
    ``bounds`` are the relative estimates): tight (effectivity ~2) where the bound is 1e4-1e6
    pessimistic, but resting on saturation (see ``HierarchicalEstimator``), not a proof.
    """
    _check_scene(scene)
    points, _ = _training(scene, training)
    if not (isinstance(tolerance, float | int) and 0 < tolerance < 1):
        raise ValueError(MARK + f"tolerance must be in (0, 1), got {tolerance!r}.")
    if isinstance(step, bool) or not isinstance(step, int) or step < 1:
        raise ValueError(MARK + f"step must be a positive integer, got {step!r}.")
    n = scene.size
    max_rank = n if max_rank is None else max_rank
    if isinstance(max_rank, bool) or not isinstance(max_rank, int) or not 1 <= max_rank <= n:
        raise ValueError(MARK + f"max_rank must be an integer in 1..{n}, got {max_rank!r}.")
    options = {"modes", "moments", "safety", "basis_moments"}
    if hierarchical is not None and not (isinstance(hierarchical, dict)
                                         and set(hierarchical) <= options):
        raise ValueError(MARK + f"hierarchical must be None or a dict with keys from "
                         f"{sorted(options)}, got {hierarchical!r}.")
    current = np.asarray(_scene_basis(scene) if basis is None else basis, dtype=np.float64)
    if current.ndim != 2 or current.shape[0] != n:
        raise ValueError(MARK + f"basis must be (n, r) with n = {n}, got {current.shape}.")

    def certificate(current):
        if hierarchical is None:
            return BoundFunction(scene, jnp.asarray(current))
        return EstimateFunction(scene, HierarchicalEstimator(scene.system, jnp.asarray(current),
                                                             **hierarchical))

    history, solves = [], 0
    while True:
        values = sweep(certificate(current), points, batch="map")
        bounds = relative_bounds(values)
        worst = int(np.argmax(bounds))
        history.append((current.shape[1], float(bounds[worst]), worst))
        if progress:
            print(f"greedy: r = {current.shape[1]}, largest "
                  f"{'bound' if hierarchical is None else 'estimate'} {bounds[worst]:.2e} at "
                  f"design {worst}", file=sys.stderr, flush=True)
        if bounds[worst] <= tolerance or current.shape[1] >= max_rank:
            break
        design = {name: jnp.asarray(v[worst]) for name, v in points.items()}
        extra = _new_directions(scene, current, design, min(step, max_rank - current.shape[1]))
        solves += 1
        if extra.shape[1] == 0:
            break
        current = np.concatenate([current, extra], axis=1)
    return GreedyBasis(jnp.asarray(current), current.shape[1], bool(bounds[worst] <= tolerance),
                       float(tolerance), bounds, tuple(history), solves)


def rank_for_bound(scene: Scene, pod: _Decomposition, tolerance: float, *,
                   parameters: dict | None = None) -> int:
    """The smallest rank r whose basis ``pod.basis(r)`` has a relative bound on |J - J_r| / J
    <= ``tolerance`` at the scene's design (or ``parameters``), by bisection on r (a bound per
    step, no full solve; the bound is nearly monotone in r, not exactly: the result is a rank
    that meets the tolerance, the smallest up to that). A ``ValueError`` if even the full
    numerical rank does not."""
    _check_scene(scene)
    if not (isinstance(tolerance, float | int) and 0 < tolerance < 1):
        raise ValueError(MARK + f"tolerance must be in (0, 1), got {tolerance!r}.")
    design = {} if parameters is None else dict(parameters)

    def meets(r: int) -> bool:
        value = np.asarray(BoundFunction(scene, pod.basis(r))(design))[None, :]
        return bool(relative_bounds(value)[0] <= tolerance)

    high = pod.numerical_rank()
    if not meets(high):
        raise ValueError(MARK + f"tolerance {tolerance:g} is not met even at the POD's numerical "
                         f"rank {high}; enlarge the snapshot set (greedy_reduce).")
    low = 0  # invariant: meets(high), not known for low
    while high - low > 1:
        mid = (low + high) // 2
        if meets(mid):
            high = mid
        else:
            low = mid
    return high


class EstimateFunction(eqx.Module):
    """parameters -> (J_r, estimate of |J - J_r|, J_f) of ``scene``'s free vibration by a
    ``HierarchicalEstimator``: a pure function for ``mj.sweep`` (the scene's values where a name
    is missing, as ``SceneFunction``). The scene's M and K must be those the estimator was built
    with (designs differ in their dampers)."""

    function: SceneFunction
    estimator: HierarchicalEstimator

    def __init__(self, scene: Scene, estimator: HierarchicalEstimator):
        _check_scene(scene)
        if not isinstance(estimator, HierarchicalEstimator):
            raise ValueError(MARK + f"estimator must be a HierarchicalEstimator, got "
                             f"{type(estimator).__name__}.")
        if estimator.basis.shape[0] != scene.size:
            raise ValueError(MARK + f"estimator: its basis has {estimator.basis.shape[0]} rows, "
                             f"the scene {scene.size} DOFs.")
        self.function = SceneFunction(scene, "energy")
        self.estimator = estimator

    def __call__(self, parameters: dict) -> jax.Array:
        e = self.estimator(*_free_vibration(self.function, parameters))
        return jnp.stack([e.value, e.energy, e.fine])


class Greedy(AbstractReduction):
    """POD-greedy over the designs ``training`` (``mj.grid``), driven by the a posteriori bound
    (or the hierarchical estimate, ``hierarchical``): from ``basis`` (default the scene's own
    POD) append ``step`` POD modes of the full solve at the worst-certified design until every
    design's relative bound on |J - J_r| / J is <= ``tolerance`` or the rank reaches
    ``max_rank``. Needs a free-vibration ``Scene`` with a ``[reduction]``. Stats:
    ``certified``, ``bounds``, ``history``, ``full_solves``."""

    training: dict
    tolerance: float = eqx.field(static=True, default=1e-4)
    start: jax.Array | None = None
    step: int = eqx.field(static=True, default=10)
    max_rank: int | None = eqx.field(static=True, default=None)
    hierarchical: dict | None = None
    progress: bool = eqx.field(static=True, default=False)

    def basis(self, problem):
        """(n, r) the greedy basis of the scene and the stats (the certificate)."""
        scene = problem_scene(problem, "Greedy")
        found = greedy_reduce(scene, self.training, self.tolerance, basis=self.start,
                              step=self.step, max_rank=self.max_rank,
                              hierarchical=self.hierarchical, progress=self.progress)
        return found.basis, ReductionStats(
            "Greedy", found.rank, certified=found.certified,
            bounds=tuple(float(b) for b in found.bounds), history=found.history,
            full_solves=found.full_solves)
