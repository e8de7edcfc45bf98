"""Modal truncation and modal + static correction (``modal_basis``, ``modal_static_basis``):
orthonormal bases that take the exact modal solution, hold the static responses of the damper
directions, and improve on plain modal truncation where a damper is strong."""

import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj


def test_modal_basis_gives_the_exact_free_vibration_of_a_kept_mode():
    # undamped Mikota chain started in mode 3 (eq. 2.5): x(t) = cos(3 t) u_3 (omega_3 = 3)
    system = mj.mikota_chain(20)
    basis = mj.modal_basis(system, 5)
    assert np.max(np.abs(basis.T @ basis - np.eye(5))) < 1e-12
    x0 = mj.mode_shape(20, 3)
    ts = jnp.linspace(0.0, 10.0, 101)
    rom = mj.exact_solve(mj.galerkin(system, basis), ts, x0).displacement
    exact = np.cos(3.0 * np.asarray(ts))[:, None] * np.asarray(x0)[None, :]
    assert np.max(np.abs(np.asarray(rom) - exact)) < 1e-10


def test_modal_static_basis_holds_the_static_response_of_every_damper_direction():
    system = mj.mikota_chain(30, dampers=[mj.GroundedDamper(12.4, 5.0),
                                          mj.RelativeDamper((3, 20), 2.0)])
    b = np.asarray(mj.damper_directions(system))
    assert b.shape == (30, 3)  # DOFs 12 and 13 of the split damper, e_3 - e_20
    basis = np.asarray(mj.modal_static_basis(system, 6))
    assert basis.shape == (30, 9)
    assert np.max(np.abs(basis.T @ basis - np.eye(9))) < 1e-12
    static = np.linalg.solve(np.asarray(system.stiffness.as_matrix()), b)
    outside = static - basis @ (basis.T @ static)
    assert np.max(np.linalg.norm(outside, axis=0) / np.linalg.norm(static, axis=0)) < 1e-10
    load = np.zeros(30)
    load[29] = 1.0
    assert mj.modal_static_basis(system, 6, loads=load).shape == (30, 10)


def test_the_static_correction_improves_on_modal_truncation_at_a_damper():
    # n = 60, c = 5 at DOF 45, started in modes 1-3 (which modal truncation holds exactly): the
    # damper couples every mode; 12 columns, J relative error 6.1e-2 modal, 1.7e-4 with 10 modes
    # and the two static directions (measured)
    system = mj.mikota_chain(60, dampers=[mj.GroundedDamper(45.0, 5.0)])
    x0 = sum(mj.mode_shape(60, l) for l in (1, 2, 3))
    full = float(mj.integrated_energy(system, 20.0, x0))
    errors = {}
    for name, basis in (("modal", mj.modal_basis(system, 12)),
                        ("static", mj.modal_static_basis(system, 10))):  # + DOFs 45, 46
        assert basis.shape == (60, 12)
        value = float(mj.integrated_energy(mj.galerkin(system, basis), 20.0, x0))
        errors[name] = abs(value / full - 1)
    assert errors["modal"] > 1e-2
    assert errors["static"] < min(1e-3, errors["modal"] / 100)


def test_bad_input_fails_in_one_line():
    system = mj.mikota_chain(10)
    with pytest.raises(ValueError, match=r"rank must be an integer in 1\.\.10"):
        mj.modal_basis(system, 0)
    with pytest.raises(ValueError, match=r"loads must be \(n,\) or \(n, s\)"):
        mj.modal_static_basis(system, 3, loads=np.ones(4))
    with pytest.raises(ValueError, match="system must be a SecondOrderSystem"):
        mj.modal_basis("chain", 3)


def test_extend_basis_adds_only_the_directions_outside_the_span():
    rng = np.random.default_rng(3)
    basis, _ = np.linalg.qr(rng.standard_normal((20, 4)))
    inside = basis @ rng.standard_normal((4, 2))  # adds nothing
    new = rng.standard_normal((20, 2))
    extra = np.concatenate([inside, new, new @ np.array([[1.0], [2.0]])], axis=1)
    out = np.asarray(mj.extend_basis(basis, extra))
    assert out.shape == (20, 6)  # two new directions, the third new column is their sum
    assert np.max(np.abs(out.T @ out - np.eye(6))) < 1e-12
    assert np.array_equal(out[:, :4], basis)
    assert np.max(np.abs(extra - out @ (out.T @ extra))) < 1e-12
    assert mj.extend_basis(basis, basis[:, 0]).shape == (20, 4)
    with pytest.raises(ValueError, match="extra must have shape"):
        mj.extend_basis(basis, np.ones(19))
    with pytest.raises(ValueError, match="tol must lie in"):
        mj.extend_basis(basis, new, tol=-1.0)
