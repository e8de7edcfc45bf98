"""Certified damper placement: search on the reduced model, certify on the full one.

The algorithm of the ``ScreenAndCertify`` strategy (``optimise``).

The design is (positions, coefficients) of the problem's grounded dampers; any relative dampers of
the chain stay as they are. Gradients are taken through the reduced model with its POD basis held
fixed (no derivative through the SVD), and the optimum is certified on the full model:

1. *relaxed search* (with ``split=True``, and to start several dampers): several starts spread
   over the chain, optax (Adam or L-BFGS) on unconstrained variables, position = 1 + (n - 1)
   sigmoid(u) in [1, n] and coefficient = c_ref exp(w) >= 0. Between DOFs a damper is split
   linearly over its neighbours (``Dampers``): a different device, which the search prefers.
2. *screening* (realisable designs, the default): the objective over the DOFs is rugged (Section
   5: J(4) = 724, J(6) = 859, J(7) = 801 with c re-optimised at each), so no relaxation points
   to the best DOF (the relaxed optimum sat at p = 7.85). Every DOF is screened on the reduced
   model with three coefficients around its local scale 2 sqrt(K_jj M_jj) (a parabola in log c
   estimates the best); several dampers are screened one at a time from the rounded relaxed
   optimum.
3. *polish*: the ``keep`` best screened designs get their coefficients optimised (L-BFGS in
   log c, positions fixed); the best wins.
4. *certification*: the full model's objective and coefficient gradient at the design are compared
   with the reduced model's. If they disagree beyond ``tolerance``, the basis is enriched with
   POD modes of a full simulation at that design (trust-region reduced-basis style) and the
   screening (of the 4 ``keep`` best DOFs) and polish run again. With ``certify="estimate"``
   the hierarchical a posteriori estimates of |J - J_r| and of the log-sensitivities' error
   (``HierarchicalEstimator`` and its ``gradient``: J_r and dJ_r against a Galerkin model on
   the basis + low modes + the design's damper moments; Hain, Ohlberger, Radic & Urban, Adv.
   Comput. Math. 45 (2019)) decide instead, with no full solve: the basis is enriched (by one
   full simulation) only where an estimate exceeds ``tolerance``. The estimates rest on a
   saturation assumption (checked on 1000 designs in ``docs/notes/hierarchical.md`` and
   ``docs/notes/hierarchical_gradient.md``), not on a proof. The ``keep`` polished designs
   are estimated too, so the result says whether the winner beats them by more than the
   estimates (the ranking certified, not only the value).

"Certified" means the reduced model is accurate (to ``tolerance``) at the design returned, which
is the best the reduced model found; the full sweep (``Grid``) is the independent check
that it is the best DOF (``benchmarks/placement.py``). Phases 1-3 live in ``_search.py``, the
objectives in ``_design.py``.
"""

import dataclasses
import time

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._errors import MARK, RESULTS, check_x64
from .._estimation.estimator import HierarchicalEstimator
from .._plain import to_plain
from .._rom.base import POD, pod_basis, snapshot_window
from .._rom.classic import extend_basis
from .._solver.ode import simulate_with_result
from .problem import DamperProblem, Energy
from .search import (
    OPTIMIZERS,
    best_index,
    default_starts,
    last_finite,
    phase_record,
    realisable_candidates,
    run_search,
    to_unconstrained,
    value_and_gradient,
)

# the relaxed search's default: Adam, step 0.1 on the unconstrained variables (one object, so
# that its compiled step is reused from call to call)
DEFAULT_OPTIMIZER = optax.adam(0.1)
LBFGS = OPTIMIZERS["lbfgs"](None)  # the polish's, as an object (its learning rate is unused)
_LEARNING_RATE = 0.1  # the polish's L-BFGS, by name, takes it and ignores it


@eqx.filter_jit
def _snapshots(problem, positions, coefficients, count: int):
    """The full model's displacements at the first ``count`` times of the grid, (count, n).

    diffrax checks ``SaveAt(ts)`` with ``eqx.error_if`` inside its own jit, so this executable
    holds that one host callback (the check passes: the grid was checked when the problem was
    built)."""
    model = problem.system(positions, coefficients)
    trajectory, result = simulate_with_result(
        model, problem.ts[:count], problem.x0, problem.v0, problem.load, problem.rtol,
        problem.rtol * 1e-2, solver=diffrax.Dopri8(), dofs=tuple(range(1, problem.size + 1)),
        displacement=True, velocity=False, max_steps=problem.max_steps, progress=False,
        adjoint=diffrax.RecursiveCheckpointAdjoint())
    return trajectory.displacement, result


