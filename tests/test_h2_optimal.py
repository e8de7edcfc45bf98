"""Dense first-order models (``LTIModel``) and H2-optimal reduction (``H2Optimal``, IRKA).

Truths: scipy's Bartels-Stewart Lyapunov and Sylvester solvers on strictly stable systems (~1e-13
relative to the Gramian); numpy's dense complex solves of the full chain for the interpolation
conditions (backward stable, ~1e-13 relative to G); central differences of the whole reduction
for the gradient (h = 1e-4 of the coefficient: truncation ~1e-8 relative; the reduction's own
tolerance enters only to second order, since the error is stationary in the reduced model)."""

import jax
import numpy as np
import pytest
import scipy.linalg as sl

import mikota_jax as mj

N = 40


def io_chain(c=1.0, position=7.3, n=N):
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(position, c)],
                             internal_damping=mj.Rayleigh(0.0, 1e-4))
    return mj.IOModel(system, mj.unit_vector(n, 3), cx=mj.unit_vector(n, n // 2))


def dense_first_order(io):
    """(A, B, C) of the full model in (x, x'), E folded in."""
    m, d, k = (np.asarray(a) for a in io.model.dense())
    n = m.shape[0]
    inverse = np.linalg.inv(m)
    return (np.block([[np.zeros((n, n)), np.eye(n)], [-inverse @ k, -inverse @ d]]),
            np.vstack([np.zeros((n, io.inputs.shape[1])), inverse @ np.asarray(io.inputs)]),
            np.hstack([np.asarray(io.cx), np.asarray(io.cv)]))


def h2_error_dense(full, reduced):
    """||G - G_r||_H2 by one Lyapunov solve of the error system's block realization."""
    a1, b1, c1 = full
    a2, b2, c2 = reduced
    a = sl.block_diag(a1, a2)
    gramian = sl.solve_continuous_lyapunov(a, -np.vstack([b1, b2]) @ np.vstack([b1, b2]).T)
    c = np.hstack([c1, -c2])
    return float(np.sqrt(np.trace(c @ gramian @ c.T)))


def test_a_dense_models_h2_norm_and_errors_match_scipys_lyapunov_solves():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((12, 12))
    a = a - (np.max(np.linalg.eigvals(a).real) + 0.05) * np.eye(12)  # strictly stable
    e = np.eye(12) + 0.1 * rng.standard_normal((12, 12))
    b, c = rng.standard_normal((12, 2)), rng.standard_normal((3, 12))
    model = mj.LTIModel(a, b, c, e)
    standard = (np.linalg.solve(e, a), np.linalg.solve(e, b), c)
    gramian = sl.solve_continuous_lyapunov(standard[0], -standard[1] @ standard[1].T)
    assert float(model.h2_norm()) == pytest.approx(np.sqrt(np.trace(c @ gramian @ c.T)),
                                                   rel=1e-11)
    io = io_chain()
    reduced = mj.reduce(io, mj.H2Optimal(6))
    truth = h2_error_dense(dense_first_order(io), reduced.standard())
    assert float((io - reduced).h2_norm()) == pytest.approx(truth, rel=1e-8)
    assert float((reduced - io).h2_norm()) == pytest.approx(truth, rel=1e-8)
    other = mj.reduce(io, mj.H2Optimal(4))
    truth = h2_error_dense(reduced.standard(), other.standard())
    assert float((reduced - other).h2_norm()) == pytest.approx(truth, rel=1e-9)


def test_a_second_order_dense_model_has_the_second_order_transfer_function():
    rng = np.random.default_rng(0)
    m = np.eye(4) + 0.1 * rng.standard_normal((4, 4))
    d, k = rng.standard_normal((4, 4)), rng.standard_normal((4, 4))
    b, cx, cv = rng.standard_normal((4, 2)), rng.standard_normal((3, 4)), rng.standard_normal(
        (3, 4))
    model = mj.LTIModel.second_order(m, d, k, b, cx=cx, cv=cv)
    s = np.array([0.3 + 2j, 1.7j, 4.0])
    g = np.asarray(model.transfer(s))
    for i, z in enumerate(s):  # numpy's complex solve: ~1e-14 relative
        expected = (cx + z * cv) @ np.linalg.solve(z * z * m + z * d + k, b)
        assert np.max(np.abs(g[i] - expected)) < 1e-12 * np.max(np.abs(expected))


@pytest.mark.parametrize("rank", [3, 6, 10])
def test_h2_optimal_settles_and_interpolates_at_its_mirrored_poles(rank):
    io = io_chain()
    reduced = mj.reduce(io, mj.H2Optimal(rank))
    assert reduced.order == 2 * rank and reduced.is_stable()
    assert reduced.stats.converged and reduced.stats.changes[-1] < 1e-8
    # Meier-Luenberger at each mirrored pole: G(-lambda) = G_r(-lambda), G'(-lambda) = G_r'(..),
    # with G from a dense complex solve of the full chain
    a, b, c = dense_first_order(io)
    ar, br, cr = reduced.standard()
    lam = np.linalg.eigvals(ar)
    for sigma in -lam[lam.imag >= 0]:
        def g(x, bb, cc, z=sigma):
            resolvent = np.linalg.solve(z * np.eye(x.shape[0]) - x, bb)
            return (cc @ resolvent)[0, 0], -(cc @ np.linalg.solve(z * np.eye(x.shape[0]) - x,
                                                                  resolvent))[0, 0]
        (value, slope), (value_r, slope_r) = g(a, b, c), g(ar, br, cr)
        assert abs(value - value_r) < 1e-7 * abs(value)
        assert abs(slope - slope_r) < 1e-6 * abs(slope)
    assert reduced.stats.optimality < 1e-6
    # no structural reduction of the same order (r DOFs, 2r states) does better
    error = float((io - reduced).h2_norm())
    for strategy in (mj.Modal(rank), mj.ModalStatic(rank)):
        assert error < float((io - mj.reduce(io, strategy)).h2_norm())


def test_h2_optimal_meets_the_tangential_conditions_of_a_two_by_two_map():
    # MIMO: G(-lambda) b = G_r(-lambda) b, c^T G(-lambda) = c^T G_r(-lambda) and c^T G' b =
    # c^T G_r' b along each pole's residue directions (b, c), G from dense complex solves
    system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(7.3, 0.8)],
                             internal_damping=mj.Rayleigh(0.0, 1e-4))
    inputs = np.stack([mj.unit_vector(N, 3), mj.unit_vector(N, 30)], axis=1)
    io = mj.IOModel(system, inputs, cx=np.stack([mj.unit_vector(N, 20), mj.unit_vector(N, 10)]))
    reduced = mj.reduce(io, mj.H2Optimal(6))
    assert reduced.stats.converged and reduced.stats.optimality < 1e-6
    a, b, c = dense_first_order(io)
    ar, br, cr = reduced.standard()
    lam, vectors = np.linalg.eig(ar)
    rights, lefts = np.linalg.solve(vectors, br), cr @ vectors
    for j in np.flatnonzero(lam.imag >= 0):
        sigma, right, left = -lam[j], rights[j], lefts[:, j]

        def g(x, bb, cc, z=sigma):
            resolvent = np.linalg.solve(z * np.eye(x.shape[0]) - x, bb)
            return cc @ resolvent, -(cc @ np.linalg.solve(z * np.eye(x.shape[0]) - x, resolvent))

        (value, slope), (value_r, slope_r) = g(a, b, c), g(ar, br, cr)
        scale = np.linalg.norm(value) * np.linalg.norm(right) * np.linalg.norm(left)
        assert np.linalg.norm((value - value_r) @ right) < 1e-6 * scale
        assert np.linalg.norm(left @ (value - value_r)) < 1e-6 * scale
        assert abs(left @ (slope - slope_r) @ right) < 1e-6 * (
            np.linalg.norm(slope) * np.linalg.norm(right) * np.linalg.norm(left))


