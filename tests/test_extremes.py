"""Stiff and extreme cases: each answer is right (against an independent truth) or fails loudly.

Damping extremes: d = 0 over long horizons, damper coefficients from 1e-8 to 1e6 (a strong damper at
DOF j adds a real eigenvalue near -c / m_j: stiff), several dampers, dampers at DOF 1 and DOF n,
relative dampers. Parameter extremes: k/m from 1e-6 to 1e6 (a free vibration obeys
x(t; k, m) = x(t sqrt(k/m); 1, 1)), masses over twelve orders of magnitude, horizons of 1e4 / Omega,
pulses of duration 1e-6 and the Dirac limit of a pulse.

Truths: scipy's ``expm`` of the first-order state matrix, the eigen-expansion of that matrix, the
closed forms of Mikota's chain (frequencies l Omega, polynomial mode shapes), closed forms of the
pulse response written without cancellation, eigenvalues by Sturm bisection in 50-digit decimal
arithmetic and the SVD of the chain's bidiagonal factor (relative accuracy). A test marked
``xfail(strict=True)`` asserts the correct behaviour where the toolkit is currently silently wrong.
"""

from decimal import Decimal, localcontext

import diffrax
import numpy as np
import pytest
import scipy.linalg as sl

import mikota_jax as mj

N = 10
M_, K_ = 1.3, 0.9  # m and k of the chain, not 1, so that Omega = sqrt(k/m) is not 1
OMEGA = np.sqrt(K_ / M_)
TS = np.linspace(0.0, 20.0, 201)
RNG = np.random.default_rng(7)
X0, V0 = RNG.standard_normal(N), RNG.standard_normal(N)
MASS = M_ / np.arange(1, N + 1)  # m_i = m / i (eq. 2.3)

ODE_SOLVERS = {"dopri8": diffrax.Dopri8(), "kvaerno5": mj.StructuredKvaerno5()}


# --- references (numpy / scipy / decimal only) ---------------------------------------------------


def dense(system):
    M, D, K = (None if a is None else np.asarray(a) for a in system.dense())
    return M, np.zeros_like(M) if D is None else D, K


def state_matrix(system):
    """A = [[0, I], [-M^-1 K, -M^-1 D]] of the physical state (x, v)."""
    M, D, K = dense(system)
    n = M.shape[0]
    inverse = np.linalg.inv(M)
    return np.block([[np.zeros((n, n)), np.eye(n)], [-inverse @ K, -inverse @ D]])


def expm_reference(system, ts, x0, v0):
    """(x, v) on ts by scipy's expm(A t) of the physical state matrix, one per time."""
    a, n = state_matrix(system), x0.shape[0]
    y = np.stack([sl.expm(a * (t - ts[0])) @ np.concatenate([x0, v0]) for t in ts])
    return y[:, :n], y[:, n:]


def energy(system, x, v):
    M, _, K = dense(system)
    return 0.5 * (np.einsum("ti,ij,tj->t", x, K, x) + np.einsum("ti,ij,tj->t", v, M, v))


def energy_integral_reference(system, horizon, x0, v0):
    """int_0^T (x^T K x + v^T M v) / 2 dt from the eigen-expansion y(t) = V exp(L t) V^-1 y0."""
    M, _, K = dense(system)
    n = M.shape[0]
    lam, vectors = np.linalg.eig(state_matrix(system))
    w = vectors * np.linalg.solve(vectors, np.concatenate([x0, v0]))[None, :]
    q = 0.5 * np.block([[K, np.zeros((n, n))], [np.zeros((n, n)), M]])
    s = lam[:, None] + lam[None, :]
    safe = np.where(np.abs(s * horizon) < 1e-12, 1.0, s)
    factor = np.where(np.abs(s * horizon) < 1e-12, horizon, np.expm1(s * horizon) / safe)
    return float(np.real(np.sum((w.T @ q @ w) * factor)))


