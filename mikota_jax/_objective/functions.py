"""Damper objectives: pure functions of a system (full or reduced) that ``jax.grad`` passes through.

Both work in the scaled modal coordinates z = (Omega eta, eta') of ``exact_solve``, x = U eta, where
z' = A z with A = [[0, Omega], [-Omega, -U^T D U]] and the energy (x^T K x + x'^T M x') / 2 is
exactly |z|^2 / 2. A reduced model is first taken to its own modal coordinates (r x r).

* ``integrated_energy``: the integral over [0, T] of the energy of the free vibration from
  (x0, v0), J = z0^T W z0 / 2 with W = int_0^T exp(A^T t) exp(A t) dt: no time grid, no
  quadrature error.
* ``smooth_peak``: a differentiable stand-in for max_k |x(t_k)| of a saved response, the
  order-p mean (mean_k x_k^p)^(1/p) for an even p, which lies in [N^(-1/p), 1] times the max.
* ``total_average_energy``: trace X with A^T X + X A = -Z (the damping-optimisation criterion of
  Veselic and Truhar), Z = I or the projector onto the ``lowest`` s modes (both the Omega eta and
  the eta' component of each). X exists only if every mode is damped.

Both integrals are built by doubling (Smith): W(2h) = W(h) + P^T W(h) P with P = exp(A h), from
Van Loan's block exponential on a short first step, so that no exp(-A^T t) of a long horizon is
ever formed (the first step shrinks with ||A|| so that a strong damper does not swamp it). Cost:
O(n^3) per doubling in the modal dimension (n for a chain, r for a ROM).
"""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from .._custom_types import Array, Float, Vector
from .._errors import (
    MARK,
    RESULTS,
    as_float,
    check,
    check_dense_memory,
    check_lowest,
    check_x64,
    first_failure,
    is_traced,
    raise_result,
    raises_value_error,
)
from .._model.loads import Pulse
from .._model.modal import modal_projection, scaled_modal, state_matrix
from .._model.reduced import ReducedModel
from .._solver.ode import (
    acceleration,
    check_problem,
    check_solve_options,
    solve_result,
    unpack,
)
from .._solver.spectral.energy import spectral_energy_with_result, spectral_trace_with_result
from .._solver.spectral.modes import uses_rows
from .._solver.spectral.response import spectral_applies

DOUBLINGS_FINITE = 16  # first step at most T / 2^16: Van Loan's exponential stays well scaled
_DOUBLINGS_MAX = 60  # ... and at least T / 2^60: ||A h|| <= 8 up to rates of 1e17 / T
_FIRST_STEP_NORM = 8.0
DOUBLINGS_INFINITE = 64  # horizon 2^64 / omega_max: every damped mode has long decayed
# ||A||_1 T above which the dense energy is refused: its rounding error grows like eps ||A|| T
# (measured on Mikota's chain, n = 30, T = 20, one damper: 2e-6 relative at ||A|| T = 2.3e11,
# 1.8e-3 at 2.3e14, 3 % at 2.3e15, and above the physical bound E0 T beyond), so this keeps it
# below ~1e-5; the spectral path has no such limit
DENSE_ENERGY_NORM_T = 1e-4 / float(jnp.finfo(jnp.float64).eps)


def _gramian_step(a, q, h):
    """(int_0^h exp(A^T t) Q exp(A t) dt, exp(A h)) by Van Loan's block exponential."""
    m = a.shape[0]
    block = jnp.block([[-a.T, q], [jnp.zeros((m, m)), a]]) * h
    e = jsl.expm(block)
    f12, f22 = e[:m, m:], e[m:, m:]
    return f22.T @ f12, f22


def doubled_gramian(a, q, h, doublings: int):
    """int_0^(h 2^doublings) exp(A^T t) Q exp(A t) dt, and exp(A h 2^doublings)."""
    w, p = _gramian_step(a, q, h)

    def double(_, carry):
        w, p = carry
        return w + p.T @ w @ p, p @ p

    return jax.lax.fori_loop(0, doublings, double, (w, p))