def test_the_optimal_errors_gradient_is_the_error_with_the_reduced_model_held():
    # at a stationary point the derivative of min_r ||G(c) - G_r|| is its partial derivative
    # with G_r fixed (the envelope theorem): jax.grad through the full model only, against
    # central differences of the whole reduction
    def optimum(c):
        io = io_chain(c)
        return io, mj.reduce(io, mj.H2Optimal(5, tolerance=1e-12))

    c0, h = 0.8, 1e-4
    _, reduced = optimum(c0)
    gradient = jax.grad(lambda c: (io_chain(c) - reduced).h2_norm())(c0)
    values = [float((io - red).h2_norm()) for io, red in (optimum(c0 + h), optimum(c0 - h))]
    assert float(gradient) == pytest.approx((values[0] - values[1]) / (2 * h), rel=1e-6)


def test_the_full_h2_norms_gradient_in_position_and_coefficient_matches_central_differences():
    # the exact spectral H2 norm, differentiated through the damped modes (h = 1e-5 of the
    # value: truncation ~1e-10 relative)
    def norm(position, c):
        return io_chain(c, position).h2_norm()

    grads = jax.grad(norm, argnums=(0, 1))(7.3, 0.8)
    h = 1e-5
    for i, (x, step) in enumerate(((7.3, h * 7.3), (0.8, h * 0.8))):
        args = [7.3, 0.8]
        up, down = list(args), list(args)
        up[i], down[i] = x + step, x - step
        central = (float(norm(*up)) - float(norm(*down))) / (2 * step)
        assert float(grads[i]) == pytest.approx(central, rel=1e-6)


def test_reductions_of_an_io_map_refuse_what_they_cannot_do():
    io = io_chain()
    with pytest.raises(ValueError, match="rank = 41 is out of reach"):
        mj.reduce(io, mj.H2Optimal(41))
    with pytest.raises(ValueError, match="rank must be an integer >= 1"):
        mj.H2Optimal(0)
    with pytest.raises(ValueError, match=r"tolerance must be in \(0, 1\)"):
        mj.H2Optimal(3, tolerance=2.0)
    with pytest.raises(ValueError, match="pass the IOModel of a full system"):
        mj.reduce(io.model, mj.H2Optimal(3))
    with pytest.raises(ValueError, match="shifts must be finite with Re > 0"):
        mj.reduce(io, mj.H2Optimal(3, shifts=(-1.0 + 2j, 1 + 1j, 1 + 3j)))
    unstable = mj.LTIModel([[0.1, 0.0], [0.0, -1.0]], [1.0, 1.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="pole at 0.1.*Re >= 0"):
        unstable.h2_norm()
    with pytest.raises(ValueError, match=r"b must have shape \(2, \?\)"):
        mj.LTIModel(np.eye(2), np.ones((3, 1)), np.ones((1, 2)))
    with pytest.raises(ValueError, match="same \\(outputs, inputs\\)"):
        io - mj.LTIModel(-np.eye(2), np.ones((2, 2)), np.ones((1, 2)))
