"""The large-chain spectral response (``rows_response``: the modal history a block of roots at a
time, then x = U eta a chunk of modes at a time, never U or the (n, 2n) vectors; used above
n = 4096) at a small chain, against the spectral path with U and the dense (matrix exponential)
path; its derivatives against central differences."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj
import mikota_jax._solver.spectral.modes as spectral_system
from mikota_jax._model.chain_combine import chain_mode_combination
from mikota_jax._model.chain_modes import chain_modes
from mikota_jax._solver.spectral.response import rows_response, spectral_solve_with_result

N = 40
TS = jnp.linspace(0.0, 5.0, 51)
RNG = np.random.default_rng(7)
X0, V0, F = (jnp.asarray(RNG.normal(size=N)) for _ in range(3))
LOAD = mj.Pulse(F, 0.3, 1.7)


def chain(position=12.4, coefficient=40.0, k=1.0, m=1.0):
    # a split damper (between two DOFs), a grounded one and a relative one
    return mj.mikota_chain(N, m, k, dampers=[mj.GroundedDamper(position, coefficient),
                                             mj.GroundedDamper(31.0, 3.0),
                                             mj.RelativeDamper((5, 20), 2.0)])


@eqx.filter_jit
def response(system, load, dofs, block):
    """(x, v, ok): ``block`` 0: the spectral path with U; else ``rows_response``, ``block``
    roots at a time (7 does not divide the 40 slots: the last block is padded)."""
    options = dict(dofs=dofs, displacement=True, velocity=True)
    if block:
        trajectory, ok, _ = rows_response(system, TS, X0, V0, load, block=block, **options)
    else:
        trajectory, ok = spectral_solve_with_result(system, TS, X0, V0, load, **options)
    return trajectory.displacement, trajectory.velocity, ok


@pytest.mark.slow  # 145-200 s in a loaded full run (the rows path compiles its cluster branches)
def test_the_large_chain_response_equals_the_spectral_and_the_dense_one():
    for load in (None, LOAD):
        for dofs in (tuple(range(1, N + 1)), (3, 17, 40)):
            x, v, ok = response(chain(), load, dofs, 7)
            x_u, v_u, ok_u = response(chain(), load, dofs, 0)
            assert bool(ok) and bool(ok_u)
            dense = mj.solve(chain(), TS, X0, V0, load, dofs=dofs, velocity=True,
                             method=mj.DenseExponential())
            for mine, same, truth in ((x, x_u, dense.displacement), (v, v_u, dense.velocity)):
                scale = float(jnp.max(jnp.abs(truth)))
                assert float(jnp.max(jnp.abs(mine - same))) <= 1e-13 * scale
                assert float(jnp.max(jnp.abs(mine - truth))) <= 1e-10 * scale


@pytest.mark.slow
def test_the_large_chain_response_has_the_derivatives_of_the_system():
    def output(design):
        system = chain(design[0], design[1], design[2], design[3])
        x, v, _ = response(system, LOAD, (3, 17, 40), 7)
        return jnp.sum(x**2) + jnp.sum(jnp.sin(v))

    design = jnp.array([12.4, 40.0, 1.3, 0.8])
    forward = jax.jit(jax.jacfwd(output))(design)
    reverse = jax.jit(jax.grad(output))(design)
    np.testing.assert_allclose(np.asarray(reverse), np.asarray(forward), rtol=1e-10)
    # k and m scale every frequency: the phases on [0, 5] make the differences converge slowly
    # (1e-5: 1.2e-5 off; 1e-6: 1.2e-7)
    for i, h in enumerate((1e-4, 1e-3, 1e-6, 1e-6)):
        step = jnp.zeros(4).at[i].set(h)
        fd = (output(design + step) - output(design - step)) / (2 * h)
        np.testing.assert_allclose(float(forward[i]), float(fd), rtol=1e-6)


def test_the_chunked_combination_is_u_times_c():
    system = mj.mikota_chain(N, 1.3, 0.8)
    masses, springs = system.mass.diagonal, system.stiffness.springs
    c = jnp.asarray(RNG.normal(size=(N, 3)))
    rows = jnp.array([0, 9, 39, 9])
    _, u = chain_modes(masses, springs)
    np.testing.assert_allclose(np.asarray(chain_mode_combination(masses, springs, rows, c, 7)),
                               np.asarray((u @ c)[rows]), atol=1e-13)

    def both(scale):  # its derivative in the chain against the derivative of U C
        m, k = masses * scale[0], springs * scale[1]
        return (chain_mode_combination(m, k, rows, c * scale[2], 7),
                (chain_modes(m, k)[1] @ (c * scale[2]))[rows])

    mine, truth = jax.jacfwd(both)(jnp.array([1.0, 1.0, 1.0]))
    np.testing.assert_allclose(np.asarray(mine), np.asarray(truth), atol=1e-11)


@pytest.mark.slow  # its jitted rows response once compiled for > 5 min beside another worker
def test_exact_solve_and_the_energy_take_the_large_chain_path_above_the_threshold(monkeypatch):
    # an unusual size and grid, so no other test's compiled solve is reused or left behind
    n, ts = 37, jnp.linspace(0.0, 3.0, 23)
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(7.0, 2.0)])
    x0 = jnp.zeros(n).at[2].set(1.0)
    dense = mj.solve(system, ts, x0, dofs=(1, 3, 37), method=mj.DenseExponential())
    monkeypatch.setattr(spectral_system, "ROWS_ABOVE", 32)
    assert spectral_system.uses_rows(system)
    mine = mj.solve(system, ts, x0, dofs=(1, 3, 37), method=mj.Spectral())
    np.testing.assert_allclose(np.asarray(mine.displacement), np.asarray(dense.displacement),
                               atol=1e-11)
    # under jit too, with no dense fallback compiled (it could not run at such a size)
    jitted = jax.jit(lambda x: mj.solve(system, ts, x, dofs=(1, 3, 37),
                                        method=mj.Spectral()).displacement)
    np.testing.assert_allclose(np.asarray(jitted(x0)), np.asarray(dense.displacement),
                               atol=1e-11)
    # the energy's default method takes the same O(n)-memory path there (no dense fallback)
    np.testing.assert_allclose(float(mj.Energy(20.0, x0)(system)),
                               float(mj.Energy(20.0, x0, method=mj.DenseExponential())(system)),
                               rtol=1e-10)
