"""The a posteriori error bound (``error_bound``) and what is built on it (``Greedy``,
``rank_for_bound``): the bounds are never below the true errors (full exact solves), vanish for
a complete basis, and certify what they claim; bad input fails in one line."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

import mikota_jax as mj
from mikota_jax._estimation.estimator import error_bound
from mikota_jax._rom.pod import pod

N = 40
T = 20.0


def _states(m, d, k, x0, step, count):
    """(count, 2 n) states (x, v) at t = 0, step, ... by numpy's matrix exponential (an
    independent truth: no library solver, no compile)."""
    n = m.shape[0]
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(m, k), -np.linalg.solve(m, d)]])
    propagator = scipy.linalg.expm(a * step)
    z, out = np.concatenate([x0, np.zeros(n)]), np.empty((count, 2 * n))
    for i in range(count):
        out[i] = z
        z = propagator @ z
    return out


def true_errors(system, basis, x0):
    """(|J - J_r|, max_t |z - z_r|_E, J, J_r): states of the full and the reduced model by
    numpy's matrix exponential at 4001 times of [0, T], J and J_r exact (``integrated_energy``)."""
    m, d, k = (np.asarray(a) for a in system.dense())
    b, x0 = np.asarray(basis), np.asarray(x0)
    full = _states(m, d, k, x0, T / 4000, 4001)
    reduced = _states(b.T @ m @ b, b.T @ d @ b, b.T @ k @ b, b.T @ x0, T / 4000, 4001)
    r = b.shape[1]
    ex = full[:, :N] - reduced[:, :r] @ b.T
    ev = full[:, N:] - reduced[:, r:] @ b.T
    state = np.sqrt(np.einsum("ti,ij,tj->t", ex, k, ex) + np.einsum("ti,ij,tj->t", ev, m, ev))
    j = float(mj.Energy(T, x0)(system))
    j_r = float(mj.Energy(T, x0)(mj.reduce(system, mj.Projection(basis))))
    return abs(j - j_r), float(state.max()), j, j_r


@pytest.fixture(scope="module")
def case():
    system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(7.0, 1.0)])
    x0 = jnp.zeros(N).at[2].set(1.0)
    states = _states(*(np.asarray(a) for a in system.dense()), np.asarray(x0), 0.01, 1001)
    return system, x0, pod(jnp.asarray(states[:, :N].T))


@pytest.mark.parametrize("rank", [pytest.param(8, marks=pytest.mark.slow), 16,
                                  pytest.param(24, marks=pytest.mark.slow)])  # 8, 24: ~30 s each
def test_bounds_are_above_the_true_errors(case, rank):
    system, x0, pod = case
    basis = pod.basis(rank)
    bound = mj.estimate(system, mj.ResidualBound(basis), T, x0)
    energy_error, state_error, j, j_r = true_errors(system, basis, x0)
    assert float(bound.value) == pytest.approx(j_r, rel=1e-8)  # the ROM's own energy
    assert state_error <= float(bound.state)
    assert energy_error <= float(bound.error)
    assert abs(j - j_r) / j <= float(bound.relative)
    # not vacuous: within a few decades of the truth (measured effectivities below 1e4)
    assert float(bound.state) < 1e3 * state_error


def test_a_complete_basis_has_a_zero_bound(case):
    system, x0, _ = case
    bound = mj.estimate(system, mj.ResidualBound(jnp.eye(N)), T, x0)
    # only the rounding floor is left (ROUNDING J_r)
    assert float(bound.error) < 1.01 * mj._estimation.estimator.ROUNDING * float(bound.value)
    assert float(bound.state) < 1e-9


def test_the_initial_error_is_the_energy_norm_of_the_part_outside_the_basis(case):
    system, _, pod = case
    basis = pod.basis(10)
    x0 = jnp.sin(jnp.arange(1.0, N + 1.0))  # not in the span
    e = np.asarray(x0 - basis @ (basis.T @ x0))
    expected = np.sqrt(e @ np.asarray(system.stiffness.as_matrix()) @ e)
    initial = error_bound(system, basis, T, x0).initial  # a detail the verb does not return
    assert float(initial) == pytest.approx(expected, rel=1e-12)


def test_the_bound_passes_jit_and_grad(case):
    system, x0, pod = case
    basis = pod.basis(16)

    def energy_bound(c):
        s = mj.mikota_chain(N, dampers=[mj.GroundedDamper(7.0, c)])
        return mj.estimate(s, mj.ResidualBound(basis), T, x0).error

    value = jax.jit(energy_bound)(1.0)
    expected = mj.estimate(system, mj.ResidualBound(basis), T, x0).error
    assert float(value) == pytest.approx(float(expected), rel=1e-10)
    h = 1e-5
    fd = (float(energy_bound(1.0 + h)) - float(energy_bound(1.0 - h))) / (2 * h)
    assert float(jax.grad(energy_bound)(1.0)) == pytest.approx(fd, rel=1e-4)


