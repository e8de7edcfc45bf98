"""Optimal viscosities at full order (``optimise`` with ``Coefficients``): a grounded and a
relative damper on a small chain, checked against scipy's L-BFGS-B on the same function, a grid
around the optimum, the first-order conditions at a bound, and the refusals."""

import warnings

import jax
import numpy as np
import pytest
import scipy.linalg as sl
import scipy.optimize
from _helpers import lyapunov_trace

import mikota_jax as mj
from mikota_jax.testing import criterion_function

N, LOWEST = 12, 5


def coefficients(system, objective=None, *, free=None, lower=0.0, upper=None, **strategy):
    """``optimise`` with ``Coefficients``: every coefficient of ``system`` (or the ``free``
    ones) within (``lower``, ``upper``), its places fixed; the total average energy by
    default."""
    objective = mj.AverageEnergy() if objective is None else objective
    design = mj.DamperDesign(system, objective, coefficients=(lower, upper), free=free)
    return mj.optimise(design, mj.Coefficients(**strategy))


def two_dampers(grounded=4.0, relative=1.0):
    return mj.mikota_chain(N, dampers=[mj.GroundedDamper(4.0, grounded),
                                       mj.RelativeDamper((2, 9), relative)],
                           internal_damping=mj.ModalDamping(0.02))


@pytest.fixture(scope="module")
def optimum():
    return coefficients(two_dampers(), mj.AverageEnergy(LOWEST))


@pytest.fixture(scope="module")
def criterion():
    function = criterion_function(two_dampers(), mj.AverageEnergy(LOWEST))
    return lambda d: tuple(np.asarray(a, dtype=float) for a in function(np.asarray(d)))


@pytest.mark.slow
def test_the_optimum_of_a_grounded_and_a_relative_damper_is_scipys_and_the_grids(
        optimum, criterion, close):
    assert optimum.result == "converged", optimum.stats["status"]
    assert optimum.stats["relative_gradient"] < 1e-6
    assert np.all(optimum.coefficients > 0)
    # an independent search on the same function: scipy's L-BFGS-B from another start
    reference = scipy.optimize.minimize(criterion, np.array([0.5, 0.5]), jac=True,
                                        method="L-BFGS-B", bounds=[(0, None)] * 2,
                                        options=dict(ftol=1e-15, gtol=1e-12, maxiter=500))
    close(optimum.value, reference.fun, rtol=1e-10)
    assert optimum.value <= reference.fun * (1 + 1e-12)
    close(optimum.coefficients, reference.x, rtol=1e-4)
    # no point of a grid around the optimum is lower (the trace is smooth: a local optimum)
    grid = optimum.coefficients * np.stack(np.meshgrid([0.9, 1.0, 1.1], [0.9, 1.0, 1.1]),
                                           axis=-1).reshape(-1, 2)
    assert min(float(criterion(d)[0]) for d in grid) >= optimum.value * (1 - 1e-13)
    # the reported value and gradient are the function's there. The search started each
    # design's roots at the previous design's (a warm start), the function on the arcs: the same
    # roots to rounding, so the gradient agrees to the rounding of its terms, f / d_i in size
    # (compared as relative gradients d_i df/dd_i / f, what the stopping rule measures)
    value, gradient = criterion(optimum.coefficients)
    close(optimum.value, value, rtol=1e-14)
    scale = optimum.coefficients / value
    close(optimum.stats["gradient"] * scale, gradient * scale, atol=1e-13)
    assert optimum.history[0][0] > optimum.value  # it went downhill from the start


def test_an_upper_bound_holds_its_damper_with_the_gradient_pushing_out(optimum, criterion):
    cap = 0.5 * optimum.coefficients[0]
    bounded = coefficients(two_dampers(), mj.AverageEnergy(LOWEST),
                                      upper=[cap, np.inf])
    assert bounded.result == "converged", bounded.stats["status"]
    # KKT at the upper bound
    assert bounded.coefficients[0] == cap and bounded.stats["gradient"][0] < 0
    assert bounded.value > optimum.value
    # the free one is optimal given the held one: its own derivative vanishes
    assert abs(bounded.stats["gradient"][1] * bounded.coefficients[1]) < 1e-6 * bounded.value
    fixed = coefficients(two_dampers(relative=0.7), mj.AverageEnergy(LOWEST),
                                    free=[0])
    assert fixed.coefficients[1] == 0.7 and fixed.result == "converged"


