"""Damper design as one verb: ``optimise(problem, strategy) -> Solution``.

The problem is a ``DamperDesign``: a system whose dampers are the start, an objective of the
family (``Energy``, ``AverageEnergy``, ``OutputEnergy``, ``H2Norm``, ``Peak``), and what may
move: the coefficients within bounds, the grounded dampers among candidate DOFs
(``positions``), the relative dampers among candidate pairs (``pairs``). The strategy says how
(``AbstractDesignStrategy``, each a final ``eqx.Module`` holding its settings):

* ``Coefficients``: the coefficients at fixed places, full order, a projected quasi-Newton
  search (``ProjectedBFGS``, or ``SpectralProjectedGradient``) in log c (``_viscosity``);
* ``CoordinateDescent``: places among the candidates, one damper at a time, every coefficient
  re-optimised at each accepted move, full order (``_damper_search``);
* ``ScreenAndCertify``: grounded dampers anywhere on the chain, a relaxed search and a screen of
  every DOF on a POD reduced model, the winner polished and certified on the full model
  (``_certify``);
* ``Grid``: one grounded damper at every candidate DOF x coefficient of a grid, full order (or on
  a reduced model: ``basis``), the best DOFs' coefficients refined (``_brute_force``).

Conventions: positions and pairs are 1-based DOFs; the coefficient vector holds the grounded
dampers' coefficients, then the relative dampers', each in the order the system gives them
(``free`` indexes it from 0); coefficients in force x time per length.
"""

import abc
import dataclasses
import enum
import time

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import optax

from .._errors import MARK, check_x64, integer_indices
from .._model.dampers import Dampers
from .._model.parameters import with_parameters
from .._model.system import SecondOrderSystem
from .._objective.family import AbstractObjective, AverageEnergy, Energy, Peak
from .._plain import to_plain
from .._solver.solve import AbstractMethod, Auto
from .damper_search import checked_pairs, checked_positions
from .viscosity import (
    AbstractBoxMinimiser,
    ProjectedBFGS,
    _free_mask,
    check_search,
    checked_bounds,
    checked_objective,
)


class DesignResult(enum.StrEnum):
    """How a design search ended (``Solution.result``); compares equal to its name."""

    converged = "converged"  # its stopping rule met (certified, stationary, no move improves)
    max_iterations = "max_iterations"  # its iteration, sweep or round budget spent first
    failed = "failed"  # it stopped without meeting its rule (a line search failed, stalled)


@dataclasses.dataclass(frozen=True)
class Solution:
    """What ``optimise`` found.

    ``system``: the optimised system (the design's, dampers moved and re-weighted);
    ``positions``: (g,) 1-based DOFs of its grounded dampers; ``pairs``: (p, 2) 1-based DOFs of
    its relative dampers; ``coefficients``: (g + p,) every damper's coefficient, grounded then
    relative; ``value``: the objective there (full order, except where ``stats`` says
    otherwise); ``result``: a ``DesignResult``; ``stats``: counts and times (``evaluations``,
    ``full_solves``, ``seconds``, ``status``, ...) and the strategy's own extras (see each
    strategy); ``history``: the strategy's path.
    """

    system: SecondOrderSystem
    positions: np.ndarray
    pairs: np.ndarray
    coefficients: np.ndarray
    value: float
    result: DesignResult
    stats: dict
    history: list

    def to_json(self) -> dict:
        """A JSON-ready dict (arrays as lists, NaN as None), without the system and the basis."""
        stats = {k: to_plain(v) for k, v in self.stats.items() if k != "basis"}
        return dict(positions=to_plain(self.positions), pairs=to_plain(self.pairs),
                    coefficients=to_plain(self.coefficients), value=to_plain(self.value),
                    result=self.result.value, stats=stats, history=to_plain(self.history))


