"""``exact_solve``: the exact solution of a linear time-invariant system on a time grid.

Method: the generalized eigenproblem K u = omega^2 M u (M = L L^T, eigh of L^-1 K L^-T) gives
M-orthonormal modes U. In scaled modal coordinates z = (Omega eta, eta'), x = U eta, the system
reads z' = A z + b with A = [[0, Omega], [-Omega, -U^T D U]] (skew plus a negative semi-definite
block, so ||exp(A t)|| <= 1 and the propagator is nearly orthogonal: no loss of accuracy with n,
unlike expm of the physical state matrix). One step is z_{k+1} = P z_k + (I - P) z*_k with P =
exp(A h) and z* = (Omega^-1 U^T f, 0) the static equilibrium of the load on the step: exact for
loads that are constant between jumps. A jump at t_b inside (t_k, t_{k+1}] adds (I - exp(A (t_{k+1}
- t_b))) (z*_after - z*_before). Undamped systems skip expm: P is a rotation by omega_l h in each
mode.

A full system whose damping is discrete dampers only takes the spectral path instead
(``_spectral_solve``: the damped modes, every output at every time as one matrix product, any
grid); this dense path is its fallback where the modes do not hold (critical damping).
"""

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from .._custom_types import Times, Vector
from .._errors import (
    MARK,
    RESULTS,
    array_module,
    check,
    check_dense_memory,
    check_output_memory,
    check_x64,
    first_failure,
    raise_result,
    raises_value_error,
)
from .._model.loads import LoadFunction, Pulse
from .._model.modal import modal_projection, scaled_modal, state_matrix
from .._model.reduced import ReducedModel
from .ode import (
    SPECTRAL_MATRICES,
    Trajectory,
    check_dofs,
    check_problem,
    check_times,
    unpack,
)
from .spectral.modes import uses_rows
from .spectral.response import spectral_applies, spectral_solve_with_result

_PULSE_ERROR = 1e-6
_UNIFORM = 1e-9  # relative spread of the steps within which one propagator serves them all


def _step_tolerance(ts, first, xp=jnp):
    """How far a step may differ from the first and still count as uniform: 1e-9 of it, or the
    rounding of t itself (8 ulps of the largest |t|): start + step k in float64 spreads the steps
    by ulp(t), 1.5e-8 of a 1e-3 step at t = 1e5 (such grids were refused as non-uniform)."""
    if xp is np:  # concrete: numpy throughout (indexing a jax array under a trace is staged)
        ts, first = np.asarray(ts), np.asarray(first)
    scale = xp.maximum(xp.abs(ts[0]), xp.abs(ts[-1]))
    return xp.maximum(_UNIFORM * xp.abs(first), 8 * xp.finfo(ts.dtype).eps * scale)
METHODS = ("auto", "spectral", "dense")


_MAX_SQUARINGS = 64


def _propagator(omega, damping_modal):
    """tau -> (z -> exp(A tau) z)."""
    n = omega.shape[0]
    if damping_modal is None:
        def apply(tau):
            c, s = jnp.cos(omega * tau), jnp.sin(omega * tau)
            return lambda z: jnp.concatenate([c * z[:n] + s * z[n:], -s * z[:n] + c * z[n:]])
        return apply
    a = state_matrix(omega, damping_modal)

    def apply(tau):
        # 64 squarings (jax's default 16 returns NaN past ||A tau|| ~ 3.5e5: a strong damper, a
        # coarse grid); a lax.cond each, so only the ones needed run
        p = jsl.expm(a * tau, max_squarings=_MAX_SQUARINGS)
        return lambda z: p @ z

    return apply