def mikota_free_vibration(n, m, k, ts, x0, v0):
    """(x, v) of Mikota's undamped chain from its closed forms, omega_l = l sqrt(k/m) (eq. 2.4) and
    the polynomial mode shapes u_l (eq. 2.5): x = sum_l u_l (a_l cos w_l t + b_l sin w_l t / w_l).
    """
    modes = np.stack([np.asarray(mj.analytic.mode_shape(n, l)) for l in range(1, n + 1)], axis=1)
    mass = m / np.arange(1, n + 1)
    weight = np.einsum("il,i,il->l", modes, mass, modes)
    a, b = (modes.T @ (mass * x0)) / weight, (modes.T @ (mass * v0)) / weight
    w = np.arange(1, n + 1) * np.sqrt(k / m)
    phase = np.outer(ts, w)
    x = (np.cos(phase) * a + np.sin(phase) * b / w) @ modes.T
    v = (-np.sin(phase) * a * w + np.cos(phase) * b) @ modes.T
    return x, v


def bidiagonal_modes(masses, springs):
    """(omega ascending, M-orthonormal modes) from the SVD of B = diag(sqrt k) L M^-1/2.

    K = L^T diag(k) L with L the lower bidiagonal difference (x_i - x_{i-1}, x_0 = 0), so
    B^T B = M^-1/2 K M^-1/2; the singular values of a bidiagonal matrix come with high relative
    accuracy (LAPACK's bidiagonal QR), whatever the grading of the masses.
    """
    n = masses.shape[0]
    factor = np.eye(n) - np.eye(n, k=-1)
    b = np.sqrt(springs)[:, None] * factor / np.sqrt(masses)[None, :]
    _, sigma, vt = np.linalg.svd(b)
    return sigma[::-1], (vt.T / np.sqrt(masses)[:, None])[:, ::-1]


def bisection_eigenvalues(masses, springs, digits=50):
    """omega^2 of K u = omega^2 M u of a chain: Sturm counts of K - lam M in ``digits`` digits."""
    with localcontext() as ctx:
        ctx.prec = digits
        m = [Decimal(float(x)) for x in masses]
        k = [Decimal(float(x)) for x in springs] + [Decimal(0)]
        n = len(m)

        def below(lam):  # number of eigenvalues below lam: negative pivots of LDL^T(K - lam M)
            count, pivot = 0, None
            for i in range(n):
                d = k[i] + k[i + 1] - lam * m[i]
                pivot = d if i == 0 else d - k[i] ** 2 / pivot
                pivot = pivot if pivot != 0 else Decimal("1e-90")
                count += pivot < 0
            return count

        top = max((k[i] + k[i + 1] + k[i] + k[i + 1]) / m[i] for i in range(n))  # Gershgorin
        values = []
        for j in range(n):
            lo, hi = Decimal(0), top
            for _ in range(240):
                mid = (lo + hi) / 2
                lo, hi = (lo, mid) if below(mid) > j else (mid, hi)
            values.append(float((lo + hi) / 2))
    return np.array(values)


def modal_free_vibration(masses, springs, ts, x0, v0):
    omega, modes = bidiagonal_modes(masses, springs)
    a, b = modes.T @ (masses * x0), modes.T @ (masses * v0)
    phase = np.outer(ts, omega)
    return (np.cos(phase) * a + np.sin(phase) * b / omega) @ modes.T


def pulse_response(system, ts, dof, amplitude, duration, start=0.0):
    """(x, v) of an undamped chain at rest hit by a rectangular pulse, in closed form per mode,
    written without cancellation: cos w(t - tau) - cos w t = 2 sin w(t - tau/2) sin(w tau/2)."""
    M, _, K = dense(system)
    omega2, modes = sl.eigh(K, M)
    w = np.sqrt(omega2)
    g = amplitude * modes[dof - 1]  # modal load U^T (amplitude e_dof)
    t = (np.asarray(ts) - start)[:, None]
    during, after = (t >= 0) & (t <= duration), t > duration
    half = np.sin(w * duration / 2)
    eta = (np.where(during, 2 * np.sin(w * t / 2) ** 2, 0.0)
           + np.where(after, 2 * np.sin(w * (t - duration / 2)) * half, 0.0)) * g / omega2
    eta_dot = (np.where(during, np.sin(w * t), 0.0)
               + np.where(after, 2 * np.cos(w * (t - duration / 2)) * half, 0.0)) * g / w
    return eta @ modes.T, eta_dot @ modes.T


