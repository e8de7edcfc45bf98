"""Optimal viscosities at full order: several dampers of any kind, some free, within bounds.

The algorithm of the ``Coefficients`` strategy (``optimise``). The design is the vector of damper
coefficients of a ``SecondOrderSystem``: its grounded dampers' ``coefficients`` first, then its
relative dampers' (``Dampers.pair_coefficients``), in the order they were given. Positions stay
where they are. The objective is evaluated at full order on the spectral path (``_spectral``:
exact, O(k n^2) per value for dampers alone), with its gradient by ``jax.grad`` through the
secular equation's implicit derivative; both compile once per problem.

Objectives (``FULL_ORDER``, of the public family), each of a free vibration:

* ``AverageEnergy(lowest)``: Veselic's total average energy trace X, A^T X + X A = -Z over the
  ``lowest`` s modes (``total_average_energy``), the criterion of FastOptimalDamping.jl and of
  Truhar & Veselic (SIAM J. Matrix Anal. Appl. 31, 2009), with Z = diag of the s lowest modes'
  two components in the scaled modal coordinates (the trace depends on the coordinates: these
  are the ones where X is the energy over all initial states of unit energy in those modes);
* ``Energy(horizon, x0, v0)``: the integrated energy of a given free vibration over [0, T]
  (``integrated_energy``);
* ``OutputEnergy(cx, cv, x0, v0, lowest, horizon)``: the energy of an output C_x x + C_v x'
  (``output_energy``), Veselic's trace with a general weight;
* ``H2Norm(inputs, cx, cv)``: the H2 norm of the map from the columns of ``inputs`` to that
  output (``h2_norm``);
* ``Peak(dof, ts, x0, v0, order=...)``: the smooth peak (``smooth_peak``, an L^p mean of order
  ``order``) of the displacement of one DOF over the time grid ``ts`` in the free vibration
  from x0, v0, exact from the damped modes (the spectral solve) at every time of the grid.

Search coordinates: u = log d of the free coefficients, where the stopping rule below is the
plain gradient (|d_i df/dd_i| = |df/du_i|) and the criterion is far closer to quadratic than in d
(a trace behaves like a / d + b d over decades of d). On FastOptimalDamping.jl's example with
two chains of 100 masses, scipy's L-BFGS-B needed 13 iterations / 17 values in d and 9 / 11 in
log d. A coefficient whose optimum is 0 tends to 0 (u to -inf) until its relative gradient is
below the tolerance; a free coefficient that starts at 0 starts at 1 % of the largest one.

Search: a projected quasi-Newton method on the box log lower <= u <= log upper (Bertsekas, SIAM J.
Control Optim. 20:221, 1982: the variables at a bound whose gradient pushes outwards are held, a
BFGS step is taken in the others, then an Armijo backtracking search along the projected arc),
with the inverse-Hessian approximation started at Barzilai-Borwein's scale and updated only on
curvature s^T y > 0 (``ProjectedBFGS``). Stops when every free, non-held variable has a relative
gradient |d_i df/dd_i| / |f| below ``tolerance`` (scale-free: the change of log f per change of
log d_i), or when a step no longer changes f in its 14th digit. ``SpectralProjectedGradient`` is
the method that Li & Tisseur (arXiv 2601.05404, 2026) propose for the trace criterion;
``Solution.stats`` keeps the iteration and evaluation counts to compare (on
FastOptimalDamping.jl's small example, n = 801, iterations / values: BFGS 8 / 10, SPG 14 / 15,
scipy's L-BFGS-B in d 13 / 17; against optax's L-BFGS and optimistix's BFGS in log d, which take
no bounds: ``docs/notes/viscosity.md``).

The minimisers are host loops over one compiled value and gradient: each step costs one full
evaluation per line-search trial, and no loop is compiled around the spectral engine.
"""

import abc
import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import MARK, RESULTS, check_lowest, check_x64, integer_indices
from .._model.dampers import Dampers
from .._model.parameters import with_parameters
from .._model.reduced import galerkin
from .._model.system import SecondOrderSystem
from .._objective.family import AverageEnergy, Energy, H2Norm, OutputEnergy, Peak, exact_method
from .._objective.functions import (
    exact_is_dense,
    integrated_energy_exact_with_result,
    smooth_peak,
    total_average_energy_with_result,
)
from .._objective.outputs import (
    _reduced_output_energy,
    output_arguments,
    output_horizon,
    output_states,
    state_matrix,
)
from .._solver.ode import initial_vector
from .._solver.solve import Auto, Spectral
from .._solver.spectral.energy import (
    spectral_energy_with_roots,
    spectral_output_energy_with_roots,
    spectral_trace_with_roots,
)
from .._solver.spectral.modes import spectral_applies
from .._solver.spectral.response import spectral_solve_with_roots
from .._solver.spectral.roots import RootStart

