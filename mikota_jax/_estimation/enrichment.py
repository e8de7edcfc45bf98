"""Sensitivity-enriched POD: a basis that holds the state *and* its derivatives with respect to
the design parameters, so the reduced model's gradient follows the full model's.

A Galerkin ROM on a basis Phi reproduces a trajectory exactly when the trajectory lies in
span(Phi), and its derivative d x / d p exactly when that lies there too. A POD of the states
alone (eq. 3.5) captures x(t) but not d x / d p: the Section 5 ROM at the paper's r = 98 has
dJ/dp 2.5e-3 off at a damper at DOF 290 with d = 100, while J itself agrees. The enriched
snapshot matrix is

    Q = [X, w_1 S_1, ..., w_P S_P],   S_j = d X / d p_j   (n x m each, the same window),

with w_j = ||X||_F / ||S_j||_F, so that every parameter direction carries as much weight as the
states (Hay, Borggaard & Pelletier, "Local improvements to reduced-order models using
sensitivity analysis of the proper orthogonal decomposition", J. Fluid Mech. 629 (2009) 41-72,
weight the sensitivity snapshots the same way). The S_j come from forward mode through the
full solve (``jax.jacfwd``; ``diffrax.ForwardMode`` for an integrated scene): P extra tangent
solves, no finite differences. The rank rule is the scene's (eq. 3.7 on Q's singular values).
"""

from collections.abc import Sequence

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import MARK
from .._model.reduced import ReductionStats
from .._rom.base import AbstractReduction, problem_scene, snapshot_window
from .._rom.pod import pod
from .._scenes.scene import Scene, solve_scene
from .._scenes.sensitivity import SceneFunction, parameters_at

DESIGN = ("positions", "coefficients")


def _history(function: SceneFunction, velocity: bool):
    """parameters -> the full model's (N, n) displacements (or velocities) over the scene."""
    scene = function.scene

    def history(parameters):
        x0, v0, load = function.excitation(parameters)
        at = eqx.tree_at(lambda s: (s.x0, s.v0, s.load), scene, (x0, v0, load),
                         is_leaf=lambda x: x is None)
        solution = solve_scene(function.system(parameters), at, None, not velocity, velocity,
                               diffrax.ForwardMode())
        return solution.velocity if velocity else solution.displacement

    return history


@eqx.filter_jit
def _states_and_tangents(function: SceneFunction, velocity: bool, parameters: dict):
    history = _history(function, velocity)
    return history(parameters), jax.jacfwd(history)(parameters)


def sensitivity_snapshots(scene: Scene, wrt: Sequence[str] = DESIGN, *,
                          parameters: dict | None = None):
    """(X, {name: S}) of ``scene`` at its values (or ``parameters``): X the (n, m) snapshot
    matrix of eq. (3.5) over the scene's ``[reduction]`` window, S the (n, m, *shape) derivative
    of it with respect to each parameter in ``wrt`` (names as in ``sensitivities``), by forward
    mode through the full solve."""
    if not isinstance(scene, Scene):
        raise ValueError(MARK + f"scene must be a Scene (see mj.app.load_scene), got "
                         f"{type(scene).__name__}.")
    if scene.reduction is None:
        raise ValueError(MARK + "scene: sensitivity snapshots need a [reduction] table (the "
                         "snapshot window and the rank rule).")
    nominal = parameters_at(scene, wrt, parameters)
    velocity = scene.reduction.quantity == "velocity"
    rows = jnp.asarray(np.flatnonzero(snapshot_window(scene.ts, scene.reduction.window)))
    states, tangents = _states_and_tangents(SceneFunction(scene, "energy"), velocity, nominal)
    snapshots = states[rows].T
    derivatives = {name: jnp.moveaxis(t[rows], 0, 1) for name, t in tangents.items()}
    if not bool(jnp.all(jnp.isfinite(snapshots))) or not all(
            bool(jnp.all(jnp.isfinite(s))) for s in derivatives.values()):
        raise ValueError(MARK + "the states or their derivatives are not finite at these "
                         "parameters (a kink, or a failed solve).")
    return snapshots, derivatives


def enriched_reduce(scene: Scene, wrt: Sequence[str] = DESIGN, *,
                    parameters: dict | None = None, rank: int | None = None,
                    energy: float | None = None):
    """(basis, stats): the sensitivity-enriched POD basis of ``scene`` (module docstring;
    ``EnrichedPOD``), stats' ``decomposition`` that of Q = [X, w_1 S_1, ...] (n x m (1 + P), P
    the parameter entries in ``wrt``; ``snapshots`` = its column count).

    ``wrt``: the design parameters (default the dampers' positions and coefficients);
    ``parameters``: the design to build at (default the scene's); the rank is ``rank``, else
    the smallest reaching ``energy`` (default the scene's ``[reduction]`` rule) under the
    scene's criterion. A parameter the states do not depend on (a zero derivative) adds nothing.
    Use the basis with ``sensitivities(..., model="reduced", basis=...)``.
    """
    x, derivatives = sensitivity_snapshots(scene, wrt, parameters=parameters)
    size = jnp.linalg.norm(x)
    blocks = [x]
    for s in derivatives.values():
        for column in np.ndindex(s.shape[2:]):  # one block per parameter entry
            block = s[(slice(None), slice(None)) + column]
            norm = jnp.linalg.norm(block)
            if float(norm) > 0:
                blocks.append(block * (size / norm))
    decomposition = pod(jnp.concatenate(blocks, axis=1), method=scene.reduction.method)
    reduction = scene.reduction
    if rank is not None:
        if isinstance(rank, bool) or not isinstance(rank, int) or not 1 <= rank <= len(
                decomposition.singular_values):
            raise ValueError(MARK + f"rank must be an integer in 1.."
                             f"{len(decomposition.singular_values)}, got {rank!r}.")
    elif energy is not None or reduction.energy is not None:
        rank = decomposition.rank_for_energy(energy if energy is not None else reduction.energy,
                                             reduction.criterion)
    else:
        rank = reduction.rank
    return decomposition.basis(rank), ReductionStats(
        "EnrichedPOD", int(rank), decomposition, snapshots=int(sum(b.shape[1] for b in blocks)))


class EnrichedPOD(AbstractReduction):
    """Sensitivity-enriched POD of a ``Scene`` with a ``[reduction]``: the POD of Q = [X, w_1 S_1,
    ...], the states and their forward-mode derivatives with respect to ``wrt`` (default the
    dampers' positions and coefficients) at ``parameters`` (default the scene's), each block
    weighted to ||X||_F; the rank is ``rank``, else the smallest reaching ``energy`` (default
    the scene's rule). Stats: ``decomposition``, ``snapshots`` (Q's columns)."""

    wrt: tuple[str, ...] = eqx.field(static=True, default=DESIGN, converter=tuple)
    parameters: dict | None = None
    rank: int | None = eqx.field(static=True, default=None)
    energy: float | None = eqx.field(static=True, default=None)

    def basis(self, problem):
        """(n, r) the enriched POD basis of the scene and the stats (``decomposition``)."""
        scene = problem_scene(problem, "EnrichedPOD")
        return enriched_reduce(scene, tuple(self.wrt), parameters=self.parameters,
                               rank=self.rank, energy=self.energy)
