"""Damper placement (``optimise`` with ``ScreenAndCertify`` and ``Grid``): gradients through the
ROM against central differences of the full model, the constraints, the realisable polish, the
certification loop, the sweep, the CLI and bad input. The private ``DamperProblem`` and
``placement_objective`` are what the strategies evaluate, tested here as internals."""

import json
import os
import subprocess
import sys

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj
from mikota_jax._placement.objective import placement_objective
from mikota_jax._placement.problem import DamperProblem
from mikota_jax._placement.search import (
    _init,
    _step,
    from_unconstrained,
    to_unconstrained,
    value_and_gradient,
)
from mikota_jax._rom.pod import pod

N = 12
HORIZON = 8.0


def problem(n=N, position=4.0, coefficient=0.8, **kwargs):
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(position, coefficient)])
    x0 = jnp.zeros(n).at[2].set(1.0)
    kwargs.setdefault("energy", 1.0)
    return DamperProblem(system, jnp.linspace(0.0, HORIZON, 401), x0, **kwargs)


def design(n=N, position=4.0, coefficient=0.8, objective=None, dampers=None):
    """The design of ``problem``: one damper (or ``dampers``) anywhere on the chain, the energy
    over [0, HORIZON] of the free vibration from x_3 = 1."""
    system = mj.mikota_chain(n, dampers=dampers or [mj.GroundedDamper(position, coefficient)])
    objective = objective or mj.Energy(HORIZON, jnp.zeros(n).at[2].set(1.0))
    return mj.DamperDesign(system, objective, positions=range(1, n + 1))


def certified(energy=1.0, **kwargs):
    """``ScreenAndCertify`` with ``problem``'s POD settings (its 401 times are the default)."""
    return mj.ScreenAndCertify(energy=energy, **kwargs)


def full_energy(n, position, coefficient):
    """Independent truth: the exact integrated energy of the full chain (matrix exponentials)."""
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(position, coefficient)])
    return float(mj.Energy(HORIZON, jnp.zeros(n).at[2].set(1.0))(system))


def full_basis(n=N):
    return jnp.eye(n)


@pytest.mark.slow
@pytest.mark.parametrize("position", [pytest.param(4.0, marks=pytest.mark.slow),
                                      pytest.param(4.3, marks=pytest.mark.slow), 1.0,
                                      float(N)])  # 4.0, 4.3: default-run time
def test_reduced_gradient_matches_central_differences_of_the_full_model(position):
    p = problem(position=position)
    objective = placement_objective(p, full_basis())  # full basis: the ROM is exact
    c = 0.8
    value, (gp, gc) = jax.value_and_grad(objective, argnums=(0, 1))(
        jnp.array([position]), jnp.array([c]))
    assert float(value) == pytest.approx(full_energy(N, position, c), rel=1e-10)
    h = 1e-4  # the exact energy carries ~1e-11 relative rounding: steps below 1e-5 amplify it
    dc = (full_energy(N, position, c + h) - full_energy(N, position, c - h)) / (2 * h)
    assert float(gc[0]) == pytest.approx(dc, rel=1e-6)
    # positions: one-sided at DOFs (the split damper has a kink there; JAX takes the right side,
    # the left side at p = n), central in between
    f = lambda q: full_energy(N, q, c)  # noqa: E731
    if position == int(position):  # second-order one-sided differences
        s = -1.0 if position == N else 1.0
        dp = s * (-3 * f(position) + 4 * f(position + s * h) - f(position + 2 * s * h)) / (2 * h)
    else:
        dp = (f(position + h) - f(position - h)) / (2 * h)
    assert float(gp[0]) == pytest.approx(dp, rel=1e-6)


def test_gradient_near_zero_coefficient_is_finite_and_matches_differences():
    p = problem()
    objective = placement_objective(p, full_basis())
    c, h = 1e-6, 5e-7  # both sides >= 0; larger steps would amplify rounding less but cross 0
    gc = jax.grad(objective, argnums=1)(jnp.array([4.0]), jnp.array([c]))
    dc = (full_energy(N, 4.0, c + h) - full_energy(N, 4.0, c - h)) / (2 * h)
    assert np.all(np.isfinite(gc))
    assert float(gc[0]) == pytest.approx(dc, rel=1e-4)


