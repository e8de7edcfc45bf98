"""solve's exact methods and its ODE integration against matrix exponentials, closed forms,
scipy and each other.

Small chains (n = 8) and few distinct shapes: every new shape or structure recompiles a solver.
"""

from functools import partial

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sl
from scipy.integrate import solve_ivp

import mikota_jax as mj
from mikota_jax._solver.ode import simulate

N = 8
M_, K_ = 1.3, 0.9  # m and k of the chain, not 1, so that Omega = sqrt(k/m) is not 1
OMEGA = np.sqrt(K_ / M_)
TS = np.linspace(0.0, 5.0, 51)
DAMPERS = (mj.GroundedDamper(3.4, 0.8), mj.RelativeDamper((2, 6), 0.3))


@pytest.fixture(scope="module")
def undamped():
    return mj.mikota_chain(N, M_, K_)


@pytest.fixture(scope="module")
def damped():
    return mj.mikota_chain(N, M_, K_, dampers=DAMPERS)


@pytest.fixture(scope="module")
def state():
    rng = np.random.default_rng(0)
    return rng.standard_normal(N), rng.standard_normal(N)


def first_order(system):
    """A = [[0, I], [-M^-1 K, -M^-1 D]] of the state (x, v)."""
    M, D, K = (None if a is None else np.asarray(a) for a in system.dense())
    n = M.shape[0]
    D = np.zeros((n, n)) if D is None else D
    Mi = np.linalg.inv(M)
    return np.block([[np.zeros((n, n)), np.eye(n)], [-Mi @ K, -Mi @ D]]), Mi


def expm_reference(system, ts, x0, v0):
    A, _ = first_order(system)
    y = np.stack([sl.expm(A * t) @ np.concatenate([x0, v0]) for t in ts])
    return y[:, :N], y[:, N:]


def ivp_reference(system, ts, force, breaks=(), y0=None):
    """solve_ivp DOP853 at rtol 1e-12, restarted at every break of the load (``force(t)``)."""
    A, Mi = first_order(system)
    rhs = lambda t, y: A @ y + np.concatenate([np.zeros(N), Mi @ force(t)])
    edges = [ts[0], *[b for b in breaks if ts[0] < b < ts[-1]], ts[-1]]
    y = np.zeros(2 * N) if y0 is None else y0
    out = np.zeros((len(ts), 2 * N))
    out[0] = y
    for a, b in zip(edges[:-1], edges[1:]):
        if breaks:  # piecewise constant: take the load inside the segment, never on a jump
            f = Mi @ force((a + b) / 2)
            field = lambda t, y, f=f: A @ y + np.concatenate([np.zeros(N), f])
        else:
            field = rhs
        seg = solve_ivp(field, (a, b), y, method="DOP853", rtol=1e-12, atol=1e-14,
                        dense_output=True)
        inside = (ts > a) & (ts <= b)
        if np.any(inside):
            out[inside] = seg.sol(ts[inside]).T
        y = seg.y[:, -1]
    return out[:, :N], out[:, N:]


def energy(system, x, v):
    M, _, K = system.dense()
    M, K = np.asarray(M), np.asarray(K)
    return 0.5 * (np.einsum("ti,ij,tj->t", x, K, x) + np.einsum("ti,ij,tj->t", v, M, v))


# --- exact methods ----------------------------------------------------------------------------


@pytest.mark.parametrize("which", ["undamped", "damped"])
def test_exact_solve_equals_the_matrix_exponential_of_the_state_matrix(which, state, close,
                                                                       request):
    system = request.getfixturevalue(which)
    x0, v0 = state
    x_ref, v_ref = expm_reference(system, TS, x0, v0)
    method = mj.Spectral() if which == "damped" else mj.DenseExponential()  # auto's pick
    out = mj.solve(system, TS, x0, v0, velocity=True, method=method)
    scale = np.max(np.abs(x_ref))
    close(out.displacement, x_ref, atol=1e-11 * scale)
    close(out.velocity, v_ref, atol=1e-11 * np.max(np.abs(v_ref)))
    assert out.displacement.shape == out.velocity.shape == (len(TS), N)


def test_first_mode_initial_displacement_oscillates_as_u1_cos_omega_t(undamped, close):
    u1 = np.arange(1.0, N + 1)  # p_1(i) = i (eq. 2.6)
    out = mj.solve(undamped, TS, u1, None, velocity=True, method=mj.DenseExponential())
    close(out.displacement, np.cos(OMEGA * TS)[:, None] * u1, atol=1e-12 * N)
    close(out.velocity, -OMEGA * np.sin(OMEGA * TS)[:, None] * u1, atol=1e-12 * N)


