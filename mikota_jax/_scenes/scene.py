"""Scenes: a declarative description of one computation (chain, dampers, excitation, time grid,
reduction, outputs), built in Python or read from TOML (``mikota_jax.app.scene_file``).

A scene holds arrays as traced leaves (so ``jax.grad`` sees the physical values) and everything that
changes a shape or the control flow (n, which outputs, the rank rule) as static data.
DOFs are 1-based. This module is data only: reading and validating scene files is the application
layer's job (``load_scene``), so the core library never parses TOML.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._custom_types import Times, Vector
from .._errors import MARK
from .._model.dampers import Dampers
from .._model.loads import Pulse
from .._model.parameters import is_chain
from .._model.system import SecondOrderSystem
from .._rom.base import POD, AbstractSnapshotProblem
from .._solver.solve import ODE, AbstractMethod, DenseExponential, Spectral, solve

PARAMETERS = ("m", "k", "masses", "springs", "positions", "coefficients", "relative_coefficients",
              "alpha", "beta", "zeta", "amplitude")
_MIKOTA_TOL = 1e-13  # relative: masses * i and springs / (n - i + 1) constant to rounding

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
    1-based DOFs and quantities; ``method``: how ``solve`` solves the full model (``Spectral()``,
    ``DenseExponential()`` or ``ODE(...)``; ``Auto().select`` names one). The reduced model of a
    scene is solved by the same ``ODE``, or by ``DenseExponential()`` where the full model is
    solved exactly (the damped modes apply to full systems only). Consistent units, as in the
    paper's dimensionless scenes.
    """

    system: SecondOrderSystem
    ts: Times
    x0: Vector | None
    v0: Vector | None
    load: Pulse | None
    reduction: POD | None = eqx.field(static=True, default=None)
    output: Output = eqx.field(static=True, default=Output(None, ("displacement",)))
    method: AbstractMethod = Spectral()
    name: str = eqx.field(static=True, default="scene")

    @property
    def size(self) -> int:
        """n, the number of DOFs."""
        return self.system.size

    def parameters(self, wrt=None) -> dict:
        """The nominal values of the parameters ``wrt`` (default: all that apply), by name: the
        points of ``sensitivities``, ``SceneFunction`` and ``mj.grid`` use these names.

        Default for Mikota's chain: m, k; for another fixed-free chain: masses, springs (a system
        of a user's matrices or a branched chain has neither); then the dampers' positions and
        coefficients present, the internal damping's alpha, beta or zeta, and the amplitude.
        """
        return scene_parameters(self, wrt)

    def snapshot_states(self, velocity: bool):
        """(N, n) the full model's displacements (or velocities) at ``ts``, every DOF: the
        snapshots of a ``POD`` (eq. 3.5)."""
        full = solve_scene(self.system, self, None, not velocity, velocity)
        return full.velocity if velocity else full.displacement


def scene_method(model, scene: Scene, adjoint=None) -> AbstractMethod:
    """The method that solves ``model`` (the scene's system or its reduced model) for ``scene``:
    ``scene.method``, with ``DenseExponential()`` for a reduced model where that is
    ``Spectral()``, and an ``ODE``'s adjoint replaced by ``adjoint`` where one is given."""
    method = scene.method
    if isinstance(method, Spectral) and not isinstance(model, SecondOrderSystem):
        method = DenseExponential()
    if isinstance(method, ODE) and adjoint is not None:
        method = eqx.tree_at(lambda m: m.adjoint, method, adjoint, is_leaf=lambda x: x is None)
    return method


def solve_scene(model, scene: Scene, dofs, displacement: bool, velocity: bool, adjoint=None):
    """``model`` solved as ``scene`` says (``scene_method``)."""
    return solve(model, scene.ts, scene.x0, scene.v0, scene.load,
                 method=scene_method(model, scene, adjoint), dofs=dofs,
                 displacement=displacement, velocity=velocity)


def mikota_parameters(system: SecondOrderSystem) -> tuple[float, float] | None:
    """(m, k) if ``system`` is Mikota's chain (m_i = m / i, k_i = (n - i + 1) k), else None."""
    if not is_chain(system):
        return None
    masses, springs = np.asarray(system.mass.diagonal), np.asarray(system.stiffness.springs)
    i = np.arange(1, masses.size + 1)
    m, k = masses * i, springs / (masses.size - i + 1)
    if np.ptp(m) > _MIKOTA_TOL * m[0] or np.ptp(k) > _MIKOTA_TOL * k[0]:
        return None
    return float(m[0]), float(k[0])


def scene_parameters(scene, wrt=None) -> dict:
    """``Scene.parameters``, checked (the allowed names: ``PARAMETERS``)."""
    system = scene.system
    mk = mikota_parameters(system)
    damping = system.damping
    available = {"amplitude": jnp.asarray(1.0)}
    if is_chain(system):
        available.update(masses=system.mass.diagonal, springs=system.stiffness.springs)
    if mk is not None:
        available.update(m=jnp.asarray(mk[0]), k=jnp.asarray(mk[1]))
    internal = system.internal
    if internal is not None and internal.rayleigh is not None:
        available.update(alpha=internal.rayleigh.alpha, beta=internal.rayleigh.beta)
    if internal is not None and internal.modal is not None:
        available["zeta"] = internal.modal.zeta
    if isinstance(damping, Dampers):
        if damping.positions.shape[0]:
            available.update(positions=damping.positions, coefficients=damping.coefficients)
        if damping.pair_count:
            available["relative_coefficients"] = damping.pair_coefficients
    if wrt is None:
        wrt = [name for name in PARAMETERS if name in available
               and not (mk is not None and name in ("masses", "springs"))]
    wrt = tuple(wrt)
    for name in wrt:
        if name not in PARAMETERS:
            raise ValueError(MARK + f"wrt: unknown parameter {name!r}; allowed: "
                             f"{list(PARAMETERS)}.")
        if name not in available:
            why = {"m": "the chain is not Mikota's (use 'masses', 'springs')",
                   "masses": "the system is not a fixed-free chain (masses and springs)",
                   "alpha": "the system has no Rayleigh damping",
                   "zeta": "the system has no modal damping"}
            why = why.get({"k": "m", "springs": "masses", "beta": "alpha"}.get(name, name),
                          "the scene has no such damper")
            raise ValueError(MARK + f"wrt: {name!r} does not apply: {why}.")
    if {"m", "masses"} <= set(wrt) or {"k", "springs"} <= set(wrt):
        raise ValueError(MARK + "wrt: give 'm'/'k' (Mikota's scalars) or 'masses'/'springs' "
                         "(vectors), not both for the same quantity.")
    if len(set(wrt)) != len(wrt) or not wrt:
        raise ValueError(MARK + f"wrt must name distinct parameters, got {list(wrt)}.")
    return {name: jnp.asarray(available[name], dtype=jnp.float64) for name in wrt}
