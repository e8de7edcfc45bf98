"""``run_scene``: compute exactly what a scene asks for, as a typed ``SceneResult``.

Lazy by construction: velocities are integrated and saved only when an output reads them (the
velocity itself, or the phase error of eq. 5.4); all DOFs are saved only when the reduction or a
whole-chain metric needs them; POD and Galerkin run only with a ``[reduction]`` table. The paper's
reduced initial state is the projection q(0) = Phi^T x(0), q'(0) = Phi^T x'(0).

Nothing here writes files: ``results.json`` is the application layer's view of a ``SceneResult``
(``mikota_jax.app.results``).
"""

import time
from collections.abc import Callable

import equinox as eqx
import jax

from .._custom_types import Array, Float, Times
from .._errors import MARK
from .._metrics import phase_error, relative_error
from .._model.reduced import ReducedModel, galerkin
from .._rom.base import pod_basis
from .._solver.trajectory import Trajectory
from .scene import Output, Scene, solve_scene

# Scene metrics: [output] quantity -> function of (full, reduced, output) -> a scalar. Computed
# only when requested, on every DOF (the full and the reduced solve then save all of them).
METRICS: dict[str, Callable[[Trajectory, Trajectory, Output], Float[Array, ""]]] = {
    "phase_error": lambda full, reduced, out: phase_error(  # eq. (5.4)
        full.displacement, full.velocity, reduced.displacement, reduced.velocity,
        aggregate=out.phase_error),
    "relative_error": lambda full, reduced, out: relative_error(full.displacement,
                                                                reduced.displacement),
}
# quantities whose values are read from the velocities
_READS_VELOCITY = ("velocity", "phase_error")


class SceneResult(eqx.Module):
    """What ``run_scene`` computed for ``scene``: the full solve and, with a ``[reduction]``, the
    POD basis (eqs. 3.5-3.8), the reduced solve (eq. 3.4) and the requested metrics (eq. 5.4).

    ``times``: the (N,) output times; ``full``: the full model's ``Trajectory`` (every DOF when a
    reduction needs the snapshots, else the 1-based output DOFs; velocities only when read);
    ``model``: the ``ReducedModel`` (its (n, r) ``basis``, and ``stats``: the POD's
    ``decomposition``, ``rank``, ``snapshots``) or None; ``reduced``: the reduced model's
    ``Trajectory`` (lifted to the full DOFs) or None; ``metrics``:
    {"phase_error", "relative_error"}: scalars, the requested ones; ``timings``: wall seconds of
    the stages ("full_solve_s", "reduction_s", "reduced_solve_s").
    """

    scene: Scene
    times: Times
    full: Trajectory
    model: ReducedModel | None
    reduced: Trajectory | None
    metrics: dict[str, Float[Array, ""]]
    timings: dict[str, float]

    @property
    def dofs(self) -> tuple[int, ...]:
        """The 1-based output DOFs (``[output] dofs``; all n by default)."""
        dofs = self.scene.output.dofs
        return dofs if dofs is not None else tuple(range(1, self.scene.size + 1))

    @property
    def rank(self) -> int | None:
        """r, the rank of the reduced model (None without a reduction)."""
        return None if self.model is None else self.model.rank


def run_scene(scene: Scene) -> SceneResult:
    """Run ``scene``; return a ``SceneResult``: the full solve, and with a ``[reduction]`` the POD
    of the (n, m) snapshots (eqs. 3.5-3.6), ``rank`` by eq. (3.7), the Galerkin model (eq. 3.4) and
    its solve, and the requested metrics (``phase_error`` by eq. 5.4, ``relative_error``).

    Only the requested DOFs (default all) and quantities are computed;
    ``mikota_jax.app.result_dict`` turns the result into the layout of ``results.json``.
    """
    if not isinstance(scene, Scene):
        raise ValueError(MARK + f"scene must be a Scene (see mj.app.load_scene), got "
                         f"{type(scene).__name__}.")
    out = scene.output
    quantities = set(out.quantities)
    n = scene.size
    dofs = out.dofs if out.dofs is not None else tuple(range(1, n + 1))
    reduction = scene.reduction
    metrics = [name for name in METRICS if name in quantities]
    wants_v = any(q in quantities for q in _READS_VELOCITY)
    snapshot_v = reduction is not None and reduction.quantity == "velocity"
    need_all = reduction is not None  # snapshots (and whole-chain metrics) need every DOF
    timings = {}

    start = time.perf_counter()
    full = solve_scene(scene.system, scene, None if need_all else dofs, True,
                       wants_v or snapshot_v)
    jax.block_until_ready(full)
    timings["full_solve_s"] = time.perf_counter() - start
    model = reduced = None
    values = {}
    if reduction is not None:
        start = time.perf_counter()
        states = full.velocity if snapshot_v else full.displacement
        model = galerkin(scene.system, *pod_basis(states, scene.ts, reduction))
        timings["reduction_s"] = time.perf_counter() - start
        start = time.perf_counter()
        reduced = solve_scene(model, scene, None if metrics else dofs, True, wants_v)
        jax.block_until_ready(reduced)
        timings["reduced_solve_s"] = time.perf_counter() - start
        values = {name: METRICS[name](full, reduced, out) for name in metrics}
    return SceneResult(scene, scene.ts, full, model, reduced, values, timings)
