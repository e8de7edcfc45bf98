"""Damping operators: grounded and relative dampers against hand-built matrices and differences."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj
from mikota_jax._placement.problem import DamperProblem

N = 6


def e(i, n=N):
    """The 1-based unit vector e_i."""
    v = np.zeros(n)
    v[i - 1] = 1.0
    return v


def damping_matrix(dampers, n=N):
    return np.asarray(mj.mikota_chain(n, dampers=dampers).damping.as_matrix())


@pytest.mark.parametrize("position", [1, 3, N])
def test_grounded_damper_at_an_integer_position_is_d_e_p_e_p_transposed(position, close):
    d = 2.5
    close(damping_matrix([mj.GroundedDamper(float(position), d)]),
          d * np.outer(e(position), e(position)), rtol=0.0)


@pytest.mark.parametrize("j, w", [(1, 0.25), (3, 0.5), (5, 0.875)])
def test_fractional_position_splits_the_coefficient_between_neighbours(j, w, close):
    d = 1.6
    expected = d * (1 - w) * np.outer(e(j), e(j)) + d * w * np.outer(e(j + 1), e(j + 1))
    close(damping_matrix([mj.GroundedDamper(j + w, d)]), expected, rtol=1e-15)


def test_relative_damper_gives_the_two_by_two_stencil(close):
    d = 0.7
    stencil = d * np.outer(e(2) - e(5), e(2) - e(5))  # [[d, -d], [-d, d]] on DOFs 2 and 5
    close(damping_matrix([mj.RelativeDamper((2, 5), d)]), stencil, rtol=0.0)
    close(damping_matrix([mj.RelativeDamper((5, 2), d)]), stencil, rtol=0.0)


def test_several_dampers_add_up(close):
    dampers = [mj.GroundedDamper(2.25, 1.0), mj.GroundedDamper(6.0, 0.5),
               mj.RelativeDamper((1, 3), 0.3), mj.RelativeDamper((3, 4), 0.2)]
    total = sum(damping_matrix([d]) for d in dampers)
    close(damping_matrix(dampers), total, rtol=1e-15)
    close(total[1, 1], 0.75, rtol=1e-15)  # 1.0 * (1 - 0.25) from the fractional damper
    close(total[2, 2], 0.25 + 0.3 + 0.2, rtol=1e-15)


def test_damping_operator_apply_equals_its_matrix(close):
    dampers = [mj.GroundedDamper(4.6, 1.3), mj.RelativeDamper((6, 1), 0.4)]
    system = mj.mikota_chain(N, dampers=dampers)
    v = np.random.default_rng(3).standard_normal(N)
    close(system.damping.mv(jnp.asarray(v)), damping_matrix(dampers) @ v, rtol=1e-14)


def test_undamped_system_has_damping_none():
    system = mj.mikota_chain(N)
    assert system.damping is None
    assert system.dense()[1] is None
    assert system.project(jnp.eye(N)[:, :2]).damping is None


def test_damper_on_a_single_mass_chain(close):
    system = mj.mikota_chain(1, dampers=[mj.GroundedDamper(1.0, 2.0)])
    close(system.damping.as_matrix(), [[2.0]], rtol=0.0)


def test_projection_equals_basis_transposed_d_basis(close):
    dampers = [mj.GroundedDamper(2.4, 1.1), mj.GroundedDamper(6.0, 0.3),
               mj.RelativeDamper((2, 4), 0.8)]
    system = mj.mikota_chain(N, dampers=dampers)
    basis, _ = np.linalg.qr(np.random.default_rng(4).standard_normal((N, 3)))
    D = damping_matrix(dampers)
    close(system.damping.project(jnp.asarray(basis)).as_matrix(), basis.T @ D @ basis,
          rtol=1e-13, atol=1e-15)
    reduced = system.project(jnp.asarray(basis))
    M, _, K = system.dense()
    close(reduced.damping.as_matrix(), basis.T @ D @ basis, rtol=1e-13, atol=1e-15)
    close(reduced.mass.as_matrix(), basis.T @ np.asarray(M) @ basis, rtol=1e-13, atol=1e-15)
    close(reduced.stiffness.as_matrix(), basis.T @ np.asarray(K) @ basis, rtol=1e-13, atol=1e-14)


# --- derivatives --------------------------------------------------------------------------------

BASIS = jnp.asarray(np.linalg.qr(np.random.default_rng(5).standard_normal((N, 3)))[0])


def projected_trace(position, coefficient):
    """trace(Phi^T D Phi) for one grounded damper: smooth in p between integers."""
    system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(position, coefficient)])
    return jnp.trace(system.damping.project(BASIS).as_matrix())


def central_difference(f, x, h):
    return (f(x + h) - f(x - h)) / (2 * h)


def test_gradient_wrt_position_and_coefficient_matches_central_differences(close):
    p, c = 3.3, 1.7
    grad_p, grad_c = jax.grad(projected_trace, argnums=(0, 1))(p, c)
    h = 1e-6 * 3
    close(grad_p, central_difference(lambda x: projected_trace(x, c), p, h), rtol=1e-7)
    close(grad_c, central_difference(lambda x: projected_trace(p, x), c, 1e-6), rtol=1e-7)
    # and the closed form: d/dp [c ((1-w)|phi_3|^2 + w |phi_4|^2)] = c (|phi_4|^2 - |phi_3|^2)
    rows = np.sum(np.asarray(BASIS) ** 2, axis=1)
    close(grad_p, c * (rows[3] - rows[2]), rtol=1e-12)
    close(grad_c, 0.7 * rows[2] + 0.3 * rows[3], rtol=1e-12)


def test_gradient_of_a_damped_response_matches_central_differences(close):
    v = jnp.asarray(np.random.default_rng(6).standard_normal(N))

    def dissipation(position, coefficient):  # v^T D v with D from a fractional damper
        system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(position, coefficient),
                                             mj.RelativeDamper((1, 2), 0.5)])
        return v @ system.damping.mv(v)

    p, c = 4.45, 0.8
    grad_p, grad_c = jax.grad(dissipation, argnums=(0, 1))(p, c)
    close(grad_p, central_difference(lambda x: dissipation(x, c), p, 4e-6), rtol=1e-7)
    close(grad_c, central_difference(lambda x: dissipation(p, x), c, 1e-6), rtol=1e-7)


def test_gradient_at_an_integer_position_is_one_sided(close):
    h = 1e-6
    grad = jax.grad(projected_trace)(3.0, 1.0)
    close(grad, (projected_trace(3.0 + h, 1.0) - projected_trace(3.0, 1.0)) / h, rtol=1e-6)
    grad_end = jax.grad(projected_trace)(float(N), 1.0)
    close(grad_end, (projected_trace(float(N), 1.0) - projected_trace(N - h, 1.0)) / h, rtol=1e-6)


def test_vmap_over_damper_positions_equals_a_loop(close):
    positions = jnp.array([1.0, 2.5, 5.75])
    batched = jax.vmap(lambda p: projected_trace(p, 1.2))(positions)
    close(batched, [projected_trace(float(p), 1.2) for p in positions], rtol=1e-14)


# --- bad input --------------------------------------------------------------------------------


@pytest.mark.parametrize("position", [0.5, 0.0, N + 0.5, -2.0, np.nan])
def test_grounded_damper_outside_one_to_n_is_rejected(position):
    with pytest.raises(ValueError, match=r"position must lie in \[1, 6\]"):
        mj.mikota_chain(N, dampers=[mj.GroundedDamper(position, 1.0)])


@pytest.mark.parametrize("coefficient", [-1.0, -1e-12, np.nan, np.inf])
def test_negative_or_non_finite_coefficient_is_rejected(coefficient):
    with pytest.raises(ValueError, match="coefficient must be finite and >= 0"):
        mj.mikota_chain(N, dampers=[mj.GroundedDamper(2.0, coefficient)])
    with pytest.raises(ValueError, match="coefficient must be finite and >= 0"):
        mj.mikota_chain(N, dampers=[mj.RelativeDamper((1, 2), coefficient)])


def test_zero_coefficient_is_allowed_and_gives_zero_damping(close):
    close(damping_matrix([mj.GroundedDamper(2.0, 0.0)]), np.zeros((N, N)), rtol=0.0)


@pytest.mark.parametrize("dofs", [(2, 2), (0, 3), (3, 7), (-1, 2)])
def test_relative_damper_dofs_equal_or_outside_one_to_n_are_rejected(dofs):
    with pytest.raises(ValueError, match="dofs"):
        mj.mikota_chain(N, dampers=[mj.RelativeDamper(dofs, 1.0)])


def test_relative_damper_dofs_are_checked_under_jit_too():
    build = eqx.filter_jit(lambda c: mj.mikota_chain(N, dampers=[mj.RelativeDamper((3, 9), c)]))
    with pytest.raises(ValueError, match=r"dofs \(3, 9\) must lie in 1..6"):
        build(jnp.asarray(1.0))


@pytest.mark.parametrize("name", ["position", "coefficient"])
def test_float32_damper_parameters_are_rejected(name):
    args = {"position": 2.0, "coefficient": 1.0}
    args[name] = jnp.float32(args[name])
    with pytest.raises(ValueError, match=f"{name} must be float64"):
        mj.GroundedDamper(**args)


def test_non_damper_objects_are_rejected():
    with pytest.raises(ValueError, match="dampers must be GroundedDamper or RelativeDamper"):
        mj.mikota_chain(N, dampers=[(2.0, 1.0)])


def test_one_damper_not_in_a_list_is_a_list_of_one_for_every_system_builder(close):
    grounded, relative = mj.GroundedDamper(2.0, 1.0), mj.RelativeDamper((1, 3), 0.5)
    for damper in (grounded, relative):
        close(damping_matrix(damper), damping_matrix([damper]), rtol=0.0, atol=0.0)
    masses, springs = np.ones(3), np.arange(1.0, 4.0)
    for build in (lambda d: mj.chain(masses, springs, d),
                  lambda d: mj.system(np.eye(3), np.diag(springs), dampers=d),
                  lambda d: mj.branched_chain([np.ones(1), np.ones(1)], [np.ones(2), np.ones(2)],
                                              1.0, 1.0, d)):
        close(build(relative).damping.as_matrix(), build([relative]).damping.as_matrix(),
              rtol=0.0, atol=0.0)
    problem = DamperProblem(mj.mikota_chain(N), np.linspace(0.0, 1.0, 3), e(3),
                            dampers=grounded)
    assert problem.base.damping.positions.tolist() == [2.0]


@pytest.mark.parametrize("dampers", [3, 2.5])
def test_dampers_that_are_neither_dampers_nor_a_list_are_refused_in_one_line(dampers):
    with pytest.raises(ValueError, match=r"^mikota_jax: dampers must be a list of "
                       r"GroundedDamper or RelativeDamper, got .*\.$"):
        mj.mikota_chain(N, dampers=dampers)
    with pytest.raises(ValueError, match="dampers must be a non-empty list of GroundedDamper"):
        DamperProblem(mj.mikota_chain(N), np.linspace(0.0, 1.0, 3), e(3), dampers=dampers)


def matrix_of(position, coefficient):
    system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(position, coefficient)])
    return system.damping.as_matrix()


def test_traced_bad_position_and_coefficient_fail_under_jit(close):
    build = eqx.filter_jit(matrix_of)
    close(build(jnp.asarray(2.5), jnp.asarray(2.0))[1, 1], 1.0, rtol=0.0)
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"position must lie in \[1, 6\]"):
        build(jnp.asarray(6.5), jnp.asarray(1.0))
    with pytest.raises(eqx.EquinoxRuntimeError, match="coefficient must be finite and >= 0"):
        build(jnp.asarray(2.0), jnp.asarray(-0.5))


def test_traced_bad_position_and_coefficient_fail_under_vmap():
    build = jax.vmap(matrix_of)
    with pytest.raises(eqx.EquinoxRuntimeError, match=r"position must lie in \[1, 6\]"):
        build(jnp.array([2.0, 0.9]), jnp.array([1.0, 1.0]))
    with pytest.raises(eqx.EquinoxRuntimeError, match="coefficient must be finite and >= 0"):
        build(jnp.array([2.0, 3.0]), jnp.array([1.0, np.nan]))