class DamperDesign(eqx.Module):
    """A damper design problem: a system, an objective, and what moves.

    ``system``: a ``SecondOrderSystem`` with ``GroundedDamper``/``RelativeDamper`` dampers, whose
    places and coefficients are the start. ``objective``: an ``AbstractObjective`` of the family.
    ``coefficients``: the bounds (lower, upper), each a number or one per coefficient (g + p,:
    grounded dampers first, then relative ones); upper None is unbounded; lower = upper holds a
    coefficient (``upper=0`` switches a damper off). ``positions``: the candidate DOFs (1-based)
    of the grounded dampers, None to keep them in place. ``pairs``: the candidate (c, 2) pairs
    (1-based) of the relative dampers, None to keep them. ``free``: 0-based indices into the
    coefficient vector that move, None for all. A design of g grounded dampers is (g,)
    positions and (g,) coefficients (plus the relative dampers' pairs and coefficients).
    """

    system: SecondOrderSystem
    objective: AbstractObjective
    coefficients: tuple
    positions: np.ndarray | None
    pairs: np.ndarray | None
    free: tuple | None = eqx.field(static=True)

    def __init__(self, system: SecondOrderSystem, objective: AbstractObjective, *,
                 coefficients=(0.0, None), positions=None, pairs=None, free=None):
        check_x64()
        if not isinstance(system, SecondOrderSystem) or not isinstance(system.damping, Dampers):
            raise ValueError(MARK + "system must be a SecondOrderSystem with GroundedDamper/"
                             f"RelativeDamper dampers, got {type(system).__name__}"
                             + ("" if not isinstance(system, SecondOrderSystem)
                                else " without discrete dampers") + ".")
        if not isinstance(objective, AbstractObjective):
            raise ValueError(MARK + "objective must be an AbstractObjective (Energy, "
                             "AverageEnergy, OutputEnergy, H2Norm, Peak), got "
                             f"{type(objective).__name__}.")
        size = _coefficient_count(system)
        if isinstance(coefficients, str) or not isinstance(coefficients, tuple | list) or len(
                coefficients) != 2:
            raise ValueError(MARK + "coefficients must be the bounds (lower, upper), each a "
                             f"number or {size} numbers, got {coefficients!r:.60}.")
        self.system, self.objective = system, objective
        self.coefficients = checked_bounds(*coefficients, size)
        n = system.size
        self.positions = None if positions is None else checked_positions(positions, n)
        self.pairs = None if pairs is None else checked_pairs(pairs, n) + 1
        if positions is not None and system.damping.positions.shape[0] == 0:
            raise ValueError(MARK + "positions: the system has no GroundedDamper to move.")
        if pairs is not None and system.damping.pair_count == 0:
            raise ValueError(MARK + "pairs: the system has no RelativeDamper to move.")
        if free is not None:
            _free_mask(free, size)  # checked here, once
            free = tuple(integer_indices(free, "free"))
        self.free = free

    @property
    def lower(self) -> np.ndarray:
        """(g + p,) lower bounds of the coefficients."""
        return self.coefficients[0]

    @property
    def upper(self) -> np.ndarray:
        """(g + p,) upper bounds of the coefficients (inf: none)."""
        return self.coefficients[1]


def _coefficient_count(system) -> int:
    return int(system.damping.coefficients.shape[0] + system.damping.pair_coefficients.shape[0])


class AbstractDesignStrategy(eqx.Module):
    """How ``optimise`` searches a ``DamperDesign``: subclass it and implement ``run``."""

    @abc.abstractmethod
    def run(self, design: DamperDesign) -> Solution:
        """Search ``design``; a ``Solution``."""


def optimise(problem: DamperDesign, strategy: AbstractDesignStrategy) -> Solution:
    """Optimise where the dampers of ``problem`` sit and how strong they are, by ``strategy``
    (``Coefficients``, ``CoordinateDescent``, ``ScreenAndCertify``, ``Grid``)."""
    if not isinstance(problem, DamperDesign):
        raise ValueError(MARK + f"problem must be a DamperDesign, got {type(problem).__name__}.")
    if not isinstance(strategy, AbstractDesignStrategy):
        raise ValueError(MARK + "strategy must be an AbstractDesignStrategy (Coefficients, "
                         "CoordinateDescent, ScreenAndCertify, Grid), got "
                         f"{type(strategy).__name__}.")
    return strategy.run(problem)


