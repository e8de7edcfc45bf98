"""O(n^2) chain modes (``_chain_modes``): exact Mikota frequencies (recognised from the data,
and by bisection alone), orthonormality, relative
accuracy for masses over twelve decades (against 50-digit decimal bisection), agreement with the
dense SVD path (``generalized_modes``), the chunked mode data, and derivatives by central
differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import sign_rule
from test_extremes import ORDERS, SPRINGS, bisection_eigenvalues

import mikota_jax as mj
from mikota_jax._model.chain_modes import _bisection, _mikota_ratio, chain_mode_data, chain_modes
from mikota_jax._model.modal import generalized_modes

M_, K_ = 1.3, 0.9


def mikota(n):
    i = np.arange(1, n + 1, dtype=float)
    return jnp.asarray(M_ / i), jnp.asarray((n - i + 1) * K_)


def random_chain(n, seed):
    rng = np.random.default_rng(seed)
    return jnp.asarray(rng.uniform(0.2, 5.0, n)), jnp.asarray(rng.uniform(0.2, 5.0, n))


def assert_modal(masses, springs, omega2, modes, tol):
    """U^T M U = I and U^T K U = diag(omega^2), relative to the scale of each entry."""
    masses, modes = np.asarray(masses), np.asarray(modes)
    gram = modes.T @ (masses[:, None] * modes)
    assert np.max(np.abs(gram - np.eye(masses.shape[0]))) < tol
    scale = np.sqrt(np.asarray(omega2))
    stretch = np.diff(modes, axis=0, prepend=0.0)  # L U: K = L^T diag(k) L without cancellation
    projected = stretch.T @ (np.asarray(springs)[:, None] * stretch) / np.outer(scale, scale)
    assert np.max(np.abs(projected - np.eye(masses.shape[0]))) < tol


@pytest.mark.parametrize("n", [1, 2, 10, 300, pytest.param(3000, marks=pytest.mark.slow)])
def test_mikota_frequencies_are_l_squared_k_over_m_to_a_few_ulps_and_modes_orthonormal(n, close):
    masses, springs = mikota(n)
    omega2, modes = jax.jit(chain_modes)(masses, springs)
    l = np.arange(1, n + 1)
    close(omega2, l**2 * K_ / M_, rtol=30 * np.finfo(float).eps)  # measured 12 ulps at n = 3000
    assert_modal(masses, springs, omega2, modes, tol=1e-12)  # measured 6e-13 at n = 3000


@pytest.mark.parametrize("n", [2, 300])
def test_bisection_alone_finds_mikota_frequencies_and_a_near_mikota_chain_is_not_taken_for_one(
        n, close):
    masses, springs = mikota(n)
    l = np.arange(1, n + 1)
    # the general path on data whose exact eigenvalues are known (exact zero pivots included)
    close(jax.jit(_bisection)(masses, springs), l**2 * K_ / M_, rtol=30 * np.finfo(float).eps)
    assert bool(_mikota_ratio(masses, springs)[0])
    # one mass off by 1e-9 relative: not Mikota's chain, its own eigenvalues (dense reference)
    nearby = masses.at[n // 2].multiply(1 + 1e-9)
    assert not bool(_mikota_ratio(nearby, springs)[0])
    omega2, _ = chain_modes(nearby, springs)
    reference, _ = generalized_modes(mj.chain(nearby, springs))
    close(omega2, reference, rtol=1e-11)
    close(omega2, _bisection(nearby, springs), rtol=0.0)
    assert np.max(np.abs(np.asarray(omega2) / (l**2 * K_ / M_) - 1)) > 1e-12


@pytest.mark.parametrize("seed", [0, 1])
def test_modes_of_a_random_chain_match_the_dense_svd_path_up_to_the_sign_rule(seed, close):
    masses, springs = random_chain(60, seed)
    omega2, modes = chain_modes(masses, springs)
    reference, reference_modes = generalized_modes(mj.chain(masses, springs))
    close(omega2, reference, rtol=1e-12)
    close(modes, sign_rule(np.asarray(reference_modes)), atol=1e-11)
    close(modes, sign_rule(np.asarray(modes)), rtol=0.0)  # largest entry of each mode positive
    assert_modal(masses, springs, omega2, modes, tol=1e-12)  # measured 7e-13 (seed 1)


@pytest.mark.parametrize("masses", ORDERS.values(), ids=ORDERS.keys())
def test_masses_over_twelve_decades_in_any_order_keep_full_relative_accuracy(masses, close):
    omega2, modes = chain_modes(jnp.asarray(masses), jnp.asarray(SPRINGS))
    close(omega2, bisection_eigenvalues(masses, SPRINGS), rtol=4 * np.finfo(float).eps)
    assert_modal(masses, SPRINGS, omega2, modes, tol=1e-13)


def test_a_long_chain_with_masses_over_twelve_decades_matches_the_dense_svd_path(close):
    rng = np.random.default_rng(3)
    masses, springs = 10.0 ** rng.uniform(-6, 6, 200), 10.0 ** rng.uniform(-2, 2, 200)
    omega2, modes = chain_modes(jnp.asarray(masses), jnp.asarray(springs))
    reference, _ = generalized_modes(mj.chain(masses, springs))
    close(omega2, reference, rtol=1e-11)  # the SVD path is the less accurate one here
    assert_modal(masses, springs, omega2, modes, tol=1e-11)


@pytest.mark.parametrize("chunk", [1, 7, 64])
def test_chain_mode_data_is_rows_and_projections_of_chain_modes(chunk, close):
    masses, springs = random_chain(20, 4)
    vectors = jnp.asarray(np.random.default_rng(5).standard_normal((20, 3)))
    rows = jnp.asarray([0, 19, 7])
    omega2, picked, projected = chain_mode_data(masses, springs, rows, vectors, chunk=chunk)
    reference, modes = chain_modes(masses, springs)
    close(omega2, reference, rtol=0.0)
    close(picked, modes[rows], atol=1e-15)
    close(projected, modes.T @ vectors, atol=1e-14)


@pytest.mark.parametrize("n", [50, 301])
def test_chain_mode_data_keeps_the_sign_rule_where_mikotas_entries_tie(n, close):
    """Mikota's modes have entries of equal size and opposite sign (n = 50: modes 10 and 50);
    ``chain_mode_data`` streams the modes through a scan and must pick the same entry for the
    sign as ``chain_modes`` (verified against the dense SVD path above), row for row."""
    system = mj.mikota_chain(n)  # m = k = 1 (the scaled data of ``mikota`` round differently)
    masses, springs = system.mass.diagonal, system.stiffness.springs
    vectors = jnp.asarray(np.random.default_rng(6).standard_normal((n, 2)))
    rows = jnp.arange(n)
    _, picked, projected = chain_mode_data(masses, springs, rows, vectors, chunk=64)
    _, modes = chain_modes(masses, springs)
    close(picked, modes, atol=1e-13)
    close(projected, modes.T @ vectors, atol=1e-12)


def test_chain_mode_data_under_jit_takes_traced_rows(close):
    masses, springs = mikota(12)
    vectors = jnp.eye(12)[:, :2]
    data = jax.jit(chain_mode_data, static_argnames="chunk")
    _, picked, projected = data(masses, springs, jnp.asarray([3]), vectors, chunk=5)
    _, modes = chain_modes(masses, springs)
    close(picked, modes[3:4], atol=1e-15)
    close(projected, modes[:2].T, atol=1e-15)


def central_difference(fn, primals, tangents, step=1e-6):
    plus = fn(*(p + step * t for p, t in zip(primals, tangents)))
    minus = fn(*(p - step * t for p, t in zip(primals, tangents)))
    return jax.tree.map(lambda a, b: (a - b) / (2 * step), plus, minus)


def test_jvp_of_chain_modes_matches_central_differences(close):
    masses, springs = random_chain(12, 6)
    rng = np.random.default_rng(7)
    tangents = tuple(jnp.asarray(rng.standard_normal(12)) for _ in range(2))
    _, (domega2, dmodes) = jax.jvp(chain_modes, (masses, springs), tangents)
    fd_omega2, fd_modes = central_difference(chain_modes, (masses, springs), tangents)
    close(domega2, fd_omega2, atol=1e-7 * np.max(np.abs(fd_omega2)))
    close(dmodes, fd_modes, atol=1e-7 * np.max(np.abs(fd_modes)))


def test_gradient_through_chain_modes_matches_the_dense_svd_path(close):
    masses, springs = random_chain(10, 8)

    def objective(modes_of):
        def fn(masses, springs):
            omega2, modes = modes_of(masses, springs)
            # sign-blind: the SVD path's signs are LAPACK's
            return omega2[2] + jnp.sum(modes[3] ** 2) + jnp.sum(modes[:, 4] ** 2 * modes[:, 5] ** 2)
        return fn

    reference = lambda m, k: generalized_modes(mj.chain(m, k))
    grads = jax.grad(objective(chain_modes), argnums=(0, 1))(masses, springs)
    expected = jax.grad(objective(reference), argnums=(0, 1))(masses, springs)
    close(grads[0], expected[0], rtol=1e-9, atol=1e-12)
    close(grads[1], expected[1], rtol=1e-9, atol=1e-12)


ROWS = jnp.asarray([2, 10])


def chunked_data(m, k, v):
    return chain_mode_data(m, k, ROWS, v, chunk=4)


def full_data(m, k, v):
    omega2, modes = chain_modes(m, k)
    return omega2, modes[ROWS], modes.T @ v


def data_primals(seed):
    masses, springs = random_chain(11, seed)
    return masses, springs, jnp.asarray(np.random.default_rng(seed).standard_normal((11, 2)))


def test_jvp_of_chain_mode_data_matches_that_of_chain_modes(close):
    primals = data_primals(9)
    rng = np.random.default_rng(10)
    tangents = tuple(jnp.asarray(rng.standard_normal(p.shape)) for p in primals)
    _, actual = jax.jvp(chunked_data, primals, tangents)
    _, expected = jax.jvp(full_data, primals, tangents)
    for a, b in zip(actual, expected):
        close(a, b, atol=1e-12 * np.max(np.abs(b)))


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_gradient_of_chain_mode_data_matches_that_of_chain_modes(close):
    primals = data_primals(11)
    scalar = lambda fn: lambda *p: sum(jnp.sum(jnp.sin(x)) for x in fn(*p))
    data, full = chunked_data, full_data
    for a, b in zip(jax.grad(scalar(data), argnums=(0, 1, 2))(*primals),
                    jax.grad(scalar(full), argnums=(0, 1, 2))(*primals)):
        close(a, b, atol=1e-12 * np.max(np.abs(b)))


def test_eigenvalue_derivative_of_mikota_chain_is_exact(close):
    # omega_l^2 = l^2 k / m with m = m_1 and k = k_n: scaling all masses by (1 + h) scales omega^2
    # by 1 / (1 + h), so d omega^2 / dh = -omega^2 along dm = masses.
    masses, springs = mikota(40)
    _, (domega2, _) = jax.jvp(chain_modes, (masses, springs), (masses, jnp.zeros(40)))
    close(domega2, -np.arange(1, 41) ** 2 * K_ / M_, rtol=1e-12)


def test_wrong_shapes_and_values_are_refused_naming_the_argument():
    masses, springs = mikota(5)
    with pytest.raises(ValueError, match="springs"):
        chain_modes(masses, springs[:4])
    with pytest.raises(ValueError, match="masses"):
        chain_modes(-masses, springs)
    with pytest.raises(Exception, match="springs"):
        jax.jit(chain_modes)(masses, -springs)
    with pytest.raises(ValueError, match="rows"):
        chain_mode_data(masses, springs, jnp.asarray([5]), jnp.eye(5))
    with pytest.raises(ValueError, match="rows"):
        chain_mode_data(masses, springs, jnp.asarray([0.5]), jnp.eye(5))
    with pytest.raises(ValueError, match="vectors"):
        chain_mode_data(masses, springs, jnp.asarray([0]), jnp.eye(4))
    with pytest.raises(ValueError, match="chunk"):
        chain_mode_data(masses, springs, jnp.asarray([0]), jnp.eye(5), chunk=0)


def test_gradient_through_mikota_modes_with_exactly_zero_pivots_is_finite_and_right(close):
    # integer data: some pivots of T - omega^2 I vanish exactly (guarded in the factorisation)
    i = np.arange(1.0, 11.0)
    masses, springs = jnp.asarray(1 / i), jnp.asarray(11 - i)

    def objective(modes_of):
        def fn(masses, springs):
            omega2, modes = modes_of(masses, springs)
            return omega2[1] + jnp.sum(modes[0] ** 2) + jnp.sum(modes[:, 3] ** 4)
        return fn

    reference = lambda m, k: generalized_modes(mj.chain(m, k))
    grads = jax.grad(objective(chain_modes), argnums=(0, 1))(masses, springs)
    expected = jax.grad(objective(reference), argnums=(0, 1))(masses, springs)
    close(grads[0], expected[0], rtol=1e-9, atol=1e-12)
    close(grads[1], expected[1], rtol=1e-9, atol=1e-12)