def _snapshot_modes(problem, positions, coefficients):
    """POD modes of a full simulation at a design (the scene's window and rank rule)."""
    ts = np.asarray(problem.ts)
    # solve only up to the window's end, by the reduction stage's own window rule
    count = int(np.flatnonzero(snapshot_window(ts, problem.snapshots))[-1]) + 1
    displacement, result = _snapshots(problem, positions, coefficients, count)
    if result != RESULTS.successful:
        raise ValueError(MARK + "the full-model snapshot solve failed (max_steps reached or "
                         "non-finite states) at the design "
                         f"positions={np.asarray(positions)}, "
                         f"coefficients={np.asarray(coefficients)}; increase max_steps.")
    request = POD(problem.snapshots, energy=problem.energy, rank=problem.rank,
                  criterion=problem.criterion)
    return pod_basis(displacement, jnp.asarray(ts[:count]), request, cap_rank=True)[0]


@dataclasses.dataclass
class CertifiedRun:
    """What ``screen_and_certify`` found: the damper design, certified on the full model.

    ``positions``/``coefficients``: the design, (g,) each, 1-based positions (at DOFs unless
    ``split``); ``gradient``: the full model's dJ/dc there, (g,); ``basis``: the final (n, r) POD
    basis (``rank`` r), e.g. for ``Grid(basis=...)``; ``objective``: the full
    model's objective there, ``objective_reduced`` the reduced model's, ``rom_error`` their
    relative difference and ``gradient_error`` that of the logarithmic coefficient sensitivities
    c dJ/dc / J (and dJ/dp / J for split designs). ``full_solves`` counts full-model solves
    (snapshot simulations and certifications, each with its forward-mode tangents); ``history``
    the path of every phase (relaxed search, screen, polish) of every round; ``relaxed_*`` the best
    relaxed design (None where no relaxed search ran: one damper at a DOF).

    ``certified_by``: "full model" or "estimate" (``certify``). Certified by the estimate, no
    full solve was taken there: ``objective`` is the reduced model's J_r, ``rom_error`` the
    estimate of |J - J_r| / J, ``gradient`` the reduced model's dJ/dc and ``gradient_error``
    the estimate of the log-sensitivity error; ``ranking`` then says whether the winner's
    J_r + estimate lies below J_r - estimate of every other polished design (None where it was
    not checked).
    """

    positions: np.ndarray
    coefficients: np.ndarray
    objective: float
    objective_reduced: float
    rom_error: float
    gradient_error: float
    gradient: np.ndarray
    certified: bool
    status: str
    rounds: int
    full_solves: int
    rank: int
    relaxed_positions: np.ndarray | None
    relaxed_coefficients: np.ndarray | None
    relaxed_objective: float | None
    initial_objective: float
    history: list
    seconds: float
    seconds_full: float
    messages: list
    certified_by: str = "full model"
    ranking: bool | None = None
    basis: np.ndarray | None = dataclasses.field(default=None, repr=False)  # final POD basis

    def to_json(self) -> dict:
        """A JSON-ready dict (arrays as lists, NaN as None), without the basis."""
        return {f.name: to_plain(getattr(self, f.name)) for f in dataclasses.fields(self)
                if f.name != "basis"}


