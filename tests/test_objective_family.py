"""The objectives family against closed forms of one mass (m = k = 1, grounded damper c:
x'' + c x' + x = 0), where every objective is known exactly:

* the Lyapunov solution of A = [[0, 1], [-1, -c]] with A^T X + X A = -I has trace 2 / c + c / 2;
* with -C^T C, C = (1, 0): P = [[1 / (2c) + c / 2, 1 / 2], [1 / 2, 1 / (2c)]], so int_0^inf x^2 dt
  is P_11 from x0 = 1 and ||G||_H2^2 = P_22 for G(s) = 1 / (s^2 + c s + 1);
* the energy on [0, T] by mpmath quadrature of the analytic x(t) at 30 digits.
"""

import functools

import diffrax
import jax
import jax.numpy as jnp
import mpmath as mp
import numpy as np
import pytest

import mikota_jax as mj

C = 0.7
T = 10.0


def one_mass(c=C):
    return mj.chain(np.ones(1), np.ones(1), [mj.GroundedDamper(1.0, c)])


def displacement(t, c=C, lib=np):
    """x(t) from x0 = 1, v0 = 0, underdamped (c < 2)."""
    zeta, omega = c / 2, lib.sqrt(1 - c**2 / 4)
    return lib.exp(-zeta * t) * (lib.cos(omega * t) + zeta / omega * lib.sin(omega * t))


def test_energy_is_the_quadrature_of_the_analytic_response():
    mp.mp.dps = 30
    c = mp.mpf(C)

    def integrand(t):
        x = displacement(t, c, mp)
        v = mp.diff(lambda s: displacement(s, c, mp), t)
        return (x**2 + v**2) / 2

    truth = float(mp.quad(integrand, [0, 2, 5, T]))  # ~1e-25: quadrature at 30 digits
    value = mj.Energy(T, x0=jnp.ones(1))(one_mass())
    assert float(value) == pytest.approx(truth, rel=1e-12)


def test_average_energy_and_its_derivative_are_the_closed_forms():
    objective = mj.AverageEnergy()
    value, slope = jax.value_and_grad(lambda c: objective(one_mass(c)))(C)
    assert float(value) == pytest.approx(2 / C + C / 2, rel=1e-12)
    assert float(slope) == pytest.approx(-2 / C**2 + 0.5, rel=1e-10)


def test_output_energy_and_h2_norm_are_the_closed_forms():
    first = jnp.ones((1, 1))
    out = mj.OutputEnergy(cx=first, x0=jnp.ones(1))(one_mass())
    assert float(out) == pytest.approx(1 / (2 * C) + C / 2, rel=1e-12)
    h2 = mj.H2Norm(jnp.ones(1), cx=first)(one_mass())
    assert float(h2) == pytest.approx(np.sqrt(1 / (2 * C)), rel=1e-12)


def test_peak_is_the_smooth_peak_of_the_exact_response():
    ts = jnp.linspace(0.0, T, 201)
    truth = np.mean(np.abs(displacement(np.asarray(ts))) ** 16) ** (1 / 16)  # float64, ~1e-16
    value = mj.Peak(1, ts, x0=jnp.ones(1))(one_mass())
    assert float(value) == pytest.approx(truth, rel=1e-12)


@pytest.mark.slow
def test_objectives_take_reduced_models_and_pass_through_vmap():
    # a Galerkin model on all modes is the full model: the same J to rounding
    system = mj.mikota_chain(6, dampers=[mj.GroundedDamper(2.0, 0.8)])
    energy = mj.Energy(5.0, x0=mj.unit_vector(6, 3))
    rom = mj.reduce(system, mj.Modal(6))
    assert float(energy(rom)) == pytest.approx(float(energy(system)), rel=1e-10)
    values = jax.vmap(lambda c: mj.AverageEnergy()(one_mass(c)))(jnp.array([0.5, 1.0, 2.0]))
    np.testing.assert_allclose(values, [2 / c + c / 2 for c in (0.5, 1.0, 2.0)], rtol=1e-12)


def test_a_user_objective_subclasses_the_abstract_one():
    class Stiffest(mj.AbstractObjective):
        def __call__(self, model):
            return jnp.max(mj.modal_decomposition(model)[0])

    assert float(Stiffest()(one_mass())) == pytest.approx(1.0, rel=1e-14)


@functools.lru_cache
def quadrature_energy(c=C):
    """J on [0, T] from x0 = 1 by mpmath quadrature of the analytic x(t) at 30 digits (~1e-25)."""
    mp.mp.dps = 30
    c = mp.mpf(c)

    def integrand(t):
        x = displacement(t, c, mp)
        v = mp.diff(lambda s: displacement(s, c, mp), t)
        return (x**2 + v**2) / 2

    return float(mp.quad(integrand, [0, 2, 5, T]))


