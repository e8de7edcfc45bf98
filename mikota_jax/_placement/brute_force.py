"""Brute force: the full (or reduced) objective of one damper on a grid of designs, via ``sweep``.

The algorithm of the ``Grid`` strategy (``optimise``).

``grid_sweep`` evaluates the full model at every (position, coefficient) of a grid -- the
independent check of ``ScreenAndCertify`` -- and refines the coefficient of the best DOFs by
golden-section search in log c; ``reduced_grid`` does the same on the reduced model, for
plots. The grid goes through ``mikota_jax.sweep`` (chunked, sharded over the devices, one compile
per chunk shape); a failed point is reported by its flag and becomes NaN here.

Evaluators, chosen by ``solve``'s method objects: ``Auto()``, the objective's own (``Energy``:
the closed form from the damped modes where the spectral path applies, else Dopri8 with the
energy as one more state), except that a damper whose own rate c / M_jj exceeds 10x the highest
eigenfrequency, which makes Dopri8 stiff (slow, and past ``max_steps`` failing), sends its
points to the exact free-vibration energy (the damped modes where the spectral path applies,
else matrix exponentials, O(n^3), any stiffness); ``Spectral()``, ``DenseExponential()`` or
``ODE(...)``: that evaluator of the ``Energy`` at every point, as ``Energy(method=...)``
computes it.

Shapes: positions (P,), 1-based in [1, n]; coefficients (C,), >= 0; results (P, C).
"""

import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import MARK, RESULTS, check_x64
from .._limits import STIFF_RATIO
from .._model.operators import diagonal_of
from .._model.reduced import check_basis
from .._objective.family import energy_options
from .._objective.functions import (
    integrated_energy_exact_with_result,
    integrated_energy_ode_with_result,
    takes_spectral,
)
from .._plain import to_plain
from .._solver.ode import check_solve_options
from .._solver.select import gershgorin_omega
from .._solver.solve import ODE, AbstractMethod, Auto, Spectral
from .._sweep import sweep
from .objective import objective_function, reduced_form
from .problem import DamperProblem, Energy


class _PointObjective(eqx.Module):
    """One design point {"positions": (), "coefficients": ()} -> its value, finiteness and failure.

    Reduced (``basis``) or full (None); ``method``: None, the problem's own evaluator, or a
    method object of ``solve``: the full model's ``Energy`` as ``Energy(method=...)`` computes it.
    ``sweep`` refuses non-finite results, so a failed or non-finite value is returned as 0 with
    its flags and turned into NaN on the host.
    """

    problem: DamperProblem
    basis: jax.Array | None
    method: AbstractMethod | None

    def __call__(self, point):
        problem = self.problem
        positions, coefficients = point["positions"][None], point["coefficients"][None]
        if self.method is not None:
            horizon = problem.ts[-1] - problem.ts[0]
            model = problem.system(positions, coefficients)
            options = energy_options(self.method)
            if options["method"] == "ode":
                value, result = integrated_energy_ode_with_result(
                    model, horizon, problem.x0, problem.v0, problem.load, options["rtol"],
                    options["atol"], max_steps=options["max_steps"],
                    adjoint=options["adjoint"])
            else:
                value, result = integrated_energy_exact_with_result(
                    model, horizon, problem.x0, problem.v0, options["method"])
            failed = result != RESULTS.successful
        else:
            value, failed = objective_function(problem, reduced_form(problem, self.basis))(
                positions, coefficients)
        finite = jnp.isfinite(value)
        return dict(value=jnp.where(finite, value, 0.0), finite=finite, failed=failed)


@eqx.filter_jit
def _point(function: _PointObjective, point):
    return function(point)


