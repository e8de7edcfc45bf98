"""Input-output models (``IOModel``): the transfer function against a direct complex solve, the
H2 norms of a model and of an error system against dense Lyapunov solves, poles, outputs in
time, and the second-order Krylov basis matching the transfer function's moments at s = 0
(Bai & Su 2005) where modal truncation of the same size does not.

Truths: numpy's dense complex solve (backward stable: ~1e-14 relative to the response) and
scipy's Bartels-Stewart Lyapunov solver on systems whose every mode is damped (Rayleigh damping
on top of the dampers), where it is accurate to ~1e-13 relative to the Gramian."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sl

import mikota_jax as mj

N = 30


def response(model, omegas, forces, dofs=None):
    """H(i omega) at the 1-based ``dofs`` (all by default): an IOModel with C_x = their rows."""
    n = model.size
    rows = np.eye(n)[np.asarray(dofs if dofs is not None else range(1, n + 1)) - 1]
    return mj.IOModel(model, forces, cx=rows).frequency_response(omegas)


def chain(c=5.0):
    return mj.mikota_chain(N, dampers=[mj.GroundedDamper(12.4, c),
                                       mj.RelativeDamper((3, 20), 2.0)])


def direct(system, omega, forces):
    m, d, k = (np.asarray(a) for a in system.dense())
    return np.linalg.solve(k - omega**2 * m + 1j * omega * d, forces)


def test_the_response_is_the_direct_complex_solve():
    system = chain()
    forces = np.zeros((N, 2))
    forces[N - 1, 0], forces[4, 1] = 1.0, 1.0
    omegas = np.array([0.0, 0.7, 3.0, 12.5])
    h = np.asarray(response(system, omegas, forces, dofs=[1, 15, 30]))
    assert h.shape == (4, 3, 2) and h.dtype == np.complex128
    for i, omega in enumerate(omegas):
        expected = direct(system, omega, forces)[[0, 14, 29]]
        assert np.max(np.abs(h[i] - expected)) < 1e-12 * np.max(np.abs(expected))
    # a complete basis reduces nothing
    rom = mj.reduce(system, mj.Projection(jnp.eye(N)))
    h_r = np.asarray(response(rom, omegas, forces, dofs=[1, 15, 30]))
    assert np.max(np.abs(h_r - h)) < 1e-11 * np.max(np.abs(h))


def test_krylov_basis_matches_the_moments_at_zero_where_modal_truncation_does_not():
    system = chain()
    force = np.zeros(N)
    force[N - 1] = 1.0
    basis = mj.reduce(system, mj.Krylov(6, force)).basis
    assert basis.shape == (N, 6) and np.max(np.abs(basis.T @ basis - np.eye(6))) < 1e-12
    full = lambda w: np.asarray(response(system, np.array([w]), force))[0, :, 0]  # noqa: E731
    errors = {}
    for name, b in (("krylov", basis), ("modal", mj.reduce(system, mj.Modal(6)).basis)):
        rom = mj.reduce(system, mj.Projection(b))
        reduced = lambda w, rom=rom: np.asarray(  # noqa: E731
            response(rom, np.array([w]), force))[0, :, 0]
        errors[name] = [np.linalg.norm(reduced(w) - full(w)) / np.linalg.norm(full(w))
                        for w in (0.0, 0.01, 0.02)]
    assert errors["krylov"][0] < 1e-12  # the static response K^-1 b: moment 0
    # six vectors of G_k match at least six moments: the error grows like omega^6 or faster
    assert errors["krylov"][1] < 1e-12
    assert errors["krylov"][2] / max(errors["krylov"][1], 1e-300) > 2.0**5 or (
        errors["krylov"][2] < 1e-13)
    assert errors["modal"][0] > 1e-4  # six modes miss the static response of the free end


def test_the_response_is_differentiable():
    force = np.zeros(N)
    force[N - 1] = 1.0

    def peak(c):
        h = response(chain(c), jnp.array([1.0, 2.0]), force, dofs=[N])
        return jnp.sum(jnp.abs(h) ** 2)

    h = 1e-6
    fd = (float(peak(5.0 + h)) - float(peak(5.0 - h))) / (2 * h)
    assert float(jax.grad(peak)(5.0)) == pytest.approx(fd, rel=1e-6)


def test_bad_input_fails_in_one_line():
    system = chain()
    with pytest.raises(ValueError, match="omegas must be finite and >= 0"):
        response(system, np.array([-1.0]), np.ones(N))
    with pytest.raises(ValueError, match=r"inputs must be \(n, m\) or \(n,\) with n = 30"):
        response(system, np.array([1.0]), np.ones(3))
    with pytest.raises(ValueError, match="rank must be an integer in 1..30"):
        mj.reduce(system, mj.Krylov(0, np.ones(N)))
    with pytest.raises(ValueError, match=r"inputs must be \(n,\) or \(n, s\)"):
        mj.reduce(system, mj.Krylov(3, np.ones(4)))


def first_order(model, b, cx, cv):
    """(A, B, C) of a model's dense first-order form in (x, x') (a reduced model's in q, with
    its B_r = Phi^T B, C_r = C Phi)."""
    system, phi = (model.system, np.asarray(model.basis)) if isinstance(
        model, mj.ReducedModel) else (model, np.eye(model.size))
    m, d, k = (np.asarray(a) for a in system.dense())
    n = m.shape[0]
    inverse = np.linalg.inv(m)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-inverse @ k, -inverse @ d]])
    return (a, np.vstack([np.zeros((n, b.shape[1])), inverse @ phi.T @ b]),
            np.hstack([cx @ phi, cv @ phi]))


def h2_dense(a, b, c):
    """||C (sI - A)^-1 B||_H2 by scipy's Lyapunov solve (every pole strictly stable here)."""
    gramian = sl.solve_continuous_lyapunov(a, -b @ b.T)
    return float(np.sqrt(np.trace(c @ gramian @ c.T)))


