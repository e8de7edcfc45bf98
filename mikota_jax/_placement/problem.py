"""The design problem of damper placement: a chain, the grounded dampers to place, the excitation
and the objective, validated once when the problem is built.

Conventions: DOFs and damper positions are 1-based in [1, n] (a position between DOFs splits the
damper linearly over its neighbours, see ``GroundedDamper``); coefficients >= 0 in force * time
per length; a design is ``positions`` (g,) and ``coefficients`` (g,) for g grounded dampers.

Objectives are small Modules (``Energy``, ``AverageEnergy``, ``Peak``), named at the public
boundary by the strings of ``OBJECTIVES``. Each says how it is evaluated on a full or Galerkin
model (``evaluate``: the value and a ``RESULTS`` code) and, where the reduced model's modal form
makes it exact (free vibration), in modal coordinates (``in_modes``: the value and a failure
flag).
"""

from collections.abc import Sequence
from typing import ClassVar

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp

from .._errors import MARK, RESULTS, check_lowest, check_x64
from .._model.dampers import Dampers, GroundedDamper, RelativeDamper
from .._model.loads import as_load
from .._model.parameters import with_parameters
from .._model.system import SecondOrderSystem
from .._objective.functions import (
    DOUBLINGS_FINITE,
    doubled_gramian,
    first_step_too_long,
    infinite_gramian,
    integrated_energy_ode_with_result,
    smooth_peak,
    takes_spectral,
    total_average_energy_with_result,
)
from .._solver.ode import check_dofs, check_times, initial_vector, simulate_with_result
from .._solver.spectral.energy import (
    energy_from_modes,
    spectral_energy_with_result,
    trace_from_modes,
)


class Energy(eqx.Module):
    """int_0^T (x^T K x + x'^T M x') / 2 dt of the problem's excitation, T = ts[-1] - ts[0].

    Exact in a reduced model's modal form for free vibration (its damped modes). The full
    model's free vibration in closed form from its damped modes where the spectral path applies
    (``integrated_energy(method="spectral")``: exact, O(k n^2); this is what certifies the
    optimum; a failure of its modes is reported, never replaced); Dopri8 (the energy as one more
    state) for a load, for a system the spectral path does not take, and for a Galerkin model
    that is not in modal form.
    """

    name: ClassVar[str] = "energy"
    forward_mode: ClassVar[bool] = True  # ODE solves: differentiated in forward mode

    def exact_in_modes(self, problem) -> bool:
        return problem.load is None

    def evaluate(self, problem, model):
        horizon = problem.ts[-1] - problem.ts[0]

        def ode():
            return integrated_energy_ode_with_result(
                model, horizon, problem.x0, problem.v0, problem.load, problem.rtol,
                problem.rtol * 1e-2, max_steps=problem.max_steps, adjoint=diffrax.ForwardMode())

        if problem.load is not None or not takes_spectral(model):
            return ode()
        # the structure decides: a failure of the damped modes is reported, never swapped for
        # Dopri8 (a lax.cond would compile both, and run both under vmap)
        value, ok = spectral_energy_with_result(model, horizon, problem.x0, problem.v0)
        return value, RESULTS.where(ok, RESULTS.successful, RESULTS.spectral_failed)

    def from_modes(self, problem, modes, q0, p0):
        return energy_from_modes(modes, q0, p0, problem.ts[-1] - problem.ts[0])

    def in_modes(self, problem, omega, z0, a):
        horizon = problem.ts[-1] - problem.ts[0]
        # a fixed first step T / 2^16 (no cond: reverse mode 25 % cheaper); a damper so strong
        # that it is too long counts as a failed evaluation, never a wrong value
        w, _ = doubled_gramian(a, jnp.eye(a.shape[0]), horizon / 2**DOUBLINGS_FINITE,
                               DOUBLINGS_FINITE)
        return z0 @ ((w + w.T) / 2) @ z0 / 2, first_step_too_long(a, horizon)


class AverageEnergy(eqx.Module):
    """The total average energy: the trace of the Lyapunov solution over the ``lowest`` modes
    (all when None), which needs no excitation."""

    lowest: int | None = eqx.field(static=True, default=None)
    name: ClassVar[str] = "average_energy"
    forward_mode: ClassVar[bool] = False  # matrix exponentials only: reverse mode as it is

    def exact_in_modes(self, problem) -> bool:
        return True

    def evaluate(self, problem, model):
        return total_average_energy_with_result(model, lowest=self.lowest)

    def from_modes(self, problem, modes, q0, p0):
        r = modes.omega.shape[0]
        return trace_from_modes(modes, None if self.lowest is None else min(self.lowest, r))

    def in_modes(self, problem, omega, z0, a):
        r = omega.shape[0]
        lowest = r if self.lowest is None else min(self.lowest, r)
        select = (jnp.arange(r) < lowest).astype(a.dtype)
        x, p = infinite_gramian(a, jnp.diag(jnp.concatenate([select, select])), omega)
        return jnp.trace(x), ~(jnp.max(jnp.abs(p)) < 1e-8)


