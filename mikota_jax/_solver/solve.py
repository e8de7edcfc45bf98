"""``solve``: one verb for a trajectory, and the methods it takes as strategy objects.

The methods (``AbstractMethod`` and its concrete, final subclasses, in the style of diffrax's
solvers and lineax's ``AutoLinearSolver``):

* ``Spectral()``: the exact solution from the damped modes of a full system with discrete
  dampers (``_exact.exact_solve(method="spectral")``), no integration error, any grid;
* ``DenseExponential()``: the exact solution from modal coordinates and a matrix exponential
  (``_exact.exact_solve(method="dense")``), any damping, reduced models included, a uniform grid
  when damped;
* ``ODE(solver, rtol, atol, ...)``: a diffrax integration (``_integrate.simulate``), any load; the
  structured implicit ``StructuredKvaerno5()`` for stiff cases;
* ``Auto()``: what ``Auto().select(model, ts, load)`` returns, a pure function of the structure
  (the system's operator types, its dampers' kind and the load's type) and, for the integrators'
  stiffness rule, of the model's values on the host; public so that a user can ask what would
  run and why. It never reads free memory or checks whether it is traced: under ``jit`` name the
  method.
"""

import abc
from collections.abc import Sequence

import diffrax
import equinox as eqx

from .._custom_types import Times, Vector
from .._errors import MARK
from .select import choose_solver


class AbstractMethod(eqx.Module):
    """How ``solve`` computes a trajectory. Subclass it and implement ``solve`` (same arguments
    as the verb, the method left out) to add one; ``solve`` passes every argument on unchanged."""

    @abc.abstractmethod
    def solve(self, model, ts, x0, v0, load, *, dofs, displacement, velocity):
        """The ``Trajectory`` of ``model`` at ``ts`` from (x0, v0) under ``load``."""


class Spectral(AbstractMethod):
    """The exact solution by the damped modes: x(t) = Re sum_j a_j exp(lambda_j t) U y_j over the
    2n roots of the secular equation (Veselic 2011).

    Applies to a full ``SecondOrderSystem`` whose damping is discrete dampers, with or without
    internal damping diagonal in modal coordinates, and no load or a ``Pulse``; any increasing
    grid; O(k^2 n^2) for the roots (k damper columns) and O(N d n) for the outputs. Anything
    else is refused in one line (use ``DenseExponential`` or ``ODE``)."""

    def solve(self, model, ts, x0, v0, load, *, dofs, displacement, velocity):
        """The ``Trajectory`` by the damped modes (``solve``'s arguments)."""
        from .exact import exact_solve

        return exact_solve(model, ts, x0, v0, load, dofs=dofs, displacement=displacement,
                           velocity=velocity, method="spectral")


class DenseExponential(AbstractMethod):
    """The exact solution in modal coordinates with one 2n x 2n matrix exponential: any
    damping matrix, reduced models, no load or a ``Pulse``; a uniform grid when damped, any
    increasing grid when undamped. O(n^3) once, O(n^2) per time step, some 32 n x n arrays of
    memory."""

    def solve(self, model, ts, x0, v0, load, *, dofs, displacement, velocity):
        """The ``Trajectory`` by the matrix exponential (``solve``'s arguments)."""
        from .exact import exact_solve

        return exact_solve(model, ts, x0, v0, load, dofs=dofs, displacement=displacement,
                           velocity=velocity, method="dense")


