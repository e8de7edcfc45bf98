"""The structured implicit solver (``solver="kvaerno5"``) and the stiff-case choice ("auto").

Truths: the exact matrix-exponential solution (small n), the analytic modal solution of Mikota's
chain at large n (x0 = a mode shape oscillates as cos(l Omega t)), central differences.
"""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj
from mikota_jax._solver.select import STIFF_THRESHOLD, choose_solver, stiffness_rate

N = 12
TS = np.linspace(0.0, 6.0, 61)
DAMPERS = (mj.GroundedDamper(4.3, 0.7), mj.RelativeDamper((2, 9), 0.4),
           mj.RelativeDamper((5, 6), 0.2))


def state(n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.standard_normal(n), rng.standard_normal(n)


def scale(a):
    return float(np.max(np.abs(np.asarray(a))))


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_kvaerno5_agrees_with_the_exact_solution_with_relative_dampers_and_a_pulse(close):
    system = mj.mikota_chain(N, 1.3, 0.9, dampers=DAMPERS)
    x0, v0 = state(N)
    load = mj.pulse(N, 5, amplitude=2.0, duration=0.7, start=0.4)
    exact = mj.solve(system, TS, x0, v0, load, velocity=True, method=mj.Spectral())
    out = mj.solve(system, TS, x0, v0, load, velocity=True,
                   method=mj.ODE(mj.StructuredKvaerno5(), rtol=1e-10, atol=1e-12))
    close(out.displacement, exact.displacement, atol=1e-7 * scale(exact.displacement))
    close(out.velocity, exact.velocity, atol=1e-7 * scale(exact.velocity))


def test_kvaerno5_solves_a_reduced_model_in_its_modal_structure(close):
    system = mj.mikota_chain(N, dampers=DAMPERS)
    x0, v0 = state(N, 1)
    basis, _ = np.linalg.qr(np.random.default_rng(2).standard_normal((N, 7)))
    reduced = mj.reduce(system, mj.Projection(jnp.asarray(basis)))
    exact = mj.solve(reduced, TS, x0, v0, method=mj.DenseExponential())
    out = mj.solve(reduced, TS, x0, v0,
                   method=mj.ODE(mj.StructuredKvaerno5(), rtol=1e-10, atol=1e-12))
    close(out.displacement, exact.displacement, atol=1e-7 * scale(exact.displacement))


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_a_very_strong_damper_is_cheap_and_accurate_for_kvaerno5_and_stiff_for_dopri8(close):
    # c / M_jj = 1e6 * 4: an eigenvalue near -4e6, far beyond the chain's highest frequency 12
    system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(4.0, 1e6)])
    x0, v0 = state(N, 3)
    exact = mj.solve(system, TS, x0, v0, method=mj.Spectral())
    out = mj.solve(system, TS, x0, v0,
                   method=mj.ODE(mj.StructuredKvaerno5(), rtol=1e-9, atol=1e-11))
    close(out.displacement, exact.displacement, atol=1e-6 * scale(exact.displacement))
    assert int(out.num_steps) < 2000
    with pytest.raises(ValueError, match="max_steps = 2000 reached.*StructuredKvaerno5"):
        mj.solve(system, TS, x0, v0, method=mj.ODE(max_steps=2000))


