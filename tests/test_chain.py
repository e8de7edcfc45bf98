"""Mikota's chain against the paper's closed forms (eqs. 2.2-2.7) and independent linear algebra."""

from fractions import Fraction

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sl

import mikota_jax as mj


def stiffness_by_hand(springs):
    """K of eq. (2.2), written entry by entry: k_i + k_{i+1} on the diagonal, -k_{i+1} beside it."""
    n = len(springs)
    K = np.zeros((n, n))
    for i in range(n):
        K[i, i] = springs[i] + (springs[i + 1] if i + 1 < n else 0.0)
        if i + 1 < n:
            K[i, i + 1] = K[i + 1, i] = -springs[i + 1]
    return K


def exact_mode_matrix(n):
    """U[i-1, l-1] = p_l(i) in exact rational arithmetic (eq. 2.5)."""
    columns = []
    for l in range(1, n + 1):
        c = mj.analytic.mode_shape_coefficients(n, l)
        p = lambda i, c=c: sum(cj * Fraction(i) ** j for j, cj in enumerate(c))
        columns.append([p(i) for i in range(1, n + 1)])
    return [[columns[l][i] for l in range(n)] for i in range(n)]


def mass_stiffness(system):
    M, _, K = system.dense()
    return np.asarray(M), np.asarray(K)


def generalized_eigenvectors(system):
    M, K = mass_stiffness(system)
    return sl.eigh(K, M)


# --- matrices -----------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 5])
def test_mikota_masses_and_springs_follow_eq_2_3(n, close):
    m, k = 2.5, 0.7
    system = mj.mikota_chain(n, m, k)
    i = np.arange(1, n + 1)
    M, D, K = system.dense()
    close(M, np.diag(m / i), rtol=1e-15)
    close(K, stiffness_by_hand((n - i + 1) * k), rtol=1e-15)
    assert D is None and system.damping is None


def test_mikota_stiffness_for_n_4_is_the_hand_written_matrix(close):
    # k_i = (5 - i) k: 4, 3, 2, 1 (eq. 2.3), assembled as in eq. (2.2)
    K = np.array([[7, -3, 0, 0], [-3, 5, -2, 0], [0, -2, 3, -1], [0, 0, -1, 1]], float)
    close(mj.mikota_chain(4).dense()[2], K, rtol=0.0)
    close(mj.mikota_chain(4, 1.0, 3.0).dense()[2], 3 * K, rtol=1e-15)


def test_general_chain_assembles_eq_2_2_from_arbitrary_masses_and_springs(close):
    rng = np.random.default_rng(1)
    masses, springs = rng.uniform(0.5, 2, 6), rng.uniform(0.5, 2, 6)
    system = mj.chain(masses, springs)
    M, _, K = system.dense()
    close(M, np.diag(masses), rtol=0.0)
    close(K, stiffness_by_hand(springs), rtol=1e-15)
    x = rng.standard_normal(6)
    close(system.stiffness.mv(jnp.asarray(x)), stiffness_by_hand(springs) @ x, rtol=1e-14)
    assert system.size == 6


def test_single_mass_chain_is_a_one_by_one_oscillator(close):
    system = mj.chain([2.0], [3.0])
    close(system.dense()[2], [[3.0]], rtol=0.0)
    close(system.stiffness.mv(jnp.array([2.0])), [6.0], rtol=0.0)


# --- eigenfrequencies (eq. 2.4) -----------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 10, 300, 1000])
@pytest.mark.parametrize("m, k", [(1.0, 1.0), (2.5, 0.7)])
def test_modal_decomposition_gives_l_sqrt_k_over_m(n, m, k, close):
    system = mj.mikota_chain(n, m, k)
    omega, modes = mj.modal_decomposition(system)
    expected = np.arange(1, n + 1) * np.sqrt(k / m)
    close(omega, expected, rtol=1e-10, what=f"n={n}")
    # U^T M U = I and U^T K U = diag(omega^2) (eq. 2.7, normalized)
    M, K = mass_stiffness(system)
    U = np.asarray(modes)
    if n <= 300:
        close(U.T @ M @ U, np.eye(n), atol=1e-10)
        close(U.T @ K @ U / expected[:, None] / expected[None, :], np.eye(n), atol=1e-9)