def relative_error(actual, expected):
    return np.max(np.abs(np.asarray(actual) - expected)) / np.max(np.abs(expected))


# --- damping extremes: d = 0 over a long horizon ------------------------------------------------

LONG = np.linspace(0.0, 1000.0, 2001)


@pytest.mark.parametrize("dampers", [(), (mj.GroundedDamper(3, 0.0),)], ids=["none", "zero"])
def test_exact_solve_conserves_the_energy_of_an_undamped_chain_over_a_thousand_time_units(
        dampers, close):
    # damping=None takes the rotation path (DenseExponential), a zero damper the damped modes
    system = mj.mikota_chain(N, M_, K_, dampers=dampers)
    method = mj.Spectral() if dampers else mj.DenseExponential()
    out = mj.solve(system, LONG, X0, V0, velocity=True, method=method)
    e = energy(system, np.asarray(out.displacement), np.asarray(out.velocity))
    close(e, np.full_like(e, e[0]), rtol=1e-12)
    x, v = mikota_free_vibration(N, M_, K_, LONG, X0, V0)
    close(out.displacement, x, atol=1e-10 * np.max(np.abs(x)))
    close(out.velocity, v, atol=1e-10 * np.max(np.abs(v)))


@pytest.mark.parametrize("rtol", [1e-8, 1e-10])
def test_dopri8_energy_drift_over_a_thousand_time_units_stays_within_horizon_times_rtol(rtol):
    system = mj.mikota_chain(N, M_, K_)
    out = mj.solve(system, LONG, X0, V0, velocity=True, method=mj.ODE(rtol=rtol, atol=rtol / 100))
    e = energy(system, np.asarray(out.displacement), np.asarray(out.velocity))
    drift = np.max(np.abs(e / e[0] - 1))  # measured: 2.1e-6 at rtol 1e-8, 2.0e-8 at 1e-10
    assert drift < LONG[-1] * rtol
    x, _ = mikota_free_vibration(N, M_, K_, LONG, X0, V0)
    assert relative_error(out.displacement, x) < LONG[-1] * rtol


def test_integrated_energy_of_an_undamped_chain_is_its_energy_times_the_horizon(close):
    system = mj.mikota_chain(N, M_, K_)
    e0 = energy(system, X0[None], V0[None])[0]
    close(mj.Energy(1000.0, X0, V0)(system), 1000.0 * e0, rtol=1e-11)
    # rtol 1e-9: 8e-8 measured
    ode = mj.Energy(1000.0, X0, V0, method=mj.ODE(rtol=1e-9, atol=1e-11))(system)
    close(ode, 1000.0 * e0, rtol=1e-6)


# --- damping extremes: weak to very strong dampers ------------------------------------------------

COEFFICIENTS = [1e-8, 1e-4, 1.0, 1e2, 1e4, 1e6]


def stiff_tolerance(coefficient, dof):
    """The references themselves agree only to ~ eps * rate (rate c i / m of the damper mode)."""
    return 1e-12 + 2e-15 * coefficient * dof / M_


# c = 1e6 at DOF n is non-finite: see test_exact_solve_with_a_very_fast_damper_mode_is_finite...
GROUNDED = [(c, dof) for dof in (1, 4, N) for c in COEFFICIENTS if (c, dof) != (1e6, N)]


@pytest.mark.parametrize("coefficient, dof", GROUNDED)
def test_exact_solve_matches_the_matrix_exponential_for_damper_coefficients_1e_8_to_1e6(
        coefficient, dof, close):
    system = mj.mikota_chain(N, M_, K_, dampers=[mj.GroundedDamper(dof, coefficient)])
    x, v = expm_reference(system, TS, X0, V0)
    out = mj.solve(system, TS, X0, V0, velocity=True, method=mj.Spectral())
    tol = stiff_tolerance(coefficient, dof)  # measured: <= 5e-13 up to c = 100, 1.1e-9 at 1e6
    close(out.displacement, x, atol=tol * np.max(np.abs(x)))
    close(out.velocity, v, atol=tol * np.max(np.abs(v)))


