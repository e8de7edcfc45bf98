"""Damper placement: optimise where grounded dampers sit and how strong they are.

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
   screening (of the 4 ``keep`` best DOFs) and polish run again.

"Certified" means the reduced model is accurate (to ``tolerance``) at the design returned, which
is the best the reduced model found; the full sweep (``sweep_dampers``) is the independent check
that it is the best DOF (``benchmarks/placement.py``).

Objectives (``DamperProblem.objective``):

* ``"energy"``: the integrated energy int_0^T (x^T K x + x'^T M x') / 2 dt of the problem's
  excitation (exact for a reduced model's free vibration; Dopri8 with the energy as one more state
  otherwise, and always for the full model, where it is 8x cheaper);
* ``"average_energy"``: the total average energy (trace of the Lyapunov solution, ``lowest`` s
  modes or all);
* ``"peak"``: a smooth peak (order-p mean) of the displacement of one DOF on the time grid.
"""

import dataclasses
import time
from collections.abc import Sequence

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from ._chain import SecondOrderSystem, generalized_modes
from ._dampers import Dampers, GroundedDamper, RelativeDamper
from ._errors import MARK, callback_free_checks, check_x64
from ._exact import state_matrix
from ._excitation import as_load
from ._galerkin import galerkin
from ._implicit import gershgorin_omega
from ._integrate import _simulate, check_dofs, check_times, initial_vector
from ._objectives import (
    _DOUBLINGS_FINITE,
    _DOUBLINGS_INFINITE,
    _doubled_gramian,
    _first_step_too_long,
    _integrated_energy,
    _integrated_energy_ode,
    _total_average_energy,
    smooth_peak,
)
from ._plain import to_plain
from ._reduction import Reduction, reduce

OBJECTIVES = ("energy", "average_energy", "peak")
OPTIMIZERS = ("adam", "lbfgs")
_W_BOUND = 40.0  # |log(c / c_ref)| <= 40: coefficients stay finite


class DamperProblem(eqx.Module):
    """What to optimise: a chain, the grounded dampers to place, the excitation and the objective.

    ``system`` gives M and K (and relative dampers, kept fixed); its grounded dampers -- or
    ``dampers``, when given -- are the design, and their positions and coefficients the start.
    ``ts`` is the time grid: the horizon T = ts[-1] - ts[0] of ``"energy"``, the samples of
    ``"peak"`` and of the snapshots. ``snapshots`` is the window (t0, t1) whose full-model
    displacements build the POD basis, ``energy`` the pseudo-energy fraction that sets its rank
    (eq. 3.7; ``criterion`` as in ``rank_for_energy``) unless ``rank`` is given.

    Shapes: ``ts`` (N,), ``x0``, ``v0`` (n,), ``load`` as in ``simulate``; the design is
    ``positions`` (g,), 1-based in [1, n], and ``coefficients`` (g,), >= 0 in force * time per
    length, for g grounded dampers. ``dof`` (1-based) and ``order`` are the ``"peak"``
    objective's (``smooth_peak``), ``lowest`` the ``"average_energy"`` one's.
    """

    mass: object
    stiffness: object
    internal: object  # the system's internal damping (Rayleigh, modal, a user's D), or None
    fixed: tuple[RelativeDamper, ...]
    positions: jax.Array
    coefficients: jax.Array
    ts: jax.Array
    x0: jax.Array
    v0: jax.Array
    load: object
    objective: str = eqx.field(static=True)
    lowest: int | None = eqx.field(static=True)
    dof: int | None = eqx.field(static=True)
    order: int = eqx.field(static=True)
    snapshots: tuple[float, float] = eqx.field(static=True)
    energy: float = eqx.field(static=True)
    criterion: str = eqx.field(static=True)
    rank: int | None = eqx.field(static=True)
    rtol: float = eqx.field(static=True)
    max_steps: int = eqx.field(static=True)

    def __init__(self, system: SecondOrderSystem, ts, x0=None, v0=None, load=None, *,
                 dampers: Sequence[GroundedDamper] | None = None, objective: str = "energy",
                 lowest: int | None = None, dof: int | None = None, order: int = 16,
                 snapshots: tuple[float, float] | None = None, energy: float = 0.9999,
                 criterion: str = "paper", rank: int | None = None, rtol: float = 1e-8,
                 max_steps: int = 100_000):
        check_x64()
        if not isinstance(system, SecondOrderSystem) or not isinstance(system.damping,
                                                                         Dampers | None):
            raise ValueError(MARK + "system must be a SecondOrderSystem (mikota_chain, chain, "
                             "branched_chain or system) with GroundedDamper/RelativeDamper "
                             "dampers.")
        n = system.size
        self.mass, self.stiffness, self.internal = system.mass, system.stiffness, system.internal
        damping = system.damping
        if dampers is None:
            if damping is None or damping.positions.shape[0] == 0:
                raise ValueError(MARK + "dampers: the system has no grounded damper to place; "
                                 "pass dampers=[GroundedDamper(position, coefficient), ...].")
            positions, coefficients = damping.positions, damping.coefficients
        else:
            dampers = list(dampers)
            if not dampers or not all(isinstance(d, GroundedDamper) for d in dampers):
                raise ValueError(MARK + "dampers must be a non-empty list of GroundedDamper.")
            positions = jnp.stack([d.position for d in dampers])
            coefficients = jnp.stack([d.coefficient for d in dampers])
        Dampers(n, [GroundedDamper(p, c) for p, c in zip(positions, coefficients)])  # checks
        self.positions, self.coefficients = positions, coefficients
        self.fixed = () if damping is None else tuple(
            RelativeDamper((i + 1, j + 1), c)
            for (i, j), c in zip(damping.pairs, damping.pair_coefficients))
        self.ts = check_times(ts)
        if self.ts.shape[0] < 2:
            raise ValueError(MARK + "ts must hold at least two times (the horizon).")
        self.x0 = initial_vector(x0, n, "x0")
        self.v0 = initial_vector(v0, n, "v0")
        self.load = as_load(load, n)
        if objective not in OBJECTIVES:
            raise ValueError(MARK + f"objective must be one of {list(OBJECTIVES)}, "
                             f"got {objective!r}.")
        if objective != "average_energy" and self.load is None and not (
                bool(jnp.any(self.x0 != 0)) or bool(jnp.any(self.v0 != 0))):
            raise ValueError(MARK + f"objective {objective!r} needs an excitation: x0, v0 or a "
                             "load (the response is zero otherwise).")
        self.objective = objective
        if lowest is not None and (isinstance(lowest, bool) or not isinstance(lowest, int)
                                   or not 1 <= lowest <= n):
            raise ValueError(MARK + f"lowest must be None or an integer in 1..{n}, "
                             f"got {lowest!r}.")
        self.lowest = lowest
        if objective == "peak":
            if dof is None:
                raise ValueError(MARK + "objective 'peak' needs dof (a 1-based DOF in 1..n).")
            dof = check_dofs([dof], n)[0]
        self.dof = dof
        if isinstance(order, bool) or not isinstance(order, int) or order < 2 or order % 2:
            raise ValueError(MARK + f"order must be an even integer >= 2, got {order!r}.")
        self.order = order
        t0, t1 = float(self.ts[0]), float(self.ts[-1])
        window = (t0, t1) if snapshots is None else tuple(float(t) for t in snapshots)
        if len(window) != 2 or not t0 <= window[0] < window[1] <= t1:
            raise ValueError(MARK + f"snapshots must be a window (start, end) inside [{t0}, "
                             f"{t1}] with start < end, got {snapshots!r}.")
        self.snapshots = window
        if not 0 < energy <= 1:
            raise ValueError(MARK + f"energy must lie in (0, 1], got {energy!r}.")
        self.energy, self.criterion = float(energy), criterion
        if rank is not None and (isinstance(rank, bool) or not isinstance(rank, int)
                                 or not 1 <= rank <= n):
            raise ValueError(MARK + f"rank must be None or an integer in 1..{n}, got {rank!r}.")
        self.rank = rank
        if not 0 < rtol < 1:
            raise ValueError(MARK + f"rtol must lie in (0, 1), got {rtol!r}.")
        self.rtol = float(rtol)
        if not isinstance(max_steps, int) or max_steps < 1:
            raise ValueError(MARK + f"max_steps must be an integer >= 1, got {max_steps!r}.")
        self.max_steps = max_steps

    @property
    def size(self) -> int:
        """n, the number of DOFs."""
        return self.mass.size

    @property
    def num_dampers(self) -> int:
        """g, the number of grounded dampers to place."""
        return self.positions.shape[0]

    def system(self, positions, coefficients) -> SecondOrderSystem:
        """The chain with grounded dampers at ``positions`` (g,), in [1, n], of ``coefficients``
        (g,), plus the fixed relative dampers."""
        grounded = [GroundedDamper(p, c) for p, c in zip(positions, coefficients)]
        return SecondOrderSystem(self.mass, self.stiffness,
                                 Dampers(self.size, [*grounded, *self.fixed]), self.internal)