def _solution(system, value, result, stats, history) -> Solution:
    damping = system.damping
    coefficients = np.concatenate([np.asarray(damping.coefficients),
                                   np.asarray(damping.pair_coefficients)])
    return Solution(system, np.asarray(damping.positions), np.asarray(damping.pairs) + 1,
                    coefficients, float(value), result, stats, history)


def _with_coefficients(system, coefficients):
    g = int(system.damping.coefficients.shape[0])
    d = jnp.asarray(coefficients, dtype=jnp.float64)
    return with_parameters(system, dict(coefficients=d[:g], relative_coefficients=d[g:]))


def _check_count(name: str, value, low: int = 1) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(MARK + f"{name} must be an integer >= {low}, got {value!r}.")


def _code(status: str, budget: str) -> DesignResult:
    if status.startswith("converged") or status.startswith("nothing to move"):
        return DesignResult.converged
    return DesignResult.max_iterations if status.startswith(budget) else DesignResult.failed


class Coefficients(AbstractDesignStrategy):
    """The coefficients at fixed places, at full order (exact, the spectral path).

    ``minimiser``: ``ProjectedBFGS()`` (default, Bertsekas 1982) or
    ``SpectralProjectedGradient()`` (Li & Tisseur's method), in u = log c, stopped when every
    free coefficient not held at a bound has |c_i dJ/dc_i| / |J| < ``tolerance``, or after
    ``max_iterations``.
    ``stats``: ``iterations``, ``evaluations`` (value-and-gradient pairs), ``seconds``,
    ``gradient`` ((g + p,) dJ/dc at the optimum), ``relative_gradient``, ``status``; ``history``:
    (value, relative gradient) per iteration. The design's ``positions`` and ``pairs`` must be
    None (``CoordinateDescent`` moves dampers).

    ``through``: a Galerkin reduction (``StructuredH2(r)`` for an ``H2Norm``; ``RationalKrylov``,
    ``Modal``, ... for an ``H2Norm`` or ``OutputEnergy``) to search on a reduced model first.
    Its basis Phi is made once, at the start design; the search runs on the Galerkin model of
    each trial design on Phi (the dampers' coefficients enter its projected damping linearly,
    so it is exact in c and differentiable). The same search at full order then starts from
    its optimum, with the reduced search's last inverse-Hessian approximation, and certifies
    it: ``value``, ``gradient`` and ``relative_gradient`` are the full model's, and the result
    is converged only where the full relative gradient is below ``tolerance``. Extra stats:
    ``rank``, ``basis``, ``seconds_offline`` (the reduction), ``reduced_coefficients``,
    ``reduced_value``, ``reduced_iterations``, ``reduced_evaluations``, ``reduced_seconds``,
    ``reduced_status``, ``rom_error`` (the reduced model's relative error of the objective at
    its optimum); ``full_solves`` counts the full evaluations, and ``iterations`` and
    ``history`` are the full-order search's.
    """

    minimiser: AbstractBoxMinimiser = ProjectedBFGS()
    tolerance: float = eqx.field(static=True, default=1e-6)
    max_iterations: int = eqx.field(static=True, default=200)
    progress: bool = eqx.field(static=True, default=False)
    through: object = None

    def __check_init__(self):
        from .._rom.base import AbstractIOReduction, AbstractReduction

        check_search(self.minimiser, self.tolerance)
        _check_count("max_iterations", self.max_iterations, 0)
        if self.through is not None and not isinstance(self.through, AbstractReduction
                                                       | AbstractIOReduction):
            raise ValueError(MARK + "through must be None or a Galerkin reduction "
                             "(StructuredH2, RationalKrylov, Modal, Projection, ...), got "
                             f"{type(self.through).__name__}.")

    def run(self, design: DamperDesign) -> Solution:
        """The optimal coefficients of ``design``."""
        from .viscosity import search_coefficients

        if design.positions is not None or design.pairs is not None:
            raise ValueError(MARK + "positions/pairs must be None for Coefficients (it keeps "
                             "every damper in place); CoordinateDescent moves them.")
        objective = checked_objective(design.system, design.objective)
        if self.through is not None:
            return self._run_through(design, objective)
        run = search_coefficients(design.system, objective, free=design.free,
                                  lower=design.lower, upper=design.upper,
                                  tolerance=self.tolerance, max_iterations=self.max_iterations,
                                  minimiser=self.minimiser, progress=self.progress)
        stats = dict(iterations=run.iterations, evaluations=run.evaluations, full_solves=0,
                     seconds=run.seconds, gradient=run.gradient,
                     relative_gradient=run.relative_gradient, status=run.status)
        result = (DesignResult.converged if run.converged
                  else _code(run.status, "max_iterations"))
        return _solution(_with_coefficients(design.system, run.coefficients), run.value, result,
                         stats, run.history)

    def _run_through(self, design: DamperDesign, objective) -> Solution:
        """The search on the Galerkin model on ``through``'s basis (made at the start design),
        then the full-order search from its optimum (module docstring of ``Coefficients``)."""
        from .._objective.family import H2Norm
        from .._rom.base import AbstractIOReduction
        from .._rom.io_model import IOModel
        from .._rom.reduce import reduce
        from .viscosity import THROUGH_REDUCED, search_coefficients

        if not isinstance(objective, THROUGH_REDUCED):
            raise ValueError(MARK + "through: a search through a reduced model takes an H2Norm "
                             f"or OutputEnergy objective, got {type(objective).__name__}.")
        by_map = isinstance(self.through, AbstractIOReduction)
        if by_map and not isinstance(objective, H2Norm):
            raise ValueError(MARK + f"through: {type(self.through).__name__} reduces an input-"
                             "output map: it takes an H2Norm objective (its inputs and outputs), "
                             f"got {type(objective).__name__}.")
        start = time.perf_counter()
        if by_map:
            reduced = reduce(IOModel(design.system, objective.inputs, objective.cx,
                                     objective.cv), self.through)
            if not isinstance(reduced, IOModel):
                raise ValueError(MARK + f"through: {type(self.through).__name__} gives a dense "
                                 "model, whose matrices do not keep the dampers; use a Galerkin "
                                 "reduction (StructuredH2, RationalKrylov, Modal, ...).")
            basis = reduced.model.basis
        else:
            basis = reduce(design.system, self.through).basis
        offline = time.perf_counter() - start
        options = dict(free=design.free, lower=design.lower, upper=design.upper,
                       tolerance=self.tolerance, minimiser=self.minimiser,
                       max_iterations=self.max_iterations, progress=self.progress)
        rom = search_coefficients(design.system, objective, basis=basis, **options)
        if self.progress:
            print(f"  reduced model ({basis.shape[1]} DOFs): optimum {rom.value:.12g}; the "
                  "full-order search from there:", flush=True)
        run = search_coefficients(_with_coefficients(design.system, rom.coefficients),
                                  objective, state=rom.state, **options)
        stats = dict(iterations=run.iterations, evaluations=run.evaluations,
                     full_solves=run.evaluations, seconds=time.perf_counter() - start,
                     seconds_offline=offline, gradient=run.gradient,
                     relative_gradient=run.relative_gradient, status=run.status,
                     rank=int(basis.shape[1]), basis=basis,
                     reduced_coefficients=rom.coefficients, reduced_value=rom.value,
                     reduced_iterations=rom.iterations, reduced_evaluations=rom.evaluations,
                     reduced_seconds=rom.seconds, reduced_status=rom.status,
                     rom_error=abs(rom.value - run.history[0][0]) / abs(run.history[0][0]))
        result = DesignResult.converged if run.converged else _code(run.status, "max_iterations")
        return _solution(_with_coefficients(design.system, run.coefficients), run.value, result,
                         stats, run.history)


