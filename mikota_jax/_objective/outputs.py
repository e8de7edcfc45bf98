"""Weighted output criteria of a system with dampers: the energy of an output, its average over
initial states, and the H2 norm of an input-output map; exact, from the damped modes.

For y(t) = C_x x(t) + C_v x'(t) (q outputs) of the free vibration M x'' + D x' + K x = 0,

* ``output_energy`` = sum over initial states z0_i of int_0^T |y(t)|^2 dt = trace(C P C^T)
  with P = int_0^T exp(A t) Z exp(A^T t) dt, Z = sum_i z0_i z0_i^T, in the first-order
  coordinates (x, x') with C = [C_x, C_v] (T = inf: A P + P A^T = -Z, a Lyapunov equation);
* ``h2_norm``: ||G||_H2 for G(s) = (C_x + s C_v)(s^2 M + s D + K)^-1 B, the same with the
  impulse responses of the inputs' columns as initial states (x(0) = 0, x'(0) = M^-1 B e_i),
  squared-rooted.

Which coordinates a trace is taken in matters: Veselic's total average energy trace X, A^T X +
X A = -Z in the scaled modal coordinates z = (Omega eta, eta') of ``total_average_energy`` and
FastOptimalDamping.jl, is ``output_energy`` with C_x = Omega U^T M, C_v = U^T M (the energy norm
|z|^2 = x^T K x + x'^T M x') and ``lowest`` s: the 2s unit states (Omega eta = e_i, eta' = e_i)
of the s lowest modes. Truhar & Veselic (SIAM J. Matrix Anal. Appl. 31:18, 2009) and Benner,
Tomljanovic & Truhar (2011) weight displacements and velocities in the same coordinates; a trace
of the physical (x, x') Gramian with C = I is another number (different bases give different
traces). The H2 norm is the criterion of Tomljanovic, Beattie & Gugercin (2018) for damping
optimisation with inputs and outputs.

Cost: O((q + m) n^2 + k n^2) after the undamped modes, where q is the number of outputs and m of
initial states (``_spectral_objectives.output_energy_from_modes``); differentiable in every
physical value (positions, coefficients, M, K) by the secular equation's implicit derivative.
Applies where the spectral path does: a full system with discrete dampers and internal damping
diagonal in modal coordinates. A ``ReducedModel`` (``reduce``) takes both criteria densely in
its r scaled modal coordinates (``_reduced_output_energy``: one Van Loan integral of the
observability Gramian by doubling, O(r^3)), with the outputs and initial states in full
coordinates as for the full model; ``jax.grad`` passes through it too.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Float
from .._errors import MARK, as_float, check, check_lowest, check_x64, raises_value_error
from .._model.modal import modal_projection, scaled_modal
from .._model.modal import state_matrix as modal_state_matrix
from .._model.reduced import ReducedModel
from .._model.system import SecondOrderSystem
from .._solver.spectral.energy import spectral_output_energy_with_result
from .._solver.spectral.modes import spectral_applies
from .functions import finite_gramian, infinite_gramian

_NOT_OK = ("the damped modes did not converge, or roots nearly coincide beyond a critically "
           "damped pair; move the damper coefficients off that point.")
_UNDAMPED_SEEN = ("a mode that nothing damps is excited by the inputs (or initial states) and "
                  "seen by the outputs: the infinite-horizon value does not exist; give a "
                  "finite horizon or move a damper off that mode's node.")
_NOT_OK_REDUCED = ("the reduced model is not definite, or one of its modes does not decay "
                   "(no damper reaches it): give a finite horizon or move a damper.")


def _matrix(value, n: int, name: str, rows: bool):
    """None, or a float64 matrix: (q, n) when ``rows`` (an output matrix), else (n, m)."""
    if value is None:
        return None
    array = as_float(value, name)
    if array.ndim == 1:
        array = array[None, :] if rows else array[:, None]
    axis = 1 if rows else 0
    if array.ndim != 2 or array.shape[axis] != n or 0 in array.shape:
        shape = "(q, n) or (n,)" if rows else "(n, m) or (n,)"
        raise ValueError(MARK + f"{name} must be {shape} with n = {n}, got shape "
                         f"{tuple(array.shape)}.")
    return check(array, ~jnp.all(jnp.isfinite(array)), f"{name} must be finite.")


def output_arguments(system, cx, cv):
    """(C_x, C_v), each (q, n) (a missing one zero), for a system the spectral path takes or a
    ``ReducedModel``."""
    if not isinstance(system, SecondOrderSystem | ReducedModel):
        raise ValueError(MARK + f"system must be a SecondOrderSystem or a ReducedModel, got "
                         f"{type(system).__name__}.")
    why = None if isinstance(system, ReducedModel) else spectral_applies(system)
    if why is not None:
        raise ValueError(MARK + f"system: {why}.")
    return output_matrices(system.size, cx, cv)


def output_matrices(n: int, cx, cv):
    """(C_x, C_v), each checked (q, n) (an (n,) vector is one output; a missing one is zero;
    at least one given)."""
    cx, cv = _matrix(cx, n, "cx", True), _matrix(cv, n, "cv", True)
    if cx is None and cv is None:
        raise ValueError(MARK + "give an output: cx (on displacements) and/or cv (on "
                         "velocities), each (q, n) or (n,).")
    if cx is not None and cv is not None and cx.shape[0] != cv.shape[0]:
        raise ValueError(MARK + f"cx and cv must have the same number of rows (outputs), got "
                         f"{cx.shape[0]} and {cv.shape[0]}.")
    zero = jnp.zeros((cx if cv is None else cv).shape)
    return (zero if cx is None else cx), (zero if cv is None else cv)


def output_states(n: int, x0, v0, lowest):
    """The initial states of ``output_energy``: x0, v0 as (n, m) (or None), checked with
    ``lowest``."""
    x0, v0 = state_matrix(x0, n, "x0"), state_matrix(v0, n, "v0")
    if x0 is not None and v0 is not None and x0.shape[1] != v0.shape[1]:
        raise ValueError(MARK + f"x0 and v0 must hold the same number of states (columns), "
                         f"got {x0.shape[1]} and {v0.shape[1]}.")
    if lowest is not None and (x0 is not None or v0 is not None):
        raise ValueError(MARK + "give either lowest (unit modal states) or x0/v0, not both.")
    check_lowest(lowest, n)
    return x0, v0


def state_matrix(value, n: int, name: str, required: bool = False):
    """None, or (n, m) float64 columns (an (n,) vector is one column)."""
    if required and value is None:
        raise ValueError(MARK + f"{name} must be (n, m) or (n,) with n = {n}, got None.")
    return _matrix(value, n, name, False)


def output_horizon(horizon):
    """None (T = inf), a checked Python float, or a checked (possibly traced) float64 array."""
    message = f"horizon must be None (infinite) or a finite time > 0, got {horizon!r}."
    if horizon is None:
        return None
    if isinstance(horizon, int | float) and not isinstance(horizon, bool):
        if not (np.isfinite(horizon) and horizon > 0):
            raise ValueError(MARK + message)
        return float(horizon)
    value = as_float(horizon, "horizon")
    return check(value, ~(jnp.isfinite(value) & (value > 0)), message)


@raises_value_error
def output_energy(system: SecondOrderSystem, cx=None, cv=None, *, x0=None, v0=None,
                  lowest: int | None = None, horizon: float | None = None) -> Float[Array, ""]:
    """sum_i int_0^T |C_x x_i(t) + C_v x_i'(t)|^2 dt over the free vibrations from the initial
    states i (see the module docstring; its relation to Veselic's trace is stated there).

    ``cx``, ``cv``: (q, n) output matrices on displacements and velocities (one may be None;
    an (n,) vector is one output). Initial states: the columns of ``x0``, ``v0`` ((n,) or
    (n, m); a missing one is zero), or ``lowest`` s: the 2s unit states of the s lowest modes
    in scaled modal coordinates (the average-energy weight Z of ``total_average_energy``);
    neither: all 2n of them. ``horizon``: T > 0, or None for T = inf (then refused where a mode
    that nothing damps is excited and reaches the output; such modes that the states do not
    excite or the outputs do not see are dropped). Units: output^2 x time.
    """
    check_x64()
    cx, cv = output_arguments(system, cx, cv)
    x0, v0 = output_states(system.size, x0, v0, lowest)
    if isinstance(system, ReducedModel):
        check_lowest(lowest, system.rank)
        value, ok = _reduced_output_energy(_bare(system), x0, v0, None, cx, cv,
                                           output_horizon(horizon), lowest)
        return check(value, ~ok, _NOT_OK_REDUCED)
    value, ok = spectral_output_energy_with_result(system, x0, v0, None, cx, cv,
                                                   output_horizon(horizon), lowest)
    value = check(value, ~ok & ~jnp.isinf(value), _NOT_OK)
    return check(value, jnp.isinf(value), _UNDAMPED_SEEN)


@raises_value_error
def h2_norm(system: SecondOrderSystem, inputs, cx=None, cv=None) -> Float[Array, ""]:
    """||G||_H2 of G(s) = (C_x + s C_v)(s^2 M + s D + K)^-1 B: the square root of the output
    energy of the impulse responses of ``inputs`` B ((n, m) or (n,): force directions), over
    [0, inf). ``cx``, ``cv`` as in ``output_energy``. Refused if a mode that nothing damps
    (a zero coefficient, or a damper on the mode's node to rounding: ``DampedModes.undamped``)
    is excited by the inputs and seen by the outputs; such modes that the inputs do not excite
    or the outputs do not see contribute nothing and are dropped."""
    check_x64()
    cx, cv = output_arguments(system, cx, cv)
    forces = state_matrix(inputs, system.size, "inputs", required=True)
    if isinstance(system, ReducedModel):
        value, ok = _reduced_output_energy(_bare(system), None, None, forces, cx, cv, None,
                                           None)
        return jnp.sqrt(check(value, ~ok, _NOT_OK_REDUCED))
    value, ok = spectral_output_energy_with_result(system, None, None, forces, cx, cv, None,
                                                   None)
    value = check(value, ~ok & ~jnp.isinf(value), _NOT_OK)
    return jnp.sqrt(check(value, jnp.isinf(value), _UNDAMPED_SEEN))


def _bare(model: ReducedModel) -> ReducedModel:
    """The model without its stats: they are static data (a strategy's shifts, a greedy
    history), and two models of one shape must share one compiled program."""
    return ReducedModel(model.system, model.basis)


@eqx.filter_jit
def _reduced_output_energy(model, x0, v0, forces, cx, cv, horizon, lowest):
    """(value, ok) of ``output_energy`` for a ``ReducedModel``, dense: in the reduced model's
    scaled modal coordinates z = (Omega eta, eta') (q = U eta, x = Phi U eta), the output is
    C z with C = [C_x Phi U Omega^-1, C_v Phi U], and the value is sum_i z0_i^T W z0_i with the
    observability Gramian W = int_0^T exp(A^T t) C^T C exp(A t) dt (Van Loan, doubling). The
    initial states are projected as ``simulate`` projects them (q0 = Phi^T x0); an impulse f
    gives eta'(0+) = (Phi U)^T f; ``lowest`` s: the 2s unit states of the reduced model's s
    lowest modes. ok: the reduced model is definite, and for T = inf every mode the output
    sees decays."""
    system, basis = model.system, model.basis
    omega, modes, damping_modal, not_definite = scaled_modal(system)
    lift = basis @ modes
    a = modal_state_matrix(omega, damping_modal)
    c = jnp.concatenate([cx @ lift / omega[None, :], cv @ lift], axis=1)
    r = omega.shape[0]
    if lowest is None and x0 is None and v0 is None and forces is None:
        lowest = r  # no state given: all 2r unit states
    if lowest is not None:
        select = (jnp.arange(r) < lowest).astype(omega.dtype)
        z0 = jnp.diag(jnp.concatenate([select, select]))
    else:
        project = modal_projection(system, modes)
        columns = next(v for v in (x0, v0, forces) if v is not None).shape[1]
        zero = jnp.zeros((r, columns))
        q0 = zero if x0 is None else omega[:, None] * project(basis.T @ x0)
        p0 = zero if v0 is None else project(basis.T @ v0)
        if forces is not None:
            p0 = p0 + lift.T @ forces
        z0 = jnp.concatenate([q0, p0])
    weight = c.T @ c
    if horizon is None:
        w, p = infinite_gramian(a, weight, omega)
        decays = jnp.max(jnp.abs(p)) < 1e-8
    else:
        w, _ = finite_gramian(a, weight, horizon)
        decays = True
    value = jnp.sum(z0 * (((w + w.T) / 2) @ z0))
    return value, ~not_definite & decays & jnp.isfinite(value)