@pytest.mark.parametrize("n", [1, 2, 10, 300, 1000])
def test_scipy_generalized_eigh_agrees_with_mikotas_conjecture(n, close):
    m, k = 0.4, 3.0
    M, K = mass_stiffness(mj.mikota_chain(n, m, k))
    omega2 = sl.eigh(K, M, eigvals_only=True)
    close(np.sqrt(omega2), np.arange(1, n + 1) * np.sqrt(k / m), rtol=1e-10)


def test_eigenfrequencies_function_returns_l_sqrt_k_over_m(close):
    close(mj.analytic.eigenfrequencies(4), [1.0, 2.0, 3.0, 4.0], rtol=0.0)
    close(mj.analytic.eigenfrequencies(3, 4.0, 9.0), [1.5, 3.0, 4.5], rtol=1e-15)
    close(mj.analytic.eigenfrequencies(1, m=2.0, k=8.0), [2.0], rtol=1e-15)


def test_eigenfrequencies_are_differentiable_in_m_and_k(close):
    # d/dm (l sqrt(k/m)) = -l sqrt(k/m) / (2m)
    grad_m = jax.grad(lambda m: jnp.sum(mj.analytic.eigenfrequencies(3, m, 4.0)))(1.0)
    close(grad_m, -(1 + 2 + 3) * 2.0 / 2.0, rtol=1e-14)


# --- mode shapes (eqs. 2.5-2.6) ----------------------------------------------------------------