def _evaluate_points(problem, basis, points_p, points_c, batch_size: int, progress: bool = False,
                     exact=None, method=None):
    """Objective at the points (p_k, c_k) through ``sweep``, ``batch_size`` per compiled chunk;
    ``exact``: a mask of points for ``method``'s evaluator (``_PointObjective``), the others
    the problem's own. (values with NaN where failed, failed)."""
    points_p, points_c = np.asarray(points_p, float), np.asarray(points_c, float)
    exact = np.zeros(points_p.size, bool) if exact is None else np.asarray(exact, bool)
    values, failed = np.full(points_p.size, np.nan), np.zeros(points_p.size, bool)
    count = len(jax.devices())
    chunk = -(-batch_size // count) * count  # sweep shards a chunk over every device
    for flag in (False, True):
        index = np.flatnonzero(exact == flag)
        if index.size == 0:
            continue
        function = _PointObjective(problem, basis, method if flag else None)
        # matrix exponentials: under vmap every Pade branch of expm is computed, so in turn
        closed_form = flag and not isinstance(method, ODE)
        batch = "map" if closed_form or basis is not None else "vmap"
        out = sweep(function, dict(positions=points_p[index], coefficients=points_c[index]),
                    chunk_size=chunk, batch=batch, progress=progress)
        values[index] = np.where(out["finite"], out["value"], np.nan)
        failed[index] = out["failed"]
    return np.where(failed, np.nan, values), failed


def _evaluate_one(problem, position: float, coefficient: float, method) -> float:
    """One design's full-model objective (inf where it fails): a golden-section step.

    A sequential search evaluates one point at a time, so it calls the compiled point function
    directly: ``sweep`` would re-trace its function (``eval_shape``) on every call."""
    out = _point(_PointObjective(problem, None, method),
                 dict(positions=jnp.asarray(position), coefficients=jnp.asarray(coefficient)))
    value = float(out["value"]) if bool(out["finite"]) and not bool(out["failed"]) else np.inf
    return value


def _evaluate_grid(problem, basis, positions, coefficients, batch_size: int, progress: bool,
                   exact=None, method=None):
    """``_evaluate_points`` on the grid positions x coefficients, as (P, C) arrays."""
    grid_p, grid_c = (a.ravel() for a in np.meshgrid(positions, coefficients, indexing="ij"))
    values, failed = _evaluate_points(problem, basis, grid_p, grid_c, batch_size, progress,
                                      None if exact is None else exact(grid_p, grid_c), method)
    shape = (len(positions), len(coefficients))
    return values.reshape(shape), failed.reshape(shape)




def _stiff_rule(problem: DamperProblem, method: AbstractMethod):
    """For ``grid_sweep``: which (positions, coefficients) ``method``'s evaluator takes (a mask
    function), None where the problem's own evaluator takes every point.

    ``Auto()``: the points of a damper whose own rate c / M_jj exceeds 10x the Gershgorin bound
    of the highest eigenfrequency (there the explicit Dopri8 is stiff and slow, and past
    ``max_steps`` fails), for the free-vibration ``Energy``; ``Spectral()``,
    ``DenseExponential()``, ``ODE(...)``: every point.
    """
    if not isinstance(method, AbstractMethod):
        raise ValueError(MARK + "method must be Auto(), Spectral(), DenseExponential() or "
                         f"ODE(...), got {method!r}.")
    energy_options(method)  # refuses another method, or an ODE whose solver is not Dopri8
    energy = isinstance(problem.objective, Energy)
    free_vibration = energy and problem.load is None
    if not isinstance(method, Auto) and not (free_vibration or energy and isinstance(method, ODE)):
        raise ValueError(MARK + f"method={method!r} computes the Energy (free vibration only "
                         "unless ODE(...)); use method=Auto() for another objective or a load.")
    if isinstance(method, Spectral) and not takes_spectral(
            problem.system(problem.positions, problem.coefficients)):
        raise ValueError(MARK + "method=Spectral() does not apply to this system (the damped "
                         "modes need a full system with discrete dampers); use Auto().")
    if not isinstance(method, Auto):
        return lambda positions, coefficients: np.ones(np.size(positions), bool)
    if not free_vibration:
        return None
    mass = np.asarray(diagonal_of(problem.base.mass))
    omega_max = gershgorin_omega(mass, problem.base.stiffness)

    def exact(positions, coefficients):
        dof = np.clip(np.floor(np.asarray(positions)).astype(int), 1, problem.size)
        return np.asarray(coefficients) / mass[dof - 1] > STIFF_RATIO * omega_max

    return exact


def _golden(f, low: float, high: float, tol: float):
    """Golden-section minimum of f on [low, high] to width ``tol``: (x, f(x), evaluations)."""
    ratio = (np.sqrt(5.0) - 1) / 2
    x1, x2 = high - ratio * (high - low), low + ratio * (high - low)
    f1, f2 = f(x1), f(x2)
    count = 2
    while high - low > tol:
        if f1 <= f2:
            high, x2, f2 = x2, x1, f1
            x1 = high - ratio * (high - low)
            f1 = f(x1)
        else:
            low, x1, f1 = x1, x2, f2
            x2 = low + ratio * (high - low)
            f2 = f(x2)
        count += 1
    return (x1, f1, count) if f1 <= f2 else (x2, f2, count)


def _check_grid(problem, positions, coefficients):
    """The grid's positions (P,) in [1, n] and coefficients (C,) >= 0, checked once, eagerly:
    the evaluations inside map them onto the system unchecked (``with_parameters``)."""
    n = problem.size
    positions = np.atleast_1d(np.asarray(positions, dtype=float))
    coefficients = np.atleast_1d(np.asarray(coefficients, dtype=float))
    if positions.ndim != 1 or not np.all((positions >= 1) & (positions <= n)):
        raise ValueError(MARK + f"positions must be a 1-d array of positions in [1, {n}].")
    if (coefficients.ndim != 1 or coefficients.size < 1
            or not np.all(np.isfinite(coefficients) & (coefficients >= 0))):
        raise ValueError(MARK + "coefficients must be a non-empty 1-d array of finite values "
                         ">= 0.")
    return positions, coefficients


def reduced_grid(problem: DamperProblem, basis, positions, coefficients, *,
                 batch_size: int = 16, progress: bool = False) -> np.ndarray:
    """The reduced model's objective for one damper on a (positions x coefficients) grid.

    ``basis``: (n, r), e.g. ``Solution.stats["basis"]`` of ``ScreenAndCertify``; ``positions``:
    (P,), 1-based in [1, n];
    ``coefficients``: (C,), >= 0. Returns a (P, C) numpy array. For plots: far cheaper than
    ``grid_sweep``.
    """
    if problem.num_dampers != 1:
        raise ValueError(MARK + "reduced_grid places one damper; the problem has "
                         f"{problem.num_dampers}.")
    basis = check_basis(basis, problem.base.size)  # orthonormal (n, r): checked here, once
    positions, coefficients = _check_grid(problem, positions, coefficients)
    values, _ = _evaluate_grid(problem, basis, positions, coefficients, batch_size, progress)
    return values


@dataclasses.dataclass
class GridRun:
    """A brute-force sweep of the full model: ``objective[i, j]`` at ``positions[i]``,
    ``coefficients[j]``, a (P, C) array for (P,) positions (1-based) and (C,) coefficients
    (NaN where a solve failed, counted in ``failed``). ``refined``: for the
    ``refine`` best DOFs, the coefficient refined by golden-section search between the grid
    neighbours of their best; ``best_*`` is the best of grid and refinement. ``exact``: how many
    points the exact evaluator took (see ``grid_sweep``)."""

    positions: np.ndarray
    coefficients: np.ndarray
    objective: np.ndarray
    best_position: float
    best_coefficient: float
    best_objective: float
    failed: int
    seconds: float
    batch_size: int
    method: AbstractMethod
    exact: int
    refined: list
    seconds_refine: float

    def to_json(self) -> dict:
        """A JSON-ready dict (arrays as lists, NaN as None, the method as its repr)."""
        return {f.name: to_plain(repr(self.method) if f.name == "method" else getattr(self, f.name))
                for f in dataclasses.fields(self)}


def grid_sweep(problem: DamperProblem, coefficients, positions=None, *,
               method: AbstractMethod | None = None,
               refine: int = 0, refine_tol: float = 1e-3, batch_size: int = 1,
               progress: bool = False) -> GridRun:
    """The full model's objective for one damper at every position x coefficient of a grid.

    ``coefficients``: (C,), >= 0; ``positions``: (P,), 1-based in [1, n], default every DOF 1..n;
    returns a ``GridRun`` with a (P, C) ``objective``. Points are evaluated ``batch_size``
    at a time with ``jax.vmap`` (one compiled chunk shape; memory bounded by the chunk), with a
    progress bar. On a CPU, ``batch_size=1`` is fastest (a vmapped adaptive solve steps every
    member with the batch's largest step count); on a GPU, use hundreds.

    ``method``: ``Auto()`` (the objective's own evaluator, what the optimiser certifies with: for
    a system with discrete dampers and no load, the closed form from the damped modes; else
    Dopri8 with the energy as one more state, except where the damper's rate c / M_jj exceeds
    10x the highest eigenfrequency, where Dopri8 would be slower than expm and, past
    ``max_steps``, fail: there the exact free-vibration energy, the damped modes where the
    spectral path applies, else matrix exponentials, O(n^3) per point, any stiffness), or
    ``Spectral()``, ``DenseExponential()``, ``ODE(...)``: the ``Energy`` by that method at every
    point (``Energy(method=...)``'s evaluators; free vibration only, except ``ODE``); None is
    ``Auto()``. ``refine`` > 0: the coefficient of the ``refine`` best DOFs
    is then refined by golden-section search in log c (to ``refine_tol``), so that the sweep's
    best does not carry the grid's spacing.
    """
    check_x64()
    if not isinstance(problem, DamperProblem):
        raise ValueError(MARK + f"problem must be a DamperProblem, got {type(problem).__name__}.")
    if problem.num_dampers != 1:
        raise ValueError(MARK + "grid_sweep places one damper; the problem has "
                         f"{problem.num_dampers}.")
    positions, coefficients = _check_grid(problem, coefficients=coefficients,
                                          positions=np.arange(1.0, problem.size + 1)
                                          if positions is None else positions)
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(MARK + f"batch_size must be an integer >= 1, got {batch_size!r}.")
    if isinstance(refine, bool) or not isinstance(refine, int) or refine < 0:
        raise ValueError(MARK + f"refine must be an integer >= 0, got {refine!r}.")
    if not (np.isfinite(refine_tol) and refine_tol > 0):
        raise ValueError(MARK + f"refine_tol must be > 0, got {refine_tol!r}.")
    method = Auto() if method is None else method
    exact = _stiff_rule(problem, method)
    if isinstance(method, ODE):  # its options checked once, eagerly (the points map unchecked)
        options = energy_options(method)
        rtol, atol, adjoint = check_solve_options(options["rtol"], options["atol"],
                                                  options["max_steps"], options["adjoint"])
        method = ODE(rtol=rtol, atol=atol, max_steps=method.max_steps, adjoint=adjoint)
    clock = time.perf_counter()
    values, failed = _evaluate_grid(problem, None, positions, coefficients, batch_size, progress,
                                    exact, method)
    seconds = time.perf_counter() - clock
    if not np.isfinite(values).any():
        raise ValueError(MARK + "grid_sweep: every full solve failed; increase max_steps.")
    exact_points = 0 if exact is None or isinstance(method, ODE) else int(exact(*(
        a.ravel() for a in np.meshgrid(positions, coefficients, indexing="ij"))).sum())
    i, j = np.unravel_index(np.nanargmin(values), values.shape)
    best = (float(positions[i]), float(coefficients[j]), float(values[i, j]))
    refined, clock = [], time.perf_counter()
    positive = coefficients > 0
    logs = np.log(coefficients[positive])
    if refine and logs.size >= 2:
        rows = np.argsort(np.nanmin(np.where(np.isfinite(values), values, np.inf), axis=1))
        for row in rows[:refine]:
            p = float(positions[row])

            def f(log_c, p=p):
                c = float(np.exp(log_c))
                stiff = exact is not None and bool(exact([p], [c])[0])
                return _evaluate_one(problem, p, c, method if stiff else None)

            k = int(np.nanargmin(np.where(np.isfinite(values[row, positive]),
                                          values[row, positive], np.inf)))
            low, high = logs[max(k - 1, 0)], logs[min(k + 1, logs.size - 1)]
            log_c, value, count = _golden(f, low, high, refine_tol)
            refined.append(dict(position=p, coefficient=float(np.exp(log_c)), objective=value,
                                evaluations=count))
            if value < best[2]:
                best = (p, float(np.exp(log_c)), value)
    return GridRun(positions, coefficients, values, *best, int(failed.sum()), seconds,
                       batch_size, method, exact_points, refined, time.perf_counter() - clock)

