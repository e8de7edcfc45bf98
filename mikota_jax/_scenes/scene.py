"""Scenes: a declarative description of one computation (chain, dampers, excitation, time grid,
reduction, outputs), built in Python or read from TOML (``mikota_jax.app.scene_file``).

A scene holds arrays as traced leaves (so ``jax.grad`` sees the physical values) and everything that
changes a shape or the control flow (n, which outputs, the solver, the rank rule) as static data.
DOFs are 1-based. This module is data only: reading and validating scene files is the application
layer's job (``load_scene``), so the core library never parses TOML.
"""

import equinox as eqx

from .._custom_types import Times, Vector
from .._model.loads import Pulse
from .._model.system import SecondOrderSystem
from .._rom.base import POD, AbstractSnapshotProblem
from .._solver.exact import exact_solve
from .._solver.ode import simulate
from .._solver.select import choose_solver

# what [output] quantities may name: histories ("full"/"reduced" columns), POD outputs, metrics
QUANTITIES = ("displacement", "velocity", "singular_values", "rank", "phase_error", "modes",
              "relative_error")
# the quantities that need a [reduction]
REDUCED_QUANTITIES = ("singular_values", "rank", "phase_error", "modes", "relative_error")


class Output(eqx.Module):
    """What to compute and report: 1-based DOFs (None: all), quantities, figures."""

    dofs: tuple[int, ...] | None
    quantities: tuple[str, ...]
    phase_error: str = "sum"
    figures: bool = False


class Scene(AbstractSnapshotProblem):
    """One computation, declaratively: run it with ``run_scene``; read one with ``load_scene``.

    ``system``: the chain or system (n DOFs); ``ts``: (N,) output times; ``x0``, ``v0``: (n,)
    initial state or None (zero); ``load``: a ``Pulse`` (eq. 4.3) or None; ``reduction``: the
    ``POD`` strategy (snapshot window, rank rule, method; eqs. 3.5-3.8), or None; ``output``:
    1-based DOFs and quantities; ``solver``: "exact" (``solve``'s exact methods) or an ``ODE``
    solver with ``rtol``, ``atol``, ``max_steps``. Consistent units, as in the paper's dimensionless
    scenes.
    """

    system: SecondOrderSystem
    ts: Times
    x0: Vector | None
    v0: Vector | None
    load: Pulse | None
    reduction: POD | None = eqx.field(static=True, default=None)
    output: Output = eqx.field(static=True, default=Output(None, ("displacement",)))
    solver: str = eqx.field(static=True, default="exact")
    rtol: float = eqx.field(static=True, default=1e-10)
    atol: float = eqx.field(static=True, default=1e-12)
    max_steps: int = eqx.field(static=True, default=100_000)
    name: str = eqx.field(static=True, default="scene")

    @property
    def size(self) -> int:
        """n, the number of DOFs."""
        return self.system.size

    def snapshot_states(self, velocity: bool):
        """(N, n) the full model's displacements (or velocities) at ``ts``, every DOF: the
        snapshots of a ``POD`` (eq. 3.5)."""
        full = solve_scene(self.system, self, None, not velocity, velocity)
        return full.velocity if velocity else full.displacement


def solve_scene(model, scene: Scene, dofs, displacement: bool, velocity: bool, adjoint=None):
    """``model`` solved as ``scene`` says: exactly, by ``simulate`` with the scene's tolerances,
    or ("auto") by what ``Auto().select`` names, integrated at the scene's tolerances."""
    kwargs = dict(dofs=dofs, displacement=displacement, velocity=velocity)
    solver = choose_solver(model, scene.ts, scene.load) if scene.solver == "auto" else scene.solver
    if solver == "exact":
        return exact_solve(model, scene.ts, scene.x0, scene.v0, scene.load, **kwargs,
                           **({"method": "spectral"} if scene.solver == "auto" else {}))
    return simulate(model, scene.ts, scene.x0, scene.v0, scene.load, solver=solver,
                    rtol=scene.rtol, atol=scene.atol, max_steps=scene.max_steps,
                    adjoint=adjoint, **kwargs)
