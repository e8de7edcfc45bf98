"""``optimise(DamperDesign, strategy) -> Solution``: each strategy reproduces the optimum of the
function it replaced (``optimise_viscosities``, ``place_dampers``, ``sweep_dampers``,
``optimise_dampers``), the Solution's fields, and the one-line refusals.

The reference numbers were printed by those functions (main before the verb, float64, CPU) on the
same problems: the algorithms are the same code, so the values agree to the last digits (1e-12
relative leaves room for a different BLAS)."""

import jax.numpy as jnp
import numpy as np
import optax
import pytest

import mikota_jax as mj

N = 12


def chain(positions, relative=None):
    dampers = [mj.GroundedDamper(float(p), 1.0) for p in positions]
    if relative:
        dampers.append(mj.RelativeDamper(relative, 0.5))
    return mj.mikota_chain(N, dampers=dampers)


@pytest.mark.slow  # ~50 s; the verb's default-run test is in test_viscosity (CI under 15 min)
def test_coefficients_reproduce_optimise_viscosities(close):
    solution = mj.optimise(mj.DamperDesign(chain([2, 5], (4, 9)), mj.AverageEnergy(4)),
                           mj.Coefficients())
    close(solution.value, 11.254138621062154, rtol=1e-12)
    close(solution.coefficients, [3.5611162142379045, 2.2318404478837484, 0.682676706102425],
          rtol=1e-9)
    assert (solution.stats["iterations"], solution.stats["evaluations"]) == (7, 8)
    assert solution.result is mj.DesignResult.converged and solution.result == "converged"
    # the Solution's fields: the optimised system holds the coefficients reported
    assert isinstance(solution.system, mj.SecondOrderSystem)
    assert solution.positions.tolist() == [2.0, 5.0] and solution.pairs.tolist() == [[4, 9]]
    close(np.asarray(solution.system.damping.coefficients), solution.coefficients[:2], rtol=0)
    close(float(mj.AverageEnergy(4)(solution.system)), solution.value, rtol=1e-9)
    assert solution.history[0][0] > solution.value
    assert {"evaluations", "full_solves", "seconds", "status"} <= set(solution.stats)
    assert solution.to_json()["result"] == "converged"


def test_coefficients_by_spg_reproduce_the_energy_optimum(close):
    design = mj.DamperDesign(chain([2, 5]), mj.Energy(20.0, np.eye(N)[2]))
    solution = mj.optimise(design, mj.Coefficients(mj.SpectralProjectedGradient()))
    close(solution.value, 26.993813951456765, rtol=1e-12)
    close(solution.coefficients, [4.328139201129726, 5.5293265060916905], rtol=1e-9)
    assert (solution.stats["iterations"], solution.stats["evaluations"]) == (8, 9)


@pytest.mark.slow  # ~70 s; the verb's default-run test is in test_damper_search (CI time)
def test_coordinate_descent_reproduces_place_dampers(close):
    design = mj.DamperDesign(chain([2, 3]), mj.AverageEnergy(4), positions=[1, 2, 3, 4, 5, 6])
    solution = mj.optimise(design, mj.CoordinateDescent())
    close(solution.value, 16.920569040305768, rtol=1e-12)
    assert solution.positions.tolist() == [5.0, 2.0]
    close(solution.coefficients, [1.4952645339931923, 4.169796972808113], rtol=1e-9)
    stats = solution.stats
    assert (stats["sweeps"], stats["evaluations"], stats["polishes"]) == (3, 108, 13)
    assert solution.result == "converged"
    close(float(mj.AverageEnergy(4)(solution.system)), solution.value, rtol=1e-9)


@pytest.fixture(scope="module")
def one_damper():
    x0 = jnp.zeros(N).at[2].set(1.0)
    system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(2.0, 1.0)])
    return mj.DamperDesign(system, mj.Energy(20.0, x0), positions=range(1, N + 1))


@pytest.mark.slow  # ~40 s: a full-order sweep with refinement
def test_grid_reproduces_sweep_dampers(one_damper, close):
    solution = mj.optimise(one_damper, mj.Grid(np.geomspace(0.1, 30, 7), refine=1))
    close(solution.value, 23.06585265312676, rtol=1e-12)
    assert solution.positions.tolist() == [3.0]
    close(solution.coefficients, [2.4222970945580102], rtol=1e-12)
    assert solution.stats["grid"].shape == (12, 7)


@pytest.mark.slow  # ~60 s: snapshots, screen, polish, certification
@pytest.mark.parametrize("optimizer", [None, optax.adam(0.1)])
def test_screen_and_certify_reproduces_optimise_dampers(one_damper, optimizer, close):
    solution = mj.optimise(one_damper, mj.ScreenAndCertify(
        ts=jnp.linspace(0.0, 20.0, 401), starts=2, iterations=10, optimizer=optimizer))
    close(solution.value, 23.065852628522517, rtol=1e-12)
    assert solution.positions.tolist() == [3.0]
    close(solution.coefficients, [2.4221823327035237], rtol=1e-9)
    stats = solution.stats
    assert (stats["rounds"], stats["full_solves"], stats["rank"]) == (1, 2, 12)
    assert stats["basis"].shape == (N, 12) and stats["rom_error"] <= 1e-4
    assert solution.result == "converged"


def test_wrong_objectives_strategies_and_bounds_are_one_line_errors():
    system = chain([2, 5])
    one_line = r"^mikota_jax: [^\n]*$"
    with pytest.raises(ValueError, match=r"^mikota_jax: objective must be an AbstractObjective"):
        mj.DamperDesign(system, "average_energy")
    with pytest.raises(ValueError, match=one_line) as error:
        mj.DamperDesign(system, mj.AverageEnergy(), coefficients=(1.0, 0.5))
    assert "lower" in str(error.value) and "upper" in str(error.value)
    with pytest.raises(ValueError, match=r"^mikota_jax: coefficients must be the bounds"):
        mj.DamperDesign(system, mj.AverageEnergy(), coefficients=1.0)
    with pytest.raises(ValueError, match=r"^mikota_jax: strategy must be an "):
        mj.optimise(mj.DamperDesign(system, mj.AverageEnergy()), "bfgs")
    with pytest.raises(ValueError, match=r"^mikota_jax: problem must be a DamperDesign"):
        mj.optimise(system, mj.Coefficients())
    for strategy in (mj.Coefficients, mj.CoordinateDescent):
        with pytest.raises(ValueError, match=r"^mikota_jax: minimiser must be ProjectedBFGS"):
            strategy(minimiser="bfgs")
    with pytest.raises(ValueError, match=r"^mikota_jax: method must be Auto\(\), Spectral"):
        mj.Grid([1.0], method="exact")
    with pytest.raises(ValueError, match=r"^mikota_jax: optimizer must be an optax "):
        mj.ScreenAndCertify(optimizer="adam")
    # an objective the full-order path does not evaluate, and one the ROM strategies do not
    with pytest.raises(ValueError, match=r"^mikota_jax: objective must be Energy, AverageEnergy "
                       r"or Peak for Grid, got H2Norm\.$"):
        mj.optimise(mj.DamperDesign(chain([2]), mj.H2Norm(np.eye(N)[:, :1]), positions=[1, 2]),
                    mj.Grid([1.0]))