def test_kvaerno5_at_ten_thousand_dofs_keeps_the_analytic_mode_shape_solution(close):
    n, omega = 10_000, 1.0
    ts = np.linspace(0.0, 12.0, 9)  # rho T ~ 1.2e5: "auto" takes kvaerno5
    u1 = np.asarray(mj.analytic.paper_mode_shape(n, 1)) / n
    u2 = np.asarray(mj.analytic.mode_shape(n, 2))
    x0 = u1 + u2
    picked = mj.Auto().select(mj.mikota_chain(n), ts)
    assert isinstance(picked, mj.ODE) and isinstance(picked.solver, mj.StructuredKvaerno5)
    out = mj.solve(mj.mikota_chain(n), ts, x0, dofs=[1, n // 2, n],
                   method=mj.ODE(picked.solver, rtol=1e-9, atol=1e-12))
    rows = np.array([0, n // 2 - 1, n - 1])
    truth = (np.cos(omega * ts)[:, None] * u1[rows] + np.cos(2 * omega * ts)[:, None] * u2[rows])
    close(out.displacement, truth, atol=1e-6)
    assert int(out.num_steps) < 1000  # Dopri8 needs ~ 3e4 steps for stability alone


@pytest.mark.slow
def test_kvaerno5_at_a_hundred_thousand_dofs_keeps_the_analytic_first_mode(close):
    n = 100_000
    ts = np.linspace(0.0, 20.0, 11)
    x0 = np.arange(1.0, n + 1) / n  # p_1(i) = i: the first mode, frequency sqrt(k/m) = 1
    out = mj.solve(mj.mikota_chain(n), ts, x0, dofs=[1, n],
                   method=mj.ODE(mj.StructuredKvaerno5(), rtol=1e-8, atol=1e-12))
    close(out.displacement, np.cos(ts)[:, None] * np.array([1.0 / n, 1.0]), atol=1e-6)


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_gradients_pass_through_the_structured_solves(close):
    x0, v0 = state(N, 4)
    ts = np.linspace(0.0, 3.0, 4)

    def response(c, p):
        system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(p, c)])
        out = mj.solve(system, ts, x0, v0, dofs=[2],
                       method=mj.ODE(mj.StructuredKvaerno5(), rtol=1e-11, atol=1e-13,
                                     max_steps=4096))
        return out.displacement[-1, 0]

    c, p = 0.9, 5.3
    grad = jax.grad(response, argnums=(0, 1))(c, p)
    h = 1e-5
    fd_c = (response(c + h, p) - response(c - h, p)) / (2 * h)
    fd_p = (response(c, p + h) - response(c, p - h)) / (2 * h)
    close(grad[0], fd_c, rtol=1e-5)
    close(grad[1], fd_p, rtol=1e-5)
    assert np.all(np.isfinite(np.asarray(grad)))


def test_kvaerno5_runs_under_vmap_over_damper_coefficients(close):
    x0, v0 = state(N, 5)
    ts = np.linspace(0.0, 2.0, 3)

    def final(c):
        system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(2.0, c)])
        out = mj.solve(system, ts, x0, v0, dofs=[1],
                       method=mj.ODE(mj.StructuredKvaerno5(), rtol=1e-10, atol=1e-12))
        return out.displacement[-1, 0]

    cs = jnp.array([0.0, 1.0, 1e4])
    close(jax.vmap(final)(cs), np.array([final(c) for c in cs]), rtol=1e-9)


def test_auto_picks_dopri8_for_the_paper_scene_and_kvaerno5_when_stiff():
    paper = mj.mikota_chain(300)
    assert choose_solver(paper, np.linspace(0.0, 20.0, 3)) == "dopri8"
    assert choose_solver(mj.mikota_chain(10_000), np.linspace(0.0, 20.0, 3)) == "kvaerno5"
    pinned = mj.mikota_chain(300, dampers=[mj.GroundedDamper(7.0, 1e4)])
    forced = lambda t: jnp.zeros(300)  # noqa: E731  (a general load: integrated)
    assert choose_solver(pinned, np.linspace(0.0, 20.0, 3), forced) == "kvaerno5"
    assert choose_solver(pinned, np.linspace(0.0, 20.0, 3)) == "exact"  # free: the damped modes
    # the Gershgorin bound is a bound: never below the true highest frequency (n sqrt(k/m))
    assert 300.0 <= stiffness_rate(paper) <= 2 * 300.0
    assert stiffness_rate(pinned) >= 7e4
    assert STIFF_THRESHOLD == 1e5


def test_auto_needs_concrete_values_and_says_so():
    x0 = np.ones(N)

    @jax.jit
    def run(k):
        return mj.solve(mj.mikota_chain(N, k=k), TS, x0, method=mj.Auto()).displacement

    with pytest.raises(ValueError, match=r"Auto\(\) needs concrete"):
        run(1.0)


