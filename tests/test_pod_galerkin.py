"""POD (eqs. 3.5-3.8), Galerkin reduction (eq. 3.4) and the error measures (eq. 5.4)."""

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import orthonormal, sign_rule

import mikota_jax as mj
from mikota_jax._rom.pod import _Decomposition, energy_fraction, pod, rank_for_energy

# --- POD of matrices with a known SVD ---------------------------------------------------------


def test_pod_recovers_a_known_svd(close):
    n, m = 12, 30
    u, v = orthonormal(n, n, 0), orthonormal(m, n, 1)
    s = 2.0 ** -np.arange(n) * 7.0
    result = pod(u @ np.diag(s) @ v.T)
    close(result.singular_values, s, rtol=1e-12)
    close(result.modes, sign_rule(u), atol=1e-10)
    close(result.modes.T @ result.modes, np.eye(n), atol=1e-14)
    largest = np.asarray(result.modes)[np.argmax(np.abs(result.modes), axis=0), np.arange(n)]
    assert np.all(largest > 0)
    close(mj.metrics.pseudo_energy(result.singular_values), np.sum(s**2), rtol=1e-13)  # eq. (3.7)


def test_pod_basis_is_the_leading_modes(close):
    u, v = orthonormal(9, 5, 2), orthonormal(7, 5, 3)
    result = pod(u @ np.diag([5.0, 4.0, 3.0, 2.0, 1.0]) @ v.T)
    basis = result.basis(3)
    assert basis.shape == (9, 3)
    close(basis, sign_rule(u[:, :3]), atol=1e-12)
    close(basis.T @ basis, np.eye(3), atol=1e-14)


@pytest.mark.parametrize("n, m", [(10, 400), (400, 10)])
def test_method_of_snapshots_agrees_with_the_svd(n, m, close):
    k = min(n, m)
    u, v = orthonormal(n, k, 4), orthonormal(m, k, 5)
    s = np.geomspace(10.0, 0.01, k)  # sigma_k / sigma_1 >= 1e-3: squaring keeps 1e-10
    q = u @ np.diag(s) @ v.T
    svd, snapshots = pod(q), pod(q, method="snapshots")
    close(snapshots.singular_values, svd.singular_values, rtol=1e-8)
    close(snapshots.singular_values, s, rtol=1e-8)
    close(snapshots.modes[:, :5], svd.modes[:, :5], atol=1e-8)
    close(snapshots.modes.T @ snapshots.modes, np.eye(k), atol=1e-8)


def test_first_mode_excitation_gives_rank_one_snapshots_with_pom_1_parallel_to_i(close):
    # Section 4: n = 10, m = k = 1, x(0) = u_1, t in [0, 20] with dt = 0.01
    n = 10
    ts = np.linspace(0.0, 20.0, 2001)
    q = mj.solve(mj.mikota_chain(n), ts, mj.analytic.mode_shape(n, 1),
                 method=mj.DenseExponential()).displacement.T
    result = pod(q)
    assert result.numerical_rank() == 1
    s = np.asarray(result.singular_values)
    assert s[1] / s[0] < 1e-13  # the paper: sigma_k>1 / sigma_1 < 1e-15, up to rounding
    i = np.arange(1.0, n + 1)
    close(result.modes[:, 0], i / np.linalg.norm(i), rtol=1e-13)
    # sigma_1^2 = sum_t cos(t)^2 |u_1|^2 with u_1 = i / n
    close(s[0] ** 2, np.sum(np.cos(ts) ** 2) * np.sum((i / n) ** 2), rtol=1e-12)


# --- choosing the rank ------------------------------------------------------------------------


def test_energy_fractions_for_both_criteria(close):
    s = jnp.array([3.0, 2.0, 1.0])
    close(energy_fraction(s), [9 / 14, 13 / 14, 1.0], rtol=1e-15)
    close(energy_fraction(s, "paper"), [(3 / 6) ** 2, (5 / 6) ** 2, 1.0], rtol=1e-15)
    close(_Decomposition(s, jnp.eye(3)).energy_fraction("paper"), [0.25, 25 / 36, 1.0], rtol=1e-15)


@pytest.mark.parametrize("energy, criterion, rank", [
    (0.5, "squared", 1), (0.9, "squared", 2), (13 / 14, "squared", 2), (0.93, "squared", 3),
    (0.25, "paper", 1), (0.5, "paper", 2), (25 / 36, "paper", 2), (0.7, "paper", 3),
    (1.0, "squared", 3), (1.0, "paper", 3), (1, "squared", 3),
])
def test_rank_for_energy_is_the_smallest_rank_reaching_the_fraction(energy, criterion, rank):
    s = jnp.array([3.0, 2.0, 1.0, 0.0])  # a zero singular value carries no energy
    assert rank_for_energy(s, energy, criterion) == rank
    assert _Decomposition(s, jnp.eye(4)).rank_for_energy(energy, criterion) == rank


@pytest.mark.parametrize("energy", [0, 0.0, -0.1, 1.5, np.nan, True, "0.9", None])
def test_bad_energy_values_are_rejected(energy):
    with pytest.raises(ValueError, match="energy must be a number in"):
        rank_for_energy(jnp.array([2.0, 1.0]), energy)