def test_exact_solve_on_a_non_uniform_grid_when_undamped(undamped, close):
    ts = np.sort(np.random.default_rng(1).uniform(0, 5, 51))
    u1 = np.arange(1.0, N + 1)
    out = mj.solve(undamped, ts, u1, method=mj.DenseExponential())  # x(ts[0]) = u1
    close(out.displacement, np.cos(OMEGA * (ts - ts[0]))[:, None] * u1, atol=1e-12 * N)


@pytest.mark.parametrize("start, duration", [
    (0.0, 0.05), pytest.param(0.21, 0.37, marks=pytest.mark.slow), (0.2, 0.4)])
def test_exact_solve_with_a_pulse_matches_solve_ivp(damped, start, duration, close):
    # (0.2, 0.4): both jumps fall exactly on grid points (spacing 0.1)
    ts = np.linspace(0.0, 4.0, 41)
    load = mj.pulse(N, 1, amplitude=2.0, duration=duration, start=start)
    f = 2.0 * np.eye(N)[0]
    force = lambda t: f if start <= t <= start + duration else np.zeros(N)
    x_ref, v_ref = ivp_reference(damped, ts, force, breaks=(start, start + duration))
    out = mj.solve(damped, ts, None, None, load, velocity=True, method=mj.Spectral())
    close(out.displacement, x_ref, atol=1e-10 * np.max(np.abs(x_ref)))
    close(out.velocity, v_ref, atol=1e-10 * np.max(np.abs(v_ref)))
    out = mj.solve(damped, ts, None, None, load, velocity=True,
                   method=mj.ODE(rtol=1e-11, atol=1e-13))
    close(out.displacement, x_ref, atol=1e-8 * np.max(np.abs(x_ref)))
    close(out.velocity, v_ref, atol=1e-8 * np.max(np.abs(v_ref)))


def test_exact_solve_rejects_a_general_load_and_a_non_uniform_damped_grid(damped, undamped):
    with pytest.raises(ValueError, match="take load=None or a Pulse"):
        mj.solve(undamped, TS, load=lambda t: jnp.zeros(N),
                 method=mj.DenseExponential())
    with pytest.raises(ValueError, match="ts must be a uniform grid"):  # the spectral path
        mj.solve(damped, np.array([0.0, 0.1, 0.3, 0.4]), np.ones(N), method=mj.DenseExponential())


# --- energy -----------------------------------------------------------------------------------


def test_energy_never_increases_in_a_damped_free_vibration(damped, close):
    rng = np.random.default_rng(2)
    x0, v0 = rng.standard_normal(N), rng.standard_normal(N)
    out = mj.solve(damped, TS, x0, v0, velocity=True, method=mj.Spectral())
    e = energy(damped, np.asarray(out.displacement), np.asarray(out.velocity))
    assert np.all(np.diff(e) <= 1e-12 * e[0])
    assert e[-1] < 0.5 * e[0]  # and the dampers do dissipate


def test_energy_is_conserved_in_an_undamped_free_vibration(undamped, state, close):
    out = mj.solve(undamped, TS, *state, velocity=True, method=mj.DenseExponential())
    e = energy(undamped, np.asarray(out.displacement), np.asarray(out.velocity))
    close(e, np.full_like(e, e[0]), rtol=1e-12)


# --- ODE (diffrax) ----------------------------------------------------------------------------


@pytest.mark.parametrize("solver, rtol, tol", [(diffrax.Dopri8(), 1e-11, 1e-8),
                                               (diffrax.Tsit5(), 1e-10, 1e-8),
                                               (mj.StructuredKvaerno5(), 1e-9, 1e-6)],
                         ids=["dopri8", "tsit5", "kvaerno5"])
def test_simulate_agrees_with_exact_solve(damped, state, solver, rtol, tol, close):
    exact = mj.solve(damped, TS, *state, velocity=True, method=mj.Spectral())
    out = mj.solve(damped, TS, *state, velocity=True,
                   method=mj.ODE(solver, rtol=rtol, atol=rtol / 100))
    close(out.displacement, exact.displacement, atol=tol * np.max(np.abs(exact.displacement)))
    close(out.velocity, exact.velocity, atol=tol * np.max(np.abs(exact.velocity)))
    assert int(out.num_steps) > 0