_SPG_MEMORY = 10  # the non-monotone line search compares with the largest of the last 10 values
_ARMIJO = 1e-4
_FIRST_STEP = 1.0  # the first step's length in log d (a factor e along the steepest descent)
_BACKTRACKS = 30


@dataclasses.dataclass(frozen=True)
class CoefficientRun:
    """What ``search_coefficients`` found.

    ``coefficients``: (g + p,) all damper coefficients (grounded, then relative) at the optimum;
    ``value``: the criterion there (full order); ``gradient``: its gradient (g + p,);
    ``relative_gradient``: max over free variables not held at a bound of |d_i df/dd_i| / |f|;
    ``converged``: whether that is below the tolerance; ``iterations``, ``evaluations`` (value
    and gradient pairs); ``seconds`` (wall, compile included); ``history``: (value, relative
    gradient) per iteration; ``status``: one line.
    """

    coefficients: np.ndarray
    value: float
    gradient: np.ndarray
    relative_gradient: float
    converged: bool
    iterations: int
    evaluations: int
    seconds: float
    history: list
    status: str
    state: object = None  # the minimiser's last state (a warm start for another search)


# the objectives the full-order searches evaluate on the spectral path, and what each needs
FULL_ORDER = (AverageEnergy, Energy, OutputEnergy, H2Norm, Peak)


def criterion_value(system, objective):
    """The objective (a ``checked_objective``) on the spectral path, +inf where it does not hold
    (a root not converged, roots coinciding beyond a critically damped pair, an undamped mode
    seen): no check inside, so a compiled search meets a failed design as a value to reject,
    never as an error."""
    return criterion_with_roots(system, objective)[0]


def criterion_with_roots(system, objective, start=None):
    """(``criterion_value``, roots): its damped roots' sweeps started at ``start`` (a
    ``RootStart``, None for the arc starts), and the roots found as the next design's start
    (None where the objective's method is dense)."""
    o = objective
    if isinstance(o, (AverageEnergy, Energy)):  # by the objective's own method (Auto: the modes)
        method = exact_method(o.method, type(o).__name__)
        if exact_is_dense(system, method):
            if isinstance(o, AverageEnergy):
                value, result = total_average_energy_with_result(system, lowest=o.lowest,
                                                                 method=method)
            else:
                value, result = integrated_energy_exact_with_result(system, o.horizon, o.x0,
                                                                    o.v0, method=method)
            return jnp.where(result == RESULTS.successful, value, jnp.inf), None
        if isinstance(o, AverageEnergy):
            value, ok, roots = spectral_trace_with_roots(system, lowest=o.lowest, start=start)
        else:
            value, ok, roots = spectral_energy_with_roots(system, o.horizon, o.x0, o.v0,
                                                          start=start)
    elif isinstance(o, H2Norm):
        value, ok, roots = spectral_output_energy_with_roots(system, None, None, o.inputs, o.cx,
                                                             o.cv, None, None, start=start)
        value = jnp.sqrt(value)
    elif isinstance(o, Peak):
        trajectory, ok, roots = spectral_solve_with_roots(system, o.ts, o.x0, o.v0, None,
                                                          dofs=(o.dof,), displacement=True,
                                                          velocity=False, start=start)
        value = smooth_peak(trajectory.displacement, o.order)
    else:  # OutputEnergy
        value, ok, roots = spectral_output_energy_with_roots(system, o.x0, o.v0, None, o.cx,
                                                             o.cv, o.horizon, o.lowest,
                                                             start=start)
    return jnp.where(ok, value, jnp.inf), roots


# the objectives a search through a Galerkin model evaluates (its dense reduced Gramian)
THROUGH_REDUCED = (H2Norm, OutputEnergy)


