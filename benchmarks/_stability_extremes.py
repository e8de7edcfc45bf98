"""Stability on extreme cases, measured: damping and parameter extremes of tests/test_extremes.py.

``rows()`` runs each case once (small chains, n = 7 or 10) against an independent truth (scipy's
``expm`` of the state matrix, Mikota's closed forms, the SVD of the chain's bidiagonal factor, the
closed-form pulse response) and returns one dict per case: ``area``, ``case``, ``measured`` (the
error or the behaviour, computed now, with a verdict: right / loud / SILENTLY WRONG /
NON-FINITE) and ``test`` (the covering test in tests/test_extremes.py). Imported by
benchmarks/stability.py; about 30-60 s, most of it compilation.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: LAPACK must not busy-wait

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
import scipy.linalg as sl  # noqa: E402

import mikota_jax as mj  # noqa: E402

DAMPING, PARAMETERS = "Damping extremes", "Parameter extremes"
BOUNDS = "Physical bounds and refusals"
N, M_, K_ = 10, 1.3, 0.9
OMEGA = np.sqrt(K_ / M_)
TS = np.linspace(0.0, 20.0, 201)
_RNG = np.random.default_rng(7)
X0, V0 = _RNG.standard_normal(N), _RNG.standard_normal(N)
MASSES = np.logspace(-6.0, 6.0, 7)
MIXED = MASSES[[3, 0, 5, 4, 2, 6, 1]]


def _dense_solve(model, ts, **kwargs):
    return mj.solve(model, ts, method=mj.DenseExponential(), **kwargs)


def _dopri8_solve(model, ts, **kwargs):
    return mj.solve(model, ts, method=mj.ODE(), **kwargs)


def _dense(system):
    M, D, K = (None if a is None else np.asarray(a) for a in system.dense())
    return M, np.zeros_like(M) if D is None else D, K


def _expm_reference(system, ts, x0, v0):
    M, D, K = _dense(system)
    n, inverse = M.shape[0], np.linalg.inv(M)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-inverse @ K, -inverse @ D]])
    y = np.stack([sl.expm(a * (t - ts[0])) @ np.concatenate([x0, v0]) for t in ts])
    return y[:, :n], y[:, n:]


def _energy(system, x, v):
    M, _, K = _dense(system)
    return 0.5 * (np.einsum("ti,ij,tj->t", x, K, x) + np.einsum("ti,ij,tj->t", v, M, v))


def _mikota_free_vibration(m, k, ts, x0, v0):
    modes = np.stack([np.asarray(mj.analytic.mode_shape(N, l)) for l in range(1, N + 1)], axis=1)
    mass = m / np.arange(1, N + 1)
    weight = np.einsum("il,i,il->l", modes, mass, modes)
    a, b = (modes.T @ (mass * x0)) / weight, (modes.T @ (mass * v0)) / weight
    w = np.arange(1, N + 1) * np.sqrt(k / m)
    phase = np.outer(ts, w)
    return ((np.cos(phase) * a + np.sin(phase) * b / w) @ modes.T,
            (-np.sin(phase) * a * w + np.cos(phase) * b) @ modes.T)


def _bidiagonal_modal(masses, ts, x0, v0):
    """Free vibration of a unit-spring chain from the SVD of diag(sqrt k) L M^-1/2 (relative
    accuracy); also returns omega ascending."""
    n = masses.shape[0]
    b = (np.eye(n) - np.eye(n, k=-1)) / np.sqrt(masses)[None, :]
    _, sigma, vt = np.linalg.svd(b)
    modes = vt.T / np.sqrt(masses)[:, None]
    a, c = modes.T @ (masses * x0), modes.T @ (masses * v0)
    phase = np.outer(ts, sigma)
    return (np.cos(phase) * a + np.sin(phase) * c / sigma) @ modes.T, sigma[::-1]


def _pulse_response(system, ts, dof, amplitude, duration, start=0.0):
    M, _, K = _dense(system)
    omega2, modes = sl.eigh(K, M)
    w, g = np.sqrt(omega2), amplitude * modes[dof - 1]
    t = (ts - start)[:, None]
    during, after = (t >= 0) & (t <= duration), t > duration
    eta = (np.where(during, 2 * np.sin(w * t / 2) ** 2, 0.0) + np.where(
        after, 2 * np.sin(w * (t - duration / 2)) * np.sin(w * duration / 2), 0.0)) * g / omega2
    return eta @ modes.T


def _rel(actual, expected):
    actual = np.asarray(actual)
    if not np.all(np.isfinite(actual)):
        return np.nan
    return float(np.max(np.abs(actual - expected)) / np.max(np.abs(expected)))


def _verdict(error, tol):
    if np.isnan(error):
        return "NON-FINITE, no error raised"
    return f"{error:.1e} ({'right' if error <= tol else 'SILENTLY WRONG'})"


def _loud(fn, match):
    try:
        fn()
    except ValueError as error:
        return "loud: ValueError" + (f" ({match})" if match in str(error) else f": {error}")
    return "SILENTLY accepted"


def _first_clause(error) -> str:
    """An error's message without the library's mark, up to its first clause."""
    message = str(error).removeprefix("mikota_jax: ")
    return message.split(";")[0].split(". ")[0].rstrip(".")


def _row(area, case, measured, test):
    return {"area": area, "case": case, "measured": measured, "test": test}


def _damping_rows():
    rows = []
    undamped = mj.mikota_chain(N, M_, K_)
    long = np.linspace(0.0, 1000.0, 2001)
    out = mj.solve(undamped, long, X0, V0, velocity=True, method=mj.DenseExponential())
    e = _energy(undamped, np.asarray(out.displacement), np.asarray(out.velocity))
    rows.append(_row(DAMPING, "d = 0, T = 1000: exact_solve energy drift",
                     _verdict(float(np.max(np.abs(e / e[0] - 1))), 1e-12),
                     "test_exact_solve_conserves_the_energy_of_an_undamped_chain_over_a_"
                     "thousand_time_units"))
    drifts = []
    for rtol in (1e-8, 1e-10):
        out = mj.solve(undamped, long, X0, V0, velocity=True,
                       method=mj.ODE(rtol=rtol, atol=rtol / 100))
        e = _energy(undamped, np.asarray(out.displacement), np.asarray(out.velocity))
        drifts.append(f"{np.max(np.abs(e / e[0] - 1)):.1e} at rtol {rtol:.0e}")
    rows.append(_row(DAMPING, "d = 0, T = 1000: dopri8 energy drift", ", ".join(drifts),
                     "test_dopri8_energy_drift_over_a_thousand_time_units_stays_within_horizon_"
                     "times_rtol"))

    errors = []
    for c in (1e-8, 1.0, 1e4, 1e6):
        system = mj.mikota_chain(N, M_, K_, dampers=[mj.GroundedDamper(4, c)])
        x, _ = _expm_reference(system, TS, X0, V0)
        out = mj.solve(system, TS, X0, V0, method=mj.Spectral())
        errors.append(f"{c:.0e}: {_rel(out.displacement, x):.0e}")
    rows.append(_row(DAMPING, "grounded c = 1e-8..1e6 at DOF 4: exact_solve vs expm",
                     "; ".join(errors),
                     "test_exact_solve_matches_the_matrix_exponential_for_damper_coefficients_"
                     "1e_8_to_1e6"))

    for case, dampers in (("grounded c = 1e6 at DOF n", [mj.GroundedDamper(N, 1e6)]),
                          ("relative c = 1e6 (3, 6)", [mj.RelativeDamper((3, 6), 1e6)])):
        system = mj.mikota_chain(N, M_, K_, dampers=dampers)
        x, _ = _expm_reference(system, TS, X0, V0)
        error = _rel(mj.solve(system, TS, X0, V0, method=mj.Spectral()).displacement, x)
        rows.append(_row(DAMPING, f"{case}: exact_solve", _verdict(error, 1e-8),
                         "test_exact_solve_with_a_very_fast_damper_mode_is_finite_and_right"))
    system = mj.mikota_chain(N, M_, K_, dampers=[mj.GroundedDamper(1, 1.0)])
    coarse = 1e5 * np.arange(TS.shape[0], dtype=float)  # the shape of TS: compiled already
    x, _ = _expm_reference(system, coarse[:3], X0, V0)
    out = np.asarray(mj.solve(system, coarse, X0, V0, method=mj.Spectral()).displacement)[:3]
    error = np.nan if not np.all(np.isfinite(out)) else float(np.max(np.abs(out - x)))
    rows.append(_row(DAMPING, "c = 1 at DOF 1, grid step 1e5: exact_solve (vs scipy expm; "
                     "both square ~20 times)", _verdict(error, 1e-10),
                     "test_exact_solve_on_a_very_coarse_grid_of_a_damped_chain_is_finite_and_"
                     "right"))

    system = mj.mikota_chain(N, M_, K_, dampers=[mj.GroundedDamper(1, 1e6)])
    exact = mj.solve(system, TS, X0, V0, method=mj.Spectral())
    out = mj.solve(system, TS, X0, V0,
                   method=mj.ODE(mj.StructuredKvaerno5(), rtol=1e-10, atol=1e-12))
    rows.append(_row(DAMPING, "c = 1e6 at DOF 1: kvaerno5 (rtol 1e-10) vs exact_solve",
                     f"{_verdict(_rel(out.displacement, exact.displacement), 5e-8)}, "
                     f"{int(out.num_steps)} steps",
                     "test_kvaerno5_with_a_1e6_damper_agrees_with_exact_solve"))
    rows.append(_row(DAMPING, "c = 1e6 at DOF 1: dopri8, max_steps = 2000",
                     _loud(lambda: mj.solve(system, TS, X0, V0, method=mj.ODE(max_steps=2000)),
                           "max_steps"),
                     "test_dopri8_with_a_1e6_damper_stops_loudly_at_max_steps"))

    several = mj.mikota_chain(N, M_, K_, dampers=[
        mj.GroundedDamper(1, 3.0), mj.GroundedDamper(5.5, 0.7), mj.GroundedDamper(N, 2.0),
        mj.RelativeDamper((2, 7), 1.5), mj.RelativeDamper((N - 1, N), 0.4)])
    x, _ = _expm_reference(several, TS, X0, V0)
    exact = _rel(mj.solve(several, TS, X0, V0, method=mj.Spectral()).displacement, x)
    rows.append(_row(DAMPING, "5 dampers incl. DOF 1, DOF n, 2 relative: exact_solve vs expm",
                     _verdict(exact, 1e-12),
                     "test_several_dampers_at_the_first_and_last_dof_match_the_matrix_"
                     "exponential"))

    errors = []
    for c in (1e-8, 1e4):
        system = mj.mikota_chain(N, M_, K_, dampers=[mj.RelativeDamper((3, 6), c)])
        x, _ = _expm_reference(system, TS, X0, V0)
        out = mj.solve(system, TS, X0, V0, method=mj.Spectral())
        errors.append(f"{c:.0e}: {_rel(out.displacement, x):.0e}")
    rows.append(_row(DAMPING, "relative (3, 6) c = 1e-8, 1e4: exact_solve vs expm",
                     "; ".join(errors),
                     "test_exact_solve_matches_the_matrix_exponential_for_relative_dampers"))
    system = mj.mikota_chain(N, M_, K_, dampers=[mj.RelativeDamper((3, 6), 1e6)])
    x, _ = _expm_reference(system, TS, X0, V0)
    out = mj.solve(system, TS, X0, V0,
                   method=mj.ODE(mj.StructuredKvaerno5(), rtol=1e-10, atol=1e-12))
    rows.append(_row(DAMPING, "relative c = 1e6 (3, 6): kvaerno5 vs expm",
                     _verdict(_rel(out.displacement, x), 5e-8),
                     "test_kvaerno5_with_a_strong_relative_damper_matches_the_matrix_"
                     "exponential"))
    return rows


def _parameter_rows():
    rows = []
    tau = np.linspace(0.0, 20.0, 201)
    x, v = _mikota_free_vibration(1.0, 1.0, tau, X0, V0)
    exact, sim = [], []
    for m, k in ((1.0, 1e-6), (1.0, 1e6)):
        rate = np.sqrt(k / m)
        system = mj.mikota_chain(N, m, k)
        exact.append(_rel(mj.solve(system, tau / rate, X0, rate * V0,
                                   method=mj.DenseExponential()).displacement, x))
        sim.append(_rel(mj.solve(system, tau / rate, X0, rate * V0,
                                 method=mj.ODE()).displacement, x))
    rows.append(_row(PARAMETERS, "k/m = 1e-6, 1e6: x(t; k, m) = x(t sqrt(k/m); 1, 1)",
                     f"exact_solve {max(exact):.0e}, dopri8 (default tol) {max(sim):.0e}",
                     "test_exact_solve_obeys_the_time_scaling_law_for_k_over_m_from_1e_6_to_1e6"))
    x, _ = _mikota_free_vibration(M_, K_, tau, X0, V0)
    system = mj.mikota_chain(N, M_, K_)
    errors = []
    for amplitude in (1e-6, 1e-10):
        out = mj.solve(system, tau, amplitude * X0, amplitude * V0, method=mj.ODE())
        error = _rel(np.asarray(out.displacement) / amplitude, x)
        errors.append(f"{amplitude:.0e}: {_verdict(error, 1e-6)}")
    rows.append(_row(PARAMETERS, "tiny amplitude, default atol (scaled): dopri8 relative error",
                     "; ".join(errors),
                     "test_simulate_with_default_tolerances_keeps_relative_accuracy_for_tiny_"
                     "amplitudes"))

    ts = np.linspace(0.0, 1e4, 501)
    for case, masses, tol, test in (
            ("masses 1e-6..1e6 increasing: exact_solve at t <= 1e4", MASSES, 1e-11,
             "test_exact_solve_with_masses_from_1e_6_to_1e6_in_monotone_order_matches_the_"
             "modal_solution"),
            ("masses 1e-6..1e6 mixed order: exact_solve at t <= 1e4", MIXED, 1e-9,
             "test_exact_solve_with_masses_in_mixed_order_matches_the_modal_solution_at_t_1e4")):
        system = mj.chain(masses, np.ones(7))
        x, omega = _bidiagonal_modal(masses, ts, X0[:7], V0[:7])
        computed, _ = mj.modal_decomposition(system)
        omega_error = float(np.max(np.abs(np.asarray(computed) - omega) / omega))
        error = _rel(mj.solve(system, ts, X0[:7], V0[:7],
                              method=mj.DenseExponential()).displacement, x)
        rows.append(_row(PARAMETERS, case,
                         f"x {_verdict(error, tol)}; omega {omega_error:.0e}", test))

    horizon = np.linspace(0.0, 1e4 / OMEGA, 2001)
    u = np.asarray(mj.analytic.mode_shape(N, 1))
    expected = np.cos(OMEGA * horizon)[:, None] * u
    system = mj.mikota_chain(N, M_, K_)
    exact = _rel(mj.solve(system, horizon, u, velocity=True,
                          method=mj.DenseExponential()).displacement, expected)
    out = mj.solve(system, horizon, u, velocity=True,
                   method=mj.ODE())  # shapes of the T = 1000 rows
    rows.append(_row(PARAMETERS, "T = 1e4 / Omega, x0 = u_1: vs u_1 cos(Omega t)",
                     f"exact_solve {_verdict(exact, 1e-9)}; dopri8 (rtol 1e-8) "
                     f"{_rel(out.displacement, expected):.0e} in {int(out.num_steps)} steps",
                     "test_a_mode_shape_oscillates_as_cos_l_omega_t_in_exact_solve_up_to_1e4_"
                     "over_omega"))

    def attempt(solve, load, x, tol):
        """The verdict of one solve, or how it refused (loud is right too)."""
        try:
            return _verdict(_rel(solve(system, TS, load=load).displacement, x), tol)
        except ValueError as error:
            return "loud: ValueError (" + str(error).removeprefix("mikota_jax: ")[:60] + "...)"

    for case, start, duration, test in (
            ("pulse tau = 1e-6 (A = 1e6)", 0.0, 1e-6,
             "test_a_pulse_of_duration_1e_6_matches_the_closed_form_in_exact_solve"),
            ("pulse tau = 1e-12 (A = 1e12)", 0.0, 1e-12,
             "test_a_pulse_too_short_for_exact_solves_formula_is_refused_with_the_dirac_remedy"),
            ("pulse tau = 1e-12 at start 1.234", 1.234, 1e-12,
             "test_a_pulse_too_short_for_its_start_time_is_integrated_right_or_refused")):
        try:
            load = mj.pulse(N, 3, 1.0 / duration, duration, start)
        except ValueError as error:
            rows.append(_row(PARAMETERS, f"{case}: vs closed form", "loud: pulse() refuses it ("
                             + str(error).removeprefix("mikota_jax: ")[:70] + "...)", test))
            continue
        x = _pulse_response(system, TS, 3, 1.0 / duration, duration, start)
        rows.append(_row(PARAMETERS, f"{case}: vs closed form",
                         f"exact_solve {attempt(_dense_solve, load, x, 1e-8)}; dopri8 "
                         f"{attempt(_dopri8_solve, load, x, 1e-6)}", test))

    v0 = 0.7 * np.eye(N)[2] / (M_ / 3)  # impulse 0.7 at DOF 3: v0 = M^-1 I e_3
    x_dirac, v_dirac = _mikota_free_vibration(M_, K_, TS, np.zeros(N), v0)
    durations = np.array([1e-2, 1e-3, 1e-4, 1e-5])
    errors = np.array([np.max(np.abs(np.asarray(mj.solve(
        system, TS, load=mj.pulse(N, 3, 0.7 / tau, tau),
        method=mj.DenseExponential()).displacement) - x_dirac))
        for tau in durations])
    rates = np.log10(errors[:-1] / errors[1:])
    constant = errors[-1] / durations[-1] / (np.max(np.abs(v_dirac)) / 2)
    rows.append(_row(PARAMETERS, "Dirac limit tau = 1e-2..1e-5: pulse vs v0 = M^-1 I e_dof",
                     f"order {rates.min():.3f}..{rates.max():.3f}; error / (tau max|v| / 2) = "
                     f"{constant:.3f}",
                     "test_a_pulse_converges_at_first_order_to_its_dirac_limit_the_initial_"
                     "velocity"))
    return rows


def _bound_rows():
    """The physical bound 0 < J <= E0 T over strong dampers, and the refusals."""
    rows = []
    n, horizon = 30, 20.0
    x0 = np.zeros(n)
    x0[2] = 1.0
    e0_t = float(np.asarray(mj.mikota_chain(n).stiffness.as_matrix())[2, 2]) / 2 * horizon
    cells = {"exact": [], "dense": []}
    for d in (1e8, 1e10, 1e12, 1e13, 1e14, 1e16):
        system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(7, d)])
        for method, spelling in (("exact", mj.Auto()), ("dense", mj.DenseExponential())):
            try:
                j = float(mj.Energy(horizon, x0, method=spelling)(system))
                ok = 0 < j <= e0_t * (1 + 1e-14)
                cells[method].append(f"{d:.0e}: {j:.6g}{'' if ok else ' (ABOVE E0 T)'}")
            except ValueError as error:
                cells[method].append(f"{d:.0e}: refused ({_first_clause(error)})")
    rows.append(_row(BOUNDS, f"n = 30, T = 20, damper at DOF 7, E0 T = {e0_t:g}: "
                     "integrated_energy (the default, spectral)", "; ".join(cells["exact"]),
                     "test_a_damper_rate_beyond_the_dense_energys_range_is_refused_and_the_spectral_path_holds"))
    rows.append(_row(BOUNDS, "the same, method='dense' (Van Loan; the default before)",
                     "; ".join(cells["dense"]) + " (refused past ||A|| T = 4.5e11; before, it "
                     "gave 533.9 at 1e13 and 569 > E0 T at 1e14 silently; only user damping "
                     "matrices and ROMs still take it)",
                     "test_a_damper_rate_beyond_the_dense_energys_range_is_refused_and_the_spectral_path_holds"))
    system = mj.mikota_chain(4, dampers=[mj.GroundedDamper(2, 0.5)])
    ts, start = np.linspace(0.0, 1.0, 11), np.eye(4)[2]
    for rtol in (1.0, 10.0, 1e300):
        rows.append(_row(BOUNDS, f"simulate dopri8 rtol = {rtol:g}",
                         _loud(lambda r=rtol: mj.solve(system, ts, start, method=mj.ODE(rtol=r)),
                               "rtol"),
                         "test_unknown_solver_and_non_positive_tolerances_are_rejected"))
    far = 1e5 + 1e-3 * np.arange(1001)
    dense = mj.solve(system, far, start, method=mj.DenseExponential()).displacement
    spectral = mj.solve(system, far, start, method=mj.Spectral()).displacement
    rows.append(_row(BOUNDS, "uniform grid far from 0 (t = 1e5 + 1e-3 k): dense vs spectral",
                     _verdict(_rel(dense, spectral), 1e-8),
                     "test_a_uniform_grid_far_from_zero_is_uniform_to_the_rounding_of_t"))
    for case, call in (("m = 1 + 2j", lambda: mj.mikota_chain(4, m=1 + 2j)),
                       ("dofs = [2.5]", lambda: mj.solve(system, ts, start, dofs=[2.5],
                                                         method=mj.Spectral())),
                       ("RelativeDamper((2.7, 3))",
                        lambda: mj.mikota_chain(4, dampers=[mj.RelativeDamper((2.7, 3), 1.0)]))):
        rows.append(_row(BOUNDS, case, _loud(call, "must"), "tests/test_fuzz.py"))
    return rows


def rows() -> list[dict]:
    """One dict per extreme case: area, case, measured (computed now), test."""
    return _damping_rows() + _parameter_rows() + _bound_rows()


if __name__ == "__main__":
    import time

    start = time.perf_counter()
    for row in rows():
        print(f"{row['area']:<19} | {row['case']:<58} | {row['measured']}")
    print(f"{time.perf_counter() - start:.1f} s")
