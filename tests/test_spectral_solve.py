"""solve's Spectral() method (responses from the damped modes) against independent truths.

Truths: scipy's expm of the physical first-order matrix at every time (any grid), a 60-digit
decimal matrix exponential (strong dampers, where the dense path itself loses eps * rate), the
dense path (uniform grids), the closed form of the critically damped oscillator, and central
differences for gradients.
"""

from decimal import Decimal, localcontext

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sl

import mikota_jax as mj
from mikota_jax._placement.objective import placement_objective
from mikota_jax._placement.problem import DamperProblem
from mikota_jax._solver.spectral.response import spectral_solve_with_result

N = 20
M_, K_ = 1.3, 0.9
TS = np.linspace(0.0, 20.0, 201)
RNG = np.random.default_rng(3)
X0, V0 = RNG.standard_normal(N), RNG.standard_normal(N)


def state_matrix(system):
    M, D, K = (np.asarray(a) for a in system.dense())
    n = M.shape[0]
    inverse = np.linalg.inv(M)
    return np.block([[np.zeros((n, n)), np.eye(n)], [-inverse @ K, -inverse @ D]])


def expm_reference(system, ts, x0, v0):
    """(x, v) by scipy's expm(A (t - t0)), one per time: any grid."""
    a, n = state_matrix(system), x0.shape[0]
    y = np.stack([sl.expm(a * (t - ts[0])) @ np.concatenate([x0, v0]) for t in ts])
    return y[:, :n], y[:, n:]


def decimal_reference(system, ts, x0, v0, digits=60):
    """(x, v) on a uniform grid by a 60-digit matrix exponential (Taylor, scaling and
    squaring) of the physical state matrix, entries taken exactly from the float64 M, D, K."""
    M, D, K = (np.asarray(a) for a in system.dense())
    n = M.shape[0]
    with localcontext() as ctx:
        ctx.prec = digits
        a = [[Decimal(0)] * (2 * n) for _ in range(2 * n)]
        for i in range(n):
            a[i][n + i] = Decimal(1)
            for j in range(n):
                a[n + i][j] = -Decimal(float(K[i, j])) / Decimal(float(M[i, i]))
                a[n + i][n + j] = -Decimal(float(D[i, j])) / Decimal(float(M[i, i]))
        h = Decimal(float(ts[1])) - Decimal(float(ts[0]))
        norm = max(sum(abs(x) for x in row) for row in a) * h
        squarings = max(0, int(norm).bit_length() + 1)
        scale = h / Decimal(2) ** squarings
        a = [[x * scale for x in row] for row in a]

        def product(p, q):
            return [[sum(p[i][k] * q[k][j] for k in range(2 * n)) for j in range(2 * n)]
                    for i in range(2 * n)]

        eye = [[Decimal(int(i == j)) for j in range(2 * n)] for i in range(2 * n)]
        term, total = eye, [row[:] for row in eye]
        for k in range(1, 40):
            term = [[x / k for x in row] for row in product(term, a)]
            total = [[x + y for x, y in zip(r, s)] for r, s in zip(total, term)]
        for _ in range(squarings):
            total = product(total, total)
        z = [Decimal(float(x)) for x in np.concatenate([x0, v0])]
        out = [np.array([float(x) for x in z])]
        for _ in range(len(ts) - 1):
            z = [sum(p * q for p, q in zip(row, z)) for row in total]
            out.append(np.array([float(x) for x in z]))
    y = np.array(out)
    return y[:, :n], y[:, n:]


def relative(actual, expected):
    return np.max(np.abs(np.asarray(actual) - expected)) / np.max(np.abs(expected))


def chain(*dampers, n=N):
    return mj.mikota_chain(n, M_, K_, dampers=dampers)


def spectral(system, ts, x0, v0=None, load=None, **kwargs):
    return mj.solve(system, ts, x0, v0, load, method=mj.Spectral(), **kwargs)


# --- against the matrix exponential and the dense path -------------------------------------------