def infinite_gramian(a, q, omega):
    """(int_0^inf exp(A^T t) Q exp(A t) dt, exp(A h 2^64)) by ``DOUBLINGS_INFINITE`` doublings
    from h = min(1 / omega_max, 8 / ||A||_1): the first step shrinks with a strong damper as in
    ``finite_gramian`` (with h = 1 / omega_max alone, a relative damper of 40 between DOFs 5
    and 9 of Mikota's n = 12 chain, ||A h|| = 60, gave trace X = 2798 where the Lyapunov
    solution is 1062.3)."""
    norm = jnp.max(jnp.sum(jnp.abs(a), axis=0))
    h = jnp.minimum(1.0 / jnp.max(omega), _FIRST_STEP_NORM / norm)
    return doubled_gramian(a, q, h, DOUBLINGS_INFINITE)


def finite_gramian(a, q, horizon):
    """(int_0^T exp(A^T t) Q exp(A t) dt, exp(A T)) by doubling from a first step T / 2^d.

    d >= 16 is chosen so that ||A||_1 T / 2^d <= 8: Van Loan's block holds exp(-A^T h), which
    for a strong damper (rate c / m_j) would otherwise swamp the result (measured on the paper's
    chain: 1e22 instead of 5950 at ||A h|| = 123, still 1e-8 at 77); a far shorter first step
    loses digits instead (P = exp(A h) near I, squared d times: 0.7 % off with d = 48 at a
    rate of 8e5). Only the d doublings needed run (a ``lax.cond`` per doubling, which costs
    reverse mode about 25 %: the optimiser's reduced objective keeps d = 16 and fails loudly
    where that step would be too long).
    """
    norm = jnp.max(jnp.sum(jnp.abs(a), axis=0)) * horizon
    doublings = jnp.clip(jnp.ceil(jnp.log2(jnp.maximum(norm, 1.0) / _FIRST_STEP_NORM)),
                         DOUBLINGS_FINITE, _DOUBLINGS_MAX)
    w, p = _gramian_step(a, q, horizon / 2.0**doublings)

    def double(k, carry):
        return jax.lax.cond(k < doublings, lambda c: (c[0] + c[1].T @ c[0] @ c[1], c[1] @ c[1]),
                            lambda c: c, carry)

    return jax.lax.fori_loop(0, _DOUBLINGS_MAX, double, (w, p))


def first_step_too_long(a, horizon):
    """Whether ||A||_1 T / 2^16 > 8: Van Loan's first step of ``finite_gramian`` must shrink."""
    step = horizon / 2.0**DOUBLINGS_FINITE
    return jnp.max(jnp.sum(jnp.abs(a), axis=0)) * step > _FIRST_STEP_NORM


def _modal_problem(model, x0, v0):
    """(A, z0, omega) of a checked full or reduced model in scaled modal coordinates."""
    system, _, y0x, y0v, _ = unpack(model, x0, v0, None)
    omega, modes, damping_modal, not_definite = scaled_modal(system)
    project = modal_projection(system, modes)
    z0 = jnp.concatenate([omega * project(y0x), project(y0v)])
    return state_matrix(omega, damping_modal), z0, omega, not_definite


@eqx.filter_jit
def van_loan_energy_with_result(model, horizon, x0, v0):
    """The dense ``integrated_energy`` (Van Loan, doubling) on checked inputs: (J, ``RESULTS``)."""
    a, z0, _, not_definite = _modal_problem(model, x0, v0)
    w, _ = finite_gramian(a, jnp.eye(a.shape[0]), horizon)
    w = (w + w.T) / 2
    out_of_range = jnp.max(jnp.sum(jnp.abs(a), axis=0)) * horizon > DENSE_ENERGY_NORM_T
    value = z0 @ w @ z0 / 2
    return value, first_failure((not_definite, RESULTS.not_definite),
                                (out_of_range | ~jnp.isfinite(value), RESULTS.out_of_range))


def takes_spectral(model) -> bool:
    """Whether the spectral path applies (the same rule as ``exact_solve``'s)."""
    return spectral_applies(model) is None