def dof_2_and_5(c2=1.0, c5=1.0):
    return mj.mikota_chain(6, dampers=[mj.GroundedDamper(2.0, c2), mj.GroundedDamper(5.0, c5)])


@pytest.mark.parametrize("minimiser", [  # SPG under -m slow: test_design_verb runs it by default
    mj.ProjectedBFGS(), pytest.param(mj.SpectralProjectedGradient(), marks=pytest.mark.slow)],
    ids=["bfgs", "spg"])
def test_a_damper_pinned_at_zero_is_fixed_and_the_other_reaches_its_lone_optimum(minimiser,
                                                                                 close):
    # the truth: the DOF-5 damper alone, its trace by scipy's dense Bartels-Stewart (refined;
    # ~1e-14 relative) minimised in log c by Brent's method (c to ~1e-7)
    lone = lambda logc: lyapunov_trace(mj.mikota_chain(  # noqa: E731
        6, dampers=[mj.GroundedDamper(5.0, float(np.exp(logc)))]))
    truth = scipy.optimize.minimize_scalar(lone, bracket=(-2.0, 0.0, 2.0), tol=1e-12)
    assert round(float(np.exp(truth.x)), 3) == 0.826 and round(truth.fun, 3) == 59.647
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no log(0) of the pinned coefficient
        pinned = coefficients(dof_2_and_5(), upper=[0.0, 10.0], minimiser=minimiser)
    assert pinned.result == "converged", pinned.stats["status"]
    assert pinned.coefficients[0] == 0.0 and pinned.stats["iterations"] > 0
    close(pinned.coefficients[1], np.exp(truth.x), rtol=1e-5)
    close(pinned.value, truth.fun, rtol=1e-11)
    # lower = upper > 0 pins too; pinning every free one leaves nothing to move
    held = coefficients(dof_2_and_5(c5=3.0), lower=[0.5, 0.0], upper=[0.5, 10.0],
                                   minimiser=minimiser)
    assert held.result == "converged" and held.coefficients[0] == 0.5
    nothing = coefficients(dof_2_and_5(), free=[1], upper=[np.inf, 2.0],
                                      lower=[0.0, 2.0], minimiser=minimiser)
    assert nothing.result == "converged" and nothing.stats["iterations"] == 0
    assert "pinned" in nothing.stats["status"]
    assert nothing.coefficients.tolist() == [1.0, 2.0]


@pytest.mark.slow
def test_a_damper_pinned_at_zero_that_leaves_a_mode_undamped_is_one_line_not_an_optimum():
    # Mikota's n = 4 chain: DOF 3 is a node of mode 2, so with the DOF-1 damper pinned at 0 mode
    # 2 is undamped and the trace infinite: no finite optimum may be reported
    system = mj.mikota_chain(4, dampers=[mj.GroundedDamper(1.0, 1.0), mj.GroundedDamper(3.0, 1.0)])
    with pytest.raises(ValueError, match=r"^mikota_jax: the criterion is not finite at the "
                       r"start design \(inf\); a mode no damper reaches \(a coefficient held "
                       r"at 0 reaches none\)[^\n]*\.$"):
        coefficients(system, upper=[0.0, 10.0])