def test_simulate_saves_only_what_was_asked(undamped, close):
    u1 = np.arange(1.0, N + 1)
    out = mj.solve(undamped, TS, u1, dofs=[3, 7], displacement=False, velocity=True,
                   method=mj.ODE(rtol=1e-10, atol=1e-12))
    assert out.displacement is None
    assert out.velocity.shape == (len(TS), 2) and out.dofs == (3, 7)
    close(out.velocity, -OMEGA * np.sin(OMEGA * TS)[:, None] * np.array([3.0, 7.0]), atol=1e-7)
    close(out.ts, TS, rtol=0.0)  # (velocity=False leaving velocity None: see the reduced model)


def test_exact_solve_saves_only_what_was_asked(undamped, close):
    u1 = np.arange(1.0, N + 1)
    out = mj.solve(undamped, TS, u1, dofs=(8, 2), displacement=False, velocity=True,
                   method=mj.DenseExponential())
    assert out.displacement is None and out.velocity.shape == (len(TS), 2)
    close(out.velocity, -OMEGA * np.sin(OMEGA * TS)[:, None] * np.array([8.0, 2.0]), atol=1e-11)


def test_simulate_with_a_user_load_function_matches_solve_ivp(damped, close):
    direction = np.linspace(1.0, 0.0, N)
    load = lambda t: jnp.sin(2.0 * t) * jnp.asarray(direction)
    force = lambda t: np.sin(2.0 * t) * direction
    x_ref, v_ref = ivp_reference(damped, TS, force)
    out = mj.solve(damped, TS, load=load, velocity=True,
                   method=mj.ODE(rtol=1e-11, atol=1e-13))
    close(out.displacement, x_ref, atol=1e-8 * np.max(np.abs(x_ref)))
    close(out.velocity, v_ref, atol=1e-8 * np.max(np.abs(v_ref)))


# --- reduced models through both solvers -----------------------------------------------------


def test_reduced_model_on_the_span_of_three_modes_is_exact_in_both_solvers(undamped, close):
    # x0 in span(u_1, u_2, u_3): the Galerkin model on that span carries the exact solution
    U = np.stack([np.asarray(mj.analytic.mode_shape(N, l)) for l in (1, 2, 3)], axis=1)
    basis, _ = np.linalg.qr(U)
    reduced = mj.reduce(undamped, mj.Projection(jnp.asarray(basis)))
    amplitudes = np.array([1.0, -0.5, 0.25])
    x0 = U @ amplitudes
    expected = sum(a * np.cos(l * OMEGA * TS)[:, None] * U[:, l - 1]
                   for l, a in zip((1, 2, 3), amplitudes))
    close(mj.solve(reduced, TS, x0, method=mj.DenseExponential()).displacement, expected,
          atol=1e-12)
    out = mj.solve(reduced, TS, x0, method=mj.ODE(rtol=1e-11, atol=1e-13))
    close(out.displacement, expected, atol=1e-8)
    assert out.displacement.shape == (len(TS), N) and out.velocity is None
    picked = mj.solve(reduced, TS, x0, dofs=[4], velocity=True, method=mj.DenseExponential())
    close(picked.displacement[:, 0], expected[:, 3], atol=1e-12)


def test_damped_reduced_model_gives_the_same_answer_in_both_solvers(damped, state, close):
    basis, _ = np.linalg.qr(np.random.default_rng(3).standard_normal((N, 4)))
    reduced = mj.reduce(damped, mj.Projection(jnp.asarray(basis)))
    exact = mj.solve(reduced, TS, *state, velocity=True, method=mj.DenseExponential())
    out = mj.solve(reduced, TS, *state, velocity=True, method=mj.ODE(rtol=1e-11, atol=1e-13))
    close(out.displacement, exact.displacement, atol=1e-8)
    close(out.velocity, exact.velocity, atol=1e-8)
    # the reduced solution is the lift of a 4-dof system: it stays in span(basis)
    residual = exact.displacement - exact.displacement @ basis @ basis.T
    assert np.max(np.abs(residual)) < 1e-12


# --- failures ---------------------------------------------------------------------------------


def test_too_few_max_steps_raises_an_error_naming_max_steps(undamped):
    with pytest.raises(ValueError, match="max_steps = 5 reached"):
        mj.solve(undamped, TS, np.ones(N), method=mj.ODE(max_steps=5))