@pytest.mark.parametrize("position, c", [(4.0, 0.8), (7.3, 25.0)])
def test_a_truncated_models_objective_is_its_galerkin_models_energy(position, c):
    """On a truncated basis the reduced objective is the spectral closed form of the Galerkin
    model's damped modes: against mpmath's eigen-expansion of that model (60 digits, about 50
    right) and Richardson-extrapolated central differences of it (steps h and h / 2, h = 1e-3 c
    and 1e-4 in the position: O(h^4) < 1e-12, and the float64 Galerkin matrices' rounding / h
    ~ 1e-11)."""
    from _helpers import mp_eigen_energy

    p = problem()
    basis = np.linalg.qr(np.random.default_rng(3).normal(size=(N, 6)))[0]
    objective = placement_objective(p, jnp.asarray(basis))
    x0 = basis.T @ np.asarray(p.x0)

    def truth(position, c):
        model = p.system(jnp.array([position]), jnp.array([c])).project(jnp.asarray(basis))
        return mp_eigen_energy(model, HORIZON, x0, np.zeros(6), as_float=False)

    def derivative(f, x, h):
        wide, narrow = ((f(x + t) - f(x - t)) / (2 * t) for t in (h, h / 2))
        return float((4 * narrow - wide) / 3)

    value, (gp, gc) = jax.value_and_grad(objective, argnums=(0, 1))(jnp.array([position]),
                                                                   jnp.array([c]))
    assert float(value) == pytest.approx(float(truth(position, c)), rel=1e-13)
    dc = derivative(lambda x: truth(position, x), c, 1e-3 * c)
    assert float(gc[0]) == pytest.approx(dc, rel=1e-9)
    if position != int(position):  # at a DOF the split damper has a kink
        dp = derivative(lambda x: truth(x, c), position, 1e-4)
        assert float(gp[0]) == pytest.approx(dp, rel=1e-9)


@pytest.mark.slow  # 21 s in CI
def test_truncated_basis_gradient_differs_from_the_full_one_by_the_rom_error():
    p = problem()
    snapshots = mj.solve(p.system(p.positions, p.coefficients), p.ts, p.x0,
                         method=mj.ODE()).displacement
    basis = pod(snapshots.T).basis(6)
    reduced = jax.grad(placement_objective(p, basis), argnums=1)(p.positions, p.coefficients)
    full = jax.grad(placement_objective(p), argnums=1)(p.positions, p.coefficients)
    exact = jax.grad(placement_objective(p, full_basis()), argnums=1)(p.positions,
                                                                         p.coefficients)
    assert float(full[0]) == pytest.approx(float(exact[0]), rel=1e-5)  # ODE vs exact
    assert abs(float(reduced[0]) - float(exact[0])) > 1e-6 * abs(float(exact[0]))


def test_reparametrisation_keeps_every_design_feasible():
    u = jnp.array([-1e3, -5.0, 0.0, 5.0, 1e3])
    w = jnp.array([-1e3, -3.0, 0.0, 3.0, 1e3])
    positions, coefficients = from_unconstrained(N, 2.0, u, w)
    assert np.all((positions >= 1) & (positions <= N))
    assert np.all(np.isfinite(coefficients) & (coefficients >= 0))
    u2, w2 = to_unconstrained(N, 2.0, np.array([1.5, 6.0, 11.5]), np.array([0.1, 2.0, 50.0]))
    p2, c2 = from_unconstrained(N, 2.0, u2, w2)
    np.testing.assert_allclose(p2, [1.5, 6.0, 11.5], rtol=1e-12)
    np.testing.assert_allclose(c2, [0.1, 2.0, 50.0], rtol=1e-12)


def test_the_energy_search_compiles_without_host_callbacks():
    """Designs are valid by construction and mapped without checks, so the compiled L-BFGS step
    and the full model's certification hold no host callback (no equinox check inside)."""
    p = problem()
    c_ref = jnp.array([0.8])
    params = to_unconstrained(N, c_ref, np.array([[4.0], [6.0]]), np.array([[0.8], [0.8]]))
    rate = jnp.asarray(0.1)
    state = _init(params, rate, optimizer="lbfgs")
    step = _step.lower(p, full_basis(), c_ref, params, state, jnp.zeros((2, 1)),
                       jnp.ones(2, bool), jnp.ones(2, bool), rate, optimizer="lbfgs",
                       positions_fixed=False)
    full = value_and_gradient.lower(p, None, p.positions, p.coefficients)
    assert "callback" not in step.as_text() and "callback" not in full.as_text()


