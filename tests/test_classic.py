"""Modal truncation and modal + static correction (``modal_basis``, ``modal_static_basis``):
orthonormal bases that take the exact modal solution, hold the static responses of the damper
directions, and improve on plain modal truncation where a damper is strong."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj
from mikota_jax._rom.classic import (
    craig_bampton_basis,
    damper_directions,
    extend_basis,
    fixed_interface_modes,
    modal_static_basis,
    static_moments,
)


def test_modal_basis_gives_the_exact_free_vibration_of_a_kept_mode():
    # undamped Mikota chain started in mode 3 (eq. 2.5): x(t) = cos(3 t) u_3 (omega_3 = 3)
    system = mj.mikota_chain(20)
    basis = mj.reduce(system, mj.Modal(5)).basis
    assert np.max(np.abs(basis.T @ basis - np.eye(5))) < 1e-12
    x0 = mj.analytic.mode_shape(20, 3)
    ts = jnp.linspace(0.0, 10.0, 101)
    model = mj.reduce(system, mj.Projection(basis))
    rom = mj.solve(model, ts, x0, method=mj.DenseExponential()).displacement
    exact = np.cos(3.0 * np.asarray(ts))[:, None] * np.asarray(x0)[None, :]
    assert np.max(np.abs(np.asarray(rom) - exact)) < 1e-10


def test_modal_basis_of_a_long_chain_computes_only_the_modes_it_keeps():
    # n >= 256: the r lowest modes by bisection (no n x n modes); the same span as the full
    # decomposition's r lowest (Mikota n = 400: the modes of omega = 1..40), orthonormal
    system = mj.mikota_chain(400)
    basis = np.asarray(mj.reduce(system, mj.Modal(40)).basis)
    _, modes = mj.modal_decomposition(system)
    reference, _ = np.linalg.qr(np.asarray(modes[:, :40]))
    assert np.max(np.abs(basis.T @ basis - np.eye(40))) < 1e-12
    assert np.linalg.norm(basis - reference @ (reference.T @ basis)) < 1e-11


def test_modal_static_basis_holds_the_static_response_of_every_damper_direction():
    system = mj.mikota_chain(30, dampers=[mj.GroundedDamper(12.4, 5.0),
                                          mj.RelativeDamper((3, 20), 2.0)])
    b = np.asarray(damper_directions(system))
    assert b.shape == (30, 3)  # DOFs 12 and 13 of the split damper, e_3 - e_20
    basis = np.asarray(modal_static_basis(system, 6))
    assert basis.shape == (30, 9)
    assert np.max(np.abs(basis.T @ basis - np.eye(9))) < 1e-12
    static = np.linalg.solve(np.asarray(system.stiffness.as_matrix()), b)
    outside = static - basis @ (basis.T @ static)
    assert np.max(np.linalg.norm(outside, axis=0) / np.linalg.norm(static, axis=0)) < 1e-10
    load = np.zeros(30)
    load[29] = 1.0
    assert modal_static_basis(system, 6, loads=load).shape == (30, 10)


@pytest.mark.slow
def test_the_static_correction_improves_on_modal_truncation_at_a_damper():
    # n = 60, c = 5 at DOF 45, started in modes 1-3 (which modal truncation holds exactly): the
    # damper couples every mode; 12 columns, J relative error 6.1e-2 modal, 1.7e-4 with 10 modes
    # and the two static directions (measured)
    system = mj.mikota_chain(60, dampers=[mj.GroundedDamper(45.0, 5.0)])
    x0 = sum(mj.analytic.mode_shape(60, l) for l in (1, 2, 3))
    full = float(mj.Energy(20.0, x0)(system))
    errors = {}
    for name, basis in (("modal", mj.reduce(system, mj.Modal(12)).basis),
                        ("static", modal_static_basis(system, 10))):  # + DOFs 45, 46
        assert basis.shape == (60, 12)
        value = float(mj.Energy(20.0, x0)(mj.reduce(system, mj.Projection(basis))))
        errors[name] = abs(value / full - 1)
    assert errors["modal"] > 1e-2
    assert errors["static"] < min(1e-3, errors["modal"] / 100)


def test_bad_input_fails_in_one_line():
    system = mj.mikota_chain(10)
    with pytest.raises(ValueError, match=r"rank must be an integer in 1\.\.10"):
        mj.reduce(system, mj.Modal(0))
    with pytest.raises(ValueError, match=r"loads must be \(n,\) or \(n, s\)"):
        mj.reduce(system, mj.ModalStatic(3, loads=np.ones(4)))
    with pytest.raises(ValueError, match="problem must be a SecondOrderSystem or a Scene"):
        mj.reduce("chain", mj.Modal(3))


def test_extend_basis_adds_only_the_directions_outside_the_span():
    rng = np.random.default_rng(3)
    basis, _ = np.linalg.qr(rng.standard_normal((20, 4)))
    inside = basis @ rng.standard_normal((4, 2))  # adds nothing
    new = rng.standard_normal((20, 2))
    extra = np.concatenate([inside, new, new @ np.array([[1.0], [2.0]])], axis=1)
    out = np.asarray(extend_basis(basis, extra))
    assert out.shape == (20, 6)  # two new directions, the third new column is their sum
    assert np.max(np.abs(out.T @ out - np.eye(6))) < 1e-12
    assert np.array_equal(out[:, :4], basis)
    assert np.max(np.abs(extra - out @ (out.T @ extra))) < 1e-12
    assert extend_basis(basis, basis[:, 0]).shape == (20, 4)
    with pytest.raises(ValueError, match="extra must have shape"):
        extend_basis(basis, np.ones(19))
    with pytest.raises(ValueError, match="tol must lie in"):
        extend_basis(basis, new, tol=-1.0)


def _frequencies(system, modes):
    k, m = np.asarray(system.stiffness.as_matrix()), np.asarray(system.mass.as_matrix())
    modes = np.asarray(modes)
    assert np.max(np.abs(modes.T @ m @ modes - np.eye(modes.shape[1]))) < 1e-12
    return np.sqrt(np.diag(modes.T @ k @ modes)), k, m


def test_fixed_interface_modes_of_a_uniform_chain_held_at_a_dof_are_the_two_pieces_modes():
    # unit masses and springs, DOF 5 of 12 held: DOFs 1..4 a fixed-fixed chain (omega_j =
    # 2 sin(j pi / 10)), DOFs 6..12 a fixed-free one (omega_j = 2 sin((2j - 1) pi / 30))
    n, held = 12, 5
    system = mj.chain(np.ones(n), np.ones(n))
    c = np.zeros(n)
    c[held - 1] = 1.0
    modes = np.asarray(fixed_interface_modes(system, c, n - 1))
    omega, _, _ = _frequencies(system, modes)
    exact = np.sort(np.concatenate([2 * np.sin(np.arange(1, 5) * np.pi / 10),
                                    2 * np.sin((2 * np.arange(1, 8) - 1) * np.pi / 30)]))
    np.testing.assert_allclose(omega, exact, rtol=1e-12)
    assert np.max(np.abs(modes[held - 1])) == 0.0
    with pytest.raises(ValueError, match=r"rank must be an integer in 1\.\.11"):
        fixed_interface_modes(system, c, n)


def test_fixed_interface_modes_of_a_long_chain_take_the_o_n_r_path_to_full_accuracy():
    # n >= 256: no dense eigenproblem (held_chain_modes). A uniform chain of 400 held at DOF 150:
    # DOFs 1..149 fixed-fixed (omega_j = 2 sin(j pi / 300)), 151..400 fixed-free
    # (omega_j = 2 sin((2j - 1) pi / 1002)), the 60 lowest to 1e-12 relative
    n = 400
    system = mj.chain(np.ones(n), np.ones(n))
    modes = np.asarray(fixed_interface_modes(system, np.eye(n)[149], 60))
    omega, _, _ = _frequencies(system, modes)
    exact = np.sort(np.concatenate([2 * np.sin(np.arange(1, 150) * np.pi / 300),
                                    2 * np.sin((2 * np.arange(1, 251) - 1) * np.pi / 1002)]))
    np.testing.assert_allclose(omega, exact[:60], rtol=1e-12)
    np.testing.assert_allclose(modes.T @ modes, np.eye(60), atol=1e-12)  # M = I
    assert np.max(np.abs(modes[149])) == 0.0
    # an uneven chain held at its first DOF, two neighbours and its last: against a dense eigh of
    # K and M with those rows and columns deleted
    rng = np.random.default_rng(5)
    n, held = 300, [0, 120, 121, 299]
    masses, springs = rng.uniform(0.2, 5.0, n), rng.uniform(0.2, 5.0, n)
    system = mj.chain(masses, springs)
    modes = np.asarray(fixed_interface_modes(system, np.eye(n)[:, held], 40))
    omega, k, m = _frequencies(system, modes)
    keep = np.setdiff1d(np.arange(n), held)
    scale = 1 / np.sqrt(masses[keep])
    dense = np.linalg.eigvalsh(scale[:, None] * k[np.ix_(keep, keep)] * scale[None, :])
    np.testing.assert_allclose(omega, np.sqrt(dense[:40]), rtol=1e-10)
    np.testing.assert_allclose(modes.T @ m @ modes, np.eye(40), atol=1e-12)
    residual = (k @ modes - m @ modes * omega**2)[keep]
    assert np.max(np.abs(residual)) < 1e-12 * np.max(np.abs(k))
    assert np.max(np.abs(modes[held])) == 0.0


def test_a_long_chain_takes_the_same_o_n_r_path_under_jit():
    # the method is chosen from the structure (a fixed-free chain, n >= 256), not from whether
    # the values are traced: the jitted basis is the eager one bit for bit and its program holds
    # no dense eigensolver; truth for the frequencies: 2 sin((2j - 1) pi / (2 (2n + 1))), exact
    n = 300
    system = mj.chain(np.ones(n), np.ones(n))
    eager = np.asarray(mj.reduce(system, mj.Modal(12)).basis)
    jitted = np.asarray(jax.jit(lambda s: mj.reduce(s, mj.Modal(12)).basis)(system))
    np.testing.assert_array_equal(jitted, eager)
    omega, _, _ = _frequencies(system, eager)
    np.testing.assert_allclose(omega, 2 * np.sin((2 * np.arange(1, 13) - 1) * np.pi / 1202),
                               rtol=1e-12)
    program = str(jax.make_jaxpr(lambda s: mj.reduce(s, mj.Modal(12)).basis)(system))
    assert "eigh" not in program and "svd" not in program


def test_fixed_interface_modes_with_a_tie_are_stationary_on_the_constraint():
    # DOF 3 tied to DOF 9 (C = e_3 - e_9): u_3 = u_9, and K u - omega^2 M u is a multiple of C
    # (the constraint force), for every mode
    system = mj.mikota_chain(12)
    c = np.zeros(12)
    c[2], c[8] = 1.0, -1.0
    modes = np.asarray(fixed_interface_modes(system, c, 6))
    omega, k, m = _frequencies(system, modes)
    np.testing.assert_allclose(modes[2], modes[8], atol=1e-12)
    residual = k @ modes - m @ modes * omega**2
    outside = residual - np.outer(c, c @ residual) / (c @ c)
    assert np.max(np.abs(outside)) < 1e-10 * np.max(np.abs(k))
    assert np.all(np.diff(omega) > 0)


def test_craig_bampton_basis_holds_the_acting_dampers_and_the_constraint_moments():
    # a grounded damper at DOF 12 (its zero-weight right neighbour is not held) and one of c = 0
    # (not held either); the basis holds the held modes and K^-1 B, (K^-1 M) K^-1 B of all four
    # damper columns
    system = mj.mikota_chain(30, dampers=[mj.GroundedDamper(12.0, 50.0),
                                          mj.GroundedDamper(20.0, 0.0)])
    basis = np.asarray(craig_bampton_basis(system, 10, moments=2))
    assert basis.shape == (30, 18)
    assert np.max(np.abs(basis.T @ basis - np.eye(18))) < 1e-12
    c = np.zeros(30)
    c[11] = 1.0
    held = np.asarray(fixed_interface_modes(system, c, 10))
    static = np.asarray(static_moments(system, damper_directions(system), 2))
    for part in (held, static):
        outside = part - basis @ (basis.T @ part)
        assert np.max(np.linalg.norm(outside, axis=0) / np.linalg.norm(part, axis=0)) < 1e-10
    with pytest.raises(ValueError, match="moments must be an integer >= 1"):
        craig_bampton_basis(system, 10, moments=0)


def test_craig_bampton_basis_takes_a_strong_damper_that_pins_its_dof():
    # Mikota n = 40, x_3(0) = 1, a damper of c = 1e4 at DOF 20 (nearly the chain held there):
    # the reduced energy against the full model's dense Van Loan value converges with the held
    # modes (measured 0.16 / 5.2e-4 / 7.3e-7 at 20 / 26 / 30 held modes + 6 moment columns)
    n = 40
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(20.0, 1e4)])
    x0 = jnp.zeros(n).at[2].set(1.0)
    full = float(mj.Energy(10.0, x0, method=mj.DenseExponential())(system))
    errors = []
    for rank in (26, 30):
        basis = craig_bampton_basis(system, rank)
        assert basis.shape == (n, rank + 6)
        errors.append(abs(float(mj.Energy(10.0, x0)(mj.reduce(system, mj.Projection(basis))))
                          / full - 1))
    assert errors[1] < 1e-5 < errors[0] < 1e-3


def test_craig_bampton_basis_with_the_start_kept_gives_the_gradients():
    # the same pinned chain (c = 1e4 at DOF 20, x_3(0) = 1): with x0 kept in the basis the ROM
    # starts exactly, and its J, dJ/dc and dJ/dp follow the full model's dense ones (measured at
    # 24 held modes + 6 moment columns: J 5.7e-3 / dJ/dc 3.8e-3 / dJ/dp 5.3 off without the start,
    # 5.3e-8 / 9.3e-5 / 2.0e-3 with it)
    n = 40
    x0 = jnp.zeros(n).at[2].set(1.0)

    def energy(position, coefficient, basis=None):
        system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(position, coefficient)])
        model = system if basis is None else mj.reduce(system, mj.Projection(basis))
        return mj.Energy(10.0, x0, method=mj.DenseExponential())(model)

    values = jax.value_and_grad(energy, argnums=(0, 1))
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(20.0, 1e4)])
    full, (dp, dc) = values(20.0, 1e4)
    errors = {}
    for kept in (False, True):
        basis = craig_bampton_basis(system, 24, states=x0 if kept else None)
        assert basis.shape == (n, 31 if kept else 30)
        value, (rp, rc) = values(20.0, 1e4, basis)
        errors[kept] = (abs(value / full - 1), abs(rc / dc - 1), abs(rp / dp - 1))
    basis = np.asarray(craig_bampton_basis(system, 24, states=x0))
    assert np.linalg.norm(x0 - basis @ (basis.T @ x0)) < 1e-12
    assert errors[True][0] < 1e-6 and errors[True][1] < 1e-3 and errors[True][2] < 1e-2
    assert errors[False][0] > 1e-3 and errors[False][2] > 1.0
    with pytest.raises(ValueError, match=r"states must be \(n,\) or \(n, s\)"):
        craig_bampton_basis(system, 10, states=np.ones(4))