STRONG = {"grounded c=1e6 at DOF n": (mj.GroundedDamper(N, 1e6),),
          "relative c=1e6 between 3 and 6": (mj.RelativeDamper((3, 6), 1e6),)}


@pytest.mark.parametrize("dampers", STRONG.values(), ids=STRONG.keys())
def test_exact_solve_with_a_very_fast_damper_mode_is_finite_and_right(dampers, close):
    # rate c / m_n = 7.7e6 (or c (1/m_3 + 1/m_6) = 6.9e6) times the grid step 0.1
    system = mj.mikota_chain(N, M_, K_, dampers=dampers)
    x, _ = expm_reference(system, TS, X0, V0)
    out = mj.solve(system, TS, X0, V0, velocity=True, method=mj.Spectral())
    close(out.displacement, x, atol=1e-8 * np.max(np.abs(x)))


def test_exact_solve_on_a_very_coarse_grid_of_a_damped_chain_is_finite_and_right(close):
    system = mj.mikota_chain(N, M_, K_, dampers=[mj.GroundedDamper(1, 1.0)])
    ts = 1e5 * np.arange(float(TS.shape[0]))  # step h = 1e5: ||A h||_1 is about 1e6
    x, _ = expm_reference(system, ts[:3], X0, V0)
    out = mj.solve(system, ts, X0, V0, velocity=True, method=mj.Spectral())
    # both sides square ~20 times (||A h|| ~ 1e6): rounding grows like 2^20 eps, here ~1e-11
    close(out.displacement[:3], x, atol=1e-10 * np.max(np.abs(X0)))


@pytest.mark.parametrize("dof", [1, 4])
def test_kvaerno5_with_a_1e6_damper_agrees_with_exact_solve(dof, close):
    system = mj.mikota_chain(N, M_, K_, dampers=[mj.GroundedDamper(dof, 1e6)])
    exact = mj.solve(system, TS, X0, V0, velocity=True, method=mj.Spectral())
    out = mj.solve(system, TS, X0, V0, velocity=True,
                   method=mj.ODE(mj.StructuredKvaerno5(), rtol=1e-10, atol=1e-12))
    # measured: 4.5e-9 (x) and 2.8e-8 (v) relative, in about 4000 steps
    close(out.displacement, exact.displacement, atol=5e-8 * np.max(np.abs(exact.displacement)))
    close(out.velocity, exact.velocity, atol=1e-7 * np.max(np.abs(exact.velocity)))


def test_dopri8_with_a_1e6_damper_stops_loudly_at_max_steps():
    system = mj.mikota_chain(N, M_, K_, dampers=[mj.GroundedDamper(1, 1e6)])
    with pytest.raises(ValueError, match="max_steps"):
        mj.solve(system, TS, X0, V0, method=mj.ODE(max_steps=2000))


SEVERAL = (mj.GroundedDamper(1, 3.0), mj.GroundedDamper(5.5, 0.7), mj.GroundedDamper(N, 2.0),
           mj.RelativeDamper((2, 7), 1.5), mj.RelativeDamper((N - 1, N), 0.4))


@pytest.mark.parametrize("solver, tol", [pytest.param("exact", 1e-12, marks=pytest.mark.slow),
                                         ("dopri8", 1e-8), ("kvaerno5", 1e-7)])
def test_several_dampers_at_the_first_and_last_dof_match_the_matrix_exponential(solver, tol,
                                                                                 close):
    system = mj.mikota_chain(N, M_, K_, dampers=SEVERAL)
    x, v = expm_reference(system, TS, X0, V0)
    if solver == "exact":
        out = mj.solve(system, TS, X0, V0, velocity=True, method=mj.Spectral())
    else:
        out = mj.solve(system, TS, X0, V0, velocity=True,
                       method=mj.ODE(ODE_SOLVERS[solver], rtol=1e-10, atol=1e-12))
    close(out.displacement, x, atol=tol * np.max(np.abs(x)))
    close(out.velocity, v, atol=tol * np.max(np.abs(v)))