def parallel(a, b):
    """1 - |cos angle(a, b)|: zero exactly when the vectors are parallel."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return 1 - abs(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))


@pytest.mark.parametrize("l", [1, 2, 3])
@pytest.mark.parametrize("n", [3, 12, 40])
def test_paper_mode_shapes_are_eigenvectors(n, l):
    _, vectors = generalized_eigenvectors(mj.mikota_chain(n, 2.0, 5.0))
    assert parallel(mj.analytic.paper_mode_shape(n, l), vectors[:, l - 1]) < 1e-12


def test_every_polynomial_mode_shape_of_n_12_is_an_eigenvector():
    n = 12
    _, vectors = generalized_eigenvectors(mj.mikota_chain(n))
    for l in range(1, n + 1):
        assert parallel(mj.analytic.mode_shape(n, l), vectors[:, l - 1]) < 1e-10, l


@pytest.mark.parametrize("l", [1, 4, 17, 40])
def test_high_polynomial_mode_shapes_of_n_40_are_eigenvectors(l):
    _, vectors = generalized_eigenvectors(mj.mikota_chain(40))
    assert parallel(mj.analytic.mode_shape(40, l), vectors[:, l - 1]) < 1e-10


def test_mode_shape_normalizations(close):
    raw = mj.analytic.mode_shape(12, 3, normalize=None)
    close(raw, mj.analytic.paper_mode_shape(12, 3), rtol=1e-13)
    close(mj.analytic.mode_shape(12, 3), raw / np.max(np.abs(raw)), rtol=1e-15)
    assert np.max(np.abs(mj.analytic.mode_shape(12, 3))) == 1.0
    close(mj.analytic.mode_shape(5, 1), np.arange(1, 6) / 5, rtol=1e-15)


@pytest.mark.parametrize("n", [7, 10])
def test_mode_shape_coefficients_match_eq_2_6_exactly(n):
    two_n_plus_1 = Fraction(2 * n + 1)
    assert mj.analytic.mode_shape_coefficients(n, 1) == (0, 1)
    assert mj.analytic.mode_shape_coefficients(n, 2) == (0, -two_n_plus_1 / 3, 1)
    assert mj.analytic.mode_shape_coefficients(n, 3) == (
        0, (Fraction(3, 2) * n * (n + 1) + 1) / 5, -Fraction(3, 5) * two_n_plus_1, 1)


def test_mode_shape_coefficients_solve_k_u_equals_l_squared_m_u_exactly():
    n = 9  # m = k = 1: m_i = 1/i, k_i = n - i + 1, lambda_l = l^2, in rational arithmetic
    U = exact_mode_matrix(n)
    springs = [Fraction(n - i + 1) for i in range(1, n + 1)] + [Fraction(0)]
    for l in range(1, n + 1):
        u = [U[i][l - 1] for i in range(n)] + [Fraction(0)]
        for i in range(n):
            left = u[i - 1] if i > 0 else Fraction(0)
            ku = springs[i] * (u[i] - left) - springs[i + 1] * (u[i + 1] - u[i])
            assert ku == l * l * u[i] / (i + 1), (l, i)


def test_modal_matrix_gram_u_t_u_is_tridiagonal_exactly():
    n = 10
    U = exact_mode_matrix(n)
    gram = [[sum(U[i][a] * U[i][b] for i in range(n)) for b in range(n)] for a in range(n)]
    for a in range(n):
        for b in range(n):
            if abs(a - b) > 1:
                assert gram[a][b] == 0, (a, b)
            elif a != b:
                assert gram[a][b] != 0, (a, b)  # genuinely tridiagonal, not diagonal


def test_modal_matrix_gram_u_t_u_is_tridiagonal_in_floating_point():
    n = 12
    U = np.stack([np.asarray(mj.analytic.mode_shape(n, l)) for l in range(1, n + 1)], axis=1)
    gram = U.T @ U
    scale = np.sqrt(np.outer(np.diag(gram), np.diag(gram)))
    far = np.abs(np.subtract.outer(np.arange(n), np.arange(n))) > 1
    assert np.max(np.abs(gram[far]) / scale[far]) < 1e-12
    assert np.min(np.abs(np.diag(gram, 1)) / np.diag(scale, 1)) > 1e-3


def test_mode_shapes_are_m_and_k_orthogonal_exactly_eq_2_7():
    n = 8
    U = exact_mode_matrix(n)
    masses = [Fraction(1, i) for i in range(1, n + 1)]
    springs = [Fraction(n - i + 1) for i in range(1, n + 1)]
    # the springs are integers, so the float matrix of eq. (2.2) converts to fractions exactly
    K = [[Fraction(v) for v in row] for row in stiffness_by_hand(springs).tolist()]
    for a in range(n):
        for b in range(n):
            mass = sum(U[i][a] * masses[i] * U[i][b] for i in range(n))
            stiff = sum(U[i][a] * K[i][j] * U[j][b] for i in range(n) for j in range(n))
            if a == b:
                assert mass > 0 and stiff == (a + 1) ** 2 * mass
            else:
                assert mass == 0 and stiff == 0, (a, b)


def test_mode_shapes_are_m_and_k_orthogonal_in_floating_point(close):
    n, m, k = 20, 1.5, 0.5
    M, K = mass_stiffness(mj.mikota_chain(n, m, k))
    U = np.stack([np.asarray(mj.analytic.mode_shape(n, l)) for l in range(1, n + 1)], axis=1)
    modal_mass, modal_stiffness = U.T @ M @ U, U.T @ K @ U
    d = np.sqrt(np.diag(modal_mass))
    close(modal_mass / np.outer(d, d), np.eye(n), atol=1e-12)
    close(modal_stiffness / np.outer(d, d), np.diag(np.arange(1, n + 1) ** 2 * k / m), atol=1e-9)


# --- bad input --------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [0, -3, 2.5, "3", True, None])
def test_mikota_chain_rejects_a_bad_n(n):
    with pytest.raises(ValueError, match="n must be an integer >= 1"):
        mj.mikota_chain(n)


@pytest.mark.parametrize("fn", [mj.analytic.eigenfrequencies,
                                lambda n: mj.analytic.mode_shape(n, 1),
                                lambda n: mj.analytic.paper_mode_shape(n, 1),
                                lambda n: mj.analytic.mode_shape_coefficients(n, 1)])
@pytest.mark.parametrize("n", [0, 2.5, True])
def test_analytic_functions_reject_a_bad_n(fn, n):
    with pytest.raises(ValueError, match="n must be an integer"):
        fn(n)


@pytest.mark.parametrize("l", [0, 6, 1.0, True])
def test_mode_shape_rejects_a_mode_number_outside_1_to_n(l):
    with pytest.raises(ValueError, match="mode number l"):
        mj.analytic.mode_shape(5, l)


def test_paper_mode_shape_only_knows_l_up_to_3():
    with pytest.raises(ValueError, match="l = 1, 2, 3 only"):
        mj.analytic.paper_mode_shape(6, 4)


def test_mode_shape_rejects_an_unknown_normalization():
    with pytest.raises(ValueError, match="normalize"):
        mj.analytic.mode_shape(5, 2, normalize="l2")


@pytest.mark.parametrize("name", ["m", "k"])
@pytest.mark.parametrize("value", [0.0, -1.0, np.nan, np.inf])
def test_mikota_chain_rejects_non_positive_or_non_finite_m_and_k(name, value):
    with pytest.raises(ValueError, match=f"{name} must be finite and > 0"):
        mj.mikota_chain(4, **{name: value})
    with pytest.raises(ValueError, match=f"{name} must be finite and > 0"):
        mj.analytic.eigenfrequencies(4, **{name: value})


@pytest.mark.parametrize("name", ["masses", "springs"])
@pytest.mark.parametrize("value", [0.0, -1.0, np.nan])
def test_chain_rejects_non_positive_or_nan_masses_and_springs(name, value):
    arrays = {"masses": np.ones(4), "springs": np.ones(4)}
    arrays[name][2] = value
    with pytest.raises(ValueError, match=f"{name} must be finite and > 0"):
        mj.chain(**arrays)


def test_chain_rejects_mismatched_or_empty_shapes():
    with pytest.raises(ValueError, match="springs must have the shape of masses"):
        mj.chain(np.ones(3), np.ones(4))
    with pytest.raises(ValueError, match="masses must be a 1-d array"):
        mj.chain(np.ones(0), np.ones(0))
    with pytest.raises(ValueError, match="masses must be a 1-d array"):
        mj.chain(np.ones((2, 2)), np.ones((2, 2)))


@pytest.mark.parametrize("name", ["masses", "springs"])
def test_chain_rejects_float32_arrays(name):
    arrays = {"masses": np.ones(3), "springs": np.ones(3)}
    arrays[name] = arrays[name].astype(np.float32)
    with pytest.raises(ValueError, match=f"{name} must be float64, got float32"):
        mj.chain(**arrays)
    arrays[name] = jnp.asarray(arrays[name])  # a jax float32 array too
    with pytest.raises(ValueError, match=f"{name} must be float64"):
        mj.chain(**arrays)


@pytest.mark.parametrize("name", ["m", "k"])
def test_mikota_chain_rejects_float32_m_and_k(name):
    with pytest.raises(ValueError, match=f"{name} must be float64, got float32"):
        mj.mikota_chain(3, **{name: np.float32(1.0)})


def test_traced_bad_m_fails_at_run_time_under_filter_jit():
    build = eqx.filter_jit(lambda m: mj.mikota_chain(3, m).mass.diagonal)
    np.testing.assert_allclose(build(jnp.asarray(3.0)), [3.0, 1.5, 1.0], rtol=1e-15)
    with pytest.raises(eqx.EquinoxRuntimeError, match="m must be finite and > 0"):
        build(jnp.asarray(-1.0))


def test_traced_bad_masses_and_springs_fail_at_run_time_under_jit():
    # (a failed check fires where its checked value is used: return both operators)
    build = lambda a, b: (mj.chain(a, b).mass.diagonal, mj.chain(a, b).stiffness.diagonal)
    with pytest.raises(eqx.EquinoxRuntimeError, match="masses must be finite and > 0"):
        eqx.filter_jit(build)(jnp.array([1.0, np.nan, 1.0]), jnp.ones(3))
    with pytest.raises(eqx.EquinoxRuntimeError, match="springs must be finite and > 0"):
        eqx.filter_jit(build)(jnp.ones(3), jnp.array([1.0, 1.0, -2.0]))
    # plain jax.jit reports the same check through XLA's runtime error
    with pytest.raises(jax.errors.JaxRuntimeError, match="k must be finite and > 0"):
        jax.jit(lambda k: mj.mikota_chain(3, 1.0, k).stiffness.diagonal)(jnp.asarray(np.nan))


def test_traced_bad_m_fails_under_vmap_and_good_batches_pass(close):
    build = jax.vmap(lambda m: mj.mikota_chain(3, m).mass.diagonal)
    close(build(jnp.array([1.0, 2.0])), [[1.0, 0.5, 1 / 3], [2.0, 1.0, 2 / 3]], rtol=1e-15)
    with pytest.raises(eqx.EquinoxRuntimeError, match="m must be finite and > 0"):
        build(jnp.array([1.0, -2.0]))
    with pytest.raises(eqx.EquinoxRuntimeError, match="masses must be finite and > 0"):
        jax.vmap(lambda a: mj.chain(a, jnp.ones(2)).mass.diagonal)(jnp.array([[1.0, 1.0],
                                                                          [1.0, 0.0]]))


def test_vmap_over_m_gives_the_batch_of_eigenfrequencies(close):
    ms = jnp.array([1.0, 4.0])
    omega = jax.vmap(lambda m: mj.modal_decomposition(mj.mikota_chain(5, m, 1.0))[0])(ms)
    close(omega, np.outer(1 / np.sqrt(ms), np.arange(1, 6)), rtol=1e-12)