@pytest.fixture(scope="module")
def small_sweep():
    p = problem(n=10)
    coefficients = np.geomspace(0.05, 50.0, 60)
    return p, mj.optimise(design(n=10), mj.Grid(coefficients))


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_sweep_equals_unbatched_evaluations(small_sweep):
    _, sweep = small_sweep
    grid, coefficients = sweep.stats["grid"], sweep.stats["coefficients"]
    assert grid.shape == (10, 60) and sweep.stats["failed"] == 0
    two = mj.DamperDesign(design(n=10).system, design(n=10).objective, positions=[2, 9])
    batched = mj.optimise(two, mj.Grid(coefficients[:7], batch_size=4))
    np.testing.assert_allclose(batched.stats["grid"], grid[[1, 8], :7], rtol=1e-12)
    for i, j in [(0, 0), (4, 30), (9, 59)]:
        assert grid[i, j] == pytest.approx(full_energy(10, i + 1.0, coefficients[j]), rel=1e-6)


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_certified_optimum_matches_the_sweep(small_sweep):
    _, sweep = small_sweep
    result = mj.optimise(design(n=10), certified(starts=4, iterations=40))
    assert result.result == mj.DesignResult.converged and result.stats["certified"]
    assert result.stats["rom_error"] <= 1e-4
    assert float(result.positions[0]) == int(result.positions[0])  # realisable: at a DOF
    # the optimum (continuous coefficient) is at least as good as the grid's best, and close
    assert result.value <= sweep.value * (1 + 1e-9)
    assert result.value == pytest.approx(sweep.value, rel=1e-3)
    assert result.value == pytest.approx(
        full_energy(10, float(result.positions[0]), float(result.coefficients[0])), rel=1e-6)
    assert result.stats["full_solves"] == 2  # one snapshot solve, one certification
    # one damper: every DOF screened (no relaxed search), and the sweep's best DOF chosen
    assert result.stats["relaxed_objective"] is None
    screen = [h for h in result.history if h["phase"] == "screen"]
    np.testing.assert_array_equal(screen[0]["positions"], np.arange(1.0, 11.0))
    assert float(result.positions[0]) == float(sweep.positions[0])


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_sweep_refinement_and_its_two_evaluators(small_sweep):
    _, sweep = small_sweep
    coarse = mj.optimise(design(n=10), mj.Grid(sweep.stats["coefficients"][::6], refine=2))
    assert len(coarse.stats["refined"]) == 2 and coarse.stats["seconds_refine"] > 0
    grid_best = float(np.nanmin(coarse.stats["grid"]))
    # refinement beats the coarse grid, reaches the fine grid's best, and is the full model's J
    assert coarse.value < grid_best
    assert coarse.value <= sweep.value * (1 + 1e-9)
    assert coarse.value == pytest.approx(sweep.value, rel=1e-3)
    assert coarse.value == pytest.approx(
        full_energy(10, float(coarse.positions[0]), float(coarse.coefficients[0])), rel=1e-6)
    # Dopri8 and the matrix exponentials agree; Auto() sends the stiff points (c / m_j large) to
    # the exact evaluator
    last = mj.DamperDesign(design(n=10).system, design(n=10).objective, positions=[10])
    ode = mj.optimise(last, mj.Grid([20.0, 50.0], method=mj.ODE(rtol=1e-10)))
    exact = mj.optimise(last, mj.Grid([20.0, 50.0], method=mj.DenseExponential()))
    spectral = mj.optimise(last, mj.Grid([20.0, 50.0], method=mj.Spectral()))
    np.testing.assert_allclose(ode.stats["grid"], exact.stats["grid"], rtol=1e-6)
    np.testing.assert_allclose(spectral.stats["grid"], exact.stats["grid"], rtol=1e-9)
    assert (ode.stats["exact"], exact.stats["exact"]) == (0, 2)
    assert 0 < sweep.stats["exact"] < sweep.stats["grid"].size


@pytest.mark.slow  # 14 s in CI
def test_split_designs_only_on_request():
    result = mj.optimise(design(), certified(starts=3, iterations=30, split=True))
    assert result.positions[0] == pytest.approx(result.stats["relaxed_positions"][0])
    assert result.value == pytest.approx(
        full_energy(N, float(result.positions[0]), float(result.coefficients[0])), rel=1e-6)