class CoordinateDescent(AbstractDesignStrategy):
    """Places among the candidates (``DamperDesign.positions``, ``pairs``), one damper at a
    time, every coefficient re-optimised (``Coefficients``'s search) at each accepted move, at
    full order.

    Each sweep screens every free candidate place of each movable damper (its coefficient at 0.1,
    1 and 10 times its current value, the others held) and polishes the ``keep`` best; sweeps
    repeat until none moves a damper (a coordinate-wise minimum) or ``max_sweeps``. ``starts``:
    the system's own placement, then ``starts - 1`` random placements (``seed``); the best wins.
    ``minimiser``, ``tolerance``: the polish's, as in ``Coefficients``. ``stats``: ``sweeps``,
    ``evaluations`` (screening values), ``polishes``, ``seconds``, ``start_values``,
    ``status``; ``history``: (sweep, index in the coefficient vector, place, value) per
    accepted move of the best start.
    """

    keep: int = eqx.field(static=True, default=2)
    max_sweeps: int = eqx.field(static=True, default=10)
    starts: int = eqx.field(static=True, default=1)
    seed: int = eqx.field(static=True, default=0)
    minimiser: AbstractBoxMinimiser = ProjectedBFGS()
    tolerance: float = eqx.field(static=True, default=1e-6)
    progress: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        for name in ("keep", "max_sweeps", "starts"):
            _check_count(name, getattr(self, name))
        _check_count("seed", self.seed, 0)
        check_search(self.minimiser, self.tolerance)

    def run(self, design: DamperDesign) -> Solution:
        """The best placement of ``design`` found."""
        from .damper_search import search_places

        objective = checked_objective(design.system, design.objective)
        run = search_places(design.system, objective, candidates=design.positions,
                            pair_candidates=None if design.pairs is None else design.pairs - 1,
                            keep=self.keep, max_sweeps=self.max_sweeps, starts=self.starts,
                            seed=self.seed, free=design.free, lower=design.lower,
                            upper=design.upper, tolerance=self.tolerance,
                            minimiser=self.minimiser,
                            progress=self.progress)
        system = design.system
        g = int(system.damping.positions.shape[0])
        moved = with_parameters(system, dict(
            positions=jnp.asarray(run.positions, jnp.float64),
            coefficients=jnp.asarray(run.coefficients[:g]),
            relative_coefficients=jnp.asarray(run.coefficients[g:])))
        moved = eqx.tree_at(lambda s: s.damping.pairs, moved, jnp.asarray(run.pairs - 1))
        stats = dict(sweeps=run.sweeps, evaluations=run.evaluations, polishes=run.polishes,
                     full_solves=0, seconds=run.seconds, start_values=run.start_values,
                     status=run.status)
        return _solution(moved, run.value, _code(run.status, "max_sweeps"), stats, run.history)