def reduced_criterion_value(model, objective):
    """An ``H2Norm`` or ``OutputEnergy`` (a ``checked_objective``) of the Galerkin model
    ``model`` (a ``ReducedModel``; inputs and outputs in full coordinates), +inf where it does
    not hold (a reduced mode undamped and seen), as ``criterion_value``."""
    o = objective
    if isinstance(o, H2Norm):
        value, ok = _reduced_output_energy(model, None, None, o.inputs, o.cx, o.cv, None, None)
        value = jnp.sqrt(value)
    else:  # OutputEnergy
        value, ok = _reduced_output_energy(model, o.x0, o.v0, None, o.cx, o.cv, o.horizon,
                                           o.lowest)
    return jnp.where(ok, value, jnp.inf)


@eqx.filter_jit
def _value_and_gradient(d, system, criterion, basis=None, start=None):
    """(f, df/dd, roots) for the (g + p,) coefficient vector d: one compile per system
    structure and criterion (the system's values are traced); with a ``basis`` (n, r), of the
    Galerkin model on it (the dampers' coefficients enter its projected damping linearly; roots
    None). ``start``, roots: as ``criterion_with_roots``."""
    grounded = system.damping.coefficients.shape[0]

    def value(d):
        designed = with_parameters(system, dict(coefficients=d[:grounded],
                                                relative_coefficients=d[grounded:]))
        if basis is None:
            return criterion_with_roots(designed, criterion, start)
        return reduced_criterion_value(galerkin(designed, basis), criterion), None

    (f, roots), g = jax.value_and_grad(value, has_aux=True)(d)
    return f, g, roots


def criterion_function(system, objective):
    """d -> (f, df/dd) of an objective of the family (``Energy``, ``AverageEnergy``,
    ``OutputEnergy``, ``H2Norm``, ``Peak``) over the (g + p,) coefficient vector d, compiled once
    per system structure (``_value_and_gradient``); the objective is checked here."""
    criterion = checked_objective(system, objective)
    return lambda d: _value_and_gradient(jnp.asarray(d, dtype=jnp.float64), system,
                                         criterion)[:2]


def _check_bounds(bound, size, name, default):
    """``lower`` or ``upper``: None (``default``), a scalar, or one value per coefficient."""
    if bound is None:
        return np.full(size, default, dtype=float)
    try:
        array = np.asarray(bound, dtype=float)
    except (ValueError, TypeError):  # ragged lists, text
        array = None
    if array is None or array.shape not in ((), (size,)):
        count = "one number" if size == 1 else f"a number or {size} numbers"
        raise ValueError(MARK + f"{name} must be {count} (one per damper coefficient: grounded "
                         f"dampers first, then relative ones), got {bound!r:.60}.")
    array = np.broadcast_to(array, (size,)).copy()
    if np.any(np.isnan(array)):
        raise ValueError(MARK + f"{name} must not be NaN, got {bound!r}.")
    return array


def _free_mask(free, size: int) -> np.ndarray:
    """(size,) booleans: which coefficients move. ``free``: None (all), or distinct 0-based
    indices into the coefficient vector; a negative index is refused, not counted from the end."""
    if free is None:
        return np.ones(size, dtype=bool)
    where = (f"0-based indices in 0..{size - 1} into the {size} damper coefficients, grounded "
             "dampers first, then relative ones")
    indices = integer_indices(free, "free")
    if not indices:
        raise ValueError(MARK + f"free must name at least one coefficient ({where}), got "
                         f"{free!r}; None frees all.")
    if not all(0 <= i < size for i in indices):
        raise ValueError(MARK + f"free must be {where}, got {free!r}.")
    if len(set(indices)) != len(indices):
        raise ValueError(MARK + f"free must not repeat an index ({where}), got {free!r}.")
    mask = np.zeros(size, dtype=bool)
    mask[list(indices)] = True
    return mask


def check_design_system(system) -> None:
    """A system the full-order searches take: discrete dampers, the spectral path."""
    check_x64()
    if not isinstance(system, SecondOrderSystem) or not isinstance(system.damping, Dampers):
        raise ValueError(MARK + "system must be a SecondOrderSystem with GroundedDamper/"
                         "RelativeDamper dampers.")
    why = spectral_applies(system)
    if why is not None:
        raise ValueError(MARK + f"system: {why}.")