class Peak(eqx.Module):
    """A smooth peak (order-p mean, ``smooth_peak``) of the displacement of the 1-based ``dof``
    on the time grid; solved with Dopri8 on the full or Galerkin model."""

    dof: int = eqx.field(static=True)
    order: int = eqx.field(static=True, default=16)
    name: ClassVar[str] = "peak"
    forward_mode: ClassVar[bool] = True

    def exact_in_modes(self, problem) -> bool:
        return False

    def evaluate(self, problem, model):
        trajectory, result = simulate_with_result(
            model, problem.ts, problem.x0, problem.v0, problem.load, problem.rtol,
            problem.rtol * 1e-2, solver=diffrax.Dopri8(), dofs=(self.dof,),
            displacement=True, velocity=False, max_steps=problem.max_steps, progress=False,
            adjoint=diffrax.ForwardMode())
        return smooth_peak(trajectory.displacement[:, 0], self.order), result

    def from_modes(self, problem, modes, q0, p0):
        raise NotImplementedError("the peak is never evaluated in modal form")

    def in_modes(self, problem, omega, z0, a):
        raise NotImplementedError("the peak is never evaluated in modal form")


OBJECTIVES = {"energy": Energy, "average_energy": AverageEnergy, "peak": Peak}


def _objective(name: str, n: int, lowest, dof, order):
    """The objective Module of a public name; its arguments checked for every name, as ever."""
    if name not in OBJECTIVES:
        raise ValueError(MARK + f"objective must be one of {list(OBJECTIVES)}, got {name!r}.")
    check_lowest(lowest, n)
    if isinstance(order, bool) or not isinstance(order, int) or order < 2 or order % 2:
        raise ValueError(MARK + f"order must be an even integer >= 2, got {order!r}.")
    if name == "peak":
        if dof is None:
            raise ValueError(MARK + "objective 'peak' needs dof (a 1-based DOF in 1..n).")
        return Peak(check_dofs([dof], n)[0], order)
    return AverageEnergy(lowest) if name == "average_energy" else Energy()


def _design_system(system, dampers) -> SecondOrderSystem:
    """The system whose grounded dampers are the design: its own, or ``dampers`` in their place
    (relative dampers kept); the dampers are checked here, once."""
    if not isinstance(system, SecondOrderSystem) or not isinstance(system.damping,
                                                                     Dampers | None):
        raise ValueError(MARK + "system must be a SecondOrderSystem (mikota_chain, chain, "
                         "branched_chain or system) with GroundedDamper/RelativeDamper "
                         "dampers.")
    damping = system.damping
    if dampers is None:
        if damping is None or damping.positions.shape[0] == 0:
            raise ValueError(MARK + "dampers: the system has no grounded damper to place; "
                             "pass dampers=[GroundedDamper(position, coefficient), ...].")
        return system  # its dampers were checked when it was built
    try:
        dampers = [dampers] if isinstance(dampers, GroundedDamper) else list(dampers)
    except TypeError:  # not a sequence
        dampers = None
    if not dampers or not all(isinstance(d, GroundedDamper) for d in dampers):
        raise ValueError(MARK + "dampers must be a non-empty list of GroundedDamper.")
    fixed = [] if damping is None else [
        RelativeDamper((int(i) + 1, int(j) + 1), c)
        for (i, j), c in zip(damping.pairs, damping.pair_coefficients)]
    return SecondOrderSystem(system.mass, system.stiffness, Dampers(system.size,
                                                                    [*dampers, *fixed]),
                             system.internal)