class _ReducedSettings(eqx.Module):
    """What the reduced-order strategies need besides the objective: the time grid of the
    snapshots, their excitation where the objective has none, and the full solves' settings."""

    ts: object
    x0: object
    v0: object
    load: object
    rtol: float
    max_steps: int


def _damper_problem(design: DamperDesign, strategy: str, settings: _ReducedSettings, **pod):
    """The private ``DamperProblem`` of a design: one grounded damper design at DOFs (the
    reduced-order strategies), its objective as one of ``_design.OBJECTIVES``."""
    from .problem import DamperProblem

    if design.pairs is not None or design.free is not None:
        raise ValueError(MARK + f"pairs/free must be None for {strategy} (it places the grounded "
                         "dampers; relative dampers stay as they are).")
    size = _coefficient_count(design.system)
    if np.any(design.lower != 0) or np.any(np.isfinite(design.upper)):
        raise ValueError(MARK + f"coefficients bounds must be (0, None) for {strategy}, got "
                         f"lower {design.lower.tolist()}, upper {design.upper.tolist()} "
                         f"({size} coefficients).")
    o = design.objective
    ts, x0, v0, load = settings.ts, settings.x0, settings.v0, settings.load
    own = {}
    if isinstance(o, Energy | Peak):
        if x0 is not None or v0 is not None or load is not None:
            raise ValueError(MARK + f"x0/v0/load must be None for {strategy}: the objective "
                             f"{type(o).__name__} carries its excitation.")
        x0, v0, load = o.x0, o.v0, o.load
    if isinstance(o, Energy):
        horizon = float(o.horizon)
        ts = np.linspace(0.0, horizon, 401) if ts is None else np.asarray(ts, dtype=float)
        if ts.ndim != 1 or ts.shape[0] < 2 or not np.isclose(ts[-1] - ts[0], horizon,
                                                               rtol=1e-12, atol=0.0):
            raise ValueError(MARK + f"ts must be a grid spanning the Energy horizon {horizon} "
                             f"(ts[-1] - ts[0]), got {settings.ts!r:.60}.")
        own = dict(objective="energy")
    elif isinstance(o, Peak):
        if ts is not None:
            raise ValueError(MARK + f"ts must be None for {strategy} with Peak: the objective "
                             "carries its time grid.")
        ts = o.ts
        own = dict(objective="peak", dof=o.dof, order=o.order)
    elif isinstance(o, AverageEnergy):
        if ts is None:
            raise ValueError(MARK + f"ts must be given for {strategy} with AverageEnergy: the "
                             "time grid of the snapshots (and x0, v0 or load their excitation).")
        own = dict(objective="average_energy", lowest=o.lowest)
    else:
        raise ValueError(MARK + f"objective must be Energy, AverageEnergy or Peak for "
                         f"{strategy}, got {type(o).__name__}.")
    if design.system.damping.positions.shape[0] == 0:
        raise ValueError(MARK + f"system: {strategy} places grounded dampers; it has none.")
    return DamperProblem(design.system, ts, x0, v0, load, rtol=settings.rtol,
                         max_steps=settings.max_steps, **own, **pod)


