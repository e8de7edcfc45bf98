"""The placement objective: a design (positions, coefficients) -> the problem's objective.

Reduced (a POD basis held fixed, no derivative through the SVD; the Galerkin model of eq. 3.4) or
full. Where the reduced objective is exact in modal coordinates (free vibration, or the total
average energy) the basis is prepared once as a ``_ModalROM``: a design then changes only its
dampers' rows, and the objective comes from the damped modes of r modal coordinates. Every
diffrax solve is differentiated in forward mode inside a custom VJP (a design has 2 g
parameters, so forward mode is the cheap direction).

Shapes: ``positions`` (g,), 1-based in [1, n]; ``coefficients`` (g,), >= 0; ``basis`` (n, r).
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from .._errors import MARK, RESULTS
from .._model.modal import generalized_modes, state_matrix
from .._model.operators import Diagonal
from .._model.parameters import check_parameters
from .._model.reduced import ReducedModel, galerkin
from .._model.system import SecondOrderSystem
from .._solver.spectral.modes import live_modal_modes
from .problem import DamperProblem


class _ModalROM(eqx.Module):
    """A reduced model in its modal coordinates, prepared once per basis.

    Psi = Phi U with U^T (Phi^T M Phi) U = I and U^T (Phi^T K Phi) U = diag(omega^2): a design
    only changes the dampers, Psi^T D Psi = B diag(w) B^T (B = rows of Psi), a low-rank term on
    r modes: the spectral path's structure, so each evaluation is the damped modes of that
    modal system and the objective in closed form from them, O(k r^2) (``live_modal_modes``),
    no eigendecomposition and no matrix exponential. With internal damping that is not diagonal
    in these coordinates (modal or a user's matrix, which a projection makes one dense r x r
    matrix, ``internal``) the state matrix's exponentials instead, O(r^3) per design: chosen
    from that structure, as the full model chooses between its spectral and dense paths.
    """

    omega: jax.Array
    modes: jax.Array  # Psi, n x r
    q0: jax.Array  # eta0 = Psi^T M x0
    p0: jax.Array  # eta0' = Psi^T M v0
    not_definite: jax.Array
    rates: jax.Array | None = None  # internal damping diagonal in modal coordinates (Rayleigh)
    internal: jax.Array | None = None  # otherwise: the internal damping, r x r modal


def _modal_rom(problem: DamperProblem, basis) -> _ModalROM:
    base = problem.base
    reduced = SecondOrderSystem(base.mass, base.stiffness, None, base.internal).project(basis)
    omega2, modes = generalized_modes(reduced)
    not_definite = jnp.any(omega2 <= 0)
    omega = jnp.sqrt(jnp.where(omega2 > 0, omega2, 1.0))
    mass = reduced.mass.as_matrix()
    project = lambda y: modes.T @ (mass @ (basis.T @ y))  # noqa: E731
    rates = internal = None
    if reduced.internal is not None:
        in_modes = reduced.internal.in_modes(omega2, modes)
        if isinstance(in_modes, Diagonal):
            rates = in_modes.diagonal
        else:
            internal = in_modes.as_matrix()
    return _ModalROM(omega, basis @ modes, project(problem.x0), project(problem.v0),
                     not_definite, rates, internal)


def _modal_objective(problem: DamperProblem, rom: _ModalROM, positions, coefficients):
    damping = problem.system(positions, coefficients).damping
    if rom.internal is None:  # dampers (and diagonal internal damping): the damped modes
        low_rank = damping.project(rom.modes)
        modes, ok = live_modal_modes(rom.omega, low_rank.factor, low_rank.weights, rom.rates)
        value = problem.objective.from_modes(problem, modes, rom.q0, rom.p0)
        return value, rom.not_definite | ~ok | ~jnp.isfinite(value)
    a = state_matrix(rom.omega, damping.project(rom.modes).as_matrix() + rom.internal)
    z0 = jnp.concatenate([rom.omega * rom.q0, rom.p0])
    value, undamped = problem.objective.in_modes(problem, rom.omega, z0, a)
    return value, rom.not_definite | undamped | ~jnp.isfinite(value)


def reduced_form(problem: DamperProblem, basis):
    """What the objective needs of a basis: a ``_ModalROM`` where it is exact, else the basis."""
    if basis is None or not problem.objective.exact_in_modes(problem):
        return basis
    return _modal_rom(problem, basis)


def _evaluate(problem: DamperProblem, model):
    """(objective value, failed) of a full or reduced model; ODE solves use forward mode."""
    value, result = problem.objective.evaluate(problem, model)
    failed = jnp.any(result != RESULTS.successful) | ~jnp.isfinite(value)
    return value, failed


def objective_function(problem: DamperProblem, reduced):
    """(positions, coefficients) -> (value, failed); ``reduced`` from ``reduced_form``, or None
    for the full model.

    Reverse-mode differentiable. A ``_ModalROM`` is exact (its damped modes, reverse mode);
    every diffrax solve is differentiated in forward mode, wrapped in a custom VJP (the design
    has only 2 x dampers parameters, so forward mode is the cheap direction). The full model's
    free-vibration "energy" is the spectral closed form (``Energy``). No check inside: the
    optimiser's designs are valid by construction, so its compiled steps hold no callback of ours.
    """
    if isinstance(reduced, _ModalROM):
        return lambda positions, coefficients: _modal_objective(problem, reduced, positions,
                                                                coefficients)

    def raw(positions, coefficients):
        model = problem.system(positions, coefficients)
        if reduced is not None:
            model = ReducedModel(model.project(reduced), reduced)  # eq. (3.4); basis checked
        return _evaluate(problem, model)

    if not problem.objective.forward_mode:
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


def placement_objective(problem: DamperProblem, basis=None):
    """The problem's objective as a pure function (positions, coefficients) -> value.

    Reduced (POD ``basis`` held fixed, (n, r); the Galerkin model of eq. 3.4) or full
    (``basis=None``). ``jax.grad``, ``jax.jit`` and ``jax.vmap`` pass through it; the value is a
    scalar, NaN where a solve failed (never silently finite). ``positions``: (g,) (or a scalar for
    g = 1), 1-based in [1, n] (between DOFs a damper is split linearly); ``coefficients``: (g,),
    >= 0, in force * time per length; both checked on entry (``eqx.error_if`` when traced).
    """
    if not isinstance(problem, DamperProblem):
        raise ValueError(MARK + f"problem must be a DamperProblem, got {type(problem).__name__}.")
    if basis is not None:
        basis = jnp.asarray(basis)
        if basis.ndim != 2 or basis.shape[0] != problem.size or basis.dtype != jnp.float64:
            raise ValueError(MARK + f"basis must be a float64 (n, r) array with n = "
                             f"{problem.size}, got {basis.dtype} {basis.shape}.")
        basis = galerkin(problem.base, basis).basis  # orthonormal: checked here, once

    def objective(positions, coefficients):
        positions = jnp.atleast_1d(jnp.asarray(positions, jnp.float64))
        coefficients = jnp.atleast_1d(jnp.asarray(coefficients, jnp.float64))
        design = check_parameters(problem.base, dict(positions=positions,
                                                     coefficients=coefficients))
        value, failed = objective_function(problem, reduced_form(problem, basis))(
            design["positions"], design["coefficients"])
        return jnp.where(failed, jnp.nan, value)

    return objective