class _ModalROM(eqx.Module):
    """A reduced model in its modal coordinates, prepared once per basis.

    Psi = Phi U with U^T (Phi^T M Phi) U = I and U^T (Phi^T K Phi) U = diag(omega^2): a design
    only changes the dampers, Psi^T D Psi = B diag(w) B^T (B = rows of Psi), so each evaluation is
    an r x r damping block and the energy's matrix exponentials -- no eigendecomposition.
    """

    omega: jax.Array
    modes: jax.Array  # Psi, n x r
    z0: jax.Array  # (Omega eta0, eta0')
    not_definite: jax.Array
    internal: jax.Array | None = None  # the internal damping (Rayleigh, modal...), r x r modal


def _modal_rom(problem: DamperProblem, basis) -> _ModalROM:
    reduced = galerkin(SecondOrderSystem(problem.mass, problem.stiffness, None, problem.internal),
                       basis).system
    omega2, modes = generalized_modes(reduced)
    not_definite = jnp.any(omega2 <= 0)
    omega = jnp.sqrt(jnp.where(omega2 > 0, omega2, 1.0))
    mass = reduced.mass.as_matrix()
    project = lambda y: modes.T @ (mass @ (basis.T @ y))  # noqa: E731
    z0 = jnp.concatenate([omega * project(problem.x0), project(problem.v0)])
    internal = None if reduced.internal is None else (
        reduced.internal.in_modes(omega2, modes).as_matrix())
    return _ModalROM(omega, basis @ modes, z0, not_definite, internal)


def _modal_objective(problem: DamperProblem, rom: _ModalROM, positions, coefficients):
    damping = problem.system(positions, coefficients).damping.project(rom.modes).as_matrix()
    if rom.internal is not None:
        damping = damping + rom.internal
    a = state_matrix(rom.omega, damping)
    if problem.objective == "energy":
        horizon = problem.ts[-1] - problem.ts[0]
        # a fixed first step T / 2^16 (no cond: reverse mode 25 % cheaper); a damper so strong
        # that it is too long counts as a failed evaluation, never a wrong value
        w, _ = _doubled_gramian(a, jnp.eye(a.shape[0]), horizon / 2**_DOUBLINGS_FINITE,
                                _DOUBLINGS_FINITE)
        value = rom.z0 @ ((w + w.T) / 2) @ rom.z0 / 2
        undamped = _first_step_too_long(a, horizon)
    else:
        r = rom.omega.shape[0]
        lowest = r if problem.lowest is None else min(problem.lowest, r)
        select = (jnp.arange(r) < lowest).astype(a.dtype)
        x, p = _doubled_gramian(a, jnp.diag(jnp.concatenate([select, select])),
                                1.0 / jnp.max(rom.omega), _DOUBLINGS_INFINITE)
        value = jnp.trace(x)
        undamped = ~(jnp.max(jnp.abs(p)) < 1e-8)
    return value, rom.not_definite | undamped | ~jnp.isfinite(value)


def _reduced(problem: DamperProblem, basis):
    """What the objective needs of a basis: a ``_ModalROM`` where it is exact, else the basis."""
    if basis is None or problem.objective == "peak" or problem.load is not None:
        return basis
    return _modal_rom(problem, basis)


def _evaluate(problem: DamperProblem, model):
    """(objective value, failed) of a full or reduced model; ODE solves use forward mode."""
    horizon = problem.ts[-1] - problem.ts[0]
    if problem.objective == "average_energy":
        value, flags = _total_average_energy(model, lowest=problem.lowest)
    elif problem.objective == "energy":
        value, flags = _integrated_energy_ode(
            model, horizon, problem.x0, problem.v0, problem.load, problem.rtol,
            problem.rtol * 1e-2, max_steps=problem.max_steps, adjoint=diffrax.ForwardMode())
    else:
        trajectory, flags = _simulate(
            model, problem.ts, problem.x0, problem.v0, problem.load, problem.rtol,
            problem.rtol * 1e-2, solver=diffrax.Dopri8(), dofs=(problem.dof,),
            displacement=True, velocity=False, max_steps=problem.max_steps, progress=False,
            adjoint=diffrax.ForwardMode())
        value = smooth_peak(trajectory.displacement[:, 0], problem.order)
    failed = jnp.any(jnp.stack([jnp.any(f) for f in flags])) | ~jnp.isfinite(value)
    return value, failed


