"""Damper objectives against independent truths: quadrature of the physical matrix exponential,
scipy's Lyapunov solver, energy conservation, central differences."""

import jax
import numpy as np
import pytest
import scipy.integrate as si
import scipy.linalg as sl
from _helpers import mp_eigen_energy

import mikota_jax as mj
from mikota_jax._objective.functions import smooth_peak

N, T = 8, 5.0
X0 = np.zeros(N)
X0[2] = 1.0
V0 = np.linspace(0.0, 1.0, N)


def damped(position=3.4, coefficient=0.7):
    return mj.mikota_chain(N, dampers=[mj.GroundedDamper(position, coefficient)])


def test_integrated_energy_equals_the_quadrature_of_the_physical_exponential(close):
    system = damped()
    m, d, k = (np.asarray(a) for a in system.dense())
    a = np.block([[np.zeros((N, N)), np.eye(N)],
                  [-np.linalg.solve(m, k), -np.linalg.solve(m, d)]])
    y0 = np.concatenate([X0, V0])

    def energy(t):
        y = sl.expm(a * t) @ y0
        return 0.5 * (y[:N] @ k @ y[:N] + y[N:] @ m @ y[N:])

    reference, _ = si.quad(energy, 0.0, T, epsabs=1e-13, epsrel=1e-13, limit=200)
    close(mj.Energy(T, X0, V0)(system), reference, rtol=1e-10)


@pytest.mark.parametrize("coefficient", [1e5, 1e7])
def test_a_very_strong_damper_keeps_the_exact_energy_exact(coefficient, close):
    # rate c / m_N up to 8e7: Van Loan's first step must shrink with it (at T / 2^16 it gave
    # 1e22 for the paper's chain). Truth: mpmath's eigen-expansion of the physical first-order
    # system at 60 digits (right to far below float64 rounding; a float64 eig of this matrix was
    # itself 3.6e-8 off at c = 1e7)
    system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(float(N), coefficient)])
    reference = mp_eigen_energy(system, T, X0, V0)
    close(mj.Energy(T, X0, V0)(system), reference, rtol=1e-13)


def test_an_undamped_chain_integrates_its_constant_energy(close):
    system = mj.mikota_chain(N)
    m, _, k = (np.asarray(a) for a in system.dense())
    e0 = 0.5 * (X0 @ k @ X0 + V0 @ m @ V0)
    close(mj.Energy(T, X0, V0)(system), e0 * T, rtol=1e-11)


@pytest.mark.parametrize("lowest", [None, pytest.param(3, marks=pytest.mark.slow)])
def test_total_average_energy_equals_scipys_lyapunov_solution(lowest, close):
    system = damped()
    m, d, k = (np.asarray(a) for a in system.dense())
    omega2, modes = sl.eigh(k, m)
    omega = np.sqrt(omega2)
    a = np.block([[np.zeros((N, N)), np.diag(omega)], [-np.diag(omega), -modes.T @ d @ modes]])
    select = np.ones(N) if lowest is None else (np.arange(N) < lowest).astype(float)
    x = sl.solve_continuous_lyapunov(a.T, -np.diag(np.concatenate([select, select])))
    close(mj.AverageEnergy(lowest=lowest)(system), np.trace(x), rtol=1e-10)


def test_objectives_of_a_full_rank_reduced_model_equal_the_full_model(close):
    system = damped()
    basis, _ = np.linalg.qr(np.random.default_rng(1).standard_normal((N, N)))
    reduced = mj.reduce(system, mj.Projection(basis))
    close(mj.Energy(T, X0, V0)(reduced), mj.Energy(T, X0, V0)(system),
          rtol=1e-10)
    close(mj.AverageEnergy()(reduced), mj.AverageEnergy()(system), rtol=1e-9)


@pytest.mark.slow  # 37 s; the spectral energy and trace gradients are checked in test_spectral
def test_gradients_in_damper_position_and_coefficient_match_central_differences(close):
    def energy(p, c):
        return mj.Energy(T, X0, V0)(damped(p, c))

    def average(p, c):
        return mj.AverageEnergy(lowest=4)(damped(p, c))

    h = 1e-4  # the objectives are exact to ~1e-13 relative: smaller steps only add noise
    for objective in (energy, average):
        gradient = np.asarray(jax.grad(objective, argnums=(0, 1))(3.4, 0.7))
        central = [(objective(3.4 + h, 0.7) - objective(3.4 - h, 0.7)) / (2 * h),
                   (objective(3.4, 0.7 + h) - objective(3.4, 0.7 - h)) / (2 * h)]
        close(gradient, central, rtol=0.0, atol=1e-6 * np.max(np.abs(gradient)))


def test_an_undamped_chain_has_no_total_average_energy():
    with pytest.raises(ValueError, match="some mode is undamped"):
        mj.AverageEnergy()(mj.mikota_chain(N))


@pytest.mark.parametrize("lowest", [0, N + 1, 2.5, True])
def test_lowest_outside_1_to_n_is_refused(lowest):
    with pytest.raises(ValueError, match=f"lowest must be None or an integer in 1..{N}"):
        mj.AverageEnergy(lowest=lowest)(damped())


@pytest.mark.parametrize("horizon", [0.0, -1.0, np.inf, np.nan])
def test_a_horizon_not_finite_and_positive_is_refused_saying_both(horizon):
    with pytest.raises(ValueError, match=r"^mikota_jax: horizon must be finite and > 0\.$"):
        mj.Energy(horizon, X0)(damped())


@pytest.mark.parametrize("order", [2, 16, 64])
def test_smooth_peak_lies_between_the_bounds_of_the_maximum(order):
    values = np.sin(np.linspace(0.0, 7.0, 301)) * np.exp(-0.1 * np.linspace(0.0, 7.0, 301))
    peak = float(smooth_peak(values, order))
    top = np.max(np.abs(values))
    assert top * values.size ** (-1.0 / order) <= peak <= top


@pytest.mark.slow  # 29 s in CI
def test_smooth_peak_of_a_simulated_response_has_the_central_difference_gradient(close):
    ts = np.linspace(0.0, T, 201)

    def peak(c):
        out = mj.solve(damped(3.4, c), ts, X0, V0, dofs=[N], method=mj.Spectral())
        return smooth_peak(out.displacement, 16)

    h = 1e-5
    close(jax.grad(peak)(0.7), (peak(0.7 + h) - peak(0.7 - h)) / (2 * h), rtol=1e-6)


@pytest.mark.parametrize("order", [0, 3, 2.0, True])
def test_smooth_peak_order_must_be_an_even_integer(order):
    with pytest.raises(ValueError, match="order must be an even integer"):
        smooth_peak(np.ones(3), order)
