"""``simulate``: one diffrax integrator for full and reduced second-order systems.

The state is one flat vector y = (x, v); the right-hand side is (v, M^-1 (f(t) - D v - K x)) with
every operator applied in its structure: O(n) for a chain (tridiagonal K, grounded dampers as one
diagonal, no M^-1 K formed). A reduced model (dense r x r operators) is solved in its modal
coordinates, where M = I, K is diagonal and the projected dampers are low rank, so a call costs
O(r p) instead of a dense r x 2r product. Only what the caller asks for is saved: the requested
1-based DOFs (lifted back for a reduced model), displacement and/or velocity.
"""

import warnings
from collections.abc import Sequence

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Times, Vector
from .._errors import (
    MARK,
    RESULTS,
    array_module,
    as_float,
    check,
    check_output_memory,
    check_x64,
    first_failure,
    integer_indices,
    raise_result,
    raises_value_error,
)
from .._model.dampers import Dampers
from .._model.internal_damping import InternalDamping
from .._model.loads import Pulse, as_load
from .._model.modal import generalized_modes
from .._model.operators import Diagonal, diagonal_of
from .._model.reduced import ReducedModel
from .._model.system import SecondOrderSystem
from .implicit import StructuredKvaerno5, physical_mass, symmetric_tridiagonal_solve
from .trajectory import Trajectory

SOLVERS = {
    "tsit5": diffrax.Tsit5,
    "dopri5": diffrax.Dopri5,
    "dopri8": diffrax.Dopri8,
    "kvaerno5": StructuredKvaerno5,
}


def check_times(ts) -> Times:
    ts = as_float(ts, "ts")
    if ts.ndim != 1 or ts.shape[0] < 1:
        raise ValueError(MARK + f"ts must be a non-empty 1-d time grid, got shape {ts.shape}.")
    xp = array_module(ts)
    bad = ~xp.all(xp.isfinite(ts)) | xp.any(xp.diff(ts) <= 0)
    return check(ts, bad, "ts must be finite and strictly increasing.")


def check_dofs(dofs, n: int) -> tuple[int, ...]:
    if dofs is None:
        return tuple(range(1, n + 1))
    dofs = integer_indices(dofs, "dofs")
    if not dofs or not all(1 <= d <= n for d in dofs):
        raise ValueError(MARK + f"dofs must be 1-based DOFs in 1..{n}, got {dofs}.")
    return dofs


def initial_vector(x, n: int, name: str) -> Vector:
    if x is None:
        return jnp.asarray(np.zeros(n))
    x = as_float(x, name)
    if x.shape != (n,):
        raise ValueError(MARK + f"{name} must have shape ({n},), got {x.shape}.")
    xp = array_module(x)
    return check(x, ~xp.all(xp.isfinite(x)), f"{name} must be finite.")


def check_problem(model, x0, v0, load):
    """Validate (model, x0, v0, load) before any compiled solve: (x0, v0, load), all of size n."""
    if not isinstance(model, ReducedModel | SecondOrderSystem):
        raise ValueError(MARK + "model must be a SecondOrderSystem or a ReducedModel, got "
                         f"{type(model).__name__}.")
    n = model.size
    return initial_vector(x0, n, "x0"), initial_vector(v0, n, "v0"), as_load(load, n)


def unpack(model, x0, v0, load):
    """(system, lift or None, initial x, initial v, load) in the coordinates the solvers use.

    A system with a diagonal or tridiagonal mass and no modal damping (a chain, a user's
    lumped or consistent 1-d mass) is solved as it is, in its structure (lift None). Any other
    -- a reduced model, another non-diagonal mass, modal damping -- is solved in its
    M-orthonormal modal coordinates eta: q = U eta with U^T M U = I, U^T K U = diag(omega^2), so
    M becomes I, K a diagonal, Rayleigh and modal damping diagonals, and projected dampers stay
    low rank; ``lift`` (basis U, or U) maps eta back to the full DOFs. The initial state is
    projected (q0 = basis^T x0, eta0 = U^T M q0).
    """
    basis = model.basis if isinstance(model, ReducedModel) else None
    system = model.system if basis is not None else model
    modal_damping = system.internal is not None and system.internal.modal is not None
    if physical_mass(system.mass) and basis is None and not modal_damping:
        return system, None, x0, v0, load
    if basis is not None:
        x0, v0 = basis.T @ x0, basis.T @ v0
    omega2, modes = generalized_modes(system)
    lift = modes if basis is None else basis @ modes
    damping = None if system.damping is None else system.damping.project(modes)
    internal = None if system.internal is None else InternalDamping(
        system.internal.in_modes(omega2, modes))
    modal = SecondOrderSystem(Diagonal(jnp.ones_like(omega2)), Diagonal(omega2), damping, internal)
    load = None if load is None else load.project(lift)
    return modal, lift, modes.T @ system.mass.mv(x0), modes.T @ system.mass.mv(v0), load


