"""Randomized POD (Halko, Martinsson & Tropp 2011) against the exact SVD of a known matrix."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import orthonormal, sign_rule

from mikota_jax._rom.pod import pod


def known(n, m, s, seed=0):
    """(Q, U) with Q = U diag(s) V^T: singular values ``s`` and left singular vectors U."""
    k = len(s)
    u, v = orthonormal(n, k, seed), orthonormal(m, k, seed + 1)
    return u @ np.diag(s) @ v.T, u


def largest_angle_sine(a, b):
    """sin of the largest principal angle between the column spaces of orthonormal a and b."""
    return float(np.linalg.norm(b - a @ (a.T @ b), 2))


# Most tests share one shape (300 x 80, rank 10, default oversampling): one compile serves them.
N, M, RANK = 300, 80, 10


@pytest.mark.parametrize("n, m", [(N, M), (M, N)])
def test_leading_values_and_modes_match_a_known_decaying_spectrum(n, m, close):
    s = 10.0 * 0.5 ** np.arange(60)  # sigma_{k+p+1} / sigma_k = 2^-10: rounding after 2 rounds
    q, u = known(n, m, s)
    result = pod(q, method="randomized", rank=RANK)
    assert result.singular_values.shape == (RANK,) and result.modes.shape == (n, RANK)
    close(result.singular_values, s[:RANK], rtol=1e-12)
    close(result.modes, sign_rule(u[:, :RANK]), atol=1e-9)
    close(result.modes.T @ result.modes, np.eye(RANK), atol=1e-13)
    assert largest_angle_sine(np.asarray(result.modes), u[:, :RANK]) < 1e-9
    exact = pod(q)
    close(result.singular_values, exact.singular_values[:RANK], rtol=1e-12)
    close(result.total_energy, np.sum(s**2), rtol=1e-13)


def test_power_iterations_sharpen_a_slowly_decaying_spectrum():
    s = 1.0 / np.arange(1.0, M + 1)  # sigma_j = 1/j: a poor case for a plain sketch
    q, u = known(N, M, s, seed=4)

    def errors(power_iterations):
        result = pod(q, method="randomized", rank=RANK, power_iterations=power_iterations)
        value = np.max(np.abs(np.asarray(result.singular_values) / s[:RANK] - 1))
        return value, largest_angle_sine(np.asarray(result.modes[:, :3]), u[:, :3])

    plain, refined = errors(0), errors(2)
    assert refined[0] < plain[0] / 10 and refined[1] < plain[1] / 10, (plain, refined)
    assert refined[0] < 0.05, refined  # sigma_10 / sigma_21 ~ 1/2: (1/2)^5 ~ 0.03 at worst


def test_a_fixed_key_is_deterministic_and_the_default_is_key_0():
    q, _ = known(N, M, 3.0 * 0.8 ** np.arange(M), seed=6)

    def run(**kwargs):
        return pod(q, method="randomized", rank=RANK, power_iterations=0, **kwargs)

    a, b, c, d = run(), run(), run(key=jax.random.key(0)), run(key=jax.random.key(1))
    for other in (b, c):
        np.testing.assert_array_equal(a.singular_values, other.singular_values)
        np.testing.assert_array_equal(a.modes, other.modes)
    assert not np.array_equal(a.singular_values, d.singular_values)  # another sketch


def test_works_under_jit_with_a_traced_legacy_key(close):
    q, _ = known(N, M, 2.0 ** -np.arange(40.0), seed=8)

    @jax.jit
    def leading(snapshots, key):
        result = pod(snapshots, method="randomized", rank=RANK, key=key)
        return result.singular_values, result.basis(RANK)

    raw = jax.random.PRNGKey(3)  # a raw uint32 key, traced here
    s, basis = leading(jnp.asarray(q), raw)
    eager = pod(q, method="randomized", rank=RANK, key=jax.random.wrap_key_data(raw))
    close(s, eager.singular_values, rtol=1e-13)
    close(basis, eager.modes, atol=1e-12)


def test_the_sketch_is_capped_at_the_smaller_side(close):
    s = np.array([4.0, 3.0, 2.0, 1.0, 0.5])
    q, u = known(30, 5, s, seed=10)
    result = pod(q, method="randomized", rank=5, oversampling=10)  # sketch 15 -> 5 columns
    close(result.singular_values, s, rtol=1e-13)
    close(result.modes, sign_rule(u), atol=1e-12)


def test_energy_of_a_truncated_pod_uses_the_total_and_refuses_the_paper_criterion(close):
    s = 10.0 * 0.6 ** np.arange(50)
    q, _ = known(N, M, s, seed=12)
    full, part = pod(q), pod(q, method="randomized", rank=RANK)
    close(part.energy_fraction(), full.energy_fraction()[:RANK], rtol=1e-12)
    for energy in (0.5, 0.9, 0.99):
        assert part.rank_for_energy(energy) == full.rank_for_energy(energy)
    with pytest.raises(ValueError, match="capture a fraction .* compute more"):
        part.rank_for_energy(1.0 - 1e-12)
    with pytest.raises(ValueError, match="needs the sum of all singular values"):
        part.energy_fraction("paper")
    with pytest.raises(ValueError, match="needs the sum of all singular values"):
        part.rank_for_energy(0.9, "paper")
    with pytest.raises(ValueError, match=r"rank must lie in 1..10"):
        part.basis(RANK + 1)


@pytest.mark.parametrize("kwargs, match", [
    ({}, r"rank \(required for method='randomized'\) must be an integer 1..5"),
    ({"rank": 0}, r"rank .* must be an integer 1..5, got 0"),
    ({"rank": 6}, r"rank .* must be an integer 1..5, got 6"),
    ({"rank": 2.0}, r"rank .* must be an integer 1..5"),
    ({"rank": True}, r"rank .* must be an integer 1..5"),
    ({"rank": 2, "oversampling": -1}, r"oversampling must be an integer >= 0, got -1"),
    ({"rank": 2, "oversampling": 1.5}, r"oversampling must be an integer >= 0"),
    ({"rank": 2, "power_iterations": -1}, r"power_iterations must be an integer >= 0"),
    ({"rank": 2, "key": 3}, r"key must be a jax.random.key"),
    ({"rank": 2, "key": np.zeros(3, np.uint32)}, r"key must be a jax.random.key"),
])
def test_bad_randomized_arguments_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        pod(np.ones((9, 5)), method="randomized", **kwargs)


def test_randomized_arguments_are_refused_for_the_full_methods():
    for method in ("svd", "snapshots"):
        with pytest.raises(ValueError, match="rank and key apply to method='randomized' only"):
            pod(np.ones((4, 3)), method=method, rank=2)
