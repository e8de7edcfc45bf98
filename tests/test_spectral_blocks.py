"""The large-chain spectral energy (the roots a block at a time, the modes' rows without U: O(n)
memory, used above n = 4096) at a small chain, against the same engine all at once with U and
against the dense Van Loan energy; its gradient against central differences."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj
from mikota_jax._solver.spectral.energy import energy_from_modes
from mikota_jax._solver.spectral.modes import live_modes, live_rows
from mikota_jax._solver.spectral.rows import BLOCK_ABOVE, row_block

N, T = 40, 20.0
X0 = np.eye(N)[2]


def chain(position, coefficient):
    # a split damper (between two DOFs), a grounded one and a relative one: the rows of U that
    # ``Dampers.touched`` lists, in ``project``'s order
    return mj.mikota_chain(N, dampers=[mj.GroundedDamper(position, coefficient),
                                       mj.GroundedDamper(31.0, 3.0),
                                       mj.RelativeDamper((5, 20), 2.0)])


@functools.partial(jax.jit, static_argnums=1)
def energy(design, block):
    """(J, roots): ``block`` 0: all at once, from U (``live_modes``); else the large-chain path
    (``live_rows``: the modes' rows and projections, ``block`` roots at a time)."""
    system = chain(design[0], design[1])
    if block:
        vectors = jnp.stack([jnp.asarray(X0), jnp.zeros(N)], axis=1)
        modes, projected, _, _ = live_rows(system, vectors, block)
        q0, p0 = projected[:, 0], projected[:, 1]
    else:
        modes, u, _ = live_modes(system)
        q0, p0 = u.T @ (system.mass.diagonal * X0), jnp.zeros(N)
    return energy_from_modes(modes, q0, p0, T, block), jax.lax.stop_gradient(modes)


@pytest.mark.slow  # 145-200 s in a loaded full run (the rows path compiles its cluster branches)
def test_the_large_chain_path_equals_the_whole_one_and_the_dense_energy():
    design = jnp.array([12.4, 40.0])
    grad = jax.jit(jax.value_and_grad(energy, has_aux=True), static_argnums=1)
    (whole, modes), grad_whole = grad(design, 0)
    (blocked, blocked_modes), grad_blocked = grad(design, 7)
    assert bool(modes.converged) and bool(blocked_modes.converged)
    # the same roots (7 does not divide 2n = 80: the last block is padded)
    lam, lam_b = np.asarray(modes.eigenvalues), np.asarray(blocked_modes.eigenvalues)
    distance = np.abs(lam_b[:, None] - lam[None, :]) / np.abs(lam)[None, :]
    assert np.max(np.min(distance, axis=1)) <= 1e-12 and np.max(np.min(distance, axis=0)) <= 1e-12
    np.testing.assert_allclose(float(blocked_modes.separation), float(modes.separation),
                               rtol=1e-9)
    # J against the dense (Van Loan) energy, an independent path
    dense = mj.Energy(T, X0, method=mj.DenseExponential())(chain(12.4, 40.0))
    np.testing.assert_allclose(float(blocked), float(dense), rtol=1e-10)
    np.testing.assert_allclose(float(blocked), float(whole), rtol=1e-12)
    # the gradient (reverse mode through the checkpointed blocks and the modes' rows) against
    # the whole path's and central differences
    np.testing.assert_allclose(np.asarray(grad_blocked), np.asarray(grad_whole), rtol=1e-9)
    for i, h in ((0, 1e-4), (1, 1e-3)):
        step = jnp.zeros(2).at[i].set(h)
        fd = (energy(design + step, 7)[0] - energy(design - step, 7)[0]) / (2 * h)
        np.testing.assert_allclose(float(grad_blocked[i]), float(fd), rtol=1e-6)
    # a batch of starts (a trailing axis) gives one J per column, blocked or not
    omega = blocked_modes.omega
    q0 = jnp.stack([omega, 1 / omega], axis=1)
    np.testing.assert_allclose(
        np.asarray(energy_from_modes(blocked_modes, q0, jnp.zeros((N, 2)), T, 7)),
        np.asarray(energy_from_modes(blocked_modes, q0, jnp.zeros((N, 2)), T, 0)), rtol=1e-12)


def test_the_block_rule():
    assert row_block(BLOCK_ABOVE) is None  # all at once up to n = 64
    assert row_block(BLOCK_ABOVE + 1) == BLOCK_ABOVE + 1  # at least two blocks of n roots
    assert row_block(300) == 218 and row_block(1000) == 65  # 2^16 / n ...
    assert row_block(30000) == 16  # ... and at least 16
    assert row_block(300, 16) == 16 and row_block(300, 0) is None
    with pytest.raises(ValueError, match="block must be an int >= 0"):
        row_block(300, -1)


def test_blocks_are_balanced_and_by_rows_is_the_same_map():
    """``balanced``: as few blocks as ``block`` allows, of equal size, padded by fewer roots
    than there are blocks (the old split left 54 of 654 rows as padding at n = 300). Truth:
    integer arithmetic, and ``by_rows`` against the map over all rows at once (exact: the same
    elementwise function)."""
    from mikota_jax._solver.spectral.rows import balanced, by_rows

    for m in (1, 7, 40, 600, 1602, 2000):
        for block in (1, 7, 16, 81, 218, 5000):
            count, size = balanced(m, block)
            assert size <= min(block, m) and count == -(-m // min(block, m))
            assert 0 <= count * size - m < count
    assert balanced(600, 218) == (3, 200)
    rows = jnp.arange(40.0)
    out = by_rows(lambda r: (r**2, jnp.sin(r)[:, None]), 7, rows)
    assert np.array_equal(out[0], rows**2) and np.array_equal(out[1], jnp.sin(rows)[:, None])


def test_batch_cond_is_lax_cond_alone_and_skips_work_no_design_needs_under_vmap():
    """``batch_cond``: outside ``vmap`` the branch ``lax.cond`` takes; under it each design's
    own branch's value, and the needed branch runs only where some design of the batch needs
    it (a ``lax.cond`` batched by JAX runs both branches for every design). Truth: the branch
    functions themselves, evaluated alone (exact), and a host callback counting the runs."""
    from mikota_jax._solver.spectral.rows import batch_cond

    runs = []

    def needed(x):
        jax.debug.callback(lambda: runs.append(1))
        return jnp.sin(x) * 2

    def cond(flag, x):
        return batch_cond(flag, needed, jnp.cos, x)

    x = jnp.array([0.3, 1.7, 2.9])
    for flag in (True, False):
        assert float(cond(flag, x[0])) == float(needed(x[0]) if flag else jnp.cos(x[0]))
    batched = jax.jit(jax.vmap(cond))
    runs.clear()
    out = batched(jnp.array([False, False, False]), x)
    jax.effects_barrier()
    assert not runs
    np.testing.assert_allclose(out, jnp.cos(x), rtol=2e-16)
    out = batched(jnp.array([False, True, False]), x)
    jax.effects_barrier()
    assert runs
    np.testing.assert_allclose(out, [jnp.cos(x[0]), 2 * jnp.sin(x[1]), jnp.cos(x[2])],
                               rtol=2e-16)