@eqx.filter_jit
def _exact(model, ts, x0, v0, load, *, dofs, displacement, velocity, uniform=True):
    system, basis, y0x, y0v, load = unpack(model, x0, v0, load)
    omega, modes, damping_modal, not_definite = scaled_modal(system)
    project = modal_projection(system, modes)
    n = omega.shape[0]
    propagate = _propagator(omega, damping_modal)
    if damping_modal is not None:  # one expm for the whole (uniform) grid
        # the mean step: (t_N - t_0) / (N - 1) is exact to ulp(t) / N, the first gap only to
        # ulp(t), an error the propagator would repeat N times (far from t = 0)
        first = (ts[-1] - ts[0]) / (ts.shape[0] - 1) if ts.shape[0] > 1 else jnp.zeros(())
        fixed = propagate(first)
        step_of = lambda k: fixed
        if not uniform:  # any grid (the spectral path's fallback): an expm where a step differs
            a = state_matrix(omega, damping_modal)
            fixed_matrix = jsl.expm(a * first, max_squarings=_MAX_SQUARINGS)

            def step_of(k):
                h = ts[k + 1] - ts[k]
                p = jax.lax.cond(jnp.abs(h - first) <= _step_tolerance(ts, first),
                                 lambda: fixed_matrix,
                                 lambda: jsl.expm(a * h, max_squarings=_MAX_SQUARINGS))
                return lambda z: p @ z
    else:  # undamped: a rotation per mode, any grid
        step_of = lambda k: propagate(ts[k + 1] - ts[k])
    z0 = jnp.concatenate([omega * project(y0x), project(y0v)])

    if load is None:
        def advance(z, k):
            return step_of(k)(z)
    else:
        z_star = jnp.concatenate([(modes.T @ load.direction) / omega, jnp.zeros(n)])
        jumps, signs = load.jump_times, jnp.array([1.0, -1.0])
        # step k covers (t_k, t_{k+1}]; a jump at or before ts[0] is in the initial load value.
        jump_steps = (jnp.searchsorted(ts, jumps, side="left") - 1).astype(jnp.int64)
        corrections = [s * (z_star - propagate(ts[jnp.clip(i + 1, 0, ts.shape[0] - 1)] - t)(z_star))
                       for s, i, t in zip(signs, jump_steps, jumps)]

        def advance(z, k):
            t = ts[k]
            on = (t >= load.start) & (t < load.start + load.duration)
            step = step_of(k)
            z = step(z) + jnp.where(on, 1.0, 0.0) * (z_star - step(z_star))  # (I - P) z*
            for i, c in zip(jump_steps, corrections):
                z = z + jnp.where(k == i, 1.0, 0.0) * c
            return z

    index = None if dofs == tuple(range(1, model.size + 1)) else jnp.asarray(dofs) - 1
    lift = modes if basis is None else basis @ modes
    rows = lift if index is None else lift[index]
    rows_x = rows / omega[None, :]

    def output(z):
        return (rows_x @ z[:n] if displacement else None, rows @ z[n:] if velocity else None)

    def body(z, k):
        z_next = advance(z, k)
        return z_next, output(z_next)

    _, ys = jax.lax.scan(body, z0, jnp.arange(ts.shape[0] - 1, dtype=jnp.int64))
    first = output(z0)
    ys = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), first, ys)
    finite = jnp.all(jnp.asarray([jnp.all(jnp.isfinite(y)) for y in ys if y is not None]))
    # the pulse enters as differences of |z*| ~ amplitude / omega: relative error eps/(omega tau)
    too_short = (jnp.finfo(omega.dtype).eps / (omega[0] * load.duration) > _PULSE_ERROR
                 if load is not None else jnp.array(False))
    result = first_failure((not_definite, RESULTS.not_definite),
                           (~finite, RESULTS.exact_not_finite),
                           (too_short, RESULTS.pulse_too_short))
    return Trajectory(ts, ys[0], ys[1], dofs, None), result