def test_bad_input_fails_in_one_line(case):
    system, x0, pod = case
    with pytest.raises(ValueError, match="horizon must be finite and > 0"):
        mj.estimate(system, mj.ResidualBound(pod.basis(5)), -1.0, x0)
    with pytest.raises(ValueError, match=r"x0 must have shape \(40,\)"):
        mj.estimate(system, mj.ResidualBound(pod.basis(5)), T, jnp.zeros(3))
    with pytest.raises(ValueError, match="orthonormal"):
        mj.estimate(system, mj.ResidualBound(2 * pod.basis(5)), T, x0)
    with pytest.raises(ValueError, match="SecondOrderSystem"):
        mj.estimate("chain", mj.ResidualBound(pod.basis(5)), T, x0)


def test_the_estimators_are_one_family_behind_estimate(case):
    system, x0, pod = case
    basis = pod.basis(16)
    rom = mj.reduce(system, mj.Projection(basis))
    # a ReducedModel or its basis: the same bound (the same computation, to rounding)
    a = mj.estimate(system, mj.ResidualBound(rom), T, x0)
    b = mj.estimate(system, mj.ResidualBound(basis), T, x0)
    assert a.rigorous and float(a.error) == pytest.approx(float(b.error), rel=1e-14)
    assert float(a.value) == pytest.approx(float(error_bound(system, basis, T, x0).value),
                                           rel=1e-14)
    with pytest.raises(ValueError, match="estimator must be ResidualBound"):
        mj.estimate(system, basis, T, x0)
    with pytest.raises(ValueError, match="ResidualBound has no gradient estimate"):
        mj.estimate(system, mj.ResidualBound(basis), T, x0, gradient=True)


def small_scene(position=7.0, coefficient=1.0):
    return mj.app.load_scene({
        "name": "small", "chain": {"type": "mikota", "n": N, "m": 1.0, "k": 1.0},
        "damper": [{"type": "grounded", "position": position, "coefficient": coefficient}],
        "initial": {"displacement": {"3": 1.0}}, "time": {"end": T, "step": 0.05},
        "reduction": {"snapshots": [0.0, 10.0], "rank": 6}})


@pytest.mark.slow  # ~50 s (default-run time: CI under 15 min)
def test_greedy_basis_certifies_the_training_designs_and_holds_between_them():
    scene = small_scene()
    training = mj.grid(positions=np.linspace(1.0, 40.0, 4)[:, None],
                       coefficients=np.geomspace(0.1, 100.0, 3)[:, None])
    result = mj.reduce(scene, mj.Greedy(training, 1e-3, step=4))
    stats = result.stats
    assert stats.certified and result.rank <= N
    assert max(stats.bounds) <= 1e-3 and stats.full_solves == len(stats.history) - 1
    assert stats.history[-1][1] <= 1e-3 < stats.history[0][1]
    # designs off the training grid: the bound there holds against the full model
    rng = np.random.default_rng(0)
    for position, coefficient in zip(rng.uniform(1, 40, 3), 10 ** rng.uniform(-1, 2, 3)):
        s = small_scene(position, coefficient)
        bound = mj.estimate(s.system, mj.ResidualBound(result.basis), T, s.x0)
        j = float(mj.Energy(T, s.x0)(s.system))
        assert abs(j - float(bound.value)) <= float(bound.error)


@pytest.mark.slow  # ~14 s, a compile per rank tried (default-run time: CI under 15 min)
def test_rank_for_bound_is_the_smallest_rank_that_meets_the_tolerance(case):
    scene = small_scene()
    pod = mj.reduce(scene, mj.POD((0.0, 10.0), rank=1)).stats.decomposition
    rank = mj.rank_for_bound(scene, pod, 1e-4)
    relative = [float(mj.estimate(scene.system, mj.ResidualBound(pod.basis(r)), T,
                                  scene.x0).relative) for r in (rank - 1, rank)]
    assert relative[1] <= 1e-4 < relative[0]
    j = float(mj.Energy(T, scene.x0)(scene.system))
    j_r = float(mj.Energy(T, scene.x0)(mj.reduce(scene.system, mj.Projection(pod.basis(rank)))))
    assert abs(j_r / j - 1) <= 1e-4
    with pytest.raises(ValueError, match="tolerance must be in"):
        mj.rank_for_bound(scene, pod, 2.0)