class DamperProblem(eqx.Module):
    """What to optimise: a chain, the grounded dampers to place, the excitation and the objective.

    ``system`` gives M and K (and relative dampers, kept fixed); its grounded dampers -- or
    ``dampers``, when given -- are the design, and their positions and coefficients the start.
    ``ts`` is the time grid: the horizon T = ts[-1] - ts[0] of ``"energy"``, the samples of
    ``"peak"`` and of the snapshots. ``snapshots`` is the window (t0, t1) whose full-model
    displacements build the POD basis, ``energy`` the pseudo-energy fraction that sets its rank
    (eq. 3.7; ``criterion`` as in ``POD``) unless ``rank`` is given.

    Shapes: ``ts`` (N,), ``x0``, ``v0`` (n,), ``load`` as in ``solve``; the design is
    ``positions`` (g,), 1-based in [1, n], and ``coefficients`` (g,), >= 0 in force * time per
    length, for g grounded dampers. ``objective``: "energy", "average_energy" (``lowest`` modes)
    or "peak" (of the 1-based ``dof``, order-``order`` mean, ``smooth_peak``); stored as the
    objective's Module (``OBJECTIVES``).
    """

    base: SecondOrderSystem  # the chain with the design's dampers at the start design
    ts: jax.Array
    x0: jax.Array
    v0: jax.Array
    load: object
    objective: Energy | AverageEnergy | Peak
    snapshots: tuple[float, float] = eqx.field(static=True)
    energy: float = eqx.field(static=True)
    criterion: str = eqx.field(static=True)
    rank: int | None = eqx.field(static=True)
    rtol: float = eqx.field(static=True)
    max_steps: int = eqx.field(static=True)

    def __init__(self, system: SecondOrderSystem, ts, x0=None, v0=None, load=None, *,
                 dampers: GroundedDamper | Sequence[GroundedDamper] | None = None,
                 objective: str = "energy",
                 lowest: int | None = None, dof: int | None = None, order: int = 16,
                 snapshots: tuple[float, float] | None = None, energy: float = 0.9999,
                 criterion: str = "paper", rank: int | None = None, rtol: float = 1e-8,
                 max_steps: int = 100_000):
        check_x64()
        self.base = _design_system(system, dampers)
        n = self.base.size
        self.ts = check_times(ts)
        if self.ts.shape[0] < 2:
            raise ValueError(MARK + "ts must hold at least two times (the horizon).")
        self.x0 = initial_vector(x0, n, "x0")
        self.v0 = initial_vector(v0, n, "v0")
        self.load = as_load(load, n)
        self.objective = _objective(objective, n, lowest, dof, order)
        t0, t1 = float(self.ts[0]), float(self.ts[-1])
        self.snapshots = (t0, t1) if snapshots is None else tuple(float(t) for t in snapshots)
        self.energy, self.criterion, self.rank = float(energy), criterion, rank
        self.rtol, self.max_steps = float(rtol), max_steps

    def __check_init__(self):
        n, t0, t1 = self.size, float(self.ts[0]), float(self.ts[-1])
        if not isinstance(self.objective, AverageEnergy) and self.load is None and not (
                bool(jnp.any(self.x0 != 0)) or bool(jnp.any(self.v0 != 0))):
            raise ValueError(MARK + f"objective {self.objective.name!r} needs an excitation: x0, "
                             "v0 or a load (the response is zero otherwise).")
        window = self.snapshots
        if len(window) != 2 or not t0 <= window[0] < window[1] <= t1:
            raise ValueError(MARK + f"snapshots must be a window (start, end) inside [{t0}, "
                             f"{t1}] with start < end, got {window!r}.")
        if not 0 < self.energy <= 1:
            raise ValueError(MARK + f"energy must lie in (0, 1], got {self.energy!r}.")
        rank = self.rank
        if rank is not None and (isinstance(rank, bool) or not isinstance(rank, int)
                                 or not 1 <= rank <= n):
            raise ValueError(MARK + f"rank must be None or an integer in 1..{n}, got {rank!r}.")
        if not 0 < self.rtol < 1:
            raise ValueError(MARK + f"rtol must lie in (0, 1), got {self.rtol!r}.")
        if (isinstance(self.max_steps, bool) or not isinstance(self.max_steps, int)
                or self.max_steps < 1):
            raise ValueError(MARK + f"max_steps must be an integer >= 1, got "
                             f"{self.max_steps!r}.")

    @property
    def size(self) -> int:
        """n, the number of DOFs."""
        return self.base.size

    @property
    def num_dampers(self) -> int:
        """g, the number of grounded dampers to place."""
        return self.base.damping.positions.shape[0]

    @property
    def positions(self) -> jax.Array:
        """The start design's positions, (g,), 1-based."""
        return self.base.damping.positions

    @property
    def coefficients(self) -> jax.Array:
        """The start design's coefficients, (g,)."""
        return self.base.damping.coefficients

    def system(self, positions, coefficients) -> SecondOrderSystem:
        """The chain with grounded dampers at ``positions`` (g,), in [1, n], of ``coefficients``
        (g,), plus the fixed relative dampers; unchecked (``with_parameters``): the design is
        checked where it enters (``placement_objective``) or valid by construction (the
        optimiser's reparametrisation)."""
        return with_parameters(self.base, dict(positions=positions, coefficients=coefficients))