@pytest.mark.slow  # 62 s in CI; certification itself stays in the default run (above)
def test_certification_enriches_a_poor_basis_until_the_models_agree(capsys):
    p = problem(n=20, energy=0.9, criterion="squared")
    result = mj.optimise(design(n=20), certified(
        energy=0.9, criterion="squared", starts=2, iterations=10, tolerance=1e-6, max_rounds=6,
        progress=True))
    stats = result.stats
    assert stats["rounds"] >= 2 and stats["full_solves"] == 2 * stats["rounds"]
    assert any("enriched" in m for m in stats["messages"])
    # every phase says when it starts (no silent minutes): snapshots, screening, certification
    printed = capsys.readouterr().out
    for phase in ("snapshots at the start design", "POD basis: r =", "screening DOFs",
                  "certifying positions", "enriching the basis", "ROM error"):
        assert phase in printed, phase
    assert stats["certified"] and result.result == "converged", stats["status"]
    assert stats["rom_error"] <= 1e-6 and stats["gradient_error"] <= 1e-6
    first_rank = pod(mj.solve(p.system(p.positions, p.coefficients), p.ts, p.x0,
                                 method=mj.ODE()).displacement.T).rank_for_energy(0.9)
    assert stats["rank"] > first_rank


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_certification_by_the_estimate_takes_no_full_solve_and_never_under_estimates():
    settings = dict(energy=0.9, criterion="squared", starts=2, iterations=10, tolerance=1e-6,
                    max_rounds=6)
    result = mj.optimise(design(n=20), certified(**settings, certify="estimate"))
    stats = result.stats
    assert stats["certified"] and stats["certified_by"] == "estimate", stats["status"]
    # full solves: the first snapshots and one per enrichment, none to certify
    assert stats["full_solves"] == stats["rounds"]
    position, coefficient = float(result.positions[0]), float(result.coefficients[0])
    truth = full_energy(20, position, coefficient)
    error = abs(result.value - truth) / truth  # the objective reported is J_r
    assert error <= stats["rom_error"] <= 1e-6  # the estimate holds the true error
    # and the log-sensitivity's (the full dJ/dc by reverse mode through the exact J)
    slope = jax.grad(lambda c: mj.Energy(HORIZON, jnp.zeros(20).at[2].set(1.0))(
        mj.mikota_chain(20, dampers=[mj.GroundedDamper(position, c)])))(coefficient)
    true_gradient_error = coefficient * abs(float(stats["gradient"][0]) - float(slope)) / truth
    assert true_gradient_error <= stats["gradient_error"] <= 1e-6
    assert stats["ranking"] is not None
    full = mj.optimise(design(n=20), certified(**settings))
    assert float(full.positions[0]) == float(result.positions[0])


@pytest.mark.slow  # 28 s in CI
def test_two_dampers_are_placed_at_dofs():
    dampers = [mj.GroundedDamper(3.0, 0.5), mj.GroundedDamper(9.0, 0.5)]
    result = mj.optimise(design(dampers=dampers), certified(starts=3, iterations=20))
    assert result.positions.shape == (2,) and np.all(result.positions == np.round(result.positions))
    assert result.stats["certified"]
    assert result.value < result.stats["initial_objective"]


@pytest.mark.slow  # 22 s in CI; certification stays in the default run (the sweep test)
def test_average_energy_objective_is_certified():
    p = problem(objective="average_energy", lowest=3)
    objective = placement_objective(p, full_basis())
    truth = mj.AverageEnergy(lowest=3)(p.system(p.positions, p.coefficients))
    assert float(objective(p.positions, p.coefficients)) == pytest.approx(float(truth), rel=1e-8)
    result = mj.optimise(design(objective=mj.AverageEnergy(3)), certified(
        ts=p.ts, x0=p.x0, starts=2, iterations=15))
    assert result.stats["certified"] and np.isfinite(result.value)


@pytest.mark.parametrize("kwargs, match", [
    (dict(position=0.5), "position must lie in"),
    (dict(position=N + 1.0), "position must lie in"),
    (dict(coefficient=-1.0), "coefficient must be finite and >= 0"),
    (dict(objective="speed"), "objective must be one of"),
    (dict(objective="peak"), "needs dof"),
    (dict(energy=0.0), "energy must lie in"),
    (dict(snapshots=(5.0, 100.0)), "snapshots must be a window"),
])
def test_bad_problems_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        problem(**kwargs)


def test_no_excitation_is_refused():
    with pytest.raises(ValueError, match="needs an excitation"):
        DamperProblem(mj.mikota_chain(N, dampers=[mj.GroundedDamper(2.0, 1.0)]),
                         jnp.linspace(0.0, 1.0, 11))