def test_unknown_criterion_and_method_are_rejected():
    with pytest.raises(ValueError, match="criterion must be one of"):
        energy_fraction(jnp.array([2.0, 1.0]), "cubed")
    with pytest.raises(ValueError, match="method must be one of"):
        pod(np.eye(3), method="eig")


@pytest.mark.parametrize("rank", [0, -1, 4, 2.0, True, None])
def test_pod_basis_rejects_bad_ranks(rank):
    result = pod(orthonormal(5, 3, 6) @ np.diag([3.0, 2.0, 1.0]) @ orthonormal(4, 3, 7).T)
    # (a rank above the numerical rank 3 may be refused for that reason instead)
    with pytest.raises(ValueError, match=r"rank must|rank = 4 exceeds the numerical rank"):
        result.basis(rank)


@pytest.mark.parametrize("snapshots, match", [
    (np.ones(3), "snapshots must be a non-empty"),
    (np.zeros((0, 3)), "snapshots must be a non-empty"),
    (np.array([[1.0, np.nan]]), "snapshots must be finite"),
    (np.ones((2, 2), np.float32), "snapshots must be float64"),
])
def test_pod_rejects_bad_snapshots(snapshots, match):
    with pytest.raises(ValueError, match=match):
        pod(snapshots)


# --- metrics ------------------------------------------------------------------------------------


def test_phase_error_eq_5_4_by_hand(close):
    x = jnp.array([[3.0, 0.0], [1.0, 1.0]])
    v = jnp.array([[0.0, 4.0], [1.0, 1.0]])
    xr = jnp.array([[3.0, 1.0], [1.0, 1.0]])
    vr = jnp.array([[0.0, 4.0], [0.0, 1.0]])
    # instant 1: sqrt(1 / 25) = 0.2; instant 2: sqrt(1 / 4) = 0.5
    close(mj.metrics.phase_error(x, v, xr, vr, aggregate="none"), [0.2, 0.5], rtol=1e-15)
    close(mj.metrics.phase_error(x, v, xr, vr, aggregate="max"), 0.5, rtol=1e-15)
    # the default: the ratio of sums
    close(mj.metrics.phase_error(x, v, xr, vr), np.sqrt(2 / 29), rtol=1e-15)
    close(mj.metrics.phase_error(x, v, xr, vr, aggregate="mean"), 0.35, rtol=1e-15)
    close(mj.metrics.phase_error(x, v, xr, vr, aggregate="sum"), np.sqrt(2 / 29), rtol=1e-15)
    close(mj.metrics.phase_error(x, v, x, v), 0.0, atol=0.0)


def test_relative_error_by_hand(close):
    reference = jnp.array([[3.0, 0.0], [0.0, 4.0]])
    close(mj.metrics.relative_error(reference, reference + jnp.array([[0.0, 1.0], [0.0, 0.0]])),
          0.2, rtol=1e-15)
    close(mj.metrics.relative_error(reference, 2 * reference), 1.0, rtol=1e-15)


def test_metrics_reject_mismatched_shapes_and_aggregates():
    a = jnp.ones((3, 2))
    with pytest.raises(ValueError, match="reduced_displacement"):
        mj.metrics.phase_error(a, a, jnp.ones((3, 3)), a)
    with pytest.raises(ValueError, match="aggregate must be one of"):
        mj.metrics.phase_error(a, a, a, a, aggregate="median")
    with pytest.raises(ValueError, match="approximation"):
        mj.metrics.relative_error(a, jnp.ones(2))


# --- Galerkin reduction -------------------------------------------------------------------------

N = 12
TS = np.linspace(0.0, 10.0, 101)
DAMPER = mj.GroundedDamper(7.0, 1.0)


@pytest.fixture(scope="module")
def damped():
    return mj.mikota_chain(N, dampers=[DAMPER])


@pytest.fixture(scope="module")
def x0():
    # a smooth initial shape (static deflection under a uniform load): fast-decaying modal content
    K = np.asarray(mj.mikota_chain(N).dense()[2])
    return np.linalg.solve(K, np.ones(N))


@pytest.mark.slow  # 24 s; test_properties checks a full basis on random chains
def test_full_rank_galerkin_with_a_random_orthonormal_basis_is_the_full_model(damped, x0, close):
    basis = orthonormal(N, N, 8)
    reduced = mj.reduce(damped, mj.Projection(jnp.asarray(basis)))
    assert reduced.rank == N and reduced.size == N
    full = mj.solve(damped, TS, x0, velocity=True, method=mj.Spectral())
    exact = mj.solve(reduced, TS, x0, velocity=True, method=mj.DenseExponential())
    scale = np.max(np.abs(full.displacement))
    close(exact.displacement, full.displacement, atol=1e-9 * scale)
    close(exact.velocity, full.velocity, atol=1e-9 * np.max(np.abs(full.velocity)))
    lifted = mj.solve(reduced, TS, x0, velocity=True, method=mj.ODE(rtol=1e-11, atol=1e-13))
    close(lifted.displacement, full.displacement, atol=1e-8 * scale)