def acceleration(system: SecondOrderSystem, load):
    """a(t, x, v) = M^-1 (f(t) - D v - K x) for a diagonal (or tridiagonal) M, prepared once.

    The mass is inverted elementwise and a chain's grounded dampers collapse to one diagonal vector,
    K stays a tridiagonal stencil (a chain) or a diagonal (modal coordinates): O(n) per call, plus
    O(r p) for dampers projected onto r modes (p = DOFs they touch); Rayleigh damping costs one
    more product with M (K (x + beta v) takes its K part).
    """
    mass = system.mass
    if isinstance(mass, Diagonal):
        inverse_mass = 1.0 / mass.diagonal
        solve_mass = lambda force: inverse_mass * force  # noqa: E731
    else:  # tridiagonal (a consistent mass): one O(n) solve per evaluation
        def solve_mass(force):
            return symmetric_tridiagonal_solve(mass.diagonal, mass.off_diagonal, force)
    damping = system.damping
    if isinstance(damping, Dampers):
        grounded = damping.grounded_diagonal()
        relative = damping.mv_relative if damping.pair_count else None
        damp = lambda v: grounded * v if relative is None else grounded * v + relative(v)  # noqa: E731
    elif damping is not None:
        damp = damping.mv
    else:
        damp = None
    internal, rayleigh = system.internal, None
    if internal is not None:
        rayleigh = internal.rayleigh  # folded into the K and M products below
        rest = InternalDamping(internal.matrix, None, internal.modal).operator(
            system.mass, system.stiffness, system.modes)
        if rest is not None:
            damp = rest.mv if damp is None else (lambda v, d=damp: d(v) + rest.mv(v))

    def accel(t, x, v):
        if rayleigh is None:
            force = -system.stiffness.mv(x)
        else:  # K x + (alpha M + beta K) v = K (x + beta v) + alpha M v: one K product
            force = -system.stiffness.mv(x + rayleigh.beta * v) - rayleigh.alpha * mass.mv(v)
        if damp is not None:
            force = force - damp(v)
        if load is not None:
            force = force + load(t)
        return solve_mass(force)

    return accel


def _save_fn(n: int, lift, dofs_index, displacement: bool, velocity: bool):
    rows = None if lift is None else lift[dofs_index]

    def pick(z):
        if rows is not None:
            return rows @ z
        return z if dofs_index is None else z[dofs_index]

    def save(t, y, args):
        return (pick(y[:n]) if displacement else None, pick(y[n:]) if velocity else None)

    return save


