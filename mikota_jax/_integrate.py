"""``simulate``: one diffrax integrator for full and reduced second-order systems.

The state is the pytree (x, v); the right-hand side is (v, M^-1 (f(t) - D v - K x)) with every
operator applied in its structure (O(n) for a chain, no M^-1 K formed). A reduced model's dense
r x r mass is factored once (Cholesky) per solve. Only what the caller asks for is saved: the
requested 1-based DOFs (lifted through the basis for a reduced model), displacement and/or velocity.
"""

from collections.abc import Sequence

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from ._chain import SecondOrderSystem
from ._custom_types import Array, Float, Times, Vector
from ._errors import MARK, as_float, check, check_x64, raises_value_error
from ._excitation import Pulse, as_load
from ._galerkin import ReducedModel
from ._operators import Diagonal

SOLVERS = {
    "tsit5": diffrax.Tsit5,
    "dopri5": diffrax.Dopri5,
    "dopri8": diffrax.Dopri8,
    "kvaerno5": diffrax.Kvaerno5,
}


class Trajectory(eqx.Module):
    """Saved outputs (rows: times, columns: requested DOFs); unrequested quantities are None."""

    ts: Times
    displacement: Float[Array, "N d"] | None
    velocity: Float[Array, "N d"] | None
    dofs: tuple[int, ...] = eqx.field(static=True)  # 1-based
    num_steps: Array | None = None


def check_times(ts) -> Times:
    ts = as_float(ts, "ts")
    if ts.ndim != 1 or ts.shape[0] < 1:
        raise ValueError(MARK + f"ts must be a non-empty 1-d time grid, got shape {ts.shape}.")
    bad = ~jnp.all(jnp.isfinite(ts)) | jnp.any(jnp.diff(ts) <= 0)
    return check(ts, bad, "ts must be finite and strictly increasing.")


def check_dofs(dofs, n: int) -> tuple[int, ...]:
    if dofs is None:
        return tuple(range(1, n + 1))
    dofs = tuple(int(d) for d in np.atleast_1d(np.asarray(dofs)))
    if not dofs or not all(1 <= d <= n for d in dofs):
        raise ValueError(MARK + f"dofs must be 1-based DOFs in 1..{n}, got {dofs}.")
    return dofs


def initial_vector(x, n: int, name: str) -> Vector:
    if x is None:
        return jnp.zeros(n)
    x = as_float(x, name)
    if x.shape != (n,):
        raise ValueError(MARK + f"{name} must have shape ({n},), got {x.shape}.")
    return check(x, ~jnp.all(jnp.isfinite(x)), f"{name} must be finite.")


def unpack(model, x0, v0, load):
    """(system, basis or None, reduced x0, reduced v0, reduced load) for a full or reduced model."""
    if isinstance(model, ReducedModel):
        n, basis = model.size, model.basis
    elif isinstance(model, SecondOrderSystem):
        n, basis = model.size, None
    else:
        raise ValueError(MARK + "model must be a SecondOrderSystem or a ReducedModel, got "
                         f"{type(model).__name__}.")
    x0, v0 = initial_vector(x0, n, "x0"), initial_vector(v0, n, "v0")
    load = as_load(load, n)
    if basis is None:
        return model, None, x0, v0, load
    load = None if load is None else load.project(basis)
    return model.system, basis, basis.T @ x0, basis.T @ v0, load


def acceleration(system: SecondOrderSystem):
    """a(t, x, v) = M^-1 (f - D v - K x), using the structure of each operator."""
    if isinstance(system.mass, Diagonal):
        solve = system.mass.solve
    else:
        factor = jsl.cho_factor(system.mass.as_matrix())
        solve = lambda y: jsl.cho_solve(factor, y)  # noqa: E731

    def accel(x, v, f):
        force = -system.stiffness.mv(x)
        if system.damping is not None:
            force = force - system.damping.mv(v)
        if f is not None:
            force = force + f
        return solve(force)

    return accel


def _save_fn(basis, dofs_index, displacement: bool, velocity: bool):
    rows = None if basis is None else basis[dofs_index]

    def pick(z):
        if rows is not None:
            return rows @ z
        return z if dofs_index is None else z[dofs_index]

    def save(t, y, args):
        x, v = y
        return (pick(x) if displacement else None, pick(v) if velocity else None)

    return save