def checked_objective(system, objective):
    """``objective`` (one of ``FULL_ORDER``) with its arguments checked and normalised before
    compiling: a free vibration (no load), states as the spectral path takes them, counts and
    the horizon as Python numbers (static: one compile each)."""
    from .._objective.family import AbstractObjective

    check_design_system(system)
    names = ", ".join(kind.__name__ for kind in FULL_ORDER)
    if not isinstance(objective, AbstractObjective):
        raise ValueError(MARK + f"objective must be an objective of the family ({names}), got "
                         f"{type(objective).__name__}.")
    if type(objective) not in FULL_ORDER:
        raise ValueError(MARK + f"objective must be one of {names} for a full-order search (the "
                         f"spectral path), got {type(objective).__name__}.")
    n = system.size
    o = objective
    if isinstance(o, Energy | Peak) and o.load is not None:
        raise ValueError(MARK + f"objective: {type(o).__name__} of a free vibration only at full "
                         "order (the spectral path), got a load.")
    if isinstance(o, Energy):
        horizon = o.horizon
        try:
            horizon = float(horizon)
        except (TypeError, ValueError):
            horizon = None
        if horizon is None or not np.isfinite(horizon) or horizon <= 0:
            raise ValueError(MARK + f"horizon must be a finite time > 0 for Energy, got "
                             f"{o.horizon!r}.")
        x0, v0 = initial_vector(o.x0, n, "x0"), initial_vector(o.v0, n, "v0")
        if not (bool(jnp.any(x0 != 0)) or bool(jnp.any(v0 != 0))):
            raise ValueError(MARK + "objective Energy needs an excitation: x0 or v0.")
        exact_method(o.method, "Energy in a full-order search", " (no ODE: it is exact)")
        return Energy(horizon, x0, v0, method=o.method)
    if isinstance(o, AverageEnergy):
        check_lowest(o.lowest, n)
        exact_method(o.method, "AverageEnergy")
        return o
    if isinstance(o, Peak):
        if type(o.method) not in (Auto, Spectral):
            raise ValueError(MARK + "Peak in a full-order search solves by the damped modes: its "
                             f"method must be Auto() or Spectral(), got {o.method!r}.")
        return _checked_peak(n, o.x0, o.v0, o.dof, o.ts, o.order)
    # OutputEnergy, H2Norm: checked as the public functions check them, before compiling
    cx, cv = output_arguments(system, o.cx, o.cv)
    if isinstance(o, H2Norm):
        return H2Norm(state_matrix(o.inputs, n, "inputs", required=True), cx, cv)
    x0, v0 = output_states(n, o.x0, o.v0, o.lowest)
    return OutputEnergy(cx, cv, x0, v0, o.lowest, output_horizon(o.horizon))


def _checked_peak(n, x0, v0, dof, ts, order) -> Peak:
    if isinstance(dof, bool) or not isinstance(dof, int | np.integer) or not 1 <= dof <= n:
        raise ValueError(MARK + f"dof must be an integer DOF in 1..{n} for Peak, got {dof!r}.")
    if isinstance(order, bool) or not isinstance(order, int) or order < 2 or order % 2:
        raise ValueError(MARK + f"order must be an even integer >= 2, got {order!r}.")
    times = None if ts is None else np.asarray(ts, dtype=float)
    if (times is None or times.ndim != 1 or times.shape[0] < 2 or not np.all(np.isfinite(times))
            or times[0] < 0 or np.any(np.diff(times) <= 0)):
        raise ValueError(MARK + "ts must be an increasing grid of >= 2 finite times >= 0 for "
                         f"Peak, got {ts!r:.80}.")
    x0, v0 = initial_vector(x0, n, "x0"), initial_vector(v0, n, "v0")
    if not (bool(jnp.any(x0 != 0)) or bool(jnp.any(v0 != 0))):
        raise ValueError(MARK + "objective Peak needs an excitation: x0 or v0.")
    return Peak(int(dof), jnp.asarray(times), x0, v0, order=order)


def checked_bounds(lower, upper, size: int):
    """(lower, upper), each (size,), from scalars or one value per coefficient, checked:
    0 <= lower <= upper, lower finite."""
    lo = _check_bounds(lower, size, "lower", 0.0)
    hi = _check_bounds(upper, size, "upper", np.inf)
    if np.any(lo < 0) or np.any(hi < lo):
        raise ValueError(MARK + f"coefficients bounds must satisfy 0 <= lower <= upper, got "
                         f"lower {lower!r}, upper {upper!r}.")
    if not np.all(np.isfinite(lo)):
        raise ValueError(MARK + f"lower must be finite, got {lower!r}.")
    return lo, hi


