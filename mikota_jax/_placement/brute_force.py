"""Brute force: the full (or reduced) objective of one damper on a grid of designs, via ``sweep``.

The algorithm of the ``Grid`` strategy (``optimise``).

``grid_sweep`` evaluates the full model at every (position, coefficient) of a grid -- the
independent check of ``ScreenAndCertify`` -- and refines the coefficient of the best DOFs by
golden-section search in log c; ``reduced_grid`` does the same on the reduced model, for
plots. The grid goes through ``mikota_jax.sweep`` (chunked, sharded over the devices, one compile
per chunk shape); a failed point is reported by its flag and becomes NaN here.

Evaluators: the objective's own (``Energy``: the closed form from the damped modes where the
spectral path applies, else Dopri8 with the energy as one more state) or the exact
free-vibration energy (the damped modes where the spectral path applies, else matrix
exponentials, O(n^3), any stiffness). Where Dopri8 would run, a damper whose own rate c / M_jj
exceeds 10x the highest eigenfrequency makes it stiff (slow, and past ``max_steps`` failing);
"auto" sends those points to the exact evaluator.

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
from .._objective.functions import integrated_energy_exact_with_result
from .._plain import to_plain
from .._solver.select import gershgorin_omega
from .._sweep import sweep
from .objective import objective_function, reduced_form
from .problem import DamperProblem, Energy


class _PointObjective(eqx.Module):
    """One design point {"positions": (), "coefficients": ()} -> its value, finiteness and failure.

    Reduced (``basis``) or full (None); ``exact``: the full model's free-vibration energy by
    matrix exponentials. ``sweep`` refuses non-finite results, so a failed or non-finite value is
    returned as 0 with its flags and turned into NaN on the host.
    """

    problem: DamperProblem
    basis: jax.Array | None
    exact: bool = eqx.field(static=True)

    def __call__(self, point):
        problem = self.problem
        positions, coefficients = point["positions"][None], point["coefficients"][None]
        if self.exact:
            horizon = problem.ts[-1] - problem.ts[0]
            value, result = integrated_energy_exact_with_result(
                problem.system(positions, coefficients), horizon, problem.x0, problem.v0)
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
                     exact=None):
    """Objective at the points (p_k, c_k) through ``sweep``, ``batch_size`` per compiled chunk;
    ``exact``: a mask of points for the exact evaluator. (values with NaN where failed, failed)."""
    points_p, points_c = np.asarray(points_p, float), np.asarray(points_c, float)
    exact = np.zeros(points_p.size, bool) if exact is None else np.asarray(exact, bool)
    values, failed = np.full(points_p.size, np.nan), np.zeros(points_p.size, bool)
    count = len(jax.devices())
    chunk = -(-batch_size // count) * count  # sweep shards a chunk over every device
    for flag in (False, True):
        index = np.flatnonzero(exact == flag)
        if index.size == 0:
            continue
        function = _PointObjective(problem, basis, flag)
        # matrix exponentials: under vmap every Pade branch of expm is computed, so in turn
        batch = "map" if flag or basis is not None else "vmap"
        out = sweep(function, dict(positions=points_p[index], coefficients=points_c[index]),
                    chunk_size=chunk, batch=batch, progress=progress)
        values[index] = np.where(out["finite"], out["value"], np.nan)
        failed[index] = out["failed"]
    return np.where(failed, np.nan, values), failed


def _evaluate_one(problem, position: float, coefficient: float, exact: bool) -> float:
    """One design's full-model objective (inf where it fails): a golden-section step.

    A sequential search evaluates one point at a time, so it calls the compiled point function
    directly: ``sweep`` would re-trace its function (``eval_shape``) on every call."""
    out = _point(_PointObjective(problem, None, exact),
                 dict(positions=jnp.asarray(position), coefficients=jnp.asarray(coefficient)))
    value = float(out["value"]) if bool(out["finite"]) and not bool(out["failed"]) else np.inf
    return value


def _evaluate_grid(problem, basis, positions, coefficients, batch_size: int, progress: bool,
                   exact=None):
    """``_evaluate_points`` on the grid positions x coefficients, as (P, C) arrays."""
    grid_p, grid_c = (a.ravel() for a in np.meshgrid(positions, coefficients, indexing="ij"))
    values, failed = _evaluate_points(problem, basis, grid_p, grid_c, batch_size, progress,
                                      None if exact is None else exact(grid_p, grid_c))
    shape = (len(positions), len(coefficients))
    return values.reshape(shape), failed.reshape(shape)




def _stiff_rule(problem: DamperProblem, method: str):
    """For ``grid_sweep``: which (positions, coefficients) the exact evaluator takes.

    "auto": the free-vibration energy of a damper whose own rate c / M_jj exceeds 10x the
    Gershgorin bound of the highest eigenfrequency (there the explicit Dopri8 is stiff and slow,
    and past ``max_steps`` fails); "exact": every point; "ode": none.
    """
    if method not in ("auto", "exact", "ode"):
        raise ValueError(MARK + f"method must be 'auto', 'exact' or 'ode', got {method!r}.")
    exact_possible = isinstance(problem.objective, Energy) and problem.load is None
    if method == "exact" and not exact_possible:
        raise ValueError(MARK + "method='exact' computes the free-vibration energy only "
                         "(objective 'energy', no load).")
    if method == "ode" or not exact_possible:
        return None
    mass = np.asarray(diagonal_of(problem.base.mass))
    omega_max = gershgorin_omega(mass, problem.base.stiffness)

    def exact(positions, coefficients):
        if method == "exact":
            return np.ones(np.size(positions), bool)
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
    method: str
    exact: int
    refined: list
    seconds_refine: float

    def to_json(self) -> dict:
        """A JSON-ready dict (arrays as lists, NaN as None)."""
        return {f.name: to_plain(getattr(self, f.name)) for f in dataclasses.fields(self)}


def grid_sweep(problem: DamperProblem, coefficients, positions=None, *, method: str = "auto",
               refine: int = 0, refine_tol: float = 1e-3, batch_size: int = 1,
               progress: bool = False) -> GridRun:
    """The full model's objective for one damper at every position x coefficient of a grid.

    ``coefficients``: (C,), >= 0; ``positions``: (P,), 1-based in [1, n], default every DOF 1..n;
    returns a ``GridRun`` with a (P, C) ``objective``. Points are evaluated ``batch_size``
    at a time with ``jax.vmap`` (one compiled chunk shape; memory bounded by the chunk), with a
    progress bar. On a CPU, ``batch_size=1`` is fastest (a vmapped adaptive solve steps every
    member with the batch's largest step count); on a GPU, use hundreds.

    ``method``: "ode" (the objective's own evaluator, what the optimiser certifies with: for a
    system with discrete dampers and no load, the closed form from the damped modes; else
    Dopri8 with the energy as one more state), "exact" (the free-vibration energy: the damped
    modes where the spectral path applies, else matrix exponentials, O(n^3) per point, any
    stiffness) or "auto": exact where the damper's rate c / M_jj exceeds 10x the highest
    eigenfrequency (where Dopri8 would be slower than expm and, past ``max_steps``, fail), the
    objective's own evaluator elsewhere. For a chain with discrete dampers and no load all three
    compute the same closed form. ``refine`` > 0: the coefficient of the ``refine`` best DOFs
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
    exact = _stiff_rule(problem, method)
    clock = time.perf_counter()
    values, failed = _evaluate_grid(problem, None, positions, coefficients, batch_size, progress,
                                    exact)
    seconds = time.perf_counter() - clock
    if not np.isfinite(values).any():
        raise ValueError(MARK + "grid_sweep: every full solve failed; increase max_steps.")
    exact_points = 0 if exact is None else int(exact(*(a.ravel() for a in np.meshgrid(
        positions, coefficients, indexing="ij"))).sum())
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
                return _evaluate_one(problem, p, c, stiff)

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

