"""``solve`` and its methods: every method against an analytic solution, ``Auto().select`` for
every kind of system, load and grid, and the refusals."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj

TS = jnp.linspace(0.0, 10.0, 41)


def one_dof(c=0.5):
    """m = k = 1 with a grounded damper c: x'' + c x' + x = 0."""
    return mj.chain(np.ones(1), np.ones(1), [mj.GroundedDamper(1.0, c)])


def one_dof_truth(ts, c=0.5):
    """x(t) from x0 = 1, v0 = 0, underdamped (c < 2): exact, evaluated in float64 (~1e-16)."""
    zeta, omega = c / 2, np.sqrt(1 - c**2 / 4)
    ts = np.asarray(ts)
    return np.exp(-zeta * ts) * (np.cos(omega * ts) + zeta / omega * np.sin(omega * ts))


@pytest.mark.parametrize("method, rtol", [
    (mj.Auto(), 1e-12), (mj.Spectral(), 1e-12), (mj.DenseExponential(), 1e-12),
    (mj.ODE(rtol=1e-11), 1e-8), (mj.ODE(mj.StructuredKvaerno5(), rtol=1e-10), 1e-5)])
def test_every_method_gives_the_analytic_one_dof_response(method, rtol):
    trajectory = mj.solve(one_dof(), TS, jnp.ones(1), method=method)
    np.testing.assert_allclose(trajectory.displacement[:, 0], one_dof_truth(TS), rtol=rtol,
                               atol=rtol * 1e-2)


def test_the_methods_agree_on_mikotas_chain_with_a_damper_and_a_pulse():
    # truth: the dense matrix exponential (exact up to rounding); the others to their accuracy
    system = mj.mikota_chain(8, dampers=[mj.GroundedDamper(3.0, 1.0)])
    load = mj.pulse(8, 1, amplitude=1.0, duration=0.05)
    dense = mj.solve(system, TS, load=load, method=mj.DenseExponential(), velocity=True)
    spectral = mj.solve(system, TS, load=load, method=mj.Spectral(), velocity=True)
    ode = mj.solve(system, TS, load=load, method=mj.ODE(rtol=1e-11), velocity=True)
    scale = np.max(np.abs(dense.displacement))
    np.testing.assert_allclose(spectral.displacement, dense.displacement, atol=1e-12 * scale)
    np.testing.assert_allclose(ode.displacement, dense.displacement, atol=1e-8 * scale)
    assert ode.num_steps is not None and spectral.num_steps is None


def test_auto_selects_from_the_structure_for_every_kind_of_system():
    chain = mj.mikota_chain(8, dampers=[mj.GroundedDamper(3.0, 1.0)])
    m, d, k = (np.asarray(a) for a in chain.dense())
    select = mj.Auto().select
    # discrete dampers, no load or a pulse: the damped modes
    assert select(chain, TS) == mj.Spectral()
    assert select(chain, TS, mj.pulse(8, 2)) == mj.Spectral()
    assert select(mj.mikota_chain(8, dampers=[mj.GroundedDamper(3.0, 1e6)]), TS) == mj.Spectral()
    # anything else integrates: a general load, no dampers, internal damping alone, a user's
    # damping matrix, a reduced model
    assert select(chain, TS, lambda t: jnp.zeros(8)) == mj.ODE()
    assert select(mj.mikota_chain(8), TS) == mj.ODE()
    assert select(mj.mikota_chain(8, internal_damping=mj.Rayleigh(0.01, 0.001)), TS) == mj.ODE()
    assert select(mj.system(m, k, d), TS) == mj.ODE()
    assert select(mj.reduce(chain, mj.Modal(4)), TS) == mj.ODE()
    # stiff: rho T above 1e5 (rho >= n sqrt(k/m) = 2000 for Mikota's chain, T = 100)
    stiff = select(mj.mikota_chain(2000), jnp.linspace(0.0, 100.0, 3))
    assert isinstance(stiff, mj.ODE) and isinstance(stiff.solver, mj.StructuredKvaerno5)
    assert isinstance(select(mj.mikota_chain(2000), jnp.linspace(0.0, 10.0, 3)).solver,
                      diffrax.Dopri8)


def test_auto_runs_the_same_method_under_jit():
    # the spectral choice is structural, so it holds for traced values; the value is the eager one
    x0 = jnp.zeros(8).at[2].set(1.0)

    def last(c):
        system = mj.mikota_chain(8, dampers=[mj.GroundedDamper(3.0, c)])
        return mj.solve(system, TS, x0).displacement[-1, 2]

    assert float(jax.jit(last)(1.0)) == pytest.approx(float(last(1.0)), rel=1e-13)
    # the integrators' stiffness rule needs values: under jit it refuses, naming the way out
    with pytest.raises(ValueError, match="name the method"):
        jax.jit(lambda c: mj.solve(mj.mikota_chain(8, internal_damping=mj.Rayleigh(c, 0.0)),
                                   TS, x0).displacement)(0.01)


def test_a_user_method_is_an_abstract_method_subclass():
    class Zero(mj.AbstractMethod):
        def solve(self, model, ts, x0, v0, load, *, dofs, displacement, velocity):
            return mj.solve(model, ts, x0, v0, load, method=mj.DenseExponential(), dofs=dofs,
                            displacement=displacement, velocity=velocity)

    out = mj.solve(one_dof(), TS, jnp.ones(1), method=Zero())
    np.testing.assert_allclose(out.displacement[:, 0], one_dof_truth(TS), rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("method, message", [
    ("dense", r"method must be Auto\(\), Spectral\(\), DenseExponential\(\), ODE\(\.\.\.\)"),
    (mj.ODE(solver="dopri8"), r"ODE\(solver=\.\.\.\) must be a diffrax solver")])
def test_a_bad_method_is_refused_in_one_line(method, message):
    with pytest.raises(ValueError, match=message) as error:
        mj.solve(one_dof(), TS, jnp.ones(1), method=method)
    assert "\n" not in str(error.value)


def test_spectral_refuses_what_it_cannot_solve():
    with pytest.raises(ValueError, match=r"Spectral\(\) does not apply"):
        mj.solve(mj.mikota_chain(8), TS, jnp.ones(8), method=mj.Spectral())