def test_auto_chooses_the_exact_path_from_the_structure_also_under_jit(close):
    # a damped chain with no load: "exact" from the types alone, so under jit too, and the same
    # trajectory as exact_solve (the same spectral program; no integration, num_steps None)
    x0 = np.ones(N)
    pulse = mj.pulse(N, 1, amplitude=1.0, duration=0.05)
    damped = mj.mikota_chain(N, dampers=[mj.GroundedDamper(2.0, 0.5)])
    assert choose_solver(damped, TS) == "exact" == choose_solver(damped, TS, pulse)
    assert choose_solver(damped, TS, lambda t: jnp.zeros(N)) == "dopri8"  # a general load
    assert choose_solver(mj.mikota_chain(N), TS) == "dopri8"  # undamped: no damped modes

    @jax.jit
    def run(c):
        system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(2.0, c)])
        return mj.solve(system, TS, x0, method=mj.Auto())

    out = run(0.5)
    assert out.num_steps is None
    close(out.displacement, mj.solve(damped, TS, x0, method=mj.DenseExponential()).displacement,
          rtol=0, atol=1e-12)


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_diffrax_solver_instances_are_still_accepted(close):
    system = mj.mikota_chain(4, dampers=[mj.GroundedDamper(2.0, 0.5)])
    x0, v0 = state(4, 6)
    exact = mj.solve(system, TS, x0, v0, method=mj.Spectral())
    out = mj.solve(system, TS, x0, v0, method=mj.ODE(diffrax.Kvaerno5(), rtol=1e-9, atol=1e-11))
    close(out.displacement, exact.displacement, atol=1e-6 * scale(exact.displacement))


def test_dense_methods_refuse_a_size_that_cannot_fit_in_memory():
    n = 200_000  # 32 n^2 float64 = 10 TB: refused before anything is allocated
    # with internal damping the spectral path needs U (a chain with dampers alone above
    # n = 4096 takes the O(n)-memory path instead: ``test_spectral_response_rows``)
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(5.0, 1.0)],
                             internal_damping=mj.Rayleigh(0.01, 0.0))
    x0 = np.ones(n)
    with pytest.raises(ValueError,
                       match=r"Spectral\(\) works with dense matrices.*StructuredKvaerno5"):
        mj.solve(system, np.linspace(0.0, 1.0, 3), x0, method=mj.Spectral())
    with pytest.raises(ValueError, match=r"Energy.*GiB.*method=ODE\(\)"):
        mj.Energy(1.0, x0)(system)
    with pytest.raises(ValueError, match=r"AverageEnergy\(\) works with dense"):
        mj.AverageEnergy()(system)


def test_a_damper_rate_beyond_the_dense_energys_range_is_refused_and_the_spectral_path_holds():
    system = mj.mikota_chain(4, dampers=[mj.GroundedDamper(2.0, 1e19)])
    start = np.eye(4)[2]  # the damped DOF displaced: as d grows it is pinned, nothing dissipates
    with pytest.raises(ValueError, match="beyond which the dense .* energy loses"):
        mj.Energy(20.0, start, method=mj.DenseExponential())(system)
    # the spectral path (the default here) stays inside the physical bound 0 < J <= E0 T and
    # tends to E0 T from below as d grows
    e0 = 0.5 * float(start @ np.asarray(system.stiffness.as_matrix()) @ start)
    for d in (1e8, 1e12, 1e16, 1e19):
        strong = mj.mikota_chain(4, dampers=[mj.GroundedDamper(2.0, d)])
        energy = float(mj.Energy(20.0, start)(strong))
        assert 0.0 < energy <= e0 * 20.0 * (1 + 1e-14), (d, energy)
        assert energy > e0 * 20.0 * (1 - 1e-6), (d, energy)


@pytest.mark.slow
def test_the_dense_energy_is_refused_where_rounding_would_cost_it_its_digits(close):
    # issue 18: n = 30, T = 20, damper at DOF 7; the dense energy was 533.9 at d = 1e13 and 569
    # (above E0 T = 550) at 1e14, with no error
    start = np.eye(30)[2]
    for d, refused in ((1e8, False), (1e12, True), (1e14, True)):
        system = mj.mikota_chain(30, dampers=[mj.GroundedDamper(7.0, d)])
        exact = float(mj.Energy(20.0, start)(system))
        assert 0 < exact <= 550.0 * (1 + 1e-14)
        if refused:
            with pytest.raises(ValueError, match="spectral path"):
                mj.Energy(20.0, start, method=mj.DenseExponential())(system)
        else:
            close(mj.Energy(20.0, start, method=mj.DenseExponential())(system), exact, rtol=1e-6)