def test_the_spectral_path_equals_scipys_matrix_exponential_on_a_non_uniform_grid(close):
    ts = np.sort(np.concatenate([[0.0], np.random.default_rng(1).uniform(0.0, 20.0, 60)]))
    system = chain(mj.GroundedDamper(7.3, 0.8), mj.RelativeDamper((2, 9), 0.3))
    x, v = expm_reference(system, ts, X0, V0)
    out = spectral(system, ts, X0, V0, velocity=True)
    assert relative(out.displacement, x) < 1e-12
    assert relative(out.velocity, v) < 1e-12


def test_both_orders_of_the_history_product_equal_scipys_matrix_exponential():
    # all DOFs: at 6 times the modal history comes first (then U eta), at 61 times U Y first;
    # each against scipy's expm at every time (truth to ~1e-14 here); under a pulse against the
    # dense path on the 61-point grid (1e-14 there; on the 6-point grid, steps of 4 s, the
    # dense path itself is 1.4e-11 off), whose every 12th time is the coarse grid
    from mikota_jax._solver.spectral.response import modal_first

    system = chain(mj.GroundedDamper(7.3, 0.8), mj.RelativeDamper((2, 9), 0.3))
    load = mj.pulse(N, 4, 2.0, 3.0, 1.0)
    fine = np.linspace(0.0, 20.0, 61)
    dense = mj.solve(system, fine, X0, V0, load, velocity=True, method=mj.DenseExponential())
    for count, eta_first in ((6, True), (61, False)):
        ts = np.linspace(0.0, 20.0, count)
        assert modal_first(count, N, N) is eta_first
        x, v = expm_reference(system, ts, X0, V0)
        out = spectral(system, ts, X0, V0, velocity=True)
        assert relative(out.displacement, x) < 1e-12, count
        assert relative(out.velocity, v) < 1e-12, count
        forced = spectral(system, ts, X0, V0, load, velocity=True)
        every = (fine.size - 1) // (count - 1)
        assert relative(forced.displacement, dense.displacement[::every]) < 1e-12, count
        assert relative(forced.velocity, dense.velocity[::every]) < 1e-12, count


POSITIONS = [1.0, 7.0, 7.3, float(N)]


@pytest.mark.parametrize("coefficient", [1e-8, 1e-4, 1.0, 1e2, 1e4, 1e6, 1e8])
def test_the_spectral_path_agrees_with_the_dense_path_within_the_dense_paths_own_error(
        coefficient):
    # the dense path's own error grows as eps * rate (rate d / m_j of the damper mode; against a
    # 60-digit truth it is 7e-7 at d = 1e8, the spectral path's 1e-13): 1e-12 plus that
    for position in POSITIONS:
        system = chain(mj.GroundedDamper(position, coefficient))
        dense = mj.solve(system, TS, X0, V0, velocity=True, method=mj.DenseExponential())
        out = spectral(system, TS, X0, V0, velocity=True)
        tol = 1e-12 + 2e-15 * coefficient * np.ceil(position) / M_
        assert relative(out.displacement, dense.displacement) < tol, position
        assert relative(out.velocity, dense.velocity) < tol, position


@pytest.mark.parametrize("coefficient, position", [  # one strength per default run
    pytest.param(1e4, 6.0, marks=pytest.mark.slow), (1e8, 3.5),
    pytest.param(1e8, 6.0, marks=pytest.mark.slow)])
def test_a_strong_damper_is_right_to_1e_12_against_a_60_digit_matrix_exponential(coefficient,
                                                                                  position):
    n = 6
    ts = np.linspace(0.0, 10.0, 51)
    system = chain(mj.GroundedDamper(position, coefficient), n=n)
    x, v = decimal_reference(system, ts, X0[:n], V0[:n])
    out = spectral(system, ts, X0[:n], V0[:n], velocity=True)
    assert relative(out.displacement, x) < 1e-12
    assert relative(out.velocity, v) < 1e-12