RELATIVE = [((3, 6), 1e-8), ((3, 6), 1e4), ((1, N), 1e2), ((N - 1, N), 1e5)]


@pytest.mark.parametrize("dofs, coefficient", RELATIVE)
def test_exact_solve_matches_the_matrix_exponential_for_relative_dampers(dofs, coefficient,
                                                                         close):
    system = mj.mikota_chain(N, M_, K_, dampers=[mj.RelativeDamper(dofs, coefficient)])
    x, v = expm_reference(system, TS, X0, V0)
    out = mj.solve(system, TS, X0, V0, velocity=True, method=mj.Spectral())
    rate = coefficient * (dofs[0] + dofs[1]) / M_  # c (1/m_i + 1/m_j)
    tol = 1e-12 + 2e-15 * rate  # measured: 7.2e-10 for c = 1e5 between DOFs 9 and 10
    close(out.displacement, x, atol=tol * np.max(np.abs(x)))
    close(out.velocity, v, atol=tol * np.max(np.abs(v)))


def test_kvaerno5_with_a_strong_relative_damper_matches_the_matrix_exponential(close):
    system = mj.mikota_chain(N, M_, K_, dampers=[mj.RelativeDamper((3, 6), 1e6)])
    x, v = expm_reference(system, TS, X0, V0)
    out = mj.solve(system, TS, X0, V0, velocity=True,
                   method=mj.ODE(mj.StructuredKvaerno5(), rtol=1e-10, atol=1e-12))
    close(out.displacement, x, atol=5e-8 * np.max(np.abs(x)))  # measured 3.7e-9
    close(out.velocity, v, atol=5e-8 * np.max(np.abs(v)))


@pytest.mark.parametrize("dampers", [(mj.GroundedDamper(4, 1e-8),), (mj.GroundedDamper(1, 1e4),),
                                     (mj.GroundedDamper(N, 1e6),),
                                     (mj.RelativeDamper((3, 6), 1e6),)],
                         ids=["1e-8", "1e4 at 1", "1e6 at n", "relative 1e6"])
def test_integrated_energy_matches_the_eigen_expansion_for_weak_and_strong_dampers(dampers,
                                                                                     close):
    system = mj.mikota_chain(N, M_, K_, dampers=dampers)
    expected = energy_integral_reference(system, 20.0, X0, V0)
    close(mj.Energy(20.0, X0, V0)(system), expected, rtol=1e-8)  # measured <= 3e-10


# --- parameter extremes: k/m from 1e-6 to 1e6 ---------------------------------------------------

SCALES = [(1.0, 1e-6), (1e6, 1.0), (1e-3, 1e-9), (1.0, 1e6), (1e-6, 1.0), (1e3, 1e9)]  # (m, k)
TAU = np.linspace(0.0, 20.0, 201)  # dimensionless time t sqrt(k/m)


@pytest.mark.parametrize("m, k", SCALES)
def test_exact_solve_obeys_the_time_scaling_law_for_k_over_m_from_1e_6_to_1e6(m, k, close):
    rate = np.sqrt(k / m)
    x, v = mikota_free_vibration(N, 1.0, 1.0, TAU, X0, V0)  # x(t; k, m) = x(t rate; 1, 1)
    out = mj.solve(mj.mikota_chain(N, m, k), TAU / rate, X0, rate * V0, velocity=True,
                   method=mj.DenseExponential())
    close(out.displacement, x, atol=1e-12 * np.max(np.abs(x)))
    close(np.asarray(out.velocity) / rate, v, atol=1e-12 * np.max(np.abs(v)))