def _objective_fn(problem: DamperProblem, reduced):
    """(positions, coefficients) -> (value, failed): ``reduced`` from ``_reduced`` or None (full).

    Reverse-mode differentiable. A ``_ModalROM`` is exact (matrix exponentials, reverse mode);
    every diffrax solve is differentiated in forward mode, wrapped in a custom VJP (the design
    has only 2 x dampers parameters, so forward mode is the cheap direction). The full model's
    "energy" uses the ODE (8x cheaper than its exact integral at n = 300).
    """
    if isinstance(reduced, _ModalROM):
        return lambda positions, coefficients: _modal_objective(problem, reduced, positions,
                                                                coefficients)

    def raw(positions, coefficients):
        model = problem.system(positions, coefficients)
        if reduced is not None:
            model = galerkin(model, reduced)
        return _evaluate(problem, model)

    if problem.objective == "average_energy":
        return raw

    @jax.custom_vjp
    def fn(positions, coefficients):
        return raw(positions, coefficients)

    def forward(positions, coefficients):
        def value(p, c):
            v, failed = raw(p, c)
            return v, (v, failed)

        (dp, dc), (v, failed) = jax.jacfwd(value, argnums=(0, 1), has_aux=True)(
            positions, coefficients)
        return (v, failed), (dp, dc)

    def backward(residual, cotangent):
        dp, dc = residual
        return cotangent[0] * dp, cotangent[0] * dc

    fn.defvjp(forward, backward)
    return fn


def _transform(n: int, c_ref, u, w):
    """Unconstrained (u, w) -> positions in [1, n], coefficients c_ref exp(w) >= 0."""
    positions = 1.0 + (n - 1) * jax.nn.sigmoid(u) if n > 1 else jnp.ones_like(u)
    return positions, c_ref * jnp.exp(jnp.clip(w, -_W_BOUND, _W_BOUND))


def _inverse(n: int, c_ref, positions, coefficients):
    """Positions in [1, n] and coefficients >= 0 -> unconstrained (u, w) (clipped at the ends)."""
    frac = np.clip((np.asarray(positions) - 1.0) / max(n - 1, 1), 1e-6, 1 - 1e-6)
    ratio = np.maximum(np.asarray(coefficients) / np.asarray(c_ref), np.exp(-_W_BOUND))
    return jnp.asarray(np.log(frac) - np.log1p(-frac)), jnp.asarray(np.log(ratio))


def _optimizer(name: str, learning_rate):
    if name == "adam":
        return optax.adam(learning_rate)
    # backtracking (Armijo) line search: optax's default zoom search did not return on this
    # objective under vmap (measured with optax 0.2.x on CPU)
    return optax.lbfgs(linesearch=optax.scale_by_backtracking_linesearch(
        max_backtracking_steps=20, store_grad=True))


def _loss(problem, reduced, c_ref, params, fixed, positions_fixed: bool):
    """(objective, (positions, coefficients, failed)) at unconstrained params; NaN on failure."""
    positions, coefficients = _transform(problem.size, c_ref, *params)
    if positions_fixed:
        positions = fixed
    value, failed = _objective_fn(problem, reduced)(positions, coefficients)
    return jnp.where(failed, jnp.nan, value), (positions, coefficients, failed)


@eqx.filter_jit
def _init_jit(params, learning_rate, *, optimizer: str):
    return jax.vmap(_optimizer(optimizer, learning_rate).init)(params)


@eqx.filter_jit
def _step_jit(problem, basis, c_ref, params, state, fixed, alive, active, learning_rate, *,
              optimizer: str, positions_fixed: bool):
    """One optax step for every start, one after the other (``lax.map``: on a CPU, batched
    matrix exponentials cost more than the same ones in turn); an inactive start is skipped, a
    start whose objective fails stops where it is (``ok`` false)."""
    opt = _optimizer(optimizer, learning_rate)
    reduced = _reduced(problem, basis)

    def skip(params, state, fixed, alive):
        positions, coefficients = _transform(problem.size, c_ref, *params)
        if positions_fixed:
            positions = fixed
        nan = jnp.asarray(jnp.nan, positions.dtype)
        return params, state, (positions, coefficients, nan, nan, alive)

    def one(params, state, fixed, alive):
        loss = lambda q: _loss(problem, reduced, c_ref, q, fixed, positions_fixed)[0]  # noqa: E731
        (value, (positions, coefficients, failed)), grad = jax.value_and_grad(
            lambda q: _loss(problem, reduced, c_ref, q, fixed, positions_fixed), has_aux=True)(
            params)
        if positions_fixed:
            grad = (jnp.zeros_like(grad[0]), grad[1])
        ok = alive & ~failed & jnp.all(jnp.isfinite(jnp.concatenate(grad)))
        grad = jax.tree.map(lambda g: jnp.where(ok, g, 0.0), grad)
        with jax.numpy_dtype_promotion("standard"):  # optax mixes int32 counts and floats
            if optimizer == "adam":
                updates, new_state = opt.update(grad, state, params)
            else:
                updates, new_state = opt.update(grad, state, params, value=value, grad=grad,
                                                value_fn=loss)
            new_params = optax.apply_updates(params, updates)
        keep = lambda a, b: jnp.where(ok, a, b)  # noqa: E731
        new_params = jax.tree.map(keep, new_params, params)
        new_state = jax.tree.map(keep, new_state, state)
        # gradient in physical units: d/dp = d/du / (dp/du), d/dc = d/dw / c
        u = params[0]
        slope = (problem.size - 1) * jax.nn.sigmoid(u) * (1 - jax.nn.sigmoid(u))
        physical = jnp.concatenate([jnp.where(positions_fixed, 0.0, grad[0] / slope),
                                    grad[1] / coefficients])
        return new_params, new_state, (positions, coefficients, value,
                                       jnp.linalg.norm(physical), ok)

    def each(args):
        params, state, fixed, alive, active = args
        return jax.lax.cond(active & alive, one, skip, params, state, fixed, alive)

    return jax.lax.map(each, (params, state, fixed, alive, active))


