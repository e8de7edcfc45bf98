"""Differentiable dense H2 norms and feedback loops (``LTIModel.h2_norm``, ``feedback``),
structure-preserving interpolation at the H2-optimal shifts (``StructuredH2``), and coefficient
searches through its Galerkin model (``Coefficients(through=...)``).

Truths: the closed form ||1 / (m s^2 + c s + k)||_H2^2 = 1 / (2 c k m) (exact) and its
derivative; central differences of scipy's Lyapunov solves (h = 1e-6: truncation and rounding
~1e-8 relative); numpy's dense complex solves of the full chain for the interpolation conditions
(~1e-13 relative to G); the full-order coefficient search's optimum (stationary to 1e-10 in
|c dJ/dc| / J, so its c holds ~1e-9 of its digits: J is quadratic in log c there)."""

import jax
import numpy as np
import pytest
import scipy.linalg as sl

import mikota_jax as mj

N = 40


def chain(c=2.0, position=30.0, n=N):
    return mj.mikota_chain(n, dampers=[mj.GroundedDamper(position, c)])


def oscillator(c0=0.5, k=4.0):
    """m = 1, c0, k with two channels: a force and the displacement (0), a force and the
    velocity at the same mass (1): closing loop 1 with gain g adds a damper g."""
    return mj.LTIModel.second_order([[1.0]], [[c0]], [[k]], [[1.0, 1.0]], cx=[[1.0], [0.0]],
                                    cv=[[0.0], [1.0]])


@pytest.mark.parametrize("gain", [0.0, 0.3, -0.2, 7.0])
def test_a_closed_loop_damper_has_the_oscillators_h2_norm_and_derivative(gain):
    k, c0 = 4.0, 0.5
    c = c0 + gain
    model = oscillator(c0, k)
    norm = lambda g: model.feedback(g, 1, 1).h2_norm()  # noqa: E731
    value, slope = jax.value_and_grad(norm)(gain)
    assert float(value) == pytest.approx((2 * c * k) ** -0.5, rel=1e-13)
    assert float(slope) == pytest.approx(-k * (2 * c * k) ** -1.5, rel=1e-12)
    jitted = jax.jit(jax.value_and_grad(norm))(gain)
    assert float(jitted[1]) == pytest.approx(float(slope), rel=1e-14)


def test_the_h2_norms_gradient_in_every_matrix_matches_central_differences():
    rng = np.random.default_rng(5)
    a = rng.standard_normal((8, 8))
    a = a - (np.max(np.linalg.eigvals(a).real) + 0.3) * np.eye(8)
    b, c = rng.standard_normal((8, 2)), rng.standard_normal((3, 8))

    def dense(a, b, c):  # scipy's Bartels-Stewart: ~1e-14 relative
        gramian = sl.solve_continuous_lyapunov(a, -b @ b.T)
        return np.sqrt(np.trace(c @ gramian @ c.T))

    model = mj.LTIModel(a, b, c)
    grads = jax.grad(lambda m: m.h2_norm())(model)
    h = 1e-6
    for name, matrix in (("a", a), ("b", b), ("c", c)):
        direction = rng.standard_normal(matrix.shape)
        args = {"a": a, "b": b, "c": c}
        up = dense(**{**args, name: matrix + h * direction})
        down = dense(**{**args, name: matrix - h * direction})
        central = (up - down) / (2 * h)
        assert float(np.sum(np.asarray(getattr(grads, name)) * direction)) == pytest.approx(
            central, rel=1e-7)


def test_feedback_refuses_what_it_cannot_close():
    model = oscillator()
    with pytest.raises(ValueError, match=r"inputs must be distinct indices in \[0, 1\]"):
        model.feedback(1.0, 2, 1)
    with pytest.raises(ValueError, match="the loop uses every input"):
        model.feedback(1.0, [0, 1], 1)
    with pytest.raises(ValueError, match=r"gain must be a scalar or \(1, 1\)"):
        model.feedback(np.ones(3), 1, 1)
    # a negative damper beyond the oscillator's own: a pole in Re s > 0, refused eagerly and
    # under jit
    with pytest.raises(ValueError, match="pole at 0.05.*Re >= 0"):
        model.feedback(-0.6, 1, 1).h2_norm()
    with pytest.raises(Exception, match="pole in Re s >= 0"):
        jax.jit(lambda g: model.feedback(g, 1, 1).h2_norm())(-0.6)