@pytest.mark.parametrize("m, k", SCALES)
def test_simulate_obeys_the_time_scaling_law_at_default_tolerances(m, k):
    rate = np.sqrt(k / m)
    x, v = mikota_free_vibration(N, 1.0, 1.0, TAU, X0, V0)
    out = mj.solve(mj.mikota_chain(N, m, k), TAU / rate, X0, rate * V0, velocity=True,
                   method=mj.ODE())
    # measured: x 1.6e-7, v 3.2e-7 (rate 1e-3); x 7.7e-8, v 1.6e-7 (rate 1e3)
    assert relative_error(out.displacement, x) < 1e-6
    assert relative_error(np.asarray(out.velocity) / rate, v) < 1e-5


@pytest.mark.parametrize("amplitude", [1e6, 1e12])
def test_simulate_keeps_relative_accuracy_for_huge_amplitudes(amplitude):
    x, _ = mikota_free_vibration(N, M_, K_, TAU, X0, V0)
    out = mj.solve(mj.mikota_chain(N, M_, K_), TAU, amplitude * X0, amplitude * V0, velocity=True,
                   method=mj.ODE())
    assert relative_error(np.asarray(out.displacement) / amplitude, x) < 1e-6


@pytest.mark.parametrize("amplitude", [1e-6, 1e-10])
def test_simulate_with_atol_scaled_to_a_tiny_amplitude_keeps_relative_accuracy(amplitude):
    x, _ = mikota_free_vibration(N, M_, K_, TAU, X0, V0)
    out = mj.solve(mj.mikota_chain(N, M_, K_), TAU, amplitude * X0, amplitude * V0, velocity=True,
                   method=mj.ODE(atol=1e-10 * amplitude))
    assert relative_error(np.asarray(out.displacement) / amplitude, x) < 1e-6


@pytest.mark.parametrize("amplitude", [1e-6, 1e-10])
def test_simulate_with_default_tolerances_keeps_relative_accuracy_for_tiny_amplitudes(amplitude):
    # a fixed default atol = 1e-10 gave 3.5e-4 (amplitude 1e-6) and 120 % (1e-10) errors
    x, _ = mikota_free_vibration(N, M_, K_, TAU, X0, V0)
    out = mj.solve(mj.mikota_chain(N, M_, K_), TAU, amplitude * X0, amplitude * V0, velocity=True,
                   method=mj.ODE())
    assert relative_error(np.asarray(out.displacement) / amplitude, x) < 1e-6


# --- parameter extremes: masses over twelve orders of magnitude ----------------------------------

MASSES = np.logspace(-6.0, 6.0, 7)
ORDERS = {"increasing": MASSES, "decreasing": MASSES[::-1],
          "mixed": MASSES[[3, 0, 5, 4, 2, 6, 1]], "alternating": MASSES[[0, 6, 1, 5, 2, 4, 3]]}
SPRINGS = np.ones(7)


@pytest.mark.parametrize("masses", ORDERS.values(), ids=ORDERS.keys())
def test_the_bidiagonal_svd_reference_reproduces_decimal_bisection_for_any_mass_order(masses,
                                                                                     close):
    omega, _ = bidiagonal_modes(masses, SPRINGS)
    close(omega**2, bisection_eigenvalues(masses, SPRINGS), rtol=1e-14)


MONOTONE = {k: ORDERS[k] for k in ("increasing", "decreasing")}
MIXED = {k: ORDERS[k] for k in ("mixed", "alternating")}


@pytest.mark.parametrize("masses", MONOTONE.values(), ids=MONOTONE.keys())
def test_exact_solve_with_masses_from_1e_6_to_1e6_in_monotone_order_matches_the_modal_solution(
        masses, close):
    system = mj.chain(masses, SPRINGS)
    omega, _ = mj.modal_decomposition(system)
    close(omega**2, bisection_eigenvalues(masses, SPRINGS), rtol=1e-14)
    x0, v0 = X0[:7], V0[:7]
    ts = np.linspace(0.0, 1e4, 501)  # the slowest period is 1.6e4, the fastest 4.4e-3
    x = modal_free_vibration(masses, SPRINGS, ts, x0, v0)
    out = mj.solve(system, ts, x0, v0, method=mj.DenseExponential())
    close(out.displacement, x, atol=1e-11 * np.max(np.abs(x)))  # measured 1.2e-13 / 4.5e-12