def check_search(minimiser, tolerance) -> None:
    """The coefficient search's ``minimiser`` and ``tolerance``."""
    if not isinstance(minimiser, AbstractBoxMinimiser):
        raise ValueError(MARK + "minimiser must be ProjectedBFGS() or SpectralProjectedGradient(), "
                         f"got {minimiser!r}.")
    if (isinstance(tolerance, bool) or not isinstance(tolerance, float | int)
            or not 0 < tolerance < 1):
        raise ValueError(MARK + f"tolerance must lie in (0, 1), got {tolerance!r}.")


def search_coefficients(system: SecondOrderSystem, objective, *, free=None, lower=0.0,
                        upper=None, tolerance: float = 1e-6, max_iterations: int = 200,
                        minimiser=None, progress: bool = False, basis=None,
                        state=None) -> CoefficientRun:
    """Optimal damper coefficients of ``system`` at full order (positions fixed): the algorithm
    of ``Coefficients``; with a ``basis`` (n, r), of its Galerkin model on that basis.
    ``state``: the minimiser's state to start from (another run's ``state``: its inverse-Hessian
    approximation or step length in u), else its own start.

    ``objective``: a ``checked_objective``; ``free``: None or 0-based indices into the (g + p,)
    coefficient vector (grounded dampers first, then relative ones) that move; ``lower``,
    ``upper``: bounds, scalars or (g + p,); a coefficient with lower = upper stays there.
    ``minimiser``: ``ProjectedBFGS()`` (default, projected quasi-Newton) or
    ``SpectralProjectedGradient()`` (Li & Tisseur's globally convergent method). See the module
    docstring.
    """
    minimiser = ProjectedBFGS() if minimiser is None else minimiser
    check_x64()
    start = time.perf_counter()
    args = objective
    d = np.concatenate([np.asarray(system.damping.coefficients),
                        np.asarray(system.damping.pair_coefficients)])
    size = d.shape[0]
    if size == 0:
        raise ValueError(MARK + "system has no damper whose coefficient could be optimised.")
    mask = _free_mask(free, size)
    lo, hi = checked_bounds(lower, upper, size)
    check_search(minimiser, tolerance)
    # a free coefficient whose bounds meet (lower = upper, 0 included) is fixed there, no search
    # variable: its log coordinate would be a constant, -inf at 0
    pinned = mask & (lo == hi)
    d, mask = np.where(pinned, lo, d), mask & ~pinned
    d = np.where(mask, np.clip(d, lo, hi), d)
    # the search runs in u = log d of the free coefficients (see the module docstring); a free
    # coefficient that starts at 0 starts at 1 % of the largest one (or at its lower bound)
    positive = d[mask & (d > 0)]
    d = np.where(mask & (d <= 0), np.maximum(lo, 1e-2 * (positive.max() if positive.size
                                                         else 1.0)), d)
    d = np.where(mask, np.minimum(d, hi), d)
    with np.errstate(divide="ignore"):
        u_lo, u_hi = np.log(lo[mask]), np.log(hi[mask])

    evaluate_jit = lambda point, start: _value_and_gradient(  # noqa: E731
        jnp.asarray(point, dtype=jnp.float64), system, args, basis, start)
    evaluations = refused = 0
    last = {}
    # each design's damped roots start where the previous design's ended (``RootStart``); the
    # first from the arc starts, with the same shapes (one compiled program for both)
    cold = None if basis is not None else RootStart.cold(system.size)
    sweeps_from = cold

    def design(u):
        point = d.copy()
        point[mask] = np.exp(u)
        return point

    def evaluate(u):  # f and df/du = d * df/dd for the free coefficients
        nonlocal evaluations, refused, sweeps_from
        evaluations += 1
        point = design(u)
        f, g, roots = evaluate_jit(point, sweeps_from)
        if not np.isfinite(f) and sweeps_from is not None and bool(sweeps_from.usable):
            # refused from the previous design's roots: once more from the arc starts, so
            # that a value never depends on where the sweeps started
            f, g, roots = evaluate_jit(point, cold)
        sweeps_from = cold if roots is None else roots
        refused += not np.isfinite(f)
        last[u.tobytes()] = np.asarray(g)
        return float(f), np.asarray(g)[mask] * point[mask]

    def held(u, g):  # at a bound with the gradient pushing out
        return ((u <= u_lo) & (g > 0)) | ((u >= u_hi) & (g < 0))

    def stationarity(u, f, g):  # max |d_i df/dd_i| / |f| over the free, non-held coefficients
        return float(np.max(np.where(held(u, g), 0.0, np.abs(g)), initial=0.0)
                     / max(abs(f), 1e-300))

    def report(iterations, f, relative, u):
        if progress:
            print(f"  iteration {iterations}: f = {f:.12g}, relative gradient {relative:.2e}, "
                  f"d = {np.array2string(design(u), precision=6)}", flush=True)

    u = np.log(d[mask])
    f, g = evaluate(u)
    if not np.isfinite(f) or not np.all(np.isfinite(g)):
        raise ValueError(MARK + f"the criterion is not finite at the start design ({f}); a mode "
                         "no damper reaches (a coefficient held at 0 reaches none) has no total "
                         "average energy: move a damper, raise its bound, or restrict lowest.")
    # the first step changes log d by _FIRST_STEP along the steepest descent (then the method's
    # own scale takes over)
    first = _FIRST_STEP / max(np.linalg.norm(g), 1e-300)
    box = _Box(evaluate, held, u_lo, u_hi)
    u, f, _, history, iterations, status, state = _minimise(
        minimiser, box, stationarity, u, f, g, first, tolerance, max_iterations, report, state)
    d, g = design(u), last[u.tobytes()]
    converged = history[-1][1] < tolerance
    if converged:
        status = "converged" if mask.any() else "nothing to move: every free coefficient is pinned"
    elif refused:
        status += (f"; {refused} trial designs had no finite criterion (the spectral path "
                   "refuses where roots meet beyond what it sums exactly: an objective's "
                   "method=DenseExponential() holds there; or a mode is undamped)")
    return CoefficientRun(d, f, g, history[-1][1], converged, iterations, evaluations,
                           time.perf_counter() - start, history, status, state)