def test_galerkin_projects_each_operator_and_lifts_back(damped, close):
    basis = orthonormal(N, 4, 9)
    reduced = mj.reduce(damped, mj.Projection(jnp.asarray(basis)))
    M, D, K = (np.asarray(a) for a in damped.dense())
    rM, rD, rK = (np.asarray(a) for a in reduced.system.dense())
    close(rM, basis.T @ M @ basis, atol=1e-14)
    close(rD, basis.T @ D @ basis, atol=1e-14)
    close(rK, basis.T @ K @ basis, atol=1e-13)
    q = np.arange(1.0, 5.0)
    close(reduced.lift(jnp.asarray(q)), basis @ q, atol=1e-14)
    close(reduced.reduce_state(jnp.asarray(basis @ q)), q, rtol=1e-13)


def test_galerkin_rejects_bad_bases(damped):
    with pytest.raises(ValueError, match="basis must have shape"):
        mj.reduce(damped, mj.Projection(jnp.ones((N + 1, 2))))
    with pytest.raises(ValueError, match="basis must have shape"):
        mj.reduce(damped, mj.Projection(jnp.ones((N, 0))))
    with pytest.raises(ValueError, match="basis must be float64"):
        mj.reduce(damped, mj.Projection(jnp.ones((N, 2), jnp.float32)))
    with pytest.raises(ValueError, match="basis must be finite"):
        mj.reduce(damped, mj.Projection(jnp.full((N, 2), jnp.nan)))


@pytest.fixture(scope="module")
def snapshot_run(damped, x0):
    full = mj.solve(damped, TS, x0, velocity=True, method=mj.Spectral())
    return full, pod(full.displacement.T)


def test_pod_galerkin_error_in_the_snapshot_window_is_small_and_decreases_with_rank(
        damped, x0, snapshot_run):
    full, result = snapshot_run
    errors = []
    for rank in (2, 4, 6):
        reduced = mj.reduce(damped, mj.Projection(result.basis(rank)))
        out = mj.solve(reduced, TS, x0, velocity=True, method=mj.DenseExponential())
        errors.append(float(mj.metrics.phase_error(full.displacement, full.velocity,
                                                   out.displacement, out.velocity,
                                                   aggregate="sum")))
        # the displacement error can't beat the best approximation from the same span
        best = full.displacement @ result.basis(rank) @ result.basis(rank).T
        assert (mj.metrics.relative_error(full.displacement, out.displacement)
                >= mj.metrics.relative_error(full.displacement, best) * (1 - 1e-9))
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-2, errors


# --- gradients and vmap through a reduced model (basis held fixed) -----------------------------

RANK, DOF = 6, 9


@pytest.fixture(scope="module")
def basis(snapshot_run):
    return jax.lax.stop_gradient(snapshot_run[1].basis(RANK))


def make_objective(solve, basis, x0):
    def objective(position, coefficient):
        system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(position, coefficient)])
        out = solve(mj.reduce(system, mj.Projection(basis)), TS, x0, dofs=[DOF])
        return jnp.sum(out.displacement**2)

    return objective


def central(f, p, c, h_p, h_c):
    return ((f(p + h_p, c) - f(p - h_p, c)) / (2 * h_p),
            (f(p, c + h_c) - f(p, c - h_c)) / (2 * h_c))


def test_gradient_of_an_exact_rom_objective_matches_central_differences(basis, x0, close):
    f = make_objective(partial(mj.solve, method=mj.DenseExponential()), basis, x0)
    p, c = 6.4, 0.8
    grad = jax.jit(jax.grad(f, argnums=(0, 1)))(p, c)
    f = jax.jit(f)
    fd = central(f, p, c, 1e-6 * p, 1e-6 * c)
    close(grad[0], fd[0], rtol=1e-6)
    close(grad[1], fd[1], rtol=1e-6)
    assert abs(float(grad[0])) > 1e-3 and abs(float(grad[1])) > 1e-3  # not trivially zero


@pytest.mark.slow  # ~15 s; CI time (the exact-solve variants stay in the default run)
def test_gradient_of_a_simulated_rom_objective_matches_central_differences(basis, x0, close):
    f = make_objective(partial(mj.solve, method=mj.ODE(rtol=1e-12, atol=1e-14)), basis, x0)
    p, c = 6.4, 0.8
    grad = jax.grad(f, argnums=(0, 1))(p, c)
    fd = central(f, p, c, 1e-6 * p, 1e-6 * c)
    close(grad[0], fd[0], rtol=1e-5)
    close(grad[1], fd[1], rtol=1e-5)


def test_vmap_over_damper_coefficients_equals_a_loop(basis, x0, close):
    f = make_objective(partial(mj.solve, method=mj.DenseExponential()), basis, x0)
    coefficients = jnp.array([0.2, 0.8, 3.0])
    batched = jax.vmap(lambda c: f(6.4, c))(coefficients)
    loop = [f(6.4, c) for c in coefficients]
    close(batched, loop, rtol=1e-12)
    assert batched[0] != batched[2]