@pytest.mark.parametrize("masses", MIXED.values(), ids=MIXED.keys())
def test_simulate_with_masses_in_mixed_order_matches_the_modal_solution(masses):
    ts = np.linspace(0.0, 10.0, 101)
    x = modal_free_vibration(masses, SPRINGS, ts, X0[:7], V0[:7])
    out = mj.solve(mj.chain(masses, SPRINGS), ts, X0[:7], V0[:7], method=mj.ODE())
    assert relative_error(out.displacement, x) < 1e-5  # measured 1.1e-6 / 3.6e-7 in ~25 000 steps


@pytest.mark.parametrize("masses", MIXED.values(), ids=MIXED.keys())
def test_modal_frequencies_of_masses_in_mixed_order_have_full_relative_accuracy(masses, close):
    omega, _ = mj.modal_decomposition(mj.chain(masses, SPRINGS))
    close(omega**2, bisection_eigenvalues(masses, SPRINGS), rtol=1e-12)


@pytest.mark.parametrize("masses", MIXED.values(), ids=MIXED.keys())
def test_exact_solve_with_masses_in_mixed_order_matches_the_modal_solution_at_t_1e4(masses,
                                                                                    close):
    ts = np.linspace(0.0, 1e4, 501)
    x = modal_free_vibration(masses, SPRINGS, ts, X0[:7], V0[:7])
    out = mj.solve(mj.chain(masses, SPRINGS), ts, X0[:7], V0[:7], method=mj.DenseExponential())
    close(out.displacement, x, atol=1e-9 * np.max(np.abs(x)))


# --- parameter extremes: long horizons -----------------------------------------------------------

HORIZON = np.linspace(0.0, 1e4 / OMEGA, 2001)  # the shape of LONG: no new compilation


@pytest.mark.parametrize("l", [1, 3, N])
def test_a_mode_shape_oscillates_as_cos_l_omega_t_in_exact_solve_up_to_1e4_over_omega(l, close):
    u = np.asarray(mj.analytic.mode_shape(N, l))
    out = mj.solve(mj.mikota_chain(N, M_, K_), HORIZON, u, velocity=True,
                   method=mj.DenseExponential())
    close(out.displacement, np.cos(l * OMEGA * HORIZON)[:, None] * u, atol=1e-9)  # 6e-11 seen


@pytest.mark.parametrize("l", [1, 3])
def test_dopri8_up_to_1e4_over_omega_loses_no_more_phase_than_rtol_per_radian(l):
    u = np.asarray(mj.analytic.mode_shape(N, l))
    out = mj.solve(mj.mikota_chain(N, M_, K_), HORIZON, u, velocity=True,
                   method=mj.ODE())  # rtol 1e-8
    error = np.max(np.abs(np.asarray(out.displacement) - np.cos(l * OMEGA * HORIZON)[:, None] * u))
    assert error < 1e-8 * l * 1e4  # measured: 1.2e-7 (l = 1), 1.5e-5 (l = 3)


# --- parameter extremes: very short pulses and the Dirac limit ------------------------------------


@pytest.mark.parametrize("start", [0.0, 1.234])
def test_a_pulse_of_duration_1e_6_matches_the_closed_form_in_exact_solve(start, close):
    system = mj.mikota_chain(N, M_, K_)
    load = mj.pulse(N, 3, 1e6, 1e-6, start)  # impulse 1
    x, v = pulse_response(system, TS, 3, 1e6, 1e-6, start)
    out = mj.solve(system, TS, load=load, velocity=True, method=mj.DenseExponential())
    close(out.displacement, x, atol=1e-9 * np.max(np.abs(x)))  # measured 1.3e-10: eps / tau
    close(out.velocity, v, atol=1e-9 * np.max(np.abs(v)))