@pytest.mark.parametrize("velocity", [False, True])
def test_structured_h2_interpolates_bitangentially_at_the_shifts_and_keeps_the_structure(
        velocity):
    system = chain(0.8, 7.3)
    out = mj.unit_vector(N, N // 2)
    io = mj.IOModel(system, mj.unit_vector(N, 3), **({"cv": out} if velocity else {"cx": out}))
    reduced = mj.reduce(io, mj.StructuredH2(4))
    stats = reduced.model.stats
    assert stats.converged and stats.strategy == "StructuredH2"
    assert 8 <= stats.rank <= 16 and stats.optimality < 1e-8
    m, d, k = (np.asarray(x) for x in reduced.model.system.dense())
    for x in (m, d, k):  # symmetric, and D >= 0: no pole in Re s > 0 for any coefficient
        assert np.max(np.abs(x - x.T)) < 1e-12 * np.max(np.abs(x))
    assert np.min(np.linalg.eigvalsh(d)) > -1e-12 * np.max(np.abs(d))
    full_m, full_d, full_k = (np.asarray(x) for x in system.dense())
    b, cx, cv = (np.asarray(x) for x in (io.inputs, io.cx, io.cv))
    for sigma in np.asarray(stats.shifts):
        def g(z):  # numpy's dense complex solve of the full chain
            return ((cx + z * cv) @ np.linalg.solve(z * z * full_m + z * full_d + full_k, b))[
                0, 0]
        assert abs(complex(reduced.transfer(sigma)[0, 0, 0]) - g(sigma)) < 1e-9 * abs(g(sigma))
        # Hermite: the slopes agree (central differences, h = 1e-5 |sigma|: each side's
        # truncation ~1e-10 relative, and G - G_r = O(h^2) around sigma)
        h = 1e-5 * abs(sigma)
        slope = (g(sigma + h) - g(sigma - h)) / (2 * h)
        slope_r = (complex(reduced.transfer(sigma + h)[0, 0, 0])
                   - complex(reduced.transfer(sigma - h)[0, 0, 0])) / (2 * h)
        assert abs(slope - slope_r) < 1e-6 * abs(slope)
    # the dampers stay dampers: the Galerkin model of another coefficient on the same basis
    # is that design's reduced model
    other = mj.reduce(chain(3.0, 7.3), mj.Projection(reduced.model.basis))
    assert np.all(np.asarray(mj.IOModel(other, io.inputs, *io.outputs()).poles()).real < 0)


def test_a_coefficient_search_through_structured_h2_reaches_the_full_optimum_certified():
    system = chain(2.0, 30.0)
    objective = mj.H2Norm(mj.unit_vector(N, 3), cx=mj.unit_vector(N, N // 2))
    design = mj.DamperDesign(system, objective)
    full = mj.optimise(design, mj.Coefficients(tolerance=1e-10))
    assert full.result == mj.DesignResult.converged
    through = mj.optimise(design, mj.Coefficients(through=mj.StructuredH2(4)))
    assert through.result == mj.DesignResult.converged
    assert through.stats["relative_gradient"] < 1e-6  # the full model's, at the answer
    assert through.stats["rank"] <= 16 and through.stats["reduced_evaluations"] >= 2
    assert through.coefficients[0] == pytest.approx(full.coefficients[0], rel=1e-5)
    assert through.value == pytest.approx(full.value, rel=1e-11)
    assert through.stats["reduced_value"] == pytest.approx(
        through.history[0][0], rel=10 * through.stats["rom_error"] + 1e-15)


def test_a_search_through_a_reduced_model_refuses_what_it_cannot_do():
    system = chain()
    h2 = mj.H2Norm(mj.unit_vector(N, 3), cx=mj.unit_vector(N, N // 2))
    with pytest.raises(ValueError, match="H2Optimal gives a dense model"):
        mj.optimise(mj.DamperDesign(system, h2), mj.Coefficients(through=mj.H2Optimal(3)))
    energy = mj.Energy(10.0, x0=mj.unit_vector(N, 3))
    with pytest.raises(ValueError, match="takes an H2Norm or OutputEnergy objective"):
        mj.optimise(mj.DamperDesign(system, energy), mj.Coefficients(through=mj.Modal(10)))
    with pytest.raises(ValueError, match="through must be None or a Galerkin reduction"):
        mj.Coefficients(through="modal")


def test_irka_that_does_not_settle_warns_and_says_so_in_its_stats():
    io = mj.IOModel(chain(0.8, 7.3), mj.unit_vector(N, 3), cx=mj.unit_vector(N, N // 2))
    for strategy in (mj.H2Optimal(4, iterations=1), mj.StructuredH2(4, iterations=1)):
        with pytest.warns(UserWarning, match="the shifts did not settle to 1e-08 in 1 sweeps"):
            reduced = mj.reduce(io, strategy)
        stats = reduced.stats if isinstance(reduced, mj.LTIModel) else reduced.model.stats
        assert not stats.converged and stats.iterations == 1