def screen_and_certify(problem: DamperProblem, *, starts: int | np.ndarray = 8,
                       optimizer=None, iterations: int = 80, split: bool = False,
                       keep: int = 4, polish_iterations: int = 20, tolerance: float = 1e-4,
                       max_rounds: int = 4, seed: int = 0, certify: str = "full",
                       progress: bool = False) -> CertifiedRun:
    """Place the problem's grounded dampers: gradients through the ROM, certified on the full model.

    The ROM is the Galerkin model (eq. 3.4) on a POD basis (eqs. 3.5-3.8) of full-model snapshots;
    returns a ``CertifiedRun`` with (g,) positions (1-based) and coefficients. See the module
    docstring for the phases. ``starts``: the number of starts of the relaxed
    search (the problem's design, then spread over the chain) or an (S, g) array of start
    positions; ``optimizer``: its optax ``GradientTransformation`` on the unconstrained
    variables (default ``optax.adam(0.1)``; an L-BFGS with a line search gets the value and its
    function too); ``iterations`` its length. The relaxed search runs for ``split=True``
    (dampers may sit between DOFs, split linearly over the neighbours) and for several dampers;
    one damper at a DOF is found by screening every DOF. ``keep``: how many screened designs are
    polished.
    ``tolerance``: the largest relative ROM error (objective and log-sensitivities) accepted at
    the optimum; beyond it the basis is enriched and the search goes on, up to ``max_rounds``.
    ``certify``: "full" (the full model's J and dJ/dc at the optimum, one solve per round) or
    "estimate" (the hierarchical estimates of the reduced J's and log-sensitivities' errors,
    no full solve; the energy objective of free vibration only, the objective the estimator
    bounds).
    """
    check_x64()
    if not isinstance(problem, DamperProblem):
        raise ValueError(MARK + f"problem must be a DamperProblem, got {type(problem).__name__}.")
    optimizer = DEFAULT_OPTIMIZER if optimizer is None else optimizer
    if not isinstance(optimizer, optax.GradientTransformation):
        raise ValueError(MARK + "optimizer must be an optax GradientTransformation (e.g. "
                         f"optax.adam(0.1)), got {type(optimizer).__name__}.")
    for name, value, low in (("iterations", iterations, 1), ("keep", keep, 1),
                             ("polish_iterations", polish_iterations, 1),
                             ("max_rounds", max_rounds, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(MARK + f"{name} must be an integer >= {low}, got {value!r}.")
    if not (np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(MARK + f"tolerance must be > 0, got {tolerance!r}.")
    if certify not in ("full", "estimate"):
        raise ValueError(MARK + f"certify must be 'full' or 'estimate', got {certify!r}.")
    if certify == "estimate" and (not isinstance(problem.objective, Energy)
                                  or problem.load is not None):
        raise ValueError(MARK + "certify='estimate' needs the 'energy' objective of free "
                         "vibration (no load): the estimate bounds that J; got objective "
                         f"{problem.objective.name!r}"
                         + (" with a load." if problem.load is not None else "."))
    n, g = problem.size, problem.num_dampers
    if isinstance(starts, int | np.integer) and not isinstance(starts, bool):
        if starts < 1:
            raise ValueError(MARK + f"starts must be >= 1, got {starts}.")
        start_positions = default_starts(problem, int(starts), seed)
    else:
        start_positions = np.asarray(starts, dtype=float)
        if start_positions.ndim == 1 and g == 1:
            start_positions = start_positions[:, None]
        if (start_positions.ndim != 2 or start_positions.shape[1] != g
                or not np.all((start_positions >= 1) & (start_positions <= n))):
            raise ValueError(MARK + f"starts must be an int or an (S, {g}) array of positions "
                             f"in [1, {n}], got shape {start_positions.shape}.")
    clock = time.perf_counter()
    coefficients0 = np.asarray(problem.coefficients)
    c_ref = jnp.asarray(np.where(coefficients0 > 0, coefficients0, 1.0))
    full_seconds, full_solves, messages, history = 0.0, 0, [], []

    def say(text):  # one line per phase, so a long run is never silent (progress=True)
        if progress:
            print(f"  [{time.perf_counter() - clock:7.1f} s] {text}", flush=True)

    def full_timed(fn, *args):
        nonlocal full_seconds, full_solves
        t = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        full_seconds += time.perf_counter() - t
        full_solves += 1
        return out

    say(f"full-model snapshots at the start design and their POD (n = {n}) ...")
    basis = full_timed(_snapshot_modes, problem, problem.positions, problem.coefficients)
    say(f"POD basis: r = {basis.shape[1]}")
    value0, _, _, failed0 = value_and_gradient(problem, basis, problem.positions,
                                                problem.coefficients)
    if bool(failed0):
        raise ValueError(MARK + "the reduced objective is not finite at the problem's own "
                         "design; check the excitation and the dampers.")
    params = to_unconstrained(n, c_ref, start_positions,
                      np.broadcast_to(coefficients0, start_positions.shape))
    dummy = jnp.zeros(start_positions.shape)
    certified, status, relaxed, shortlist, ranking = False, "", None, None, None
    for round_ in range(max_rounds):
        if split or g > 1:
            search = run_search(problem, basis, c_ref, params, dummy, optimizer=optimizer,
                             iterations=iterations, learning_rate=_LEARNING_RATE,
                             positions_fixed=False, tol=1e-7, progress=progress,
                             label=f"round {round_ + 1}: relaxed search", race=round_ == 0)
            history.append(phase_record("search", round_, search))
            dead = int(np.sum(~search.alive))
            if dead:
                messages.append(f"round {round_ + 1}: {dead} of {len(search.alive)} starts "
                                "stopped (objective not finite or solve failed); the rest went "
                                "on.")
            last, best = _best_finite(search, "at any start (a solve failed); try other "
                                      "starts or a larger max_steps")
            relaxed = tuple(a[best] for a in last)
            params = search.params
        if split:
            positions, coefficients = relaxed[0], relaxed[1]
        else:
            say(f"round {round_ + 1}: screening DOFs on the reduced model (r = "
                f"{basis.shape[1]}) ...")
            cand_p, cand_c, shortlist = realisable_candidates(
                problem, basis, relaxed, shortlist, keep, round_, history)
            say(f"round {round_ + 1}: {len(cand_p)} designs to polish, at DOFs "
                f"{np.asarray(cand_p).astype(int).tolist()}")
            polish = run_search(problem, basis, c_ref, to_unconstrained(n, c_ref, cand_p, cand_c),
                             jnp.asarray(cand_p), optimizer="lbfgs",
                             iterations=polish_iterations, learning_rate=_LEARNING_RATE,
                             positions_fixed=True, tol=1e-9, progress=progress,
                             label=f"round {round_ + 1}: polish")
            history.append(phase_record("polish", round_, polish))
            polished, k = _best_finite(polish, "at any screened DOF (every solve failed); "
                                       "try a larger max_steps")
            positions, coefficients = polished[0][k], polished[1][k]
        positions, coefficients = jnp.asarray(positions), jnp.asarray(coefficients)
        if certify == "estimate":
            say(f"round {round_ + 1}: estimating the reduced model's error at positions "
                f"{np.asarray(positions).tolist()} (no full solve) ...")
            rom_value, rom_gp, rom_gc, _ = value_and_gradient(problem, basis, positions,
                                                               coefficients)
            rom_error, gradient_error, ranking = _estimate(
                problem, basis, positions, coefficients, None if split else polished, split)
            full_value, full_gc = rom_value, rom_gc
            certified = rom_error <= tolerance and gradient_error <= tolerance
            errors = (f"estimated ROM error {rom_error:.2e}, log-sensitivity error "
                      f"{gradient_error:.2e} (no full solve)")
            ranked = ("" if ranking is None else "; the winner beats the other polished designs "
                      "by more than their estimates" if ranking else "; the polished designs' "
                      "estimates overlap the winner's (ranking not certified)")
            say(f"round {round_ + 1}: reduced objective {float(rom_value):.10g}, estimated "
                f"error {rom_error:.1e}, log-sensitivity error {gradient_error:.1e}")
        else:
            say(f"round {round_ + 1}: certifying positions {np.asarray(positions).tolist()} on "
                "the full model ...")
            full_value, full_gp, full_gc, full_failed = full_timed(
                value_and_gradient, problem, None, positions, coefficients)
            rom_value, rom_gp, rom_gc, _ = value_and_gradient(problem, basis, positions,
                                                               coefficients)
            if bool(full_failed):
                raise ValueError(MARK + "the full-model solve at the optimum failed (max_steps "
                                 "reached or non-finite); increase max_steps.")
            scale = abs(float(full_value))
            rom_error = abs(float(rom_value) - float(full_value)) / scale
            sensitivities = (np.abs(np.asarray(coefficients) * np.asarray(rom_gc - full_gc))
                             / scale)
            if split:
                sensitivities = np.concatenate([sensitivities, np.abs(np.asarray(
                    rom_gp - full_gp)) * (n - 1) / scale])
            gradient_error = float(np.max(sensitivities))
            certified = rom_error <= tolerance and gradient_error <= tolerance
            errors = f"ROM error {rom_error:.2e}, log-sensitivity error {gradient_error:.2e}"
            ranked = ""
            say(f"round {round_ + 1}: full objective {float(full_value):.10g}, ROM error "
                f"{rom_error:.1e}, log-sensitivity error {gradient_error:.1e}")
        if certified:
            status = (f"certified in round {round_ + 1} by the "
                      + (f"estimate: {errors}" if certify == "estimate" else
                         f"full model: reduced and full model agree to "
                         f"{max(rom_error, gradient_error):.2e}")
                      + f" (tolerance {tolerance:.0e}){ranked}.")
            break
        messages.append(f"round {round_ + 1}: {errors} > tolerance {tolerance:.0e}: basis "
                        f"enriched at positions {np.asarray(positions).tolist()}.")
        if round_ == max_rounds - 1:
            status = (f"NOT certified after {max_rounds} rounds: {errors} (tolerance "
                      f"{tolerance:.0e}); the objective reported is the "
                      + ("reduced model's." if certify == "estimate" else "full model's."))
            break
        say(f"round {round_ + 1}: enriching the basis with full-model snapshots there ...")
        modes = full_timed(_snapshot_modes, problem, positions, coefficients)
        basis = extend_basis(basis, modes, tol=1e-8)
    return CertifiedRun(
        positions=np.asarray(positions), coefficients=np.asarray(coefficients),
        objective=float(full_value), objective_reduced=float(rom_value), rom_error=rom_error,
        gradient_error=gradient_error, gradient=np.asarray(full_gc), certified=certified,
        status=status, rounds=round_ + 1, full_solves=full_solves, rank=int(basis.shape[1]),
        relaxed_positions=None if relaxed is None else relaxed[0],
        relaxed_coefficients=None if relaxed is None else relaxed[1],
        relaxed_objective=None if relaxed is None else float(relaxed[2]),
        initial_objective=float(value0),
        history=history, seconds=time.perf_counter() - clock, seconds_full=full_seconds,
        messages=messages, certified_by="estimate" if certify == "estimate" else "full model",
        ranking=ranking, basis=np.asarray(basis))


def _best_finite(search, why: str):
    """``last_finite(search)`` and the index of its best start; one line naming ``why`` where
    no start stayed finite."""
    last = last_finite(search)
    if last is None:
        raise ValueError(MARK + f"ScreenAndCertify stopped: the objective was not finite {why}.")
    return last, best_index(last[2])


def _estimate(problem, basis, positions, coefficients, polished, split):
    """(estimate of |J - J_r| / J at the design, of the log-sensitivity error, ranking) by the
    hierarchical estimator of ``basis`` (its fine space: basis + 2 r low modes + 3 damper
    moments), no full solve. The log-sensitivity error: max c |dJ/dc - dJ_r/dc| / J, and for
    ``split`` designs also (n - 1) |dJ/dp - dJ_r/dp| / J, as the full certification measures
    it. ``ranking``: whether J_r + estimate at the design lies below J_r - estimate of every
    other polished design (``polished``: their (positions, coefficients, values); None: not
    checked)."""
    horizon = problem.ts[-1] - problem.ts[0]
    system = problem.system(positions, coefficients)
    estimator = HierarchicalEstimator(system, basis)  # M and K: the same at every design
    own = estimator.gradient(system, horizon, problem.x0, problem.v0)
    relative = float(own.relative)
    gradient_error = float(own.log_sensitivity_error)
    if split:
        floor = float(own.value - own.energy)
        worst = (problem.size - 1) * float(jnp.max(own.error["positions"]))
        gradient_error = max(gradient_error, worst / floor if floor > 0 else float("inf"))
    if polished is None or len(polished[0]) < 2:
        return relative, gradient_error, None
    high = float(own.value + own.energy)
    for p, c in zip(np.asarray(polished[0]), np.asarray(polished[1]), strict=True):
        if np.array_equal(p, np.asarray(positions)) and np.array_equal(c, np.asarray(
                coefficients)):
            continue
        other = estimator(problem.system(jnp.asarray(p), jnp.asarray(c)), horizon,
                          problem.x0, problem.v0)
        if not float(other.value - other.energy) > high:
            return relative, gradient_error, False
    return relative, gradient_error, True

