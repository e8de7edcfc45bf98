"""Gradients at the edges: coefficient -> 0, positions at 1, n and integers, long horizons.

The response is the exact integrated energy (no tolerance), so finite differences are clean; the
one-sided behaviour at integer positions (the linear split has a kink there) is the documented
convention of ``GroundedDamper``: JAX returns the right-sided derivative, the left-sided one at n.
"""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj

N = 8
X0 = np.eye(N)[2]  # x_3(0) = 1, as in Section 5


def energy(position, coefficient, horizon=20.0, solver="exact"):
    system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(position, coefficient)])
    if solver == "exact":
        return mj.Energy(horizon, X0)(system)
    solver = diffrax.Dopri8() if solver == "dopri8" else mj.StructuredKvaerno5()
    out = mj.solve(system, jnp.array([0.0, horizon]), X0, dofs=[3], velocity=True,
                   method=mj.ODE(solver, rtol=1e-12, atol=1e-14, max_steps=200_000))
    return out.displacement[-1, 0]


def one_sided(f, x, h):
    """Second-order one-sided difference (h > 0: right, h < 0: left)."""
    return (-3 * f(x) + 4 * f(x + h) - f(x + 2 * h)) / (2 * h)


def central(f, x, h):
    return (f(x + h) - f(x - h)) / (2 * h)


@pytest.mark.slow
@pytest.mark.parametrize("coefficient", [pytest.param(0.0, marks=pytest.mark.slow), 1e-8, 1e-4])
def test_the_coefficient_gradient_is_finite_and_right_as_the_damper_vanishes(coefficient, close):
    grad_p, grad_c = jax.grad(energy, argnums=(0, 1))(4.5, coefficient)
    assert np.isfinite(grad_p) and np.isfinite(grad_c)
    reference = one_sided(lambda c: energy(4.5, c), coefficient, 1e-5)
    close(grad_c, reference, rtol=1e-6)
    assert grad_c < 0  # any damping lowers the energy integral of a free vibration
    # the position derivative scales with the coefficient: exactly zero without a damper
    if coefficient == 0.0:
        assert grad_p == 0.0
    else:
        noise = 1e-11 * float(energy(4.5, coefficient)) / 1e-4  # the exact energy's ~1e-11
        close(grad_p, central(lambda p: energy(p, coefficient), 4.5, 1e-4), rtol=1e-5,
              atol=noise)


@pytest.mark.slow
@pytest.mark.parametrize("position, side", [(1.0, 1), (float(N), -1)])
def test_position_gradients_at_the_chain_ends_are_the_inward_one_sided_derivatives(
        position, side, close):
    grad = jax.grad(energy)(position, 0.8)
    assert np.isfinite(grad)
    close(grad, one_sided(lambda p: energy(p, 0.8), position, side * 1e-4), rtol=1e-6)


def test_the_kink_at_an_integer_position_gives_the_right_sided_derivative(close):
    right = one_sided(lambda p: energy(p, 0.8), 5.0, 1e-5)
    left = one_sided(lambda p: energy(p, 0.8), 5.0, -1e-5)
    grad = jax.grad(energy)(5.0, 0.8)
    close(grad, right, rtol=1e-6)
    assert abs(right - left) > 1e-3 * abs(right)  # a genuine kink, not a rounding effect


def test_gradients_through_a_long_horizon_stay_finite_and_match_differences(close):
    # T = 1000 / Omega with a weak damper: the energy barely decays, the integral is large
    grad_p, grad_c = jax.grad(lambda p, c: energy(p, c, horizon=1000.0), argnums=(0, 1))(3.5, 1e-3)
    close(grad_c, central(lambda c: energy(3.5, c, horizon=1000.0), 1e-3, 1e-6), rtol=1e-5)
    close(grad_p, central(lambda p: energy(p, 1e-3, horizon=1000.0), 3.5, 1e-4), rtol=1e-5)


@pytest.mark.slow  # ~35 s for both solvers; the exact-energy versions above run by default
@pytest.mark.parametrize("solver", ["dopri8", "kvaerno5"])
def test_gradients_of_a_response_after_many_periods_match_central_differences(solver, close):
    response = lambda c: energy(3.5, c, horizon=200.0, solver=solver)
    grad = jax.grad(response)(0.05)
    assert np.isfinite(grad)
    close(grad, central(response, 0.05, 1e-5), rtol=1e-4)