@eqx.filter_jit
def _simulate(model, ts, x0, v0, load, rtol, atol, *, solver, dofs, displacement, velocity,
              max_steps, throw, progress):
    system, basis, y0x, y0v, load = unpack(model, x0, v0, load)
    accel = acceleration(system)

    def field(t, y, args):
        x, v = y
        return v, accel(x, v, None if load is None else load(t))

    controller = diffrax.PIDController(rtol=rtol, atol=atol)
    if isinstance(load, Pulse):
        controller = diffrax.ClipStepSizeController(controller, jump_ts=load.jump_times)
    n = model.size
    index = None if dofs == tuple(range(1, n + 1)) else jnp.asarray(dofs) - 1
    if index is None and basis is not None:
        index = jnp.arange(n)
    saveat = diffrax.SaveAt(ts=ts, fn=_save_fn(basis, index, displacement, velocity))
    meter = diffrax.TqdmProgressMeter() if progress else diffrax.NoProgressMeter()
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field), solver, ts[0], ts[-1], None, (y0x, y0v), saveat=saveat,
        stepsize_controller=controller, max_steps=max_steps, throw=False, progress_meter=meter)
    out = sol.ys
    if throw:
        out = eqx.error_if(
            out, sol.result == diffrax.RESULTS.max_steps_reached,
            MARK + f"simulate stopped: max_steps = {max_steps} reached before ts[-1]. Increase "
            "max_steps, loosen rtol/atol, or for a stiff case (large n, strong damper) use "
            "solver='kvaerno5' or the exact solver.")
        out = eqx.error_if(
            out, sol.result != diffrax.RESULTS.successful,
            MARK + "simulate failed inside diffrax (step size collapsed or the implicit solve "
            "diverged); check the inputs for non-finite values, or try another solver.")
        finite = jnp.all(jnp.asarray([jnp.all(jnp.isfinite(a)) for a in jax.tree.leaves(out)]))
        out = eqx.error_if(out, ~finite, MARK + "simulate produced non-finite states; check the "
                           "inputs and tolerances, or use a stiff solver.")
    return Trajectory(ts, out[0], out[1], dofs, sol.stats["num_steps"])


@raises_value_error
def simulate(model: SecondOrderSystem | ReducedModel, ts: Times, x0: Vector | None = None,
             v0: Vector | None = None, load=None, *, dofs: Sequence[int] | None = None,
             displacement: bool = True, velocity: bool = False,
             solver: str | diffrax.AbstractSolver = "dopri8", rtol: float = 1e-8,
             atol: float = 1e-10, max_steps: int = 100_000, throw: bool = True,
             progress: bool = False) -> Trajectory:
    """Integrate M x'' + D x' + K x = f(t) with diffrax from x(ts[0]) = x0, x'(ts[0]) = v0.

    ``model`` is a full system or a ``ReducedModel`` (initial state and load given in full
    coordinates, projected by the basis; outputs lifted back, eq. 3.2). ``dofs`` are 1-based
    (default: all). Tolerances are traced: changing them does not recompile.
    """
    check_x64()
    if isinstance(solver, str):
        if solver not in SOLVERS:
            raise ValueError(MARK + f"solver must be one of {sorted(SOLVERS)} or a diffrax solver, "
                             f"got {solver!r}.")
        solver = SOLVERS[solver]()
    if not (displacement or velocity):
        raise ValueError(MARK + "ask for displacement and/or velocity; nothing would be saved.")
    if not isinstance(max_steps, int) or max_steps < 1:
        raise ValueError(MARK + f"max_steps must be an integer >= 1, got {max_steps!r}.")
    ts = check_times(ts)
    rtol, atol = as_float(rtol, "rtol"), as_float(atol, "atol")
    rtol = check(rtol, ~(rtol > 0), "rtol must be > 0.")
    atol = check(atol, ~(atol > 0), "atol must be > 0.")
    n = model.size if isinstance(model, SecondOrderSystem | ReducedModel) else 0
    return _simulate(model, ts, x0, v0, load, rtol, atol, solver=solver,
                     dofs=check_dofs(dofs, max(n, 1)), displacement=displacement,
                     velocity=velocity, max_steps=max_steps, throw=throw, progress=progress)