# under a user's jax.jit, equinox's runtime error arrives wrapped in jax's
RUNTIME_ERRORS = (eqx.EquinoxRuntimeError, jax.errors.JaxRuntimeError)


def test_too_few_max_steps_under_jit_fails_with_the_same_message(undamped):
    solve = jax.jit(lambda x0: mj.solve(undamped, TS, x0, method=mj.ODE(max_steps=5)).displacement)
    with pytest.raises(RUNTIME_ERRORS, match="max_steps = 5 reached"):
        jax.block_until_ready(solve(jnp.ones(N)))


def test_a_non_finite_initial_state_is_refused_eagerly_and_under_jit(undamped):
    x0 = np.ones(N)
    x0[2] = np.nan
    with pytest.raises(ValueError, match="x0 must be finite"):
        mj.solve(undamped, TS, x0, method=mj.ODE())
    solve = jax.jit(lambda x0: mj.solve(undamped, TS, x0, method=mj.ODE()).displacement)
    with pytest.raises(RUNTIME_ERRORS, match="x0 must be finite"):
        jax.block_until_ready(solve(jnp.asarray(x0)))


def test_throw_false_returns_the_partial_solution_instead(undamped):
    out = simulate(undamped, TS, np.ones(N), max_steps=5, throw=False)  # no solve counterpart
    assert int(out.num_steps) == 5
    assert not np.all(np.isfinite(np.asarray(out.displacement[-1])))  # never reached ts[-1]


# --- bad input --------------------------------------------------------------------------------

SOLVES = {"ODE": partial(mj.solve, method=mj.ODE()),
          "DenseExponential": partial(mj.solve, method=mj.DenseExponential())}


@pytest.mark.parametrize("solve", SOLVES.values(), ids=SOLVES.keys())
@pytest.mark.parametrize("ts", [np.zeros(0), np.array([0.0, 1.0, 0.5]), np.array([0.0, 0.0, 1.0]),
                                np.array([0.0, np.nan, 1.0]), np.zeros((2, 2))])
def test_empty_or_non_increasing_times_are_rejected(solve, ts, undamped):
    with pytest.raises(ValueError, match="ts must be"):
        solve(undamped, ts, np.ones(N))


def test_traced_decreasing_times_fail_under_jit(undamped):
    run = eqx.filter_jit(lambda ts: mj.solve(undamped, ts, np.ones(N),
                                             method=mj.DenseExponential()).displacement)
    with pytest.raises(eqx.EquinoxRuntimeError, match="ts must be finite and strictly increasing"):
        run(jnp.asarray(TS[::-1]))


@pytest.mark.parametrize("solve", SOLVES.values(), ids=SOLVES.keys())
@pytest.mark.parametrize("dofs", [[0], [N + 1], [2, -1], []])
def test_dofs_outside_one_to_n_are_rejected(solve, dofs, undamped):
    with pytest.raises(ValueError, match="dofs must be 1-based DOFs in 1..8"):
        solve(undamped, TS, np.ones(N), dofs=dofs)


@pytest.mark.parametrize("solve", SOLVES.values(), ids=SOLVES.keys())
def test_wrong_initial_state_shape_or_precision_is_rejected(solve, undamped):
    with pytest.raises(ValueError, match=r"x0 must have shape \(8,\), got \(7,\)"):
        solve(undamped, TS, np.ones(N - 1))
    with pytest.raises(ValueError, match=r"v0 must have shape \(8,\)"):
        solve(undamped, TS, np.ones(N), np.ones((N, 1)))
    with pytest.raises(ValueError, match="x0 must be float64, got float32"):
        solve(undamped, TS, np.ones(N, np.float32))
    with pytest.raises(ValueError, match="x0 must be finite"):
        solve(undamped, TS, np.full(N, np.nan))