def damped_chain(n=24):
    # Rayleigh damping on top of the dampers damps every mode: the dense Lyapunov truth is sound
    return mj.mikota_chain(n, dampers=[mj.GroundedDamper(5.0, 1.0),
                                       mj.RelativeDamper((2, 9), 0.5)],
                           internal_damping=mj.Rayleigh(0.01, 0.001))


def test_the_transfer_function_is_the_direct_solve_also_at_the_eigenfrequencies():
    # Mikota's chain has omega_l = l: s = 2i, 7i sit on undamped eigenfrequencies, where a
    # modal Woodbury solve would lose its digits; velocity outputs too
    system = chain()
    b = np.zeros((N, 2))
    b[N - 1, 0], b[4, 1] = 1.0, 1.0
    cx, cv = np.eye(N)[[0, 14]], 0.3 * np.eye(N)[[29, 2]]
    s = np.array([2j, 7j, 0.4 + 3.3j, 5.0, 0.0])
    g = np.asarray(mj.IOModel(system, b, cx=cx, cv=cv).transfer(s))
    m, d, k = (np.asarray(a) for a in system.dense())
    for i, z in enumerate(s):
        expected = (cx + z * cv) @ np.linalg.solve(z * z * m + z * d + k, b)
        assert np.max(np.abs(g[i] - expected)) < 1e-12 * np.max(np.abs(expected))


def test_h2_norms_of_a_model_and_of_its_error_systems_match_dense_lyapunov_solves():
    n = 24
    system = damped_chain(n)
    b = np.eye(n)[:, [2]]
    cx, cv = np.eye(n)[[11]], 0.2 * np.eye(n)[[11]]
    full = mj.IOModel(system, b, cx=cx, cv=cv)
    assert float(full.h2_norm()) == pytest.approx(h2_dense(*first_order(system, b, cx, cv)),
                                                  rel=1e-11)
    a1, b1, c1 = first_order(system, b, cx, cv)
    for strategy in (mj.Modal(6), mj.Krylov(5, b[:, 0])):
        reduced = mj.reduce(full, strategy)
        assert isinstance(reduced, mj.IOModel) and isinstance(reduced.model, mj.ReducedModel)
        a2, b2, c2 = first_order(reduced.model, b, cx, cv)
        error = full - reduced
        truth = h2_dense(sl.block_diag(a1, a2), np.vstack([b1, b2]), np.hstack([c1, -c2]))
        # the error's truth is good to ~1e-13 of ||G||; the difference formula to ~1e-15 ||G||
        assert abs(float(error.h2_norm()) - truth) < 1e-10 * float(full.h2_norm())
        # both orders of the difference, and G - G = 0 to its floor
        assert float((reduced - full).h2_norm()) == pytest.approx(truth, rel=1e-8)
    assert float((full - full).h2_norm()) < 1e-6 * float(full.h2_norm())