class ScreenAndCertify(AbstractDesignStrategy):
    """Grounded dampers anywhere on the chain, searched on a POD reduced model (the Galerkin
    model, eq. 3.4) and certified on the full one (``positions`` of the design: every DOF
    1..n).

    1. a relaxed search (several dampers, or ``split``: between DOFs) from ``starts`` starts
       with ``optimizer`` (an optax ``GradientTransformation``, default ``optax.adam(0.1)``)
       for ``iterations`` steps on unconstrained variables; 2. every DOF screened on the reduced
       model; 3. the ``keep`` best polished (L-BFGS in log c, ``polish_iterations``); 4. the
       winner's objective and log-sensitivities compared with the full model's (``certify=
       "full"``) or estimated (``"estimate"``, no full solve, ``Energy`` of free vibration
       only); beyond ``tolerance`` the basis is enriched and the rounds go on, up to
       ``max_rounds``.

    The POD basis: full-model displacements on ``ts`` (default for ``Energy``: 401 times over
    its horizon; ``Peak``: its own grid; ``AverageEnergy``: required, with the excitation
    ``x0``, ``v0`` or ``load``) in the window ``snapshots`` (default all of ``ts``), its rank
    from the pseudo-energy fraction ``energy`` (eq. 3.7, ``criterion`` as in
    ``rank_for_energy``) unless ``rank`` is given. ``rtol``, ``max_steps``: the full Dopri8
    solves'. ``stats``: ``full_solves``, ``seconds``, ``seconds_full``, ``rounds``, ``rank``,
    ``basis`` ((n, r)), ``certified``, ``certified_by``, ``rom_error``, ``gradient_error``,
    ``objective_reduced``, ``gradient``, ``initial_objective``, ``relaxed_*``, ``ranking``,
    ``messages``, ``status``; ``history``: every phase of every round. The result is
    ``converged`` when certified.
    """

    ts: object = None
    x0: object = None
    v0: object = None
    load: object = None
    snapshots: tuple | None = eqx.field(static=True, default=None)
    energy: float = eqx.field(static=True, default=0.9999)
    criterion: str = eqx.field(static=True, default="paper")
    rank: int | None = eqx.field(static=True, default=None)
    rtol: float = eqx.field(static=True, default=1e-8)
    max_steps: int = eqx.field(static=True, default=100_000)
    starts: object = 8
    optimizer: optax.GradientTransformation | None = eqx.field(static=True, default=None)
    iterations: int = eqx.field(static=True, default=80)
    split: bool = eqx.field(static=True, default=False)
    keep: int = eqx.field(static=True, default=4)
    polish_iterations: int = eqx.field(static=True, default=20)
    tolerance: float = eqx.field(static=True, default=1e-4)
    max_rounds: int = eqx.field(static=True, default=4)
    seed: int = eqx.field(static=True, default=0)
    certify: str = eqx.field(static=True, default="full")
    progress: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        if self.optimizer is not None and not isinstance(self.optimizer,
                                                         optax.GradientTransformation):
            raise ValueError(MARK + "optimizer must be an optax GradientTransformation (e.g. "
                             f"optax.adam(0.1)), got {type(self.optimizer).__name__}.")
        if self.certify not in ("full", "estimate"):
            raise ValueError(MARK + f"certify must be 'full' or 'estimate', got "
                             f"{self.certify!r}.")

    def run(self, design: DamperDesign) -> Solution:
        """The certified design of ``design``."""
        from .certify import screen_and_certify

        n = design.system.size
        if design.positions is None or not np.array_equal(design.positions,
                                                          np.arange(1.0, n + 1)):
            raise ValueError(MARK + f"positions must be every DOF 1..{n} for ScreenAndCertify "
                             "(it searches the whole chain), e.g. positions=range(1, n + 1).")
        settings = _ReducedSettings(self.ts, self.x0, self.v0, self.load, self.rtol,
                                    self.max_steps)
        problem = _damper_problem(design, "ScreenAndCertify", settings,
                                  snapshots=self.snapshots, energy=self.energy,
                                  criterion=self.criterion, rank=self.rank)
        run = screen_and_certify(problem, starts=self.starts, optimizer=self.optimizer,
                                 iterations=self.iterations, split=self.split, keep=self.keep,
                                 polish_iterations=self.polish_iterations,
                                 tolerance=self.tolerance, max_rounds=self.max_rounds,
                                 seed=self.seed, certify=self.certify, progress=self.progress)
        system = problem.system(jnp.asarray(run.positions), jnp.asarray(run.coefficients))
        stats = {f.name: getattr(run, f.name) for f in dataclasses.fields(run)
                 if f.name not in ("positions", "coefficients", "objective", "history")}
        stats["evaluations"] = None  # the relaxed searches' steps are in ``history``
        result = (DesignResult.converged if run.certified
                  else DesignResult.max_iterations)
        return _solution(system, run.objective, result, stats, run.history)