@pytest.mark.parametrize("dampers", [
    (mj.RelativeDamper((3, 6), 1e-8),), (mj.RelativeDamper((3, 6), 1.0),),
    (mj.RelativeDamper((1, N), 1e2),),
    pytest.param((mj.GroundedDamper(1, 3.0), mj.GroundedDamper(5.5, 0.7),
                  mj.GroundedDamper(N, 2.0), mj.RelativeDamper((2, 7), 1.5),
                  mj.RelativeDamper((N - 1, N), 0.4)), marks=pytest.mark.slow)],
    ids=["relative 1e-8", "relative 1", "relative 1e2 ends", "several"])
def test_relative_and_several_dampers_agree_with_the_dense_path(dampers):
    system = chain(*dampers)
    dense = mj.solve(system, TS, X0, V0, velocity=True, method=mj.DenseExponential())
    out = spectral(system, TS, X0, V0, velocity=True)
    assert relative(out.displacement, dense.displacement) < 1e-12
    assert relative(out.velocity, dense.velocity) < 1e-12


@pytest.mark.parametrize("start, duration", [(0.0, 0.05), (0.21, 0.37), (2.0, 3.0), (-1.0, 1.5),
                                             (-2.0, 1.0)])
def test_a_pulse_agrees_with_the_dense_path(start, duration):
    # (-1, 1.5): on at ts[0], off at 0.5; (-2, 1): over before ts[0], only the free vibration
    system = chain(mj.GroundedDamper(7.3, 0.5))
    load = mj.pulse(N, 4, 2.0, duration, start)
    dense = mj.solve(system, TS, X0, V0, load, velocity=True, method=mj.DenseExponential())
    out = spectral(system, TS, X0, V0, load, velocity=True)
    assert relative(out.displacement, dense.displacement) < 1e-12
    assert relative(out.velocity, dense.velocity) < 1e-12


def test_a_subset_of_dofs_and_velocity_only_are_the_columns_of_the_full_solve(close):
    system = chain(mj.GroundedDamper(7.3, 0.5))
    full = spectral(system, TS, X0, V0, velocity=True)
    picked = spectral(system, TS, X0, V0, dofs=(8, 2), displacement=False, velocity=True)
    assert picked.displacement is None and picked.dofs == (8, 2)
    close(picked.velocity, np.asarray(full.velocity)[:, [7, 1]], rtol=0, atol=1e-14)


def test_auto_takes_the_spectral_path_on_any_grid_and_a_strong_damper_never_overflows():
    ts = np.concatenate([[0.0], np.geomspace(1e-3, 1e4, 100)])
    system = chain(mj.GroundedDamper(N, 1e8))
    x, _ = expm_reference(system, ts[:40], X0, V0)
    out = mj.solve(system, ts, X0, V0, velocity=True, method=mj.Spectral())
    assert np.all(np.isfinite(np.asarray(out.displacement)))
    assert relative(out.displacement[:40], x) < 1e-6  # expm's own eps * rate
    M, _, K = (np.asarray(m) for m in system.dense())
    x, v = np.asarray(out.displacement), np.asarray(out.velocity)
    energy = 0.5 * (np.einsum("ti,ij,tj->t", x, K, x) + np.einsum("ti,ij,tj->t", v, M, v))
    assert np.all(np.diff(energy) <= 1e-12 * energy[0])  # never grows, up to t = 1e4


# --- the fallback ---------------------------------------------------------------------------


def critical():
    # m = k = 1, d = 2: lambda = -1 twice, one eigenvector; x0 = 1 gives x = (1 + t) e^-t
    return mj.mikota_chain(1, dampers=[mj.GroundedDamper(1.0, 2.0)])


@pytest.mark.parametrize("ts", [np.linspace(0.0, 5.0, 51), pytest.param(
    np.array([0.0, 0.3, 1.0, 2.5, 4.0]), marks=pytest.mark.slow)], ids=["uniform", "non-uniform"])