def exact_is_dense(model, method) -> bool:
    """Whether an exact objective's ``method`` ("exact", "spectral", "dense") takes the dense
    path for ``model``: asked for, or the spectral path does not apply (from the structure)."""
    return method == "dense" or not takes_spectral(model)


def integrated_energy_exact_with_result(model, horizon, x0, v0, method="exact"):
    """``integrated_energy`` without a load on checked inputs: (J, ``RESULTS``). ``method``:
    "exact" (spectral where it applies, from the structure alone, else dense), "spectral" or
    "dense". A failure of the spectral path is reported, never replaced by the dense one (which
    under ``jit`` would compile, and under ``vmap`` run, beside it)."""
    if exact_is_dense(model, method):
        return van_loan_energy_with_result(model, horizon, x0, v0)
    value, ok = spectral_energy_with_result(model, horizon, x0, v0)
    return value, RESULTS.where(ok, RESULTS.successful, RESULTS.spectral_failed)


@eqx.filter_jit
def integrated_energy_ode_with_result(model, horizon, x0, v0, load, rtol, atol, *, max_steps,
                                      adjoint):
    """The energy integral as one more state of the diffrax solve (Dopri8), O(n) per stage:
    (J, ``RESULTS``)."""
    system, _, y0x, y0v, load = unpack(model, x0, v0, load)
    accel = acceleration(system, load)
    m = system.size

    def field(t, y, args):
        x, v = y[:m], y[m:2 * m]
        power = (x @ system.stiffness.mv(x) + v @ system.mass.mv(v)) / 2
        return jnp.concatenate([v, accel(t, x, v), power[None]])

    controller = diffrax.PIDController(rtol=rtol, atol=atol)
    if isinstance(load, Pulse):
        controller = diffrax.ClipStepSizeController(controller, jump_ts=load.jump_times)
    y0 = jnp.concatenate([y0x, y0v, jnp.zeros(1)])
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field), diffrax.Dopri8(), 0.0, horizon, None, y0,
        saveat=diffrax.SaveAt(t1=True), stepsize_controller=controller, max_steps=max_steps,
        throw=False, adjoint=adjoint)
    value = sol.ys[-1, -1]
    return value, solve_result(sol, value)


def _modal_size(model) -> int:
    """The size of the dense modal problem: r for a reduced model, n for a full one."""
    return model.rank if isinstance(model, ReducedModel) else model.size


_EXACT_METHODS = ("exact", "spectral", "dense")
_SPELLING = {"exact": "Auto()", "spectral": "Spectral()", "dense": "DenseExponential()"}


def _check_spectral(model, method):
    why = spectral_applies(model) if method == "spectral" else None
    if why is not None:
        raise ValueError(MARK + f"method=Spectral() does not apply: {why}; use method=Auto().")