@eqx.filter_jit
def simulate_with_result(model, ts, x0, v0, load, rtol, atol, *, solver, dofs, displacement,
                         velocity, max_steps, progress, adjoint):
    """The compiled solve of ``simulate`` on checked inputs: (``Trajectory``, ``RESULTS``)."""
    system, lift, y0x, y0v, load = unpack(model, x0, v0, load)
    accel = acceleration(system, load)
    if isinstance(solver, StructuredKvaerno5):
        solver = solver.bind(system, load)
    m = system.size  # the state is one flat vector (x, v): fewer, larger kernels per stage

    def field(t, y, args):
        x, v = y[:m], y[m:]
        return jnp.concatenate([v, accel(t, x, v)])

    controller = diffrax.PIDController(rtol=rtol, atol=atol)
    if isinstance(load, Pulse):
        controller = diffrax.ClipStepSizeController(controller, jump_ts=load.jump_times)
    n = model.size
    index = None if dofs == tuple(range(1, n + 1)) else jnp.asarray(dofs) - 1
    if index is None and lift is not None:
        index = jnp.arange(n)
    saveat = diffrax.SaveAt(ts=ts, fn=_save_fn(m, lift, index, displacement, velocity))
    meter = diffrax.TqdmProgressMeter() if progress else diffrax.NoProgressMeter()
    y0 = jnp.concatenate([y0x, y0v])
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field), solver, ts[0], ts[-1], None, y0, saveat=saveat,
        stepsize_controller=controller, max_steps=max_steps, throw=False, progress_meter=meter,
        adjoint=adjoint)
    out = sol.ys
    result = solve_result(sol, out)
    return Trajectory(ts, out[0], out[1], dofs, sol.stats["num_steps"]), result


def solve_result(sol, out) -> RESULTS:
    """Our ``RESULTS`` of a diffrax solve: max_steps reached, another diffrax failure, or
    non-finite ``out`` (in that order)."""
    max_steps_reached = sol.result == diffrax.RESULTS.max_steps_reached
    failed = (sol.result != diffrax.RESULTS.successful) & ~max_steps_reached
    finite = jnp.all(jnp.asarray([jnp.all(jnp.isfinite(a)) for a in jax.tree.leaves(out)]))
    return first_failure((max_steps_reached, RESULTS.max_steps_reached),
                         (failed, RESULTS.solver_failed), (~finite, RESULTS.non_finite_states))




def check_solve_options(rtol, atol, max_steps, adjoint):
    """Validated (rtol, atol, adjoint) of a diffrax solve (tolerances traced, so no recompile)."""
    if not isinstance(max_steps, int) or max_steps < 1:
        raise ValueError(MARK + f"max_steps must be an integer >= 1, got {max_steps!r}.")
    rtol, atol = as_float(rtol, "rtol"), as_float(atol, "atol")
    # rtol >= 1 allows a 100 % error per step: Dopri8 returned 5.5x (rtol 0.5) to 1e22x
    # (rtol 1e300) errors, silently; above 1e-2 it is allowed, with a warning
    rtol = check(rtol, ~((rtol > 0) & (rtol < 1)), "rtol must be > 0 and < 1.")
    atol = check(atol, ~((atol > 0) & jnp.isfinite(atol)), "atol must be > 0 and finite.")
    if not isinstance(rtol, jax.core.Tracer) and float(rtol) > 1e-2:
        warnings.warn(f"mikota_jax: rtol = {float(rtol):g} allows errors of that order per step "
                      "and more over the run; 1e-2 or below gives results to trust.", stacklevel=3)
    if adjoint is None:
        adjoint = diffrax.RecursiveCheckpointAdjoint()
    elif not isinstance(adjoint, diffrax.AbstractAdjoint):
        raise ValueError(MARK + f"adjoint must be a diffrax adjoint, got {adjoint!r}.")
    return rtol, atol, adjoint


def default_atol(rtol, model, ts, x0, v0, load):
    """1e-2 rtol x the excitation's scale: max(|x0|, |v0|, the load's), or 1 when all are zero.

    The load's scale is its static deflection |f| / min K_ii, or for a pulse shorter than that
    suggests, its impulse |f| duration / min M_ii. An absolute tolerance fixed at 1e-10 returned
    a response of amplitude 1e-10 120 % off; this one follows the amplitude (for the paper's unit
    excitations it is 1e-2 rtol, as before).
    """
    scale = jnp.maximum(jnp.max(jnp.abs(x0)), jnp.max(jnp.abs(v0)))
    if load is not None:
        system = model.system if isinstance(model, ReducedModel) else model
        flexibility = 1.0 / jnp.min(jnp.abs(diagonal_of(system.stiffness)))
        if isinstance(load, Pulse):
            mobility = load.duration / jnp.min(jnp.abs(diagonal_of(system.mass)))
            force = jnp.max(jnp.abs(load.direction)) * jnp.minimum(flexibility, mobility)
        else:
            force = jnp.max(jnp.abs(jax.vmap(load)(ts))) * flexibility
        scale = jnp.maximum(scale, force)
    scale = jnp.where(jnp.isfinite(scale) & (scale > 0), scale, 1.0)
    return 1e-2 * rtol * scale