@dataclasses.dataclass
class _Search:
    """What one batched search did: final params, path, which starts are still alive."""

    params: tuple
    positions: np.ndarray  # (iterations, starts, g)
    coefficients: np.ndarray
    values: np.ndarray  # (iterations, starts)
    gradient_norms: np.ndarray
    alive: np.ndarray  # (starts,)


def _search(problem, basis, c_ref, params, fixed, *, optimizer, iterations, learning_rate,
            positions_fixed, tol, progress, label, race: bool = False) -> _Search:
    """Iterate ``_step``; with ``race``, the worse half of the running starts stops after a
    quarter and after half of the iterations (successive halving), so that most of the work goes
    to the most promising starts."""
    learning_rate = jnp.asarray(learning_rate, float)
    state = _init(params, learning_rate, optimizer=optimizer)
    starts = params[0].shape[0]
    alive = jnp.ones(starts, bool)
    active = np.ones(starts, bool)
    cuts = {max(iterations // 4, 1), max(iterations // 2, 2)} if race and starts > 2 else set()
    records = []
    bar = _progress(progress, iterations, label)
    for iteration in range(1, iterations + 1):
        new_params, state, record = _step(problem, basis, c_ref, params, state, fixed, alive,
                                          jnp.asarray(active), learning_rate,
                                          optimizer=optimizer, positions_fixed=positions_fixed)
        records.append([np.asarray(a) for a in record])
        values, ok = records[-1][2], records[-1][4]
        alive = alive & jnp.asarray(ok)
        moved = max(float(jnp.max(jnp.abs(a - b))) for a, b in zip(new_params, params))
        params = new_params
        if bar is not None:
            finite = values[np.isfinite(values)]
            bar.update(1)
            bar.set_postfix(best=f"{finite.min():.6g}" if finite.size else "-")
        running = active & np.asarray(alive)
        if iteration in cuts and running.sum() > 1:
            ranked = np.argsort(np.where(running & np.isfinite(values), values, np.inf))
            active = np.zeros(starts, bool)
            active[ranked[: max(running.sum() // 2, 1)]] = True
        if not (active & np.asarray(alive)).any() or moved < tol:
            break
    if bar is not None:
        bar.close()
    positions, coefficients, values, norms, _ = (np.stack(a) for a in zip(*records))
    return _Search(params, positions, coefficients, values, norms, np.asarray(alive))


def _callback_free(fn):
    """Run a jitted function with equinox checks traced as NaN (no host callbacks).

    Every design the optimiser builds is valid by construction; a host callback inside the
    vmapped L-BFGS line search (a while loop) can deadlock XLA's CPU runtime.
    """

    def wrapper(*args, **kwargs):
        with callback_free_checks():
            return fn(*args, **kwargs)

    return wrapper


def _progress(progress: bool, total: int, label: str):
    if not progress:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=label, leave=False)


@eqx.filter_jit
def _value_and_gradient_jit(problem, basis, positions, coefficients):
    """(objective, d/dpositions, d/dcoefficients, failed) of the reduced (basis) or full model."""
    (value, failed), (gp, gc) = jax.value_and_grad(
        _objective_fn(problem, _reduced(problem, basis)), argnums=(0, 1), has_aux=True)(
        positions, coefficients)
    return value, gp, gc, failed


@eqx.filter_jit
def _snapshots_jit(problem, positions, coefficients, ts):
    model = problem.system(positions, coefficients)
    trajectory, flags = _simulate(
        model, ts, problem.x0, problem.v0, problem.load, problem.rtol, problem.rtol * 1e-2,
        solver=diffrax.Dopri8(), dofs=tuple(range(1, problem.size + 1)), displacement=True,
        velocity=False, max_steps=problem.max_steps, progress=False,
        adjoint=diffrax.RecursiveCheckpointAdjoint())
    return trajectory.displacement, flags


def _snapshot_modes(problem, positions, coefficients):
    """POD modes of a full simulation at a design (the scene's window and rank rule)."""
    ts = np.asarray(problem.ts)
    ts = jnp.asarray(ts[ts <= problem.snapshots[1] + 1e-12])
    displacement, flags = _snapshots(problem, positions, coefficients, ts)
    if any(bool(f) for f in flags):
        raise ValueError(MARK + "the full-model snapshot solve failed (max_steps reached or "
                         "non-finite states) at the design "
                         f"positions={np.asarray(positions)}, "
                         f"coefficients={np.asarray(coefficients)}; increase max_steps.")
    request = Reduction(problem.snapshots, energy=problem.energy, rank=problem.rank,
                        criterion=problem.criterion)
    return reduce(displacement, ts, request, cap_rank=True).basis


def _enrich(basis, modes, tol: float = 1e-8):
    """basis plus the part of ``modes`` outside its span (orthonormal, directions above tol)."""
    residual = modes - basis @ (basis.T @ modes)
    residual = residual - basis @ (basis.T @ residual)  # twice is enough (Kahan-Parlett)
    u, s, _ = jnp.linalg.svd(residual, full_matrices=False)
    keep = int(np.sum(np.asarray(s) > tol))
    return jnp.concatenate([basis, u[:, :keep]], axis=1)


_SCREEN_RATIO = 3.0  # trial coefficients s_j / 3, s_j, 3 s_j around the local scale s_j


@eqx.filter_jit
def _screen_values_jit(problem, basis, positions, coefficients, index, dofs, trials):
    """The reduced objective with damper ``index`` moved to each of ``dofs`` and given each of
    ``trials`` (J, 3) coefficients, the other dampers as they are; NaN where it fails."""
    objective = _objective_fn(problem, _reduced(problem, basis))

    def one(args):
        dof, c = args
        value, failed = objective(positions.at[index].set(dof), coefficients.at[index].set(c))
        return jnp.where(failed, jnp.nan, value)

    grid = jnp.repeat(dofs, trials.shape[1]), trials.ravel()
    return jax.lax.map(one, grid).reshape(trials.shape)


_screen_values = _callback_free(_screen_values_jit)


def _diagonal(op) -> np.ndarray:
    """The main diagonal of a mass or stiffness operator, on the host."""
    return np.asarray(op.diagonal if hasattr(op, "diagonal") else jnp.diag(op.as_matrix()))


def _local_scale(problem: DamperProblem) -> np.ndarray:
    """s_j = 2 sqrt(K_jj M_jj): the critical damping of DOF j held by its own springs."""
    return 2.0 * np.sqrt(_diagonal(problem.stiffness) * _diagonal(problem.mass))


def _screen(problem, basis, positions, coefficients, index: int, dofs: np.ndarray):
    """Screen DOFs for damper ``index``: (estimated best objective, its coefficient) per DOF.

    Three reduced evaluations per DOF, at s_j / 3, s_j and 3 s_j; a parabola in log c through
    them estimates the best coefficient when it has its minimum inside, else the best trial
    counts. The estimate only ranks DOFs: the best ones are then polished exactly.
    """
    scale = _local_scale(problem)[dofs.astype(int) - 1]
    factors = _SCREEN_RATIO ** np.array([-1.0, 0.0, 1.0])
    trials = scale[:, None] * factors[None, :]
    values = np.asarray(_screen_values(problem, basis, jnp.asarray(positions),
                                       jnp.asarray(coefficients), jnp.asarray(index),
                                       jnp.asarray(dofs, float), jnp.asarray(trials)))
    low, mid, high = values.T
    curvature = low - 2 * mid + high
    with np.errstate(invalid="ignore", divide="ignore"):
        shift = (low - high) / (2 * curvature)  # vertex, in units of log(ratio)
        vertex = mid - (low - high) ** 2 / (8 * curvature)
    inside = np.isfinite(values).all(axis=1) & (curvature > 0) & (np.abs(shift) <= 1)
    best = np.nanargmin(np.where(np.isfinite(values), values, np.inf), axis=1)
    estimate = np.where(inside, vertex, values[np.arange(len(dofs)), best])
    coefficient = np.where(inside, scale * _SCREEN_RATIO ** np.where(inside, shift, 0.0),
                           trials[np.arange(len(dofs)), best])
    estimate = np.where(np.isfinite(values).any(axis=1), estimate, np.inf)
    return estimate, coefficient


def _default_starts(problem: DamperProblem, starts: int, seed: int):
    """(S, g) positions: the problem's own design first, then spread over [1, n]."""
    n, g = problem.size, problem.num_dampers
    own = np.asarray(problem.positions)[None, :]
    if starts == 1:
        return own
    if g == 1:
        spread = 1.0 + (n - 1) * (np.arange(starts - 1) + 0.5)[:, None] / (starts - 1)
    else:
        rng = np.random.default_rng(seed)
        spread = np.sort(rng.uniform(1.0, n, (starts - 1, g)), axis=1)
    return np.concatenate([own, spread])


@dataclasses.dataclass
class PlacementResult:
    """The optimised damper design, certified on the full model.

    ``positions``/``coefficients``: the design, (g,) each, 1-based positions (at DOFs unless
    ``split``); ``gradient``: the full model's dJ/dc there, (g,); ``basis``: the final (n, r) POD
    basis (``rank`` r), e.g. for ``placement_objective``; ``objective``: the full
    model's objective there, ``objective_reduced`` the reduced model's, ``rom_error`` their
    relative difference and ``gradient_error`` that of the logarithmic coefficient sensitivities
    c dJ/dc / J (and dJ/dp / J for split designs). ``full_solves`` counts full-model solves
    (snapshot simulations and certifications, each with its forward-mode tangents); ``history``
    the path of every phase (relaxed search, screen, polish) of every round; ``relaxed_*`` the best
    relaxed design (None where no relaxed search ran: one damper at a DOF).
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
    basis: np.ndarray | None = dataclasses.field(default=None, repr=False)  # final POD basis

    def to_json(self) -> dict:
        """A JSON-ready dict (arrays as lists, NaN as None), without the basis."""
        return {f.name: to_plain(getattr(self, f.name)) for f in dataclasses.fields(self)
                if f.name != "basis"}


def _phase_record(phase: str, round_: int, search: _Search) -> dict:
    return dict(phase=phase, round=round_, positions=search.positions,
                coefficients=search.coefficients, objective=search.values,
                gradient_norm=search.gradient_norms)


def _best(values, mask=None) -> int:
    values = np.where(np.isfinite(values), values, np.inf)
    if mask is not None:
        values = np.where(mask, values, np.inf)
    return int(np.argmin(values))


def _realisable_candidates(problem, basis, relaxed, shortlist, keep: int, round_: int,
                          history: list):
    """(positions, coefficients) of ``keep`` designs at DOFs to polish, and the new shortlist.

    One damper: the first round screens every DOF (``_screen``), later rounds re-screen the
    ``4 keep`` best of the previous screening with the enriched basis; the ``keep`` best go on.
    Several dampers: from the rounded relaxed optimum, each damper in turn is screened over every
    DOF with the others fixed and moved to its best; the candidates are that design and, for each
    damper, its next best DOFs.
    """
    n, g = problem.size, problem.num_dampers
    if g == 1:
        dofs = np.arange(1.0, n + 1) if shortlist is None else shortlist
        estimate, coefficient = _screen(problem, basis, np.asarray(problem.positions),
                                        np.asarray(problem.coefficients), 0, dofs)
        history.append(dict(phase="screen", round=round_, damper=0, positions=dofs,
                            coefficients=coefficient, objective=estimate))
        order = np.argsort(estimate, kind="stable")
        top = order[:min(keep, len(order))]
        top = np.concatenate([top, np.full(keep - len(top), top[0])])  # one shape: one compile
        return dofs[top][:, None], coefficient[top][:, None], dofs[order[:4 * keep]]
    positions = np.clip(np.round(relaxed[0]), 1, n)
    coefficients = np.asarray(relaxed[1], float).copy()
    dofs = np.arange(1.0, n + 1)
    alternatives = []
    for i in range(g):
        estimate, coefficient = _screen(problem, basis, positions, coefficients, i, dofs)
        history.append(dict(phase="screen", round=round_, damper=i, positions=dofs,
                            coefficients=coefficient, objective=estimate))
        order = np.argsort(estimate, kind="stable")
        positions[i], coefficients[i] = dofs[order[0]], coefficient[order[0]]
        alternatives.append([(dofs[j], coefficient[j]) for j in order[1:keep]])
    cand_p, cand_c = [positions.copy()], [coefficients.copy()]
    for i, options in enumerate(alternatives):
        for dof, c in options:
            p, q = positions.copy(), coefficients.copy()
            p[i], q[i] = dof, c
            cand_p.append(p)
            cand_c.append(q)
    return np.stack(cand_p), np.stack(cand_c), None


def optimise_dampers(problem: DamperProblem, *, starts: int | np.ndarray = 8,
                     optimizer: str = "adam", iterations: int = 80,
                     learning_rate: float = 0.1, split: bool = False, keep: int = 4,
                     polish_iterations: int = 20, tolerance: float = 1e-4, max_rounds: int = 4,
                     seed: int = 0, progress: bool = False) -> PlacementResult:
    """Place the problem's grounded dampers: gradients through the ROM, certified on the full model.

    The ROM is the Galerkin model (eq. 3.4) on a POD basis (eqs. 3.5-3.8) of full-model snapshots;
    returns a ``PlacementResult`` with (g,) positions (1-based) and coefficients. See the module
    docstring for the phases. ``starts``: the number of starts of the relaxed
    search (the problem's design, then spread over the chain) or an (S, g) array of start
    positions; ``optimizer``: its "adam" (``learning_rate`` on the unconstrained variables) or
    "lbfgs"; ``iterations`` its length. The relaxed search runs for ``split=True`` (dampers may
    sit between DOFs, split linearly over the neighbours) and for several dampers; one damper at
    a DOF is found by screening every DOF. ``keep``: how many screened designs are polished.
    ``tolerance``: the largest relative ROM error (objective and log-sensitivities) accepted at
    the optimum; beyond it the basis is enriched and the search goes on, up to ``max_rounds``.
    """
    check_x64()
    if not isinstance(problem, DamperProblem):
        raise ValueError(MARK + f"problem must be a DamperProblem, got {type(problem).__name__}.")
    if optimizer not in OPTIMIZERS:
        raise ValueError(MARK + f"optimizer must be one of {list(OPTIMIZERS)}, got "
                         f"{optimizer!r}.")
    for name, value, low in (("iterations", iterations, 1), ("keep", keep, 1),
                             ("polish_iterations", polish_iterations, 1),
                             ("max_rounds", max_rounds, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(MARK + f"{name} must be an integer >= {low}, got {value!r}.")
    if not (np.isfinite(learning_rate) and learning_rate > 0):
        raise ValueError(MARK + f"learning_rate must be > 0, got {learning_rate!r}.")
    if not (np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(MARK + f"tolerance must be > 0, got {tolerance!r}.")
    n, g = problem.size, problem.num_dampers
    if isinstance(starts, int | np.integer) and not isinstance(starts, bool):
        if starts < 1:
            raise ValueError(MARK + f"starts must be >= 1, got {starts}.")
        start_positions = _default_starts(problem, int(starts), seed)
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

    def full_timed(fn, *args):
        nonlocal full_seconds, full_solves
        t = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        full_seconds += time.perf_counter() - t
        full_solves += 1
        return out

    basis = full_timed(_snapshot_modes, problem, problem.positions, problem.coefficients)
    value0, _, _, failed0 = _value_and_gradient(problem, basis, problem.positions,
                                                problem.coefficients)
    if bool(failed0):
        raise ValueError(MARK + "the reduced objective is not finite at the problem's own "
                         "design; check the excitation and the dampers.")
    params = _inverse(n, c_ref, start_positions,
                      np.broadcast_to(coefficients0, start_positions.shape))
    dummy = jnp.zeros(start_positions.shape)
    certified, status, relaxed, shortlist = False, "", None, None
    for round_ in range(max_rounds):
        if split or g > 1:
            search = _search(problem, basis, c_ref, params, dummy, optimizer=optimizer,
                             iterations=iterations, learning_rate=learning_rate,
                             positions_fixed=False, tol=1e-7, progress=progress,
                             label=f"round {round_ + 1}: relaxed search", race=round_ == 0)
            history.append(_phase_record("search", round_, search))
            dead = int(np.sum(~search.alive))
            if dead:
                messages.append(f"round {round_ + 1}: {dead} of {len(search.alive)} starts "
                                "stopped (objective not finite or solve failed); the rest went "
                                "on.")
            last = _last_finite(search)
            if last is None:
                raise ValueError(MARK + "optimise_dampers stopped: the objective was not finite "
                                 "at any start (a solve failed); try other starts or a larger "
                                 "max_steps.")
            best = _best(last[2])
            relaxed = tuple(a[best] for a in last)
            params = search.params
        if split:
            positions, coefficients = relaxed[0], relaxed[1]
        else:
            cand_p, cand_c, shortlist = _realisable_candidates(
                problem, basis, relaxed, shortlist, keep, round_, history)
            polish = _search(problem, basis, c_ref, _inverse(n, c_ref, cand_p, cand_c),
                             jnp.asarray(cand_p), optimizer="lbfgs",
                             iterations=polish_iterations, learning_rate=learning_rate,
                             positions_fixed=True, tol=1e-9, progress=progress,
                             label=f"round {round_ + 1}: polish")
            history.append(_phase_record("polish", round_, polish))
            polished = _last_finite(polish)
            if polished is None:
                raise ValueError(MARK + "optimise_dampers stopped: the objective was not finite "
                                 "at any screened DOF (every solve failed); try a larger "
                                 "max_steps.")
            k = _best(polished[2])
            positions, coefficients = polished[0][k], polished[1][k]
        positions, coefficients = jnp.asarray(positions), jnp.asarray(coefficients)
        full_value, full_gp, full_gc, full_failed = full_timed(
            _value_and_gradient, problem, None, positions, coefficients)
        rom_value, rom_gp, rom_gc, _ = _value_and_gradient(problem, basis, positions,
                                                           coefficients)
        if bool(full_failed):
            raise ValueError(MARK + "the full-model solve at the optimum failed (max_steps "
                             "reached or non-finite); increase max_steps.")
        scale = abs(float(full_value))
        rom_error = abs(float(rom_value) - float(full_value)) / scale
        sensitivities = np.abs(np.asarray(coefficients) * np.asarray(rom_gc - full_gc)) / scale
        if split:
            sensitivities = np.concatenate([sensitivities, np.abs(np.asarray(rom_gp - full_gp))
                                            * (n - 1) / scale])
        gradient_error = float(np.max(sensitivities))
        certified = rom_error <= tolerance and gradient_error <= tolerance
        if certified:
            status = (f"certified in round {round_ + 1}: reduced and full model agree to "
                      f"{max(rom_error, gradient_error):.2e} (tolerance {tolerance:.0e}).")
            break
        messages.append(f"round {round_ + 1}: ROM error {rom_error:.2e}, log-sensitivity error "
                        f"{gradient_error:.2e} > tolerance {tolerance:.0e}: basis enriched at "
                        f"positions {np.asarray(positions).tolist()}.")
        if round_ == max_rounds - 1:
            status = (f"NOT certified after {max_rounds} rounds: ROM error {rom_error:.2e}, "
                      f"log-sensitivity error {gradient_error:.2e} (tolerance "
                      f"{tolerance:.0e}); the objective reported is the full model's.")
            break
        modes = full_timed(_snapshot_modes, problem, positions, coefficients)
        basis = _enrich(basis, modes)
    return PlacementResult(
        positions=np.asarray(positions), coefficients=np.asarray(coefficients),
        objective=float(full_value), objective_reduced=float(rom_value), rom_error=rom_error,
        gradient_error=gradient_error, gradient=np.asarray(full_gc), certified=certified,
        status=status, rounds=round_ + 1, full_solves=full_solves, rank=int(basis.shape[1]),
        relaxed_positions=None if relaxed is None else relaxed[0],
        relaxed_coefficients=None if relaxed is None else relaxed[1],
        relaxed_objective=None if relaxed is None else float(relaxed[2]),
        initial_objective=float(value0),
        history=history, seconds=time.perf_counter() - clock, seconds_full=full_seconds,
        messages=messages, basis=np.asarray(basis))


def _last_finite(search: _Search):
    """Per start, the last design with a finite objective: (positions, coefficients, values)."""
    finite = np.isfinite(search.values)
    if not finite.any():
        return None
    index = np.where(finite, np.arange(len(search.values))[:, None], -1).max(axis=0)
    starts = np.arange(search.values.shape[1])
    ok = index >= 0
    index = np.maximum(index, 0)
    values = np.where(ok, search.values[index, starts], np.nan)
    return search.positions[index, starts], search.coefficients[index, starts], values


_init = _callback_free(_init_jit)
_step = _callback_free(_step_jit)
_value_and_gradient = _callback_free(_value_and_gradient_jit)
_snapshots = _callback_free(_snapshots_jit)


@eqx.filter_jit
def _grid_values_jit(problem, basis, positions, coefficients, exact: bool = False):
    """(values, failed) of one-damper designs, reduced (``basis``) or full (None), vmapped.
    ``exact``: the full model's free-vibration energy by matrix exponentials (any stiffness)."""
    if exact:
        horizon = problem.ts[-1] - problem.ts[0]

        def one(p, c):
            value, (not_definite, out_of_range) = _integrated_energy(
                problem.system(p[None], c[None]), horizon, problem.x0, problem.v0)
            return value, not_definite | out_of_range
    else:
        objective = _objective_fn(problem, _reduced(problem, basis))
        one = lambda p, c: objective(p[None], c[None])  # noqa: E731
    if exact or basis is not None:
        # matrix exponentials: under vmap every Pade branch of expm is computed, so in turn
        return jax.lax.map(lambda pc: one(*pc), (positions, coefficients))
    return jax.vmap(one)(positions, coefficients)


_grid_values = _callback_free(_grid_values_jit)


def _evaluate_points(problem, basis, points_p, points_c, batch_size: int, bar=None,
                     exact=None):
    """Objective at the points (p_k, c_k), ``batch_size`` per compiled call (the last chunk
    padded, so one shape compiles once); ``exact``: a mask of points for the exact evaluator.
    (values with NaN where failed, failed)."""
    points_p, points_c = np.asarray(points_p, float), np.asarray(points_c, float)
    exact = np.zeros(points_p.size, bool) if exact is None else np.asarray(exact, bool)
    values, failed = np.full(points_p.size, np.nan), np.zeros(points_p.size, bool)
    for flag in (False, True):
        index = np.flatnonzero(exact == flag)
        if index.size == 0:
            continue
        chunks = -(-index.size // batch_size)
        padded = np.concatenate([index, np.full(chunks * batch_size - index.size, index[-1])])
        for k in range(chunks):
            part = padded[k * batch_size:(k + 1) * batch_size]
            value, bad = _grid_values(problem, basis, jnp.asarray(points_p[part]),
                                      jnp.asarray(points_c[part]), exact=flag)
            values[part], failed[part] = np.asarray(value), np.asarray(bad)
            if bar is not None:
                bar.update(len(part))
    return np.where(failed, np.nan, values), failed


def _evaluate_grid(problem, basis, positions, coefficients, batch_size: int, progress: bool,
                   label: str, exact=None):
    """``_evaluate_points`` on the grid positions x coefficients, as (P, C) arrays."""
    grid_p, grid_c = (a.ravel() for a in np.meshgrid(positions, coefficients, indexing="ij"))
    bar = _progress(progress, grid_p.size, label)
    values, failed = _evaluate_points(problem, basis, grid_p, grid_c, batch_size, bar,
                                      None if exact is None else exact(grid_p, grid_c))
    if bar is not None:
        bar.close()
    shape = (len(positions), len(coefficients))
    return values.reshape(shape), failed.reshape(shape)


_STIFF_RATIO = 10.0  # beyond 10x the highest eigenfrequency, Dopri8 costs more than expm


def _stiff_rule(problem: DamperProblem, method: str):
    """For ``sweep_dampers``: which (positions, coefficients) the exact evaluator takes.

    "auto": the free-vibration energy of a damper whose own rate c / M_jj exceeds 10x the
    Gershgorin bound of the highest eigenfrequency (there the explicit Dopri8 is stiff and slow,
    and past ``max_steps`` fails); "exact": every point; "ode": none.
    """
    if method not in ("auto", "exact", "ode"):
        raise ValueError(MARK + f"method must be 'auto', 'exact' or 'ode', got {method!r}.")
    exact_possible = problem.objective == "energy" and problem.load is None
    if method == "exact" and not exact_possible:
        raise ValueError(MARK + "method='exact' computes the free-vibration energy only "
                         "(objective 'energy', no load).")
    if method == "ode" or not exact_possible:
        return None
    mass = _diagonal(problem.mass)
    omega_max = gershgorin_omega(mass, problem.stiffness)

    def exact(positions, coefficients):
        if method == "exact":
            return np.ones(np.size(positions), bool)
        dof = np.clip(np.floor(np.asarray(positions)).astype(int), 1, problem.size)
        return np.asarray(coefficients) / mass[dof - 1] > _STIFF_RATIO * omega_max

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


def reduced_landscape(problem: DamperProblem, basis, positions, coefficients, *,
                      batch_size: int = 16, progress: bool = False) -> np.ndarray:
    """The reduced model's objective for one damper on a (positions x coefficients) grid.

    ``basis``: (n, r), e.g. ``PlacementResult.basis``; ``positions``: (P,), 1-based in [1, n];
    ``coefficients``: (C,), >= 0. Returns a (P, C) numpy array. For plots: far cheaper than
    ``sweep_dampers``.
    """
    if problem.num_dampers != 1:
        raise ValueError(MARK + "reduced_landscape places one damper; the problem has "
                         f"{problem.num_dampers}.")
    values, _ = _evaluate_grid(problem, jnp.asarray(basis), np.asarray(positions, float),
                               np.asarray(coefficients, float), batch_size, progress,
                               "landscape (reduced model)")
    return values


@dataclasses.dataclass
class SweepResult:
    """A brute-force sweep of the full model: ``objective[i, j]`` at ``positions[i]``,
    ``coefficients[j]``, a (P, C) array for (P,) positions (1-based) and (C,) coefficients
    (NaN where a solve failed, counted in ``failed``). ``refined``: for the
    ``refine`` best DOFs, the coefficient refined by golden-section search between the grid
    neighbours of their best; ``best_*`` is the best of grid and refinement. ``exact``: how many
    points the exact evaluator took (see ``sweep_dampers``)."""

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


def sweep_dampers(problem: DamperProblem, coefficients, positions=None, *, method: str = "auto",
                  refine: int = 0, refine_tol: float = 1e-3, batch_size: int = 1,
                  progress: bool = False) -> SweepResult:
    """The full model's objective for one damper at every position x coefficient of a grid.

    ``coefficients``: (C,), >= 0; ``positions``: (P,), 1-based in [1, n], default every DOF 1..n;
    returns a ``SweepResult`` with a (P, C) ``objective``. Points are evaluated ``batch_size``
    at a time with ``jax.vmap`` (one compiled chunk shape; memory bounded by the chunk), with a
    progress bar. On a CPU, ``batch_size=1`` is fastest (a vmapped adaptive solve steps every
    member with the batch's largest step count); on a GPU, use hundreds.

    ``method``: "ode" (Dopri8 with the energy as one more state: what the optimiser certifies
    with), "exact" (the free-vibration energy by matrix exponentials, O(n^3) per point, any
    stiffness) or "auto": exact where the damper's rate c / M_jj exceeds 10x the highest
    eigenfrequency (there Dopri8 is slower than expm and, past ``max_steps``, fails), the ODE
    elsewhere. ``refine`` > 0: the coefficient of the ``refine`` best DOFs is then refined by
    golden-section search in log c (to ``refine_tol``), so that the sweep's best does not carry
    the grid's spacing.
    """
    check_x64()
    if not isinstance(problem, DamperProblem):
        raise ValueError(MARK + f"problem must be a DamperProblem, got {type(problem).__name__}.")
    if problem.num_dampers != 1:
        raise ValueError(MARK + "sweep_dampers places one damper; the problem has "
                         f"{problem.num_dampers}.")
    n = problem.size
    positions = (np.arange(1.0, n + 1) if positions is None
                 else np.atleast_1d(np.asarray(positions, dtype=float)))
    coefficients = np.atleast_1d(np.asarray(coefficients, dtype=float))
    if positions.ndim != 1 or not np.all((positions >= 1) & (positions <= n)):
        raise ValueError(MARK + f"positions must be a 1-d array of positions in [1, {n}].")
    if (coefficients.ndim != 1 or coefficients.size < 1
            or not np.all(np.isfinite(coefficients) & (coefficients >= 0))):
        raise ValueError(MARK + "coefficients must be a non-empty 1-d array of finite values "
                         ">= 0.")
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(MARK + f"batch_size must be an integer >= 1, got {batch_size!r}.")
    if isinstance(refine, bool) or not isinstance(refine, int) or refine < 0:
        raise ValueError(MARK + f"refine must be an integer >= 0, got {refine!r}.")
    if not (np.isfinite(refine_tol) and refine_tol > 0):
        raise ValueError(MARK + f"refine_tol must be > 0, got {refine_tol!r}.")
    exact = _stiff_rule(problem, method)
    clock = time.perf_counter()
    values, failed = _evaluate_grid(problem, None, positions, coefficients, batch_size, progress,
                                    "sweep (full model)", exact)
    seconds = time.perf_counter() - clock
    if not np.isfinite(values).any():
        raise ValueError(MARK + "sweep_dampers: every full solve failed; increase max_steps.")
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
                value, _ = _evaluate_points(problem, None, [p], [np.exp(log_c)], 1, None,
                                            None if exact is None else exact([p],
                                                                             [np.exp(log_c)]))
                return float(value[0]) if np.isfinite(value[0]) else np.inf

            k = int(np.nanargmin(np.where(np.isfinite(values[row, positive]),
                                          values[row, positive], np.inf)))
            low, high = logs[max(k - 1, 0)], logs[min(k + 1, logs.size - 1)]
            log_c, value, count = _golden(f, low, high, refine_tol)
            refined.append(dict(position=p, coefficient=float(np.exp(log_c)), objective=value,
                                evaluations=count))
            if value < best[2]:
                best = (p, float(np.exp(log_c)), value)
    return SweepResult(positions, coefficients, values, *best, int(failed.sum()), seconds,
                       batch_size, method, exact_points, refined, time.perf_counter() - clock)


def placement_objective(problem: DamperProblem, basis=None):
    """The problem's objective as a pure function (positions, coefficients) -> value.

    Reduced (POD ``basis`` held fixed, (n, r); the Galerkin model of eq. 3.4) or full
    (``basis=None``). ``jax.grad``, ``jax.jit`` and ``jax.vmap`` pass through it; the value is a
    scalar, NaN where a solve failed (never silently finite). ``positions``: (g,) (or a scalar for
    g = 1), 1-based in [1, n] (between DOFs a damper is split linearly); ``coefficients``: (g,),
    >= 0, in force * time per length.
    """
    if not isinstance(problem, DamperProblem):
        raise ValueError(MARK + f"problem must be a DamperProblem, got {type(problem).__name__}.")
    if basis is not None:
        basis = jnp.asarray(basis)
        if basis.ndim != 2 or basis.shape[0] != problem.size or basis.dtype != jnp.float64:
            raise ValueError(MARK + f"basis must be a float64 (n, r) array with n = "
                             f"{problem.size}, got {basis.dtype} {basis.shape}.")

    def objective(positions, coefficients):
        positions = jnp.atleast_1d(jnp.asarray(positions, jnp.float64))
        coefficients = jnp.atleast_1d(jnp.asarray(coefficients, jnp.float64))
        with callback_free_checks():
            value, failed = _objective_fn(problem, _reduced(problem, basis))(positions,
                                                                          coefficients)
        return jnp.where(failed, jnp.nan, value)

    return objective
