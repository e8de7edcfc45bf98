"""Frequency response (``frequency_response``) against a direct complex solve, and the
second-order Krylov basis (``krylov_basis``) matching the transfer function's moments at s = 0
(Bai & Su 2005) where modal truncation of the same size does not."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj

N = 30


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
    h = np.asarray(mj.frequency_response(system, omegas, forces, dofs=[1, 15, 30]))
    assert h.shape == (4, 3, 2) and h.dtype == np.complex128
    for i, omega in enumerate(omegas):
        expected = direct(system, omega, forces)[[0, 14, 29]]
        assert np.max(np.abs(h[i] - expected)) < 1e-12 * np.max(np.abs(expected))
    # a complete basis reduces nothing
    rom = mj.reduce(system, mj.Projection(jnp.eye(N)))
    h_r = np.asarray(mj.frequency_response(rom, omegas, forces, dofs=[1, 15, 30]))
    assert np.max(np.abs(h_r - h)) < 1e-11 * np.max(np.abs(h))


def test_krylov_basis_matches_the_moments_at_zero_where_modal_truncation_does_not():
    system = chain()
    force = np.zeros(N)
    force[N - 1] = 1.0
    basis = mj.reduce(system, mj.Krylov(6, force)).basis
    assert basis.shape == (N, 6) and np.max(np.abs(basis.T @ basis - np.eye(6))) < 1e-12
    full = lambda w: np.asarray(mj.frequency_response(system, np.array([w]), force))[0, :, 0]  # noqa: E731
    errors = {}
    for name, b in (("krylov", basis), ("modal", mj.reduce(system, mj.Modal(6)).basis)):
        rom = mj.reduce(system, mj.Projection(b))
        reduced = lambda w, rom=rom: np.asarray(  # noqa: E731
            mj.frequency_response(rom, np.array([w]), force))[0, :, 0]
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
        h = mj.frequency_response(chain(c), jnp.array([1.0, 2.0]), force, dofs=[N])
        return jnp.sum(jnp.abs(h) ** 2)

    h = 1e-6
    fd = (float(peak(5.0 + h)) - float(peak(5.0 - h))) / (2 * h)
    assert float(jax.grad(peak)(5.0)) == pytest.approx(fd, rel=1e-6)


def test_bad_input_fails_in_one_line():
    system = chain()
    with pytest.raises(ValueError, match="omegas must be finite and >= 0"):
        mj.frequency_response(system, np.array([-1.0]), np.ones(N))
    with pytest.raises(ValueError, match=r"inputs must be \(n,\) or \(n, s\) with n = 30"):
        mj.frequency_response(system, np.array([1.0]), np.ones(3))
    with pytest.raises(ValueError, match="rank must be an integer in 1..30"):
        mj.reduce(system, mj.Krylov(0, np.ones(N)))
    with pytest.raises(ValueError, match=r"inputs must be \(n,\) or \(n, s\)"):
        mj.reduce(system, mj.Krylov(3, np.ones(4)))
