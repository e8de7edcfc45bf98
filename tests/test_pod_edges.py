"""POD and Galerkin on edge cases: rank-deficient snapshots, repeated singular values, ranks and
energies at the limits, one-sample windows, a one-mass chain, and bases that are not orthonormal.

Every case either gives the right answer (checked against an analytic solution or a construction
with a known SVD) or stops with a ValueError that names the argument.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import orthonormal, sign_rule

import mikota_jax as mj
from mikota_jax._rom.pod import pod, rank_for_energy

# under a user's jax.jit, equinox's runtime error arrives wrapped in jax's (which some jax versions
# raise as a ValueError); the message is what the tests check
TRACED_ERRORS = (ValueError, eqx.EquinoxRuntimeError, jax.errors.JaxRuntimeError)
ENERGIES = (0.5, 0.9, 0.99, 0.9999, 1 - 1e-8, 1 - 1e-12, 1 - 1e-14, 1.0)


def known(n, m, s, seed=0):
    """(Q, U) with Q = U diag(s) V^T: singular values ``s`` and left singular vectors U."""
    k = len(s)
    u, v = orthonormal(n, k, seed), orthonormal(m, k, seed + 1)
    return u @ np.diag(s) @ v.T, u


# --- rank-deficient snapshots -------------------------------------------------------------------


@pytest.fixture(scope="module", params=[(6, 2), (20, 1), (30, 3)], ids=lambda p: f"n{p[0]}-l{p[1]}")
def single_mode(request):
    """Snapshots of an undamped Mikota chain released from its l-th mode: x(t) = u_l cos(l t)."""
    n, l = request.param
    ts = np.linspace(0.0, 20.0, 2001)
    shape = np.asarray(mj.analytic.mode_shape(n, l))
    q = mj.solve(mj.mikota_chain(n), ts, shape, method=mj.DenseExponential()).displacement.T
    return n, l, ts, shape, q


@pytest.mark.parametrize("method", ["svd", "snapshots"])
def test_a_single_mode_excitation_gives_rank_one_with_the_mode_shape_as_first_pom(
        single_mode, method, close):
    n, l, ts, shape, q = single_mode
    result = pod(q, method=method)
    assert result.numerical_rank() == 1
    s = np.asarray(result.singular_values)
    # sigma_1^2 = sum_t cos(l t)^2 |u_l|^2 (omega_l = l for m = k = 1, eq. 2.4)
    close(s[0] ** 2, np.sum(np.cos(l * ts) ** 2) * np.sum(shape**2), rtol=1e-12)
    close(result.modes[:, 0], sign_rule(shape[:, None] / np.linalg.norm(shape))[:, 0], atol=1e-12)
    for criterion in ("squared", "paper"):
        assert [result.rank_for_energy(e, criterion) for e in ENERGIES] == [1] * len(ENERGIES)


def test_a_rank_above_the_numerical_rank_is_refused_eagerly_for_every_method(single_mode):
    q = single_mode[4]
    for result in (pod(q), pod(q, method="snapshots"),
                   pod(q, method="randomized", rank=3)):
        assert result.basis(1).shape == (q.shape[0], 1)
        with pytest.raises(ValueError, match="rank = 2 exceeds the numerical rank 1"):
            result.basis(2)


def test_a_rank_above_the_numerical_rank_is_refused_under_jit(single_mode):
    q = jnp.asarray(single_mode[4])
    one, two = (jax.jit(lambda snapshots, r=r: pod(snapshots).basis(r)) for r in (1, 2))
    assert jax.block_until_ready(one(q)).shape == (q.shape[0], 1)
    with pytest.raises(TRACED_ERRORS, match="rank = 2 exceeds the numerical rank"):
        jax.block_until_ready(two(q))


def test_energy_one_gives_the_exact_rank_and_no_energy_goes_past_it():
    # rank 3 by construction; the other 5 singular values are rounding noise (~1e-16)
    q, _ = known(8, 40, [3.0, 2.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0], seed=2)
    result = pod(q)
    assert result.numerical_rank() == 3 and result.modes.shape[1] == 8
    for criterion in ("squared", "paper"):
        ranks = [result.rank_for_energy(e, criterion) for e in ENERGIES]
        assert ranks == sorted(ranks) and ranks[-1] == 3, ranks  # monotone, capped at 3
        free = [rank_for_energy(result.singular_values, e, criterion) for e in ENERGIES]
        assert free == ranks
    with pytest.raises(ValueError, match="rank = 4 exceeds the numerical rank 3"):
        result.basis(4)


def test_all_zero_snapshots_have_rank_zero_and_give_no_basis():
    result = pod(np.zeros((4, 7)))  # a chain at rest
    assert result.numerical_rank() == 0
    with pytest.raises(ValueError, match="singular values must be finite and not all zero"):
        result.rank_for_energy(0.9)
    with pytest.raises(ValueError, match="rank = 1 exceeds the numerical rank 0"):
        result.basis(1)


@pytest.mark.parametrize("energy", [0, 0.0, -0.0, -1e-300, 1 + 1e-15, 1.5, np.nan, np.inf, None])
def test_energies_outside_0_1_are_refused_by_full_and_truncated_pods(energy):
    q, _ = known(6, 9, [3.0, 2.0, 1.0], seed=4)
    for result in (pod(q), pod(q, method="randomized", rank=2)):
        with pytest.raises(ValueError, match=r"energy must be a number in \(0, 1\]"):
            result.rank_for_energy(energy)


# --- repeated singular values -------------------------------------------------------------------


@pytest.mark.parametrize("method", ["svd", "snapshots"])
def test_repeated_singular_values_are_exact_and_their_poms_span_the_right_subspace(method, close):
    s = np.array([3.0, 2.0, 2.0, 2.0, 1.0, 1.0, 0.5])
    q, u = known(9, 25, s, seed=6)  # rank 7 of 9
    result = pod(q, method=method)
    assert result.numerical_rank() == len(s)
    close(result.singular_values[: len(s)], s, rtol=1e-13)
    modes = np.asarray(result.basis(len(s)))
    close(modes.T @ modes, np.eye(len(s)), atol=1e-13)
    # a repeated value's POMs are any orthonormal basis of its subspace: compare projectors
    for cluster in (slice(0, 1), slice(1, 4), slice(4, 6), slice(6, 7)):
        close(modes[:, cluster] @ modes[:, cluster].T, u[:, cluster] @ u[:, cluster].T,
              atol=1e-12)


# --- the smallest problems ----------------------------------------------------------------------


@pytest.mark.parametrize("method", ["svd", "snapshots"])
def test_a_one_sample_window_gives_one_pom_and_the_rayleigh_quotient_rom(method, close):
    n = 7
    system = mj.mikota_chain(n)
    x0 = np.linspace(0.2, 1.0, n) ** 2  # not a mode shape
    sample = mj.solve(system, jnp.zeros(1), x0,
                      method=mj.DenseExponential()).displacement.T  # Q is n x 1
    assert sample.shape == (n, 1)
    result = pod(sample, method=method)
    close(result.singular_values, [np.linalg.norm(x0)], rtol=1e-14)
    close(result.modes[:, 0], x0 / np.linalg.norm(x0), rtol=1e-14)
    assert result.numerical_rank() == 1 and result.rank_for_energy(1.0) == 1
    with pytest.raises(ValueError, match=r"rank must lie in 1..1"):
        result.basis(2)
    # one mode phi = x0 / |x0|: q'' + (phi^T K phi / phi^T M phi) q = 0, so x = x0 cos(w t)
    M, _, K = (np.asarray(a) for a in system.dense())
    omega = np.sqrt(x0 @ K @ x0 / (x0 @ M @ x0))
    ts = np.linspace(0.0, 10.0, 101)
    rom = mj.reduce(system, mj.Projection(result.basis(1)))
    out = mj.solve(rom, ts, x0, method=mj.DenseExponential())
    close(out.displacement, np.cos(omega * ts)[:, None] * x0[None, :], atol=1e-13)


def test_a_one_mass_chain_is_simulated_solved_reduced_and_agrees_with_the_cosine(close):
    m, k, x0 = 2.0, 8.0, 0.3
    system = mj.chain([m], [k])
    ts = np.linspace(0.0, 10.0, 201)
    analytic = x0 * np.cos(np.sqrt(k / m) * ts)[:, None]
    exact = mj.solve(system, ts, np.array([x0]), method=mj.DenseExponential())
    close(exact.displacement, analytic, atol=1e-14)
    simulated = mj.solve(system, ts, np.array([x0]), method=mj.ODE(rtol=1e-12, atol=1e-14))
    close(simulated.displacement, analytic, atol=1e-9 * x0)
    result = pod(exact.displacement.T)
    close(result.singular_values, [np.linalg.norm(analytic)], rtol=1e-13)
    close(result.modes, [[1.0]], rtol=1e-15)
    reduced = mj.reduce(system, mj.Projection(result.basis(1)))
    close(mj.solve(reduced, ts, np.array([x0]), method=mj.DenseExponential()).displacement,
          analytic, atol=1e-14)


def test_a_damped_one_mass_chain_follows_the_damped_oscillator(close):
    m, k, c, x0 = 2.0, 8.0, 0.5, 0.3
    system = mj.chain([m], [k], [mj.GroundedDamper(1.0, c)])
    close(system.dense()[1], [[c]], rtol=1e-15)
    ts = np.linspace(0.0, 10.0, 201)
    omega, zeta = np.sqrt(k / m), c / (2 * np.sqrt(k * m))
    damped = omega * np.sqrt(1 - zeta**2)
    analytic = x0 * np.exp(-zeta * omega * ts) * (np.cos(damped * ts)
                                                   + zeta * omega / damped * np.sin(damped * ts))
    close(mj.solve(system, ts, np.array([x0]), method=mj.Spectral()).displacement[:, 0], analytic,
          atol=1e-14)


# --- bases the Galerkin projection must refuse --------------------------------------------------

N = 8
BASIS = orthonormal(N, 4, 10)
NOT_ORTHONORMAL = "basis must have orthonormal columns"


@pytest.fixture(scope="module")
def chain():
    return mj.mikota_chain(N, dampers=[mj.GroundedDamper(3.0, 0.4)])


BAD_BASES = {
    "a duplicated column": np.column_stack([BASIS, BASIS[:, :1]]),
    "dependent columns": np.column_stack([BASIS[:, :3], BASIS[:, :3] @ np.ones(3) / np.sqrt(3)]),
    "unnormalised columns": 2.0 * BASIS,
    "a random matrix": np.random.default_rng(11).standard_normal((N, 4)),
    "orthogonality lost at 1e-5": BASIS + 1e-5 * np.random.default_rng(12).standard_normal((N, 4)),
}


@pytest.mark.parametrize("basis", BAD_BASES.values(), ids=BAD_BASES.keys())
def test_a_singular_or_non_orthonormal_basis_is_refused_eagerly(chain, basis):
    with pytest.raises(ValueError, match=NOT_ORTHONORMAL):
        mj.reduce(chain, mj.Projection(jnp.asarray(basis)))


def test_a_non_orthonormal_basis_is_refused_under_jit_and_vmap(chain, close):
    project = jax.jit(lambda basis: mj.reduce(chain, mj.Projection(basis)).system.mass.as_matrix())
    M = np.asarray(chain.dense()[0])
    close(project(jnp.asarray(BASIS)), BASIS.T @ M @ BASIS, atol=1e-15)
    with pytest.raises(TRACED_ERRORS, match=NOT_ORTHONORMAL):
        jax.block_until_ready(project(jnp.asarray(2.0 * BASIS)))
    duplicated = np.column_stack([BASIS[:, :3], BASIS[:, :1]])
    batch = jnp.stack([jnp.asarray(BASIS), jnp.asarray(duplicated)])
    with pytest.raises(TRACED_ERRORS, match=NOT_ORTHONORMAL):
        jax.block_until_ready(jax.vmap(project)(batch))


def test_a_basis_orthonormal_to_rounding_is_accepted_and_reproduces_the_projection(chain, close):
    # QR of a nearly dependent set: orthonormal to ~1e-15 however ill-conditioned the input
    raw = BASIS @ np.diag([1.0, 1.0, 1.0, 1e-9]) + BASIS[:, :1]
    basis = np.linalg.qr(raw)[0]
    reduced = mj.reduce(chain, mj.Projection(jnp.asarray(basis)))
    K = np.asarray(chain.dense()[2])
    close(reduced.system.dense()[2], basis.T @ K @ basis, atol=1e-13)