@dataclasses.dataclass(frozen=True)
class _Box:
    """What a minimiser sees of the search: ``evaluate`` (u -> f, df/du, one full-order value and
    gradient), ``held`` (u, g -> the variables at a bound whose gradient pushes out), and the
    bounds ``lower`` <= u <= ``upper`` (-inf, inf where none)."""

    evaluate: object
    held: object
    lower: np.ndarray
    upper: np.ndarray


class AbstractBoxMinimiser(eqx.Module):
    """How ``Coefficients`` minimises f(u) over the box of u = log c (host-side numpy, one
    compiled value and gradient per trial point): ``init`` a state, ``step`` to the next accepted
    point; the search around them records, reports and stops (see the module docstring).

    Subclass it to add a minimiser: ``step`` receives the ``box``, whose ``evaluate(u)`` returns
    (f, df/du) at a trial point (one full-order value and gradient), ``held(u, g)`` the boolean
    mask of the variables at a bound whose gradient pushes out, and ``lower``, ``upper`` the
    bounds of u (-inf, inf where none); project a trial point with ``np.clip(u, lower, upper)``.
    """

    @abc.abstractmethod
    def init(self, size: int, first: float):
        """The state before the first step: ``first`` is the first step's length per unit
        gradient (a change of ``_FIRST_STEP`` in log c along the steepest descent)."""

    @abc.abstractmethod
    def step(self, state, box: _Box, u, f, g, history: list, iteration: int):
        """(u, f, g, state) at the next accepted point, or None where its line search found no
        decrease; ``history``: (value, relative gradient) of the points accepted so far."""