@pytest.mark.parametrize("solver", ["dopri8", "kvaerno5"])
@pytest.mark.parametrize("start, duration", [(0.0, 1e-6), (1.234, 1e-6), (0.0, 1e-12)])
def test_a_very_short_pulse_matches_the_closed_form_in_simulate(solver, start, duration):
    system = mj.mikota_chain(N, M_, K_)
    load = mj.pulse(N, 3, 1.0 / duration, duration, start)
    x, v = pulse_response(system, TS, 3, 1.0 / duration, duration, start)
    out = mj.solve(system, TS, load=load, velocity=True, method=mj.ODE(ODE_SOLVERS[solver]))
    # measured at rtol 1e-8: x <= 3.6e-7, v <= 1.2e-6 (kvaerno5; dopri8 <= 2.5e-7)
    assert relative_error(out.displacement, x) < 1e-6
    assert relative_error(out.velocity, v) < 5e-6


def test_a_pulse_too_short_for_exact_solves_formula_is_refused_with_the_dirac_remedy(close):
    # exact_solve forms (I - P) z* with |z*| = A / omega: relative error eps / (omega tau), which
    # measured 9e-5 at tau = 1e-12 and 1e-2 at 1e-14 before the check; simulate stays right
    system = mj.mikota_chain(N, M_, K_)
    with pytest.raises(ValueError, match="pulse duration is too short.*Dirac limit"):
        mj.solve(system, TS, load=mj.pulse(N, 3, 1e12, 1e-12), method=mj.DenseExponential())
    x, _ = pulse_response(system, TS, 3, 1e12, 1e-12)
    out = mj.solve(system, TS, load=mj.pulse(N, 3, 1e12, 1e-12), method=mj.ODE())
    assert relative_error(out.displacement, x) < 1e-6


def test_a_pulse_too_short_for_its_start_time_is_integrated_right_or_refused():
    system = mj.mikota_chain(N, M_, K_)
    x, _ = pulse_response(system, TS, 3, 1e12, 1e-12, 1.234)
    try:
        out = mj.solve(system, TS, load=mj.pulse(N, 3, 1e12, 1e-12, 1.234), velocity=True,
                       method=mj.ODE())
    except ValueError as error:  # loud is right too
        assert "duration" in str(error)
        return
    assert relative_error(out.displacement, x) < 1e-6


DURATIONS = np.array([1e-1, 1e-2, 1e-3, 1e-4, 1e-5])


@pytest.mark.parametrize("solve", ["exact_solve", "simulate"])
def test_a_pulse_converges_at_first_order_to_its_dirac_limit_the_initial_velocity(solve, close):
    # impulse I at DOF 3 = initial velocity v0 = M^-1 I e_3; x_dirac = sum_l u_l g_l sin(w t) / w
    impulse, dof = 0.7, 3
    system = mj.mikota_chain(N, M_, K_)
    v0 = impulse * np.eye(N)[dof - 1] / MASS
    x_dirac, v_dirac = mikota_free_vibration(N, M_, K_, TS, np.zeros(N), v0)
    out = mj.solve(system, TS, None, v0, velocity=True, method=mj.DenseExponential())
    close(out.displacement, x_dirac, atol=1e-12)
    errors = []
    for tau in DURATIONS:
        load = mj.pulse(N, dof, impulse / tau, tau)
        if solve == "exact_solve":
            out = mj.solve(system, TS, load=load, velocity=True, method=mj.DenseExponential())
        else:
            out = mj.solve(system, TS, load=load, velocity=True,
                           method=mj.ODE(rtol=1e-11, atol=1e-13))
        errors.append(np.max(np.abs(np.asarray(out.displacement) - x_dirac)))
    rates = np.log10(np.array(errors[:-1]) / np.array(errors[1:]))
    close(rates, np.ones_like(rates), atol=0.02)  # error O(tau): measured 0.999 .. 1.001
    # leading term: the pulse acts as a Dirac at its midpoint, x(t - tau/2), error tau/2 max|v|
    close(np.array(errors[1:]) / DURATIONS[1:], np.max(np.abs(v_dirac)) / 2, rtol=0.02)