@raises_value_error
def integrated_energy(model, horizon: float, x0: Vector | None = None,
                      v0: Vector | None = None, load=None, *, method: str = "exact",
                      rtol: float = 1e-9, atol: float = 1e-11, max_steps: int = 100_000,
                      adjoint: diffrax.AbstractAdjoint | None = None) -> Float[Array, ""]:
    """The integrated energy J = int_0^T (x^T K x + x'^T M x') / 2 dt of a response (eq. 3.1).

    ``model`` is a ``SecondOrderSystem`` or a ``ReducedModel`` (x0, v0 and the load in full
    coordinates, projected). ``horizon`` T (time units) > 0; ``x0``, ``v0``: (n,) at t = 0
    (default zero); ``load`` as in ``simulate``. A scalar in energy x time (consistent units).
    Differentiable in every physical value (masses, springs, damper positions and coefficients,
    T, x0, v0): the damper-placement objective ``"energy"``.

    ``method="exact"`` (free vibration only, no tolerance): ``"spectral"`` where it applies and
    holds, else ``"dense"``. ``"spectral"``: from the damped modes in closed form
    (``_spectral_objectives``), O(k n^2) after the undamped modes for k damper columns; applies
    to a full system with discrete dampers and internal damping diagonal in modal coordinates
    (Rayleigh, modal; then O(n^3) in one matrix product), not to a reduced model, a user's
    damping matrix or an undamped system. A mode at or near critical damping (two roots
    meeting) is summed as a pair by a contour integral (``_spectral_clusters``), right to
    rounding on both sides. ``"exact"`` is ``"spectral"`` wherever it applies, chosen from the
    structure alone: where it fails (a root not converged, three roots nearly coinciding) it
    says so in one line, eagerly and under ``jit``, and no dense path is compiled beside it. A
    fixed-free chain with dampers alone above n = 4096 runs in O(n) memory (404 s for J +
    gradient at n = 30000 on 2 cores, ``docs/notes/spectral_energy_large.md``). ``"dense"``: a
    matrix-exponential integral (Van Loan, doubling), O(n^3) -- the choice for a reduced model.
    ``method="ode"``: the integral is one more state of an adaptive Dopri8 solve (``rtol``/
    ``atol``, ``max_steps``, ``adjoint`` as in ``simulate``; use ``diffrax.ForwardMode()`` under
    ``jax.jvp``/``jax.jacfwd``), O(n) per step and loads allowed.
    """
    check_x64()
    if method not in _EXACT_METHODS + ("ode",):
        raise ValueError(MARK + "method must be 'exact', 'spectral', 'dense' or 'ode', got "
                         f"{method!r}.")
    horizon = as_float(horizon, "horizon")
    horizon = check(horizon, ~(jnp.isfinite(horizon) & (horizon > 0)),
                    "horizon must be finite and > 0.")
    x0, v0, load = check_problem(model, x0, v0, load)
    if method in _EXACT_METHODS:
        if load is not None:
            raise ValueError(MARK + f"method={_SPELLING[method]} integrates free vibration only; "
                             "for a load use Energy(..., method=ODE()).")
        _check_spectral(model, method)
        # a chain above n = 4096 with dampers alone: the spectral path in O(n) memory, and no
        # dense fallback (it could not run there either: a failure is reported, not hidden)
        large = not exact_is_dense(model, method) and uses_rows(model)
        if large:
            method = "spectral"
        else:
            check_dense_memory(_modal_size(model), 100 if not takes_spectral(model) else 12,
                               "Energy(method=Auto())")
        value, result = integrated_energy_exact_with_result(model, horizon, x0, v0, method)
        return raise_result(value, result)
    rtol, atol, adjoint = check_solve_options(rtol, atol, max_steps, adjoint)
    value, result = integrated_energy_ode_with_result(
        model, horizon, x0, v0, load, rtol, atol, max_steps=max_steps, adjoint=adjoint)
    return raise_result(value, result, max_steps=max_steps)


@eqx.filter_jit
def _dense_trace_with_result(model, *, lowest):
    """The dense ``total_average_energy`` (doubling of Van Loan's integral): (trace X,
    ``RESULTS``)."""
    system, _, _, _, _ = unpack(model, jnp.zeros(model.size), jnp.zeros(model.size), None)
    omega, _, damping_modal, not_definite = scaled_modal(system)
    a = state_matrix(omega, damping_modal)
    n = omega.shape[0]
    select = jnp.ones(n) if lowest is None else (jnp.arange(n) < lowest).astype(omega.dtype)
    z = jnp.diag(jnp.concatenate([select, select]))
    x, p = infinite_gramian(a, z, omega)
    undamped = ~(jnp.max(jnp.abs(p)) < 1e-8) | ~jnp.all(jnp.isfinite(x))
    return jnp.trace(x), first_failure((not_definite, RESULTS.not_definite),
                                       (undamped, RESULTS.not_damped))


def total_average_energy_with_result(model, *, lowest, method="exact"):
    """The compiled ``total_average_energy`` on checked inputs: (trace X, ``RESULTS``)."""
    if exact_is_dense(model, method):
        return _dense_trace_with_result(model, lowest=lowest)
    value, ok = spectral_trace_with_result(model, lowest=lowest)
    # an undamped mode: X does not exist (inf), which is said as such
    return value, RESULTS.where(ok, RESULTS.successful,
                                RESULTS.where(jnp.isinf(value), RESULTS.not_damped,
                                              RESULTS.spectral_failed))