SPECTRAL_MATRICES = 12  # float64 n x n arrays the spectral solve holds at its peak, generously


@raises_value_error
def simulate(model: SecondOrderSystem | ReducedModel, ts: Times, x0: Vector | None = None,
             v0: Vector | None = None, load=None, *, dofs: Sequence[int] | None = None,
             displacement: bool = True, velocity: bool = False,
             solver: str | diffrax.AbstractSolver = "dopri8", rtol: float = 1e-8,
             atol: float | None = None, max_steps: int = 100_000, throw: bool = True,
             progress: bool = False,
             adjoint: diffrax.AbstractAdjoint | None = None) -> Trajectory:
    """Integrate M x'' + D x' + K x = f(t) (eq. 3.1) with diffrax from x = x0, x' = v0 at ts[0].

    ``model`` is a full system or a ``ReducedModel`` (eq. 3.4; initial state and load given in
    full coordinates, projected by the basis; outputs lifted back, eq. 3.2). ``ts``: the (N,)
    increasing output times; ``x0``, ``v0``: (n,) (default zero); ``load``: None, a ``Pulse``
    (eq. 4.3), a ``LoadFunction`` or a callable t -> (n,). ``dofs`` are 1-based (default: all);
    returns a ``Trajectory`` of (N, d) arrays (d = len(dofs)). Tolerances are traced: changing
    them does not recompile. ``atol`` is absolute (displacement and velocity units); by default it
    is 1e-2 rtol times the excitation's scale (``default_atol``), so a response of amplitude 1e-10
    keeps the relative accuracy of one of amplitude 1.

    ``solver``: "dopri8" (default; explicit, the most accurate per step), "tsit5", "dopri5",
    "kvaerno5" (L-stable implicit ESDIRK whose stage equations are solved exactly in the chain's
    O(n) structure: for stiff cases, large n or a strong damper), or a diffrax solver instance
    (diffrax's own implicit solvers factor a dense 2n x 2n Jacobian). ``Auto().select`` chooses
    between the exact solution and these; this function only integrates.

    ``adjoint`` is how derivatives pass through the solve (diffrax's; default
    ``RecursiveCheckpointAdjoint``, for reverse mode); use ``diffrax.ForwardMode()`` under
    ``jax.jvp``/``jax.jacfwd``, which is the cheaper choice for a few parameters. In reverse mode
    the checkpoint count follows ``max_steps``: a bound near the real step count (e.g. 2**14 for
    the paper's n = 300 chain) makes the gradient several times cheaper than the default 100 000.
    """
    check_x64()
    if isinstance(solver, str):
        if solver not in SOLVERS:
            raise ValueError(MARK + f"solver must be one of {sorted(SOLVERS)} or a "
                             f"diffrax solver, got {solver!r}.")
    if not (displacement or velocity):
        raise ValueError(MARK + "ask for displacement and/or velocity; nothing would be saved.")
    ts = check_times(ts)
    x0, v0, load = check_problem(model, x0, v0, load)
    if atol is None:
        atol = default_atol(as_float(rtol, "rtol"), model, ts, x0, v0, load)
    rtol, atol, adjoint = check_solve_options(rtol, atol, max_steps, adjoint)
    checked_dofs = check_dofs(dofs, model.size)
    check_output_memory(ts.shape[0], len(checked_dofs) * (displacement + velocity)
                        + 2 * model.size, "ODE()")
    if isinstance(solver, str):
        solver = SOLVERS[solver]()
    trajectory, result = simulate_with_result(
        model, ts, x0, v0, load, rtol, atol, solver=solver, dofs=checked_dofs,
        displacement=displacement, velocity=velocity, max_steps=max_steps, progress=progress,
        adjoint=adjoint)
    if throw:
        trajectory = raise_result(trajectory, result, max_steps=max_steps)
    return trajectory