@pytest.mark.parametrize("kwargs, match", [
    (dict(optimizer="sgd"), "optimizer must be an optax GradientTransformation"),
    (dict(iterations=0), "iterations must be an integer >= 1"),
    (dict(starts=np.array([[0.0]])), "starts must be an int or"),
    (dict(tolerance=-1.0), "tolerance must be > 0"),
    (dict(certify="half"), "certify must be 'full' or 'estimate'"),
    (dict(energy=0.0), "energy must lie in"),
    (dict(snapshots=(5.0, 100.0)), "snapshots must be a window"),
    (dict(ts=jnp.linspace(0.0, 2 * HORIZON, 11)), "ts must be a grid spanning"),
])
def test_bad_optimiser_settings_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        mj.optimise(design(), mj.ScreenAndCertify(**kwargs))
    average = design(objective=mj.AverageEnergy(3))
    with pytest.raises(ValueError, match="certify='estimate' needs the 'energy' objective"):
        mj.optimise(average, mj.ScreenAndCertify(ts=jnp.linspace(0.0, 1.0, 11),
                                                 x0=jnp.ones(N), certify="estimate"))
    with pytest.raises(ValueError, match="ts must be given"):
        mj.optimise(average, mj.ScreenAndCertify())
    with pytest.raises(ValueError, match="positions must be every DOF"):
        mj.optimise(mj.DamperDesign(average.system, average.objective, positions=[1, 2]),
                    mj.ScreenAndCertify())


@pytest.mark.parametrize("kwargs, match", [
    (dict(method="ode"), r"^mikota_jax: method must be Auto\(\), Spectral\(\), "
     r"DenseExponential\(\) or ODE\(...\), got 'ode'\.$"),
    (dict(method=mj.ODE(diffrax.Kvaerno5())), "integrates with Dopri8"),
    (dict(refine=-1), "refine must be an integer >= 0"),
    (dict(coefficients=[-1.0]), "coefficients must be a non-empty"),
])
def test_bad_sweep_settings_are_refused(kwargs, match):
    kwargs = dict(coefficients=[1.0]) | kwargs
    with pytest.raises(ValueError, match=match):
        mj.optimise(design(), mj.Grid(**kwargs))
    peak = design(objective=mj.Peak(3, jnp.linspace(0.0, 1.0, 11), jnp.ones(N)))
    for method in (mj.Spectral(), mj.DenseExponential(), mj.ODE()):
        with pytest.raises(ValueError, match=r"computes the Energy .*use method=Auto\(\)"):
            mj.optimise(peak, mj.Grid([1.0], method=method))
    with pytest.raises(ValueError, match="positions must be distinct integer DOFs"):
        mj.DamperDesign(peak.system, peak.objective, positions=[0])


def test_failing_solves_stop_with_a_reason_not_a_nan_optimum():
    p = problem(objective="peak", dof=N, max_steps=3)
    peak = design(objective=mj.Peak(N, p.ts, p.x0))
    with pytest.raises(ValueError, match="solve failed"):
        mj.optimise(peak, mj.ScreenAndCertify(max_steps=3, energy=1.0, starts=2, iterations=3))
    assert np.isnan(float(placement_objective(p)(p.positions, p.coefficients)))


@pytest.mark.slow  # 34 s in CI: a whole optimisation through the CLI
def test_cli_optimise_writes_json_and_plot(tmp_path):
    scene = tmp_path / "small.toml"
    scene.write_text(
        '[chain]\ntype = "mikota"\nn = 10\n[[damper]]\nposition = 5\ncoefficient = 1.0\n'
        '[initial]\ndisplacement = { 3 = 1.0 }\n[time]\nend = 8.0\nstep = 0.02\n'
        '[reduction]\nsnapshots = [0.0, 8.0]\nenergy = 1.0\n')
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-m", "mikota_jax", "optimise", str(scene), "--out", str(out),
         "--starts", "2", "--iterations", "8", "--no-progress"],
        capture_output=True, text=True, env=os.environ | {"MIKOTA_JAX_CACHE": "0"})
    assert done.returncode == 0, done.stderr
    report = json.loads((out / "placement.json").read_text())
    assert report["result"]["stats"]["certified"] and report["result"]["result"] == "converged"
    assert report["result"]["positions"][0] == int(report["result"]["positions"][0])
    assert (out / "placement.png").stat().st_size > 10_000
    bad = subprocess.run(
        [sys.executable, "-m", "mikota_jax", "optimise", str(scene), "--out", str(out),
         "--iterations", "0"], capture_output=True, text=True)
    assert bad.returncode == 2 and "iterations must be an integer" in bad.stderr