@raises_value_error
def total_average_energy(model, lowest: int | None = None, *,
                         method: str = "exact") -> Float[Array, ""]:
    """Veselic's total average energy: trace X with A^T X + X A = -Z, a scalar.

    A is the state matrix of M x'' + D x' + K x = 0 (eq. 3.1) in scaled modal coordinates (see
    the module docstring); ``model`` a ``SecondOrderSystem`` or ``ReducedModel``. ``lowest=None``:
    Z = I (every mode); ``lowest=s``: Z selects the s lowest eigenfrequencies (both components of
    each). Its unit is time: X = int_0^inf exp(A^T t) Z exp(A t) dt. Raises if some mode is
    undamped (then X does not exist). Differentiable in the physical values.

    ``method`` as in ``integrated_energy``: ``"exact"`` takes ``"spectral"`` (closed form from the
    damped modes, O(k n^2 + s n^2) for dampers alone, O(n^3) in one matrix product with internal
    damping; a full system with discrete dampers) wherever it applies, else ``"dense"``
    (Smith doubling of Van Loan's integral, O(n^3) per doubling, 64 doublings).
    """
    check_x64()
    if method not in _EXACT_METHODS:
        raise ValueError(MARK + f"method must be 'exact', 'spectral' or 'dense', got {method!r}.")
    check_problem(model, None, None, None)
    modal_size = _modal_size(model)
    check_lowest(lowest, modal_size)
    _check_spectral(model, method)
    check_dense_memory(_modal_size(model), 100 if not takes_spectral(model) else 12,
                       "AverageEnergy()")
    value, result = total_average_energy_with_result(model, lowest=lowest, method=method)
    _name_undamped_modes(model, result, lowest)
    return raise_result(value, result)


def _name_undamped_modes(model, result, lowest):
    """Eagerly, a refusal for an undamped mode names the modes (1-based, by frequency); under a
    caller's ``jit`` the code's own line says the same without the numbers."""
    if (any(is_traced(leaf) for leaf in jax.tree.leaves(result)) or not takes_spectral(model)
            or not bool(np.any(np.asarray(result == RESULTS.not_damped)))):
        return
    from .._solver.spectral.modes import damped_modes

    modes = damped_modes(model)
    undamped = np.asarray(modes.undamped) | ~np.asarray(modes.active)
    if lowest is not None:
        undamped[lowest:] = False
    numbers = (np.nonzero(undamped)[0] + 1).tolist()
    if numbers:
        shown = ", ".join(map(str, numbers[:8])) + (", ..." if len(numbers) > 8 else "")
        which = (f"mode {shown} (1-based, by frequency) is" if len(numbers) == 1 else
                 f"modes {shown} (1-based, by frequency) are")
        raise ValueError(MARK + f"AverageEnergy: {which} undamped (no damper moves "
                         f"{'it' if len(numbers) == 1 else 'them'}), so the Lyapunov solution "
                         "does not exist; place a damper where every mode moves, or restrict Z "
                         f"with lowest=s (s < {numbers[0]}).")


def smooth_peak(values, order: int = 16) -> Float[Array, ""]:
    """(mean_k values_k^order)^(1/order): a smooth peak of |values|, in [N^(-1/order), 1] x max.

    ``values``: any float64 array of N entries (flattened), e.g. the (N, 1) ``displacement`` of
    ``solve(..., dofs=[d])``; a scalar in the units of ``values``. ``order`` an
    even integer >= 2 (higher: closer to the max, less smooth). Scaled by the max, which carries
    no derivative of its own, so large orders do not overflow.
    """
    if isinstance(order, bool) or not isinstance(order, int) or order < 2 or order % 2:
        raise ValueError(MARK + f"order must be an even integer >= 2, got {order!r}.")
    values = jnp.ravel(jnp.asarray(values))
    if values.dtype != jnp.float64 or values.shape[0] < 1:
        raise ValueError(MARK + "values must be a non-empty float64 array, got "
                         f"{values.dtype} of shape {values.shape}.")
    scale = jax.lax.stop_gradient(jnp.max(jnp.abs(values)))
    scale = jnp.where(scale > 0, scale, 1.0)
    return scale * jnp.mean((values / scale) ** order) ** (1.0 / order)