class ODE(AbstractMethod):
    """A diffrax integration of the first-order form: any load (a ``Pulse`` or any
    callable t -> (n,)), any model, any grid.

    ``solver``: a diffrax solver (default ``diffrax.Dopri8()``, explicit, the most accurate per
    step), or ``StructuredKvaerno5()`` (L-stable, its stage equations solved in the chain's O(n)
    structure: for stiff cases); ``rtol``, ``atol`` (default 1e-2 rtol times the excitation's
    scale), ``max_steps``, ``progress`` (a progress bar) and ``adjoint`` (how derivatives pass
    through the solve; default ``diffrax.RecursiveCheckpointAdjoint()``, for reverse mode; use
    ``diffrax.ForwardMode()`` under ``jax.jvp``/``jax.jacfwd``). Tolerances are traced: changing
    them does not recompile."""

    solver: diffrax.AbstractSolver = diffrax.Dopri8()
    rtol: float = 1e-8
    atol: float | None = None
    max_steps: int = eqx.field(static=True, default=100_000)
    progress: bool = eqx.field(static=True, default=False)
    adjoint: diffrax.AbstractAdjoint | None = None

    def solve(self, model, ts, x0, v0, load, *, dofs, displacement, velocity):
        """The ``Trajectory`` by diffrax (``solve``'s arguments)."""
        from .ode import simulate

        if not isinstance(self.solver, diffrax.AbstractSolver):
            raise ValueError(MARK + f"ODE(solver=...) must be a diffrax solver (e.g. "
                             f"diffrax.Dopri8(), mj.StructuredKvaerno5()), got {self.solver!r}.")
        return simulate(model, ts, x0, v0, load, dofs=dofs, displacement=displacement,
                        velocity=velocity, solver=self.solver, rtol=self.rtol, atol=self.atol,
                        max_steps=self.max_steps, progress=self.progress, adjoint=self.adjoint)


class Auto(AbstractMethod):
    """The method chosen from the structure, shown by ``select``: ``Spectral()`` for a full
    system with discrete dampers and no load or a ``Pulse``; otherwise ``ODE`` with
    ``StructuredKvaerno5()`` where rho T > 1e5 (rho: a Gershgorin bound of the highest
    eigenfrequency or damper decay rate, T the span of ``ts``: Dopri8 would need some rho T / 5
    steps for stability alone), else ``ODE()`` (Dopri8)."""

    def select(self, model, ts, load=None) -> AbstractMethod:
        """The method ``solve`` would run for ``model``, ``ts`` and ``load``. Needs concrete
        values for the stiffness rule (it runs on the host, before anything is compiled): under
        ``jit``, name the method."""
        from .implicit import StructuredKvaerno5

        choice = choose_solver(model, ts, load)
        if choice == "exact":
            return Spectral()
        return ODE(StructuredKvaerno5()) if choice == "kvaerno5" else ODE()

    def solve(self, model, ts, x0, v0, load, *, dofs, displacement, velocity):
        """The ``Trajectory`` by the method ``select`` returns (``solve``'s arguments)."""
        return self.select(model, ts, load).solve(model, ts, x0, v0, load, dofs=dofs,
                                                  displacement=displacement, velocity=velocity)


_AUTO = Auto()


def solve(model, ts: Times, x0: Vector | None = None, v0: Vector | None = None, load=None, *,
          method: AbstractMethod = _AUTO, dofs: Sequence[int] | None = None,
          displacement: bool = True, velocity: bool = False):
    """The response of M x'' + D x' + K x = f(t) (eq. 3.1) from x = x0, x' = v0 at ts[0].

    ``model``: a ``SecondOrderSystem`` or a ``ReducedModel`` (initial state and load in full
    coordinates, outputs lifted back, eqs. 3.2-3.4); ``ts``: the (N,) increasing output times;
    ``x0``, ``v0``: (n,) (default zero); ``load``: None, a ``Pulse`` (eq. 4.3) or any
    callable t -> (n,); ``dofs``: 1-based (default all, d = len(dofs)).
    Returns a ``Trajectory`` of (N, d) arrays (``displacement``, ``velocity``; ``num_steps`` of an
    integration, None for an exact method). ``method``: ``Auto()`` (default), ``Spectral()``,
    ``DenseExponential()`` or ``ODE(...)``; ``Auto().select(model, ts, load)`` says which one
    runs.

    >>> import jax.numpy as jnp, mikota_jax as mj
    >>> system = mj.mikota_chain(8, dampers=[mj.GroundedDamper(3.0, 1.0)])
    >>> mj.Auto().select(system, jnp.linspace(0.0, 10.0, 101))
    Spectral()
    """
    if not isinstance(method, AbstractMethod):
        raise ValueError(MARK + "method must be Auto(), Spectral(), DenseExponential(), ODE(...) "
                         f"or another AbstractMethod, got {method!r}.")
    return method.solve(model, ts, x0, v0, load, dofs=dofs, displacement=displacement,
                        velocity=velocity)