def test_the_spectral_projected_gradient_reaches_the_same_optimum_and_bound(optimum):
    # Li & Tisseur's method (SPG): the optimum of the projected BFGS, and the KKT point at a cap
    spg_ = mj.SpectralProjectedGradient()
    spg = coefficients(two_dampers(), mj.AverageEnergy(LOWEST), minimiser=spg_)
    assert spg.result == "converged", spg.stats["status"]
    assert spg.stats["relative_gradient"] < 1e-6
    assert spg.value == pytest.approx(optimum.value, rel=1e-10)
    np.testing.assert_allclose(spg.coefficients, optimum.coefficients, rtol=1e-4)
    cap = 0.5 * optimum.coefficients[0]
    bounded = coefficients(two_dampers(), mj.AverageEnergy(LOWEST),
                                      upper=[cap, np.inf], minimiser=spg_)
    assert bounded.result == "converged" and bounded.coefficients[0] == cap
    assert bounded.stats["gradient"][0] < 0


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_the_energy_of_a_free_vibration_is_optimised_in_one_coefficient(close):
    system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(5.0, 1.0)])
    x0 = np.eye(N)[2]
    result = coefficients(system, mj.Energy(20.0, x0))
    assert result.result == "converged", result.stats["status"]
    energy = criterion_function(system, mj.Energy(20.0, jax.numpy.asarray(x0)))
    c = result.coefficients
    value, gradient = energy(c)
    close(value, result.value, rtol=1e-14)
    close(gradient, 0.0, atol=1e-6 * result.value / c[0])
    # against central differences of the value: the gradient the search used is the function's
    h = 1e-4 * c[0]
    close(gradient[0], (energy(c + h)[0] - energy(c - h)[0]) / (2 * h), atol=1e-6 * value / c[0])
    for factor in (0.98, 1.02):  # a minimum along the only direction
        assert float(energy(c * factor)[0]) > result.value


@pytest.mark.parametrize("kwargs,match", [
    (dict(objective="maximum"), r"^mikota_jax: objective must be an AbstractObjective"),
    (dict(objective=mj.H2Norm(None, cx=[1.0] * 12)), "inputs must be"),
    (dict(objective=mj.OutputEnergy()), "give an output"),
    (dict(objective=mj.AverageEnergy(0)), "lowest must be None or an integer"),
    (dict(free=[5]), r"^mikota_jax: free must be 0-based indices in 0..1 into the 2 damper "
     r"coefficients, grounded dampers first, then relative ones, got \[5\]\.$"),
    (dict(free=[-1]), r"free must be 0-based indices in 0..1 .*, got \[-1\]\.$"),
    (dict(free=[0, 0]), r"free must not repeat an index \(0-based indices in 0..1 .*\[0, 0\]"),
    (dict(free=[]), r"free must name at least one coefficient .*; None frees all\.$"),
    (dict(free=[0.5]), r"free must be integers, got \[0.5\]"),
    (dict(lower=-1.0), "0 <= lower <= upper"),
    (dict(lower=np.inf), r"^mikota_jax: lower must be finite, got inf\.$"),
    (dict(upper=[1.0, -1.0]), "0 <= lower <= upper"),
    (dict(lower=[0.0, 0.0, 0.0]), r"^mikota_jax: lower must be a number or 2 numbers \(one per "
     r"damper coefficient: grounded dampers first, then relative ones\), got \[0.0, 0.0, 0.0\]\.$"),
    (dict(upper=[1.0]), r"upper must be a number or 2 numbers .*, got \[1.0\]\.$"),
    (dict(upper="big"), r"upper must be a number or 2 numbers"),
    (dict(tolerance=0.0), "tolerance must lie in"),
    (dict(minimiser="spg"), r"^mikota_jax: minimiser must be ProjectedBFGS\(\) or "
     r"SpectralProjectedGradient\(\), got 'spg'\.$"),
    (dict(objective=mj.Energy(None)), "horizon must be a finite time > 0"),
    (dict(objective=mj.Energy(1.0)), "needs an excitation"),
    (dict(objective=mj.Energy(1.0, np.ones(N), load=mj.pulse(N, 1, 1.0, 0.1))),
     "free vibration only")])
def test_bad_arguments_are_refused_by_name(kwargs, match):
    with pytest.raises(ValueError, match=match):
        coefficients(two_dampers(), **kwargs)


def test_a_system_without_the_spectral_path_is_refused():
    with pytest.raises(ValueError, match="GroundedDamper/RelativeDamper"):
        coefficients(mj.mikota_chain(N))