def test_a_critically_damped_dof_is_one_cluster_and_exact(ts, close):
    # the double root -1 of one mass at c = 2: summed by contour, x = (1 + t) e^-t (exact)
    system = critical()
    x0 = np.array([1.0])
    _, ok = spectral_solve_with_result(system, jnp.asarray(ts), jnp.asarray(x0), jnp.zeros(1),
                                       None, dofs=(1,), displacement=True, velocity=False)
    assert bool(ok)
    expected = ((1 + ts) * np.exp(-ts))[:, None]
    close(mj.solve(system, ts, x0, method=mj.Spectral()).displacement, expected, atol=1e-15)
    jitted = jax.jit(lambda t, x: mj.solve(system, t, x, method=mj.Spectral()).displacement)
    close(jitted(ts, x0), expected, atol=1e-15)


# --- transformations and gradients ----------------------------------------------------------------


@pytest.mark.slow  # 88 s on a loaded 2-core machine (three compiles, the dense branch too)
def test_jit_and_vmap_over_coefficients_give_the_eager_results(close):
    coefficients = jnp.array([0.01, 1.0, 30.0])

    def tip(c):
        system = chain(mj.GroundedDamper(7.3, c))
        return mj.solve(system, TS, X0, V0, dofs=[N], method=mj.Spectral()).displacement[:, 0]

    eager = np.stack([np.asarray(tip(c)) for c in coefficients])
    close(jax.jit(tip)(coefficients[1]), eager[1], atol=1e-14)
    close(jax.vmap(tip)(coefficients), eager, atol=1e-13)


def tip_energy(position, coefficient, x0, method="spectral", n=10):
    system = mj.mikota_chain(n, M_, K_, dampers=[mj.GroundedDamper(position, coefficient)])
    method = mj.Spectral() if method == "spectral" else mj.DenseExponential()
    out = mj.solve(system, TS, x0, dofs=[n, 3], velocity=True, method=method)
    return jnp.sum(out.displacement**2) + jnp.sum(out.velocity**2)


@pytest.mark.slow  # 72 s on a loaded 2-core machine (the dense path's gradient compiles expm)
@pytest.mark.parametrize("position", [7.3, 4.0])
def test_gradients_match_central_differences_and_the_dense_path(position, close):
    x0 = jnp.asarray(X0[:10])
    point = (jnp.array(position), jnp.array(0.7), x0)
    grad = jax.grad(tip_energy, argnums=(0, 1, 2))(*point)
    dense = jax.grad(lambda p, c, x: tip_energy(p, c, x, "dense"), argnums=(0, 1, 2))(*point)
    for ours, theirs in zip(grad, dense):
        close(ours, theirs, rtol=1e-7, atol=1e-7 * np.max(np.abs(np.asarray(theirs))))
    h = 1e-5  # right-sided in position: a kink at every integer
    by_p = (tip_energy(position + h, 0.7, x0) - tip_energy(position, 0.7, x0)) / h
    by_p = by_p if position == 4.0 else (tip_energy(position + h, 0.7, x0)
                                          - tip_energy(position - h, 0.7, x0)) / (2 * h)
    by_c = (tip_energy(position, 0.7 + h, x0) - tip_energy(position, 0.7 - h, x0)) / (2 * h)
    e = jnp.zeros(10).at[4].set(h)
    by_x = (tip_energy(position, 0.7, x0 + e) - tip_energy(position, 0.7, x0 - e)) / (2 * h)
    close(grad[0], by_p, rtol=1e-6 if position != 4.0 else 1e-4)
    close(grad[1], by_c, rtol=1e-7)
    close(grad[2][4], by_x, rtol=1e-7)


@pytest.mark.slow
@pytest.mark.parametrize("internal", [mj.Rayleigh(0.05, 0.002),
                                      pytest.param(mj.ModalDamping(0.01), marks=pytest.mark.slow)])
def test_internal_damping_diagonal_in_modes_takes_the_spectral_path_and_matches_dense(internal,
                                                                                       close):
    n = 30
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(7.3, 2.0),
                                         mj.RelativeDamper((2, 20), 0.5)],
                             internal_damping=internal)
    x0 = np.linspace(-1.0, 1.0, n)
    ts = np.linspace(0.0, 20.0, 401)
    spectral = mj.solve(system, ts, x0, velocity=True, method=mj.Spectral())
    dense = mj.solve(system, ts, x0, velocity=True, method=mj.DenseExponential())
    scale = np.max(np.abs(dense.displacement))
    close(spectral.displacement, dense.displacement, atol=1e-12 * scale, rtol=0)
    close(spectral.velocity, dense.velocity, atol=1e-11 * np.max(np.abs(dense.velocity)), rtol=0)