def test_unknown_solver_and_non_positive_tolerances_are_rejected(undamped):
    with pytest.raises(ValueError, match="solver must be one of"):
        simulate(undamped, TS, np.ones(N), solver="rk4")  # the strings of the private verb
    for rtol in (0.0, -1e-8, np.nan, 1.0, 10.0, 1e300, np.inf):
        with pytest.raises(ValueError, match="rtol must be > 0 and < 1"):
            mj.solve(undamped, TS, np.ones(N), method=mj.ODE(rtol=rtol))
    for atol in (0.0, np.inf):
        with pytest.raises(ValueError, match="atol must be > 0 and finite"):
            mj.solve(undamped, TS, np.ones(N), method=mj.ODE(atol=atol))
    with pytest.warns(UserWarning, match="rtol = 0.5 allows errors"):
        mj.solve(undamped, TS, np.ones(N), method=mj.ODE(rtol=0.5))
    with pytest.raises(ValueError, match="max_steps must be an integer"):
        mj.solve(undamped, TS, np.ones(N), method=mj.ODE(max_steps=0))
    with pytest.raises(ValueError, match="ask for displacement and/or velocity"):
        mj.solve(undamped, TS, np.ones(N), displacement=False, method=mj.ODE())


def test_a_pulse_of_the_wrong_size_is_rejected(undamped):
    with pytest.raises(ValueError, match="load has size 5"):
        mj.solve(undamped, TS, load=mj.pulse(5, 1), method=mj.DenseExponential())
    with pytest.raises(ValueError, match="pulse duration must be finite and > 0"):
        mj.pulse(N, 1, duration=0.0)
    with pytest.raises(ValueError, match="dof must be an integer DOF in 1..8"):
        mj.pulse(N, 9)


@pytest.mark.parametrize("name", ["amplitude", "start"])
def test_a_non_finite_pulse_amplitude_or_start_is_refused_naming_it_eagerly_and_under_jit(name):
    with pytest.raises(ValueError, match=rf"^mikota_jax: pulse {name} must be finite\.$"):
        mj.pulse(N, 1, **{name: np.nan})
    with pytest.raises(ValueError, match=rf"^mikota_jax: pulse {name} must be a scalar, got "
                       r"shape \(2,\)\.$"):
        mj.pulse(N, 1, **{name: [1.0, 2.0]})
    build = eqx.filter_jit(lambda value: mj.pulse(N, 1, **{name: value}))
    assert build(jnp.asarray(0.5)).size == N
    with pytest.raises(eqx.EquinoxRuntimeError, match=f"pulse {name} must be finite"):
        build(jnp.asarray(np.inf))


# --- derivatives through the solve ---------------------------------------------------------------


def damped_tip_energy(coefficient, adjoint):
    """Time-summed squared tip displacement of a chain with one damper of ``coefficient``."""
    system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(3.4, coefficient)])
    out = mj.solve(system, TS, mj.unit_vector(N, 2), dofs=[N],
                   method=mj.ODE(rtol=1e-11, atol=1e-13, adjoint=adjoint))
    return jnp.sum(out.displacement ** 2)


@pytest.mark.parametrize("adjoint", [
    pytest.param(diffrax.ForwardMode(), marks=pytest.mark.slow),
    diffrax.RecursiveCheckpointAdjoint(),
    pytest.param(diffrax.DirectAdjoint(), marks=pytest.mark.slow)],  # 13 s in CI
    ids=lambda a: type(a).__name__)
def test_each_adjoint_gives_the_central_difference_derivative(adjoint, close):
    c, h = 0.7, 1e-5
    differentiate = jax.jacfwd if isinstance(adjoint, diffrax.ForwardMode) else jax.grad
    derivative = differentiate(damped_tip_energy)(jnp.asarray(c), adjoint)
    central = (damped_tip_energy(c + h, adjoint) - damped_tip_energy(c - h, adjoint)) / (2 * h)
    close(derivative, central, rtol=1e-6)


def test_an_adjoint_that_is_not_a_diffrax_adjoint_is_refused(undamped):
    with pytest.raises(ValueError, match="adjoint must be a diffrax adjoint"):
        mj.solve(undamped, TS, np.ones(N), method=mj.ODE(adjoint="forward"))


@pytest.mark.parametrize("dofs", [[2.5], [True], ["3"], [1 + 2j]])
def test_non_integer_dofs_and_damper_pairs_are_refused_never_rounded(undamped, dofs):
    with pytest.raises(ValueError, match="dofs must be integers"):
        mj.solve(undamped, TS, np.ones(N), dofs=dofs, method=mj.ODE())
    with pytest.raises(ValueError, match="RelativeDamper dofs must be integers"):
        mj.RelativeDamper((2.7, 3), 1.0)
    out = mj.solve(undamped, TS, np.ones(N), dofs=[2.0], method=mj.ODE())
    assert out.dofs == (2,)  # an integral value