@raises_value_error
def exact_solve(model, ts: Times, x0: Vector | None = None, v0: Vector | None = None, load=None,
                *, dofs: Sequence[int] | None = None, displacement: bool = True,
                velocity: bool = False, method: str = "auto") -> Trajectory:
    """The exact solution of M x'' + D x' + K x = f (eq. 3.1) for no load or a ``Pulse`` (eq. 4.3).

    Same arguments and outputs as ``simulate``: ``model`` a ``SecondOrderSystem`` or a
    ``ReducedModel`` (solved in r DOFs, lifted back by eq. 3.2); ``ts`` (N,); ``x0``, ``v0`` (n,)
    in full coordinates (default zero); ``dofs`` 1-based (default all, d = len(dofs)); returns a
    ``Trajectory`` of (N, d) arrays, ``num_steps`` None. No integration error.

    ``method``: "spectral", "dense" or "auto" (spectral where it applies, else dense). The
    spectral path applies to a full ``SecondOrderSystem`` whose damping is discrete dampers
    (``GroundedDamper``, ``RelativeDamper``), with or without internal damping that is diagonal
    in modal coordinates (``Rayleigh``, ``ModalDamping``): x(t) = Re sum_j a_j exp(lambda_j t) U
    y_j over the 2n damped modes (``_spectral``), every requested output at every time as one
    matrix product; any increasing grid; the undamped modes (O(n^2) for a fixed-free chain,
    else one dense eigendecomposition), the secular equation for the roots (O(k^2 n^2) a sweep,
    k damper columns) and O(N d n) for the outputs; a pair of roots at or near critical damping
    is summed by a contour integral around it (``_spectral_clusters``), right to rounding on
    both sides of the double root. The choice is made from the structure alone: where the
    spectral path fails (a root not converged, three roots nearly coinciding) it says so in one
    line (use ``method="dense"``), eagerly and under ``jit``, and nothing else is compiled or
    run. The dense path (the only one for a ``ReducedModel``, a user's
    damping matrix or an undamped system): modal coordinates and a matrix exponential; any
    increasing grid when undamped (a rotation per mode), a uniform grid when damped (one 2n x 2n
    matrix exponential serves every step); one eigendecomposition and O(n^2) per time step.
    Dense memory limits n on
    both paths (``simulate`` is O(n)): some 32 n x n float64 arrays on the dense one, 12 on the
    spectral one, except for a fixed-free chain with dampers alone above n = 4096: its spectral
    path holds neither U nor the (n, 2n) vectors (O(n (N + 2^24 / n)) memory: the (N, n) modal
    history, then x = U eta a chunk of modes at a time; 401 times x all DOFs at n = 30000 in
    235 s at 1.9 GiB on 2 cores, ``docs/notes/spectral_response_large.md``).
    """
    check_x64()
    if method not in METHODS:
        raise ValueError(MARK + f"method must be 'auto', 'spectral' or 'dense', got {method!r}.")
    if isinstance(load, LoadFunction) or (load is not None and not isinstance(load, Pulse)):
        raise ValueError(MARK + "the exact methods (Spectral(), DenseExponential()) take "
                         "load=None or a Pulse (piecewise constant); integrate a general f(t) "
                         "with solve(..., method=ODE()).")
    if not (displacement or velocity):
        raise ValueError(MARK + "ask for displacement and/or velocity; nothing would be saved.")
    refusal = spectral_applies(model)
    if method == "spectral" and refusal is not None:
        raise ValueError(MARK + f"Spectral() does not apply: {refusal}; use "
                         "DenseExponential().")
    spectral = refusal is None and method != "dense"
    ts = check_times(ts)
    system = model.system if isinstance(model, ReducedModel) else model
    if ts.shape[0] > 2 and system.damped and not spectral:
        xp = array_module(ts)
        gaps = xp.diff(ts)
        ts = check(ts, xp.max(xp.abs(gaps - gaps[0])) > _step_tolerance(ts, gaps[0], xp),
                   "ts must be a uniform grid for DenseExponential() of a damped system; use "
                   "method=ODE() for other grids.")
    x0, v0, load = check_problem(model, x0, v0, load)
    damped = system.damped
    if not (spectral and uses_rows(system)):  # a large chain's spectral path: O(n (N + block))
        check_dense_memory(system.size, (SPECTRAL_MATRICES if spectral else 32) if damped else 6,
                           "DenseExponential()" if not spectral else "Spectral()")
    options = dict(dofs=check_dofs(dofs, model.size), displacement=displacement,
                   velocity=velocity)
    # the outputs and the (N, n) complex coefficient tables of the modal sums
    check_output_memory(ts.shape[0], len(options["dofs"]) * (displacement + velocity)
                        + 4 * system.size, "the exact solution")
    if not spectral:
        trajectory, result = _exact(model, ts, x0, v0, load, **options)
        return raise_result(trajectory, result)
    # the path is chosen from the structure alone: no dense fallback is compiled or run where
    # the spectral one fails (a root not converged, roots nearly coinciding outside a pair),
    # which is reported in one line instead
    trajectory, ok = spectral_solve_with_result(model, ts, x0, v0, load, **options)
    return raise_result(trajectory, RESULTS.where(ok, RESULTS.successful,
                                                  RESULTS.spectral_failed))


dense_solve_with_result = _exact  # the dense path by name (``mikota_jax.testing``)