class ProjectedBFGS(AbstractBoxMinimiser):
    """Projected BFGS (Bertsekas, SIAM J. Control Optim. 20:221, 1982): the variables at a bound
    whose gradient pushes outwards are held, a BFGS step is taken in the others, then an Armijo
    backtracking search (step / 4, up to 30 times) along the projected arc; the inverse-Hessian
    approximation starts at Barzilai-Borwein's scale and is updated only on curvature
    s^T y > 0."""

    def init(self, size: int, first: float):
        """The first inverse-Hessian approximation, ``first`` times the identity."""
        return np.eye(size) * first

    def step(self, state, box, u, f, g, history, iteration):
        """One projected quasi-Newton step from ``u`` (``AbstractBoxMinimiser.step``)."""
        h, size = state, u.shape[0]
        move = ~box.held(u, g)
        direction = np.zeros(size)
        direction[move] = -(h[np.ix_(move, move)] @ g[move])
        if g[move] @ direction[move] >= 0:  # not a descent direction: restart from the gradient
            h = np.eye(size) * (h.trace() / size)
            direction[move] = -(h[np.ix_(move, move)] @ g[move])
        step = 1.0
        for _ in range(_BACKTRACKS):
            trial = np.clip(u + step * direction, box.lower, box.upper)
            f_trial, g_trial = box.evaluate(trial)
            if np.isfinite(f_trial) and f_trial <= f + _ARMIJO * (g @ (trial - u)):
                break
            step /= 4
        else:
            return None
        s, y = trial - u, g_trial - g
        curvature = s @ y
        if curvature > 1e-12 * np.linalg.norm(s) * np.linalg.norm(y):
            if iteration == 1:  # Barzilai-Borwein's scale once the first curvature is known
                h = np.eye(size) * (curvature / (y @ y))
            rho = 1.0 / curvature
            left = np.eye(size) - rho * np.outer(s, y)
            h = left @ h @ left.T + rho * np.outer(s, s)
        return trial, f_trial, g_trial, h


class SpectralProjectedGradient(AbstractBoxMinimiser):
    """Spectral projected gradient (Birgin, Martinez & Raydan, SIAM J. Optim. 10:1196, 2000,
    algorithm SPG2; the method Li & Tisseur, arXiv 2601.05404, propose for optimal damping): the
    projected Barzilai-Borwein step u -> P(u - alpha g), alpha = s^T s / s^T y, accepted by a
    non-monotone Armijo test against the largest of the last 10 values, with safeguarded
    quadratic backtracking."""

    def init(self, size: int, first: float):
        """The first step length alpha."""
        return first

    def step(self, state, box, u, f, g, history, iteration):
        """One projected Barzilai-Borwein step from ``u`` (``AbstractBoxMinimiser.step``)."""
        alpha = state
        direction = np.clip(u - alpha * g, box.lower, box.upper) - u
        slope = g @ direction
        reference = max(value for value, _ in history[-_SPG_MEMORY:])
        step = 1.0
        for _ in range(_BACKTRACKS):
            trial = u + step * direction
            f_trial, g_trial = box.evaluate(trial)
            if np.isfinite(f_trial) and f_trial <= reference + _ARMIJO * step * slope:
                break
            curvature = f_trial - f - step * slope if np.isfinite(f_trial) else np.inf
            guess = -0.5 * step**2 * slope / curvature if curvature > 0 else 0.0
            step = guess if 0.1 * step <= guess <= 0.9 * step else step / 2
        else:
            return None
        s, y = trial - u, g_trial - g
        curvature = s @ y
        alpha = (float(np.clip((s @ s) / curvature, 1e-30, 1e30)) if curvature > 0
                 else 1e3 * alpha)
        return trial, f_trial, g_trial, alpha


def _minimise(minimiser, box, stationarity, u, f, g, first, tolerance, max_iterations, report,
              state=None):
    """``minimiser``'s steps from u until stationary (every free, non-held relative gradient
    below ``tolerance``), stalled (f unchanged to 1e-14), its line search fails, or
    ``max_iterations``: (u, f, g, history, iterations, status)."""
    state = minimiser.init(u.shape[0], first) if state is None else state
    history = [(f, stationarity(u, f, g))]
    status, iterations = "max_iterations reached", 0
    for iterations in range(1, max_iterations + 1):
        if history[-1][1] < tolerance:
            iterations -= 1
            break
        accepted = minimiser.step(state, box, u, f, g, history, iterations)
        if accepted is None:
            status = "line search failed (no decrease along the projected direction)"
            break
        trial, f_trial, g_trial, state = accepted
        history.append((f_trial, stationarity(trial, f_trial, g_trial)))
        report(iterations, f_trial, history[-1][1], trial)
        stalled = (abs(f_trial - f) / max(abs(f), 1e-300) < 1e-14
                   and history[-1][1] >= tolerance)
        u, f, g = trial, f_trial, g_trial
        if stalled:
            status = "stalled (f unchanged to 1e-14)"
            break
    return u, f, g, history, iterations, status, state