# --- errors ---------------------------------------------------------------------------------


def test_the_spectral_method_is_refused_where_it_does_not_apply_with_the_reason():
    undamped = mj.mikota_chain(5)
    with pytest.raises(ValueError, match=r"Spectral\(\).*undamped"):
        mj.solve(undamped, TS, np.ones(5), method=mj.Spectral())
    user = mj.system(np.ones(5), mj.mikota_chain(5).stiffness, 0.1 * np.eye(5),
                     dampers=[mj.GroundedDamper(2.0, 1.0)])
    with pytest.raises(ValueError, match=r"Spectral\(\).*damping matrix"):
        mj.solve(user, TS, np.ones(5), method=mj.Spectral())
    damped = mj.mikota_chain(5, dampers=[mj.GroundedDamper(2.0, 1.0)])
    reduced = mj.reduce(damped, mj.Projection(jnp.eye(5)[:, :2]))
    with pytest.raises(ValueError, match=r"Spectral\(\).*ReducedModel"):
        mj.solve(reduced, TS, np.ones(5), method=mj.Spectral())
    with pytest.raises(ValueError, match="method must be"):
        mj.solve(damped, TS, np.ones(5), method="modal")


# --- solve's Auto() and the optimiser's certification take the spectral path ---------------------


def test_simulate_auto_takes_the_exact_spectral_solution_where_it_applies(close):
    system = chain(mj.GroundedDamper(7.3, 0.5))
    exact = mj.solve(system, TS, X0, V0, velocity=True, method=mj.DenseExponential())
    auto = mj.solve(system, TS, X0, V0, velocity=True, method=mj.Auto())
    assert auto.num_steps is None  # no integration: the modal expansion
    for got, want in ((auto.displacement, exact.displacement), (auto.velocity, exact.velocity)):
        close(got, want, rtol=0, atol=1e-12 * float(np.max(np.abs(np.asarray(want)))))
    # a general load is integrated (Dopri8 here: rho T is small), to its tolerance
    load = lambda t: jnp.zeros(N).at[0].set(jnp.sin(t))  # noqa: E731
    ode = mj.solve(system, TS, X0, V0, load, method=mj.Auto())
    assert ode.num_steps is not None and int(ode.num_steps) > 0


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_the_full_energy_the_optimiser_certifies_with_is_the_exact_one(close):
    system = chain(mj.GroundedDamper(4.0, 0.8))
    problem = DamperProblem(system, jnp.linspace(0.0, 20.0, 11), X0, V0)
    objective = placement_objective(problem)  # the full model
    value = objective(jnp.array([4.0]), jnp.array([0.8]))
    close(value, mj.Energy(20.0, X0, V0, method=mj.DenseExponential())(system), rtol=1e-11)
    gradient = jax.grad(objective, argnums=1)(jnp.array([4.0]), jnp.array([0.8]))
    h = 1e-5
    central = (objective(jnp.array([4.0]), jnp.array([0.8 + h]))
               - objective(jnp.array([4.0]), jnp.array([0.8 - h]))) / (2 * h)
    close(gradient[0], central, rtol=1e-7)


def test_a_uniform_grid_far_from_zero_is_uniform_to_the_rounding_of_t(close):
    # start + step k in float64 spreads the steps by ulp(t): 1.5e-8 of the step at t = 1e5
    system = chain(mj.GroundedDamper(3.0, 0.5), n=4)
    shifted = 1e5 + 1e-3 * np.arange(201)
    at_zero = 1e-3 * np.arange(201)
    x0 = X0[:4]
    for method in (mj.DenseExponential(), mj.Spectral()):
        far = mj.solve(system, shifted, x0, method=method).displacement
        near = mj.solve(system, at_zero, x0, method=method).displacement
        close(far, near, rtol=0, atol=1e-9 * float(np.max(np.abs(np.asarray(near)))))