def triple_chain(n1, d, internal=0.02):
    """Truhar & Veselic's triple chain (SIAM J. Matrix Anal. Appl. 31:18, 2009): three rows of
    n1 masses 1, 2, 3 with springs 10, 20, 1, each grounded at its outer end and joined to
    m_0 = 10, grounded by k_0 = 50; n = 3 n1 + 1; dampers at DOFs 1, n1 and 2 n1 + 1; modal
    internal damping 2 %."""
    ones = np.ones(n1)
    return mj.branched_chain(
        [ones, 2 * ones, 3 * ones], [10 * np.ones(n1 + 1), 20 * np.ones(n1 + 1), np.ones(n1 + 1)],
        10.0, 50.0, dampers=[mj.GroundedDamper(1, d[0]), mj.GroundedDamper(n1, d[1]),
                             mj.GroundedDamper(2 * n1 + 1, d[2])],
        internal_damping=mj.ModalDamping(internal))


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_truhar_veselic_triple_chain_optimum_is_the_dense_lyapunov_optimum(close):
    n1, lowest, start = 8, 8, np.array([100.0, 100.0, 100.0])
    result = coefficients(triple_chain(n1, start), mj.AverageEnergy(lowest))
    assert result.result == "converged", result.stats["status"]
    assert result.stats["relative_gradient"] < 1e-6
    # independent: scipy's dense Lyapunov trace (its own eigh, Bartels-Stewart) minimised by
    # L-BFGS-B in log d with finite differences, from the same start
    dense = lambda logd: lyapunov_trace(triple_chain(n1, np.exp(logd)), lowest)  # noqa: E731
    reference = scipy.optimize.minimize(dense, np.log(start), method="L-BFGS-B",
                                        options=dict(ftol=1e-14, gtol=1e-10, maxiter=200))
    close(result.value, reference.fun, rtol=1e-8)
    close(result.coefficients, np.exp(reference.x), rtol=2e-3)
    close(result.value, lyapunov_trace(triple_chain(n1, result.coefficients), lowest), rtol=1e-9)
    assert result.value < dense(np.log(start))


@pytest.mark.slow
def test_the_smooth_peak_optimum_is_the_dense_exponentials_optimum(close):
    n, dof, ts = 8, 8, np.linspace(0.0, 10.0, 201)
    x0 = np.zeros(n)
    x0[dof - 1] = 1.0  # the damper two DOFs away: neither a weak nor a rigid one is best

    def system(d):
        return mj.mikota_chain(n, dampers=[mj.GroundedDamper(6, d)])

    def dense_peak(d):  # scipy's expm on the first-order form at every time of the grid
        m, damping, k = (np.asarray(a) for a in system(d).dense())
        minv = np.diag(1 / np.diag(m))
        a = np.block([[np.zeros((n, n)), np.eye(n)], [-minv @ k, -minv @ damping]])
        z0 = np.concatenate([x0, np.zeros(n)])
        x = np.array([(sl.expm(a * t) @ z0)[dof - 1] for t in ts])
        scale = np.max(np.abs(x))
        return scale * np.mean((x / scale) ** 16) ** (1 / 16)

    # the minimum is flat (f'' / f ~ 5e-4 in log d): the default stopping rule (relative
    # gradient 1e-6) leaves f up to ~1e-9 above it, so compare at a tighter one
    result = coefficients(system(1.0), mj.Peak(dof, ts, x0), tolerance=1e-8)
    assert result.result == "converged", result.stats["status"]
    close(result.value, dense_peak(result.coefficients[0]), rtol=1e-10)
    reference = scipy.optimize.minimize_scalar(lambda u: dense_peak(np.exp(u)),
                                               bounds=(np.log(1e-2), np.log(1e3)),
                                               method="bounded", options=dict(xatol=1e-9))
    close(result.value, reference.fun, rtol=1e-9)
    assert result.value <= reference.fun * (1 + 1e-10)
    # the minimum is flat (f changes by < 1e-9 over 0.2 % in d): the place to a looser tolerance
    close(result.coefficients[0], np.exp(reference.x), rtol=1e-2)
    with pytest.raises(ValueError, match="dof must be an integer DOF in 1..8"):
        coefficients(system(1.0), mj.Peak(9, ts, x0))
    with pytest.raises(ValueError, match="ts must be an increasing grid"):
        coefficients(system(1.0), mj.Peak(dof, ts[::-1], x0))
