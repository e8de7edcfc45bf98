"""Two-sided projection (``TwoSided``), second-order balanced truncation (``SOBT``) and the
oscillator form of a dense model (``LTIModel.oscillators``).

Truths: scipy's Lyapunov solver on the physical first-order form of a chain whose every mode is
damped (Rayleigh damping on top of the damper: ~1e-13 relative to the Gramians, so the
Hankel-like values to ~1e-10 relative where they are above 1e-6 of the largest); numpy's dense
complex solves of the full chain (~1e-13 relative to G); the Galerkin model of the same basis,
built by another code path (``reduce`` with ``Projection``)."""

import numpy as np
import pytest
import scipy.linalg as sl

import mikota_jax as mj

N = 30


def io_chain(n=N, velocity=False):
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(7.3, 1.0)],
                             internal_damping=mj.Rayleigh(0.0, 1e-3))
    out = mj.unit_vector(n, n // 2)
    return mj.IOModel(system, mj.unit_vector(n, 3), **({"cv": out} if velocity else {"cx": out}))


def dense_g(io, sigma):
    """G(sigma) and G'(sigma) of the full chain by dense complex solves."""
    m, d, k = (np.asarray(a) for a in io.model.dense())
    b, cx, cv = (np.asarray(a) for a in (io.inputs, io.cx, io.cv))
    x = np.linalg.solve(sigma**2 * m + sigma * d + k, b)
    dx = -np.linalg.solve(sigma**2 * m + sigma * d + k, (2 * sigma * m + d) @ x)
    return (cx + sigma * cv) @ x, cv @ x + (cx + sigma * cv) @ dx


def test_two_sided_with_one_basis_is_the_galerkin_model():
    io = io_chain()
    basis = np.linalg.qr(np.random.default_rng(1).standard_normal((N, 6)))[0]
    two_sided = mj.reduce(io, mj.TwoSided(basis, basis))
    galerkin = mj.reduce(io, mj.Projection(basis))
    s = np.array([0.2 + 1.5j, 4j, 3.0])
    expected = np.asarray(galerkin.transfer(s))
    assert np.max(np.abs(np.asarray(two_sided.transfer(s)) - expected)) < 1e-12 * np.max(
        np.abs(expected))


def test_two_sided_krylov_bases_interpolate_g_and_its_derivative():
    # V = P(sigma)^-1 B, W = P(sigma)^-T C^T (Re and Im parts): Hermite interpolation at sigma
    io = io_chain()
    m, d, k = (np.asarray(a) for a in io.model.dense())
    sigma = 0.3 + 2.2j
    pencil = sigma**2 * m + sigma * d + k
    v = np.linalg.solve(pencil, np.asarray(io.inputs))[:, 0]
    w = np.linalg.solve(pencil.T, np.asarray(io.cx).T)[:, 0]
    model = mj.reduce(io, mj.TwoSided(np.stack([v.real, v.imag], 1),
                                      np.stack([w.real, w.imag], 1)))
    value, slope = dense_g(io, sigma)
    h = 1e-5
    g_r = np.asarray(model.transfer(np.array([sigma, sigma + h, sigma - h])))[:, 0, 0]
    assert abs(g_r[0] - value[0, 0]) < 1e-11 * abs(value[0, 0])
    # the reduced model's derivative by central differences (truncation ~1e-10 relative)
    assert abs((g_r[1] - g_r[2]) / (2 * h) - slope[0, 0]) < 1e-7 * abs(slope[0, 0])


@pytest.mark.parametrize("variant", ["p", "v", "pv", "vp"])
def test_sobts_values_are_the_physical_gramians_and_the_full_rank_is_exact(variant):
    io = io_chain()
    m, d, k = (np.asarray(a) for a in io.model.dense())
    inverse = np.linalg.inv(m)
    a = np.block([[np.zeros((N, N)), np.eye(N)], [-inverse @ k, -inverse @ d]])
    b = np.vstack([np.zeros((N, 1)), inverse @ np.asarray(io.inputs)])
    c = np.hstack([np.asarray(io.cx), np.zeros((1, N))])
    p = sl.solve_continuous_lyapunov(a, -b @ b.T)
    q = sl.solve_continuous_lyapunov(a.T, -c.T @ c)
    block = {"p": slice(0, N), "v": slice(N, 2 * N)}
    x, y = block[variant[0]], block[variant[-1]]
    truth = np.sort(np.sqrt(np.abs(np.linalg.eigvals(p[x, x] @ q[y, y]))))[::-1]
    model = mj.reduce(io, mj.SOBT(8, variant))
    assert model.stats.modes == N and model.stats.dropped == 0.0
    values = np.asarray(model.stats.bounds)
    assert np.allclose(values, truth[:8], rtol=1e-8)
    # all N DOFs kept: an exact change of coordinates, the same transfer function
    full = mj.reduce(io, mj.SOBT(N, variant))
    s = np.array([0.1 + 2j, 7j])
    g = np.array([dense_g(io, z)[0][0, 0] for z in s])
    assert np.max(np.abs(np.asarray(full.transfer(s))[:, 0, 0] - g)) < 1e-10 * np.max(np.abs(g))


def test_sobt_leaves_out_the_modes_damped_below_rounding_and_says_what_it_costs():
    # Mikota n = 120, damper at DOF 7, no internal damping: the upper modes decay below what a
    # dense Gramian resolves (C_ll / 2 <= 2 n eps max omega) and are dropped. Their share of the
    # H2 norm is 5 % here, which it says; the exact H2 norm from the damped modes resolves them
    system = mj.mikota_chain(120, dampers=[mj.GroundedDamper(7.0, 1.0)])
    io = mj.IOModel(system, mj.unit_vector(120, 3), cx=mj.unit_vector(120, 60))
    with pytest.warns(UserWarning, match="carry 0.053 of the H2 norm"):
        model = mj.reduce(io, mj.SOBT(10))
    assert model.stats.modes == 83 and model.is_stable()
    error = float((io - model).h2_norm()) / float(io.h2_norm())
    assert model.stats.dropped < error < 0.5


def test_the_oscillator_form_has_the_same_transfer_function():
    io = io_chain()
    model = mj.reduce(io, mj.H2Optimal(5))
    mass, damping, stiffness, b, cx, cv = model.oscillators()
    assert np.allclose(mass, np.eye(5)) and np.allclose(damping, np.diag(np.diag(damping)))
    assert np.all(np.diag(damping) > 0) and np.all(np.diag(stiffness) > 0)
    again = mj.LTIModel.second_order(mass, damping, stiffness, b, cx=cx, cv=cv)
    s = np.array([0.1 + 1j, 3j, 2.0, 10 + 30j])
    expected = np.asarray(model.transfer(s))  # numpy's dense solve: ~1e-14 relative
    assert np.max(np.abs(np.asarray(again.transfer(s)) - expected) / np.abs(expected)) < 1e-10
    two_inputs = mj.LTIModel(-np.eye(2), np.eye(2), np.ones((1, 2)))
    with pytest.raises(ValueError, match="single-input"):
        two_inputs.oscillators()


def test_the_balanced_and_two_sided_strategies_refuse_in_one_line():
    io = io_chain()
    with pytest.raises(ValueError, match="variant must be one of"):
        mj.SOBT(3, "x")
    with pytest.raises(ValueError, match="rank = 31 is out of reach"):
        mj.reduce(io, mj.SOBT(31))
    with pytest.raises(ValueError, match="basis and test_basis must have one shape"):
        mj.TwoSided(np.ones((N, 2)), np.ones((N, 3)))
    with pytest.raises(ValueError, match="W\\^T M V is singular"):
        mj.reduce(io, mj.TwoSided(np.eye(N)[:, :2], np.eye(N)[:, 2:4]))