@pytest.mark.parametrize(("method", "rel"), [(mj.Auto(), 1e-12), (mj.Spectral(), 1e-12),
                                             (mj.DenseExponential(), 1e-10)],
                         ids=["auto", "spectral", "dense"])
def test_energy_takes_the_exact_methods_of_solve(method, rel):
    # truth: the quadrature (~1e-25); the damped modes hold it to rounding, Van Loan's doubling
    # to 3e-12 (measured)
    value = mj.Energy(T, x0=jnp.ones(1), method=method)(one_mass())
    assert float(value) == pytest.approx(quadrature_energy(), rel=rel)


def test_energy_by_ode_takes_its_tolerances():
    # Dopri8 with the energy as one more state: rtol 1e-9, atol 1e-11 (the old "ode") to ~1e-7;
    # ODE()'s own rtol 1e-8 (atol None: 1e-11) to ~1e-6
    truth = quadrature_energy()
    tight = mj.Energy(T, x0=jnp.ones(1), method=mj.ODE(rtol=1e-9, atol=1e-11))(one_mass())
    assert float(tight) == pytest.approx(truth, rel=1e-7)
    default = mj.Energy(T, x0=jnp.ones(1), method=mj.ODE())(one_mass())
    assert float(default) == pytest.approx(truth, rel=1e-6)


@pytest.mark.slow  # ~50 s of compiles (default-run time: CI under 15 min)
def test_energy_with_a_method_object_passes_through_jit_vmap_and_grad():
    # truths: the quadrature (~1e-25) and its central difference in c (h = 1e-5: ~1e-9 relative)
    for method in (mj.Spectral(), mj.DenseExponential(), mj.ODE(rtol=1e-9, atol=1e-11)):
        energy = mj.Energy(T, x0=jnp.ones(1), method=method)
        value, slope = jax.jit(jax.value_and_grad(lambda c, e=energy: e(one_mass(c))))(C)
        assert float(value) == pytest.approx(quadrature_energy(), rel=1e-7)
        h = 1e-5
        central = (quadrature_energy(C + h) - quadrature_energy(C - h)) / (2 * h)
        assert float(slope) == pytest.approx(central, rel=1e-6)
    values = jax.vmap(lambda c: mj.Energy(T, x0=jnp.ones(1), method=mj.Spectral())(one_mass(c)))(
        jnp.array([0.5, C]))
    assert float(values[1]) == pytest.approx(quadrature_energy(), rel=1e-12)


@pytest.mark.parametrize(("method", "rel"), [(mj.Auto(), 1e-13), (mj.Spectral(), 1e-13),
                                             (mj.DenseExponential(), 1e-10)],
                         ids=["auto", "spectral", "dense"])
def test_average_energy_takes_the_exact_methods_of_solve(method, rel):
    # one mass, m = k = 1: trace X = c / 2 + 2 / c exactly
    value = mj.AverageEnergy(method=method)(one_mass())
    assert float(value) == pytest.approx(C / 2 + 2 / C, rel=rel)


@pytest.mark.parametrize("method", ["dense", mj.ODE()], ids=["string", "ode"])
def test_average_energy_refuses_other_methods_in_one_line(method):
    with pytest.raises(ValueError, match="AverageEnergy's method must be") as info:
        mj.AverageEnergy(method=method)(one_mass())
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(("objective", "says"), [
    (mj.Energy(T, x0=jnp.ones(1), method=mj.ODE()), "no ODE"),
    (mj.Peak(1, np.linspace(0.0, T, 11), x0=jnp.ones(1), method=mj.DenseExponential()),
     "Auto\\(\\) or Spectral\\(\\)"),
    (mj.Peak(1, np.linspace(0.0, T, 11), x0=jnp.ones(1), method=mj.ODE()),
     "Auto\\(\\) or Spectral\\(\\)"),
], ids=["energy by ode", "peak by dense", "peak by ode"])
def test_a_full_order_search_refuses_a_method_it_would_not_use_in_one_line(objective, says):
    # it used to drop the method and search on the damped modes
    with pytest.raises(ValueError, match=says) as info:
        mj.optimise(mj.DamperDesign(one_mass(), objective), mj.Coefficients())
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("method", ["exact", mj.ODE(diffrax.Kvaerno5()), None],
                         ids=["string", "kvaerno5", "none"])
def test_energy_refuses_other_methods_in_one_line(method):
    with pytest.raises(ValueError, match="method") as info:
        mj.Energy(T, x0=jnp.ones(1), method=method)(one_mass())
    assert "\n" not in str(info.value)