def test_poles_are_the_eigenvalues_of_the_first_order_form():
    system = damped_chain(12)
    io = mj.IOModel(system, np.eye(12)[:, 0], cx=np.eye(12)[5])
    expected = np.linalg.eigvals(first_order(system, np.eye(12)[:, [0]], np.eye(12)[[5]],
                                             np.zeros((1, 12)))[0])
    poles = np.asarray(io.poles())
    assert poles.shape == (24,)
    assert max(np.min(np.abs(expected - p)) for p in poles) < 1e-11 * np.max(np.abs(expected))
    reduced = mj.reduce(io, mj.Modal(4))
    a2 = first_order(reduced.model, np.eye(12)[:, [0]], np.eye(12)[[5]], np.zeros((1, 12)))[0]
    assert np.allclose(np.sort_complex(np.asarray(reduced.poles())),
                       np.sort_complex(np.linalg.eigvals(a2)), rtol=0, atol=1e-12)


def test_the_output_in_time_is_c_times_the_solved_state():
    system = chain()
    b = np.eye(N)[:, [N - 1]]
    io = mj.IOModel(system, b, cx=np.eye(N)[[3]], cv=np.eye(N)[[3]])
    ts = jnp.linspace(0.0, 4.0, 41)
    y = np.asarray(io.output(ts, lambda t: jnp.array([jnp.sin(2.0 * t)])))
    trajectory = mj.solve(system, ts, load=lambda t: jnp.asarray(b[:, 0]) * jnp.sin(2.0 * t),
                          dofs=[4], velocity=True)
    expected = np.asarray(trajectory.displacement + trajectory.velocity)
    assert y.shape == (41, 1) and np.max(np.abs(y - expected)) < 1e-12 * np.max(np.abs(expected))


def test_io_models_fail_in_one_line():
    system = chain()
    with pytest.raises(ValueError, match="give an output: cx"):
        mj.IOModel(system, np.ones(N))
    with pytest.raises(ValueError, match="model must be a SecondOrderSystem or a ReducedModel"):
        mj.IOModel("chain", np.ones(N), cx=np.ones(N))
    full = mj.IOModel(system, np.ones(N), cx=np.ones(N))
    with pytest.raises(ValueError, match=r"same \(outputs, inputs\), got \(1, 1\) and \(1, 2\)"):
        full - mj.IOModel(system, np.ones((N, 2)), cx=np.ones(N))
    with pytest.raises(ValueError, match="reduced already"):
        mj.reduce(mj.reduce(full, mj.Modal(4)), mj.Modal(2))
    with pytest.raises(ValueError, match="omegas must be finite and >= 0"):
        full.frequency_response(np.array([-1.0]))
    basis = mj.reduce(system, mj.Modal(4)).basis

    def error(c):  # the smaller model depends on c: its Schur form would need a derivative
        small = mj.IOModel(mj.reduce(chain(c), mj.Projection(basis)), np.ones(N), cx=np.ones(N))
        return (full - small).h2_norm()

    with pytest.raises(ValueError, match="differentiable in the larger model only"):
        jax.grad(error)(5.0)


def test_the_error_norm_is_differentiable_in_the_full_model():
    # d/dc ||G(c) - G_r||_H2 with the reduced model held fixed, against central differences
    # (h = 1e-5: truncation ~1e-10 relative, rounding ~1e-11 / h of the norm)
    n = 24
    b, cx = np.eye(n)[:, 2], np.eye(n)[11]

    def chain_at(c):
        return mj.mikota_chain(n, dampers=[mj.GroundedDamper(5.0, c)],
                               internal_damping=mj.Rayleigh(0.01, 0.001))

    reduced = mj.reduce(mj.IOModel(chain_at(1.0), b, cx=cx), mj.Modal(6))

    def error(c):
        return (mj.IOModel(chain_at(c), b, cx=cx) - reduced).h2_norm()

    h = 1e-5
    central = (float(error(1.3 + h)) - float(error(1.3 - h))) / (2 * h)
    assert float(jax.grad(error)(1.3)) == pytest.approx(central, rel=1e-7)