class Grid(AbstractDesignStrategy):
    """One grounded damper at every candidate DOF (``DamperDesign.positions``, 1-based) x each
    of ``coefficients`` ((C,), >= 0), at full order (brute force, the independent check of
    ``ScreenAndCertify``), or on the Galerkin model (eq. 3.4) of ``basis`` ((n, r), far cheaper,
    for plots).

    ``refine`` > 0: the coefficient of the ``refine`` best DOFs then refined by golden-section
    search in log c (to ``refine_tol``; full order only). ``method``, ``solve``'s method objects
    as ``Energy(method=...)`` takes them: ``Auto()`` (default: the objective's own evaluator,
    the exact free-vibration energy where the damper's rate c / M_jj makes Dopri8 stiff),
    ``Spectral()`` (the damped modes), ``DenseExponential()`` (matrix exponentials) or
    ``ODE(rtol=..., ...)`` (Dopri8), each the ``Energy`` at every point (free vibration only,
    except ``ODE``). ``batch_size`` points per compiled chunk (``jax.vmap``). ``ts``, ``x0``,
    ``v0``, ``load``, ``rtol``, ``max_steps``: as in ``ScreenAndCertify`` (``Auto()``'s
    Dopri8). ``stats``: ``grid`` ((P, C) objective, NaN where a solve failed), ``positions``,
    ``coefficients``, ``failed``, ``exact`` (points by the closed forms of ``method``),
    ``refined``, ``evaluations``, ``seconds``, ``seconds_refine``, ``method``; the result is
    ``converged`` (the grid is complete).
    """

    coefficients: object
    refine: int = eqx.field(static=True, default=0)
    refine_tol: float = eqx.field(static=True, default=1e-3)
    method: AbstractMethod = Auto()
    batch_size: int = eqx.field(static=True, default=1)
    basis: object = None
    ts: object = None
    x0: object = None
    v0: object = None
    load: object = None
    rtol: float = eqx.field(static=True, default=1e-8)
    max_steps: int = eqx.field(static=True, default=100_000)
    progress: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        _check_count("refine", self.refine, 0)
        _check_count("batch_size", self.batch_size)
        if not (np.isfinite(self.refine_tol) and self.refine_tol > 0):
            raise ValueError(MARK + f"refine_tol must be > 0, got {self.refine_tol!r}.")
        if not isinstance(self.method, AbstractMethod):
            raise ValueError(MARK + "method must be Auto(), Spectral(), DenseExponential() or "
                             f"ODE(...), got {self.method!r}.")
        if self.basis is not None and self.refine:
            raise ValueError(MARK + "refine must be 0 on a reduced model (basis given).")

    def run(self, design: DamperDesign) -> Solution:
        """The grid of ``design``'s objective and its best point."""
        from .brute_force import grid_sweep, reduced_grid

        if design.positions is None:
            raise ValueError(MARK + "positions must be the candidate DOFs of the damper for "
                             "Grid, got None.")
        if design.system.damping.positions.shape[0] != 1:
            raise ValueError(MARK + "system: Grid places one grounded damper; it has "
                             f"{design.system.damping.positions.shape[0]}.")
        settings = _ReducedSettings(self.ts, self.x0, self.v0, self.load, self.rtol,
                                    self.max_steps)
        problem = _damper_problem(design, "Grid", settings)
        positions = design.positions
        if self.basis is not None:
            import time

            clock = time.perf_counter()
            coefficients = np.atleast_1d(np.asarray(self.coefficients, dtype=float))
            values = reduced_grid(problem, self.basis, positions, coefficients,
                                  batch_size=self.batch_size, progress=self.progress)
            if not np.isfinite(values).any():
                raise ValueError(MARK + "Grid: every reduced evaluation failed.")
            i, j = np.unravel_index(np.nanargmin(values), values.shape)
            best = (float(positions[i]), float(coefficients[j]), float(values[i, j]))
            stats = dict(grid=values, positions=positions, coefficients=coefficients,
                         failed=int(np.isnan(values).sum()), evaluations=values.size,
                         full_solves=0, seconds=time.perf_counter() - clock, reduced=True,
                         status="complete (reduced model)")
        else:
            run = grid_sweep(problem, self.coefficients, positions, method=self.method,
                             refine=self.refine, refine_tol=self.refine_tol,
                             batch_size=self.batch_size, progress=self.progress)
            best = (run.best_position, run.best_coefficient, run.best_objective)
            evaluations = run.objective.size + sum(r["evaluations"] for r in run.refined)
            stats = dict(grid=run.objective, positions=run.positions,
                         coefficients=run.coefficients, failed=run.failed, exact=run.exact,
                         refined=run.refined, evaluations=evaluations, full_solves=evaluations,
                         seconds=run.seconds, seconds_refine=run.seconds_refine,
                         batch_size=run.batch_size, method=repr(run.method), reduced=False,
                         status="complete")
        system = problem.system(jnp.asarray([best[0]]), jnp.asarray([best[1]]))
        return _solution(system, best[2], DesignResult.converged, stats, [])
