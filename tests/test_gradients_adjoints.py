"""Gradients of a damper objective through a reduced model (basis held fixed), by forward and
reverse mode, against central differences; at an integer position (a kink of the linear damper
split) the derivative is the right-sided one. A small version of ``benchmarks/gradients.py``."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj
from mikota_jax._rom.pod import pod

N, RANK, SNAPSHOT_END = 30, 10, 2.5
TS = jnp.linspace(0.0, 5.0, 201)
RTOL, ATOL = 1e-12, 1e-14
X0 = mj.unit_vector(N, 3)


@pytest.fixture(scope="module")
def basis():
    """POD of exact snapshots on [0, 2.5], damper d = 1 at DOF 7; held fixed, not differentiated."""
    system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(7.0, 1.0)])
    snapshots = mj.solve(system, TS, X0, method=mj.Spectral()).displacement[TS <= SNAPSHOT_END].T
    return jax.lax.stop_gradient(pod(snapshots).basis(RANK))


def objective(basis, adjoint=None):
    """J(p, c): trapezoid of the total energy (x^T K x + v^T M v) / 2 of the ROM over TS."""

    def energy(position, coefficient):
        system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(position, coefficient)])
        reduced = mj.reduce(system, mj.Projection(basis)).system
        out = mj.solve(reduced, TS, basis.T @ X0, displacement=True, velocity=True,
                       method=mj.ODE(rtol=RTOL, atol=ATOL, adjoint=adjoint))
        q, qd = out.displacement, out.velocity
        k, m = reduced.stiffness.as_matrix(), reduced.mass.as_matrix()
        return jnp.trapezoid(0.5 * (jnp.sum((q @ k) * q, axis=1) + jnp.sum((qd @ m) * qd, axis=1)),
                             TS)

    return energy


MODES = {
    "forward": lambda b: jax.jacfwd(objective(b, diffrax.ForwardMode()), argnums=(0, 1)),
    "reverse": lambda b: jax.grad(objective(b, diffrax.RecursiveCheckpointAdjoint()),
                                  argnums=(0, 1)),
}


@pytest.fixture(scope="module")
def value(basis):
    return jax.jit(objective(basis))

# forward mode under -m slow: tests/test_solvers.py checks every adjoint against differences
MODE_PARAMS = [pytest.param("forward", marks=pytest.mark.slow), "reverse"]


@pytest.fixture(scope="module")
def gradients(basis):
    return {name: jax.jit(make(basis)) for name, make in MODES.items()}


@pytest.mark.parametrize("mode", MODE_PARAMS)
def test_rom_gradient_matches_central_differences_at_a_fractional_position(
        mode, value, gradients, close):
    p, c, h = 7.3, 1.0, 1e-4
    grad_p, grad_c = gradients[mode](p, c)
    central_p = (value(p + h, c) - value(p - h, c)) / (2 * h)
    central_c = (value(p, c + h) - value(p, c - h)) / (2 * h)
    close(grad_p, central_p, rtol=1e-6)
    close(grad_c, central_c, rtol=1e-6)
    assert abs(float(grad_p)) > 1e-2 and abs(float(grad_c)) > 1e-2  # not trivially zero


@pytest.mark.parametrize("mode", MODE_PARAMS)
def test_rom_gradient_at_an_integer_position_is_the_right_sided_derivative(
        mode, value, gradients, close):
    p, c, h = 7.0, 1.0, 1e-4
    grad_p = float(gradients[mode](p, c)[0])
    f0 = value(p, c)
    # second-order one-sided differences: J is smooth on [7, 8] and on [6, 7], with a kink at 7
    right = (-3 * f0 + 4 * value(p + h, c) - value(p + 2 * h, c)) / (2 * h)
    left = (3 * f0 - 4 * value(p - h, c) + value(p - 2 * h, c)) / (2 * h)
    close(grad_p, right, rtol=1e-6)
    assert abs(grad_p - float(left)) > 1e-3 * abs(grad_p)  # a real kink: the sides differ
    assert np.isfinite(grad_p)
