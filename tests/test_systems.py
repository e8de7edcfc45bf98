"""Any second-order system: a user's matrices, internal damping, branched chains (issue 7).

Truths: the eigenvalues of the state matrix (numpy, dense) for damping ratios; Rayleigh's closed
form alpha / (2 omega) + beta omega / 2; ``mikota_chain`` for Mikota's chain given as matrices; a
hand-assembled stiffness and scipy's eigh for branched chains; dense solutions for the banded and
sparse formats; central differences for gradients.
"""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
import scipy.sparse as sp

import mikota_jax as mj
from mikota_jax._model.operators import (
    Dense,
    Diagonal,
    Sparse,
    SymmetricBanded,
    SymmetricTridiagonal,
)
from mikota_jax._objective.functions import integrated_energy
from mikota_jax._placement.objective import placement_objective
from mikota_jax._placement.problem import DamperProblem
from mikota_jax._rom.pod import pod

N = 8
TS = jnp.linspace(0.0, 6.0, 61)
DAMPER = mj.GroundedDamper(3.0, 0.4)


def damping_ratios(system):
    """zeta_l = -Re(lambda) / |lambda| of the state matrix's eigenvalues, by ascending |lambda|."""
    m, d, k = (np.asarray(a) for a in system.dense())
    n = m.shape[0]
    d = np.zeros((n, n)) if d is None else d
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(m, k), -np.linalg.solve(m, d)]])
    lam = np.linalg.eigvals(a)
    lam = lam[lam.imag > 0]  # underdamped modes: one of each conjugate pair
    lam = lam[np.argsort(np.abs(lam))]
    return -lam.real / np.abs(lam), np.abs(lam)


def spd(n, seed, scale=1.0):
    """A random symmetric positive definite matrix, well conditioned."""
    a = np.random.default_rng(seed).standard_normal((n, n))
    return scale * (a @ a.T / n + np.eye(n))


def pentadiagonal_stiffness(n):
    """A grounded chain with second-neighbour springs: sum_s k_s (e_a - e_b)(e_a - e_b)^T (SPD)."""
    k = np.zeros((n, n))
    springs = [(a, a - 1, 1.0 + 0.1 * a) for a in range(n)] + [(a, a - 2, 0.3)
                                                                for a in range(2, n)]
    for a, b, spring in springs:
        e = np.zeros(n)
        e[a] = 1.0
        if b >= 0:
            e[b] = -1.0
        k += spring * np.outer(e, e)
    return k


def branched():
    masses = [jnp.array([1.0, 0.8, 1.2]), jnp.array([0.5, 0.7]), jnp.array([1.0, 1.0, 0.9])]
    springs = [jnp.array([1.0, 2.0, 1.5, 1.0]), jnp.array([2.0, 1.0, 3.0]),
               jnp.array([1.0, 1.0, 1.0, 2.0])]
    return masses, springs


def assembled_branched(masses, springs, hub_mass, hub_spring):
    """The branched chain's M and K assembled spring by spring (independent of the package)."""
    n = sum(len(m) for m in masses) + 1
    k, offset = np.zeros((n, n)), 0
    for m, s in zip(masses, springs):
        ends = [(offset, None)] + [(offset + i, offset + i - 1) for i in range(1, len(m))]
        ends.append((offset + len(m) - 1, n - 1))
        for (a, b), spring in zip(ends, np.asarray(s)):
            e = np.zeros(n)
            e[a] = 1.0
            if b is not None:
                e[b] = -1.0
            k += spring * np.outer(e, e)
        offset += len(m)
    k[n - 1, n - 1] += hub_spring
    return np.diag(np.concatenate([np.asarray(m) for m in masses] + [[hub_mass]])), k


# ----------------------------------------------------------------------------- internal damping

@pytest.mark.parametrize("zeta", [0.03, np.linspace(0.01, 0.2, N)])
def test_modal_damping_gives_exactly_the_requested_ratio_in_every_mode(zeta):
    system = mj.mikota_chain(N, internal_damping=mj.ModalDamping(jnp.asarray(zeta)))
    ratios, magnitude = damping_ratios(system)
    np.testing.assert_allclose(ratios, np.broadcast_to(zeta, (N,)), rtol=0, atol=1e-13)
    np.testing.assert_allclose(magnitude, np.arange(1, N + 1), rtol=1e-13)  # |lambda| = omega


def test_modal_damping_of_a_dense_user_system_has_the_requested_ratios():
    zeta = np.linspace(0.05, 0.4, 6)
    system = mj.system(spd(6, 1), spd(6, 2, 10.0), internal_damping=mj.ModalDamping(zeta))
    ratios, magnitude = damping_ratios(system)
    omega = np.sqrt(scipy.linalg.eigh(spd(6, 2, 10.0), spd(6, 1), eigvals_only=True))
    np.testing.assert_allclose(ratios, zeta, atol=1e-12)
    np.testing.assert_allclose(magnitude, omega, rtol=1e-12)


def test_rayleigh_damping_matches_its_closed_form_ratios_on_a_branched_chain():
    alpha, beta = 0.02, 0.01
    masses, springs = branched()
    system = mj.branched_chain(masses, springs, 2.0, 1.0,
                               internal_damping=mj.Rayleigh(alpha, beta))
    m, k = assembled_branched(masses, springs, 2.0, 1.0)
    omega = np.sqrt(scipy.linalg.eigh(k, m, eigvals_only=True))
    ratios, _ = damping_ratios(system)
    np.testing.assert_allclose(ratios, alpha / (2 * omega) + beta * omega / 2, atol=1e-13)


def test_rayleigh_and_modal_damping_add_to_dampers_and_a_user_matrix():
    m, d, k = mj.mikota_chain(N).dense()
    user = np.diag(np.linspace(0.0, 0.3, N))
    system = mj.system(m, k, user, dampers=[DAMPER],
                       internal_damping=(mj.Rayleigh(0.1, 0.01), mj.ModalDamping(0.02)))
    omega, modes = (np.asarray(a) for a in mj.modal_decomposition(system))
    modal = np.asarray(m) @ modes @ np.diag(2 * 0.02 * omega) @ modes.T @ np.asarray(m)
    dampers = np.zeros((N, N))
    dampers[2, 2] = 0.4
    expected = 0.1 * np.asarray(m) + 0.01 * np.asarray(k) + modal + user + dampers
    np.testing.assert_allclose(system.dense()[1], expected, atol=1e-13)


# --------------------------------------------------------------- Mikota's chain as user matrices

def mikota_matrices():
    m, _, k = (np.asarray(a) for a in mj.mikota_chain(N).dense())
    return m, k


def mikota_as(form):
    m, k = mikota_matrices()
    if form == "dense":  # operators as they are: no structure detected
        return Dense(jnp.asarray(m)), Dense(jnp.asarray(k))
    if form == "arrays":  # concrete dense arrays: their diagonal / tridiagonal structure is found
        return m, k
    if form == "bands":
        return np.diag(m), (np.diag(k), np.diag(k, 1))
    if form == "scipy":
        return sp.csr_matrix(m), sp.csr_matrix(k)
    return np.diag(m), Dense(jnp.asarray(k))  # diagonal mass, dense stiffness


@pytest.mark.parametrize("form,structure", [
    pytest.param("dense", (Dense, Dense), marks=pytest.mark.slow),  # default-run time
    pytest.param("arrays", (Diagonal, SymmetricTridiagonal), marks=pytest.mark.slow),
    ("bands", (Diagonal, SymmetricTridiagonal)),
    # scipy.sparse input also in test_banded_sparse_and_dense_stiffness_give_the_same_solutions
    pytest.param("scipy", (Diagonal, SymmetricTridiagonal), marks=pytest.mark.slow),
    ("mixed", (Diagonal, Dense))])
def test_mikota_chain_as_user_matrices_gives_the_same_solution(form, structure):
    reference = mj.mikota_chain(N, dampers=[DAMPER], internal_damping=mj.Rayleigh(0.05, 0.002))
    mass, stiffness = mikota_as(form)
    system = mj.system(mass, stiffness, dampers=[DAMPER],
                       internal_damping=mj.Rayleigh(0.05, 0.002))
    assert (type(system.mass), type(system.stiffness)) == structure
    x0 = jnp.asarray(mj.analytic.mode_shape(N, 2))
    expected = mj.solve(reference, TS, x0=x0, method=mj.Spectral()).displacement
    np.testing.assert_allclose(mj.solve(system, TS, x0=x0, method=mj.Spectral()).displacement,
                               expected, atol=1e-12)
    simulated = mj.solve(system, TS, x0=x0, method=mj.ODE(rtol=1e-10)).displacement
    np.testing.assert_allclose(simulated, expected, atol=1e-8)
    np.testing.assert_allclose(mj.modal_decomposition(system)[0], np.arange(1, N + 1), rtol=1e-12)


# ------------------------------------------------------------ banded, sparse and dense agree

def formats_of(k):
    return {"dense": Dense(jnp.asarray(k)), "bands": (np.diag(k), np.diag(k, 1), np.diag(k, 2)),
            "scipy": sp.coo_matrix(k)}


def test_banded_sparse_and_dense_stiffness_give_the_same_solutions():
    k = pentadiagonal_stiffness(N)
    k = k + 0.6 * (np.abs(np.subtract.outer(np.arange(N), np.arange(N))) == 2) + 0.5 * np.eye(N)
    assert np.all(np.linalg.eigvalsh(k) > 0.1)  # positive off-band entries: no spring "links"
    mass = np.linspace(1.0, 2.0, N)
    x0 = jnp.zeros(N).at[0].set(1.0)
    solutions = {}
    for name, stiffness in formats_of(k).items():
        system = mj.system(mass, stiffness, dampers=[DAMPER],
                           internal_damping=mj.Rayleigh(0.01, 0.005))
        assert isinstance(system.stiffness, {"dense": Dense, "bands": SymmetricBanded,
                                             "scipy": Sparse}[name])
        np.testing.assert_allclose(system.stiffness.as_matrix(), k, atol=1e-15)
        v = jnp.linspace(-1.0, 1.0, N)
        np.testing.assert_allclose(system.stiffness.mv(v), k @ np.asarray(v), atol=1e-14)
        solutions[name] = mj.solve(system, TS, x0=x0, method=mj.ODE(rtol=1e-10)).displacement
        if name == "scipy":  # the stiff solver's dense fallback for a sparse stiffness
            solutions["kvaerno5"] = mj.solve(
                system, TS, x0=x0,
                method=mj.ODE(mj.StructuredKvaerno5(), rtol=1e-10)).displacement
    exact = mj.solve(mj.system(mass, k, dampers=[DAMPER],
                               internal_damping=mj.Rayleigh(0.01, 0.005)), TS, x0=x0,
                     method=mj.Spectral())
    for solution in solutions.values():
        np.testing.assert_allclose(solution, exact.displacement, atol=1e-8)


def test_a_non_diagonal_mass_from_every_format_gives_the_same_solutions():
    m, k = spd(N, 3), pentadiagonal_stiffness(N)
    m = m * (np.abs(np.subtract.outer(np.arange(N), np.arange(N))) <= 1)  # tridiagonal mass
    m = m + N * np.eye(N)  # still SPD
    x0 = jnp.linspace(0.0, 1.0, N)
    reference = mj.solve(mj.system(m, k), TS, x0=x0, method=mj.DenseExponential()).displacement
    for mass in ((np.diag(m), np.diag(m, 1)), sp.csr_matrix(m)):
        system = mj.system(mass, sp.csr_matrix(k), internal_damping=mj.ModalDamping(0.05))
        damped = mj.solve(system, TS, x0=x0, method=mj.DenseExponential()).displacement
        simulated = mj.solve(system, TS, x0=x0, method=mj.ODE(rtol=1e-10)).displacement
        np.testing.assert_allclose(simulated, damped, atol=1e-8)
        undamped = mj.solve(mj.system(mass, sp.csr_matrix(k)), TS, x0=x0,
                            method=mj.DenseExponential()).displacement
        np.testing.assert_allclose(undamped, reference, atol=1e-12)


# ------------------------------------------------------------------------------ branched chains

def test_branched_chain_stiffness_and_frequencies_match_the_assembled_system():
    masses, springs = branched()
    system = mj.branched_chain(masses, springs, 2.0, 1.0)
    m, k = assembled_branched(masses, springs, 2.0, 1.0)
    np.testing.assert_allclose(system.stiffness.as_matrix(), k, atol=1e-15)
    np.testing.assert_allclose(system.mass.as_matrix(), m, atol=0)
    assert system.stiffness.links == ((2, 8), (4, 8))  # 0-based: branch ends 1, 2 to the hub
    for given in (k, sp.csr_matrix(k)):  # the same structure is found in a user's matrices
        found = mj.system(m, given).stiffness
        assert isinstance(found, SymmetricTridiagonal) and found.links == ((2, 8), (4, 8))
        np.testing.assert_allclose(found.as_matrix(), k, atol=1e-15)
    omega = np.sqrt(scipy.linalg.eigh(k, m, eigvals_only=True))
    np.testing.assert_allclose(mj.modal_decomposition(system)[0], omega, rtol=1e-12)
    v = jnp.arange(1.0, 10.0)
    np.testing.assert_allclose(system.stiffness.mv(v), k @ np.asarray(v), atol=1e-13)


@pytest.mark.slow  # 20 s in CI; test_stiff covers the structured solver
def test_branched_chain_stiff_solver_keeps_the_structure_and_is_exact():
    masses, springs = branched()
    dampers = [mj.GroundedDamper(2.0, 0.5), mj.RelativeDamper((4, 9), 0.3)]
    system = mj.branched_chain(masses, springs, 2.0, 1.0, dampers,
                               internal_damping=mj.Rayleigh(0.02, 0.01))
    from mikota_jax._solver.implicit import dense_shifted_solver, shifted_solver

    rhs = jnp.linspace(-1.0, 2.0, 9)
    np.testing.assert_allclose(shifted_solver(system, 0.3)(rhs),
                               dense_shifted_solver(system, 0.3)(rhs), rtol=1e-12)
    v0 = jnp.zeros(9).at[0].set(1.0)
    exact = mj.solve(system, TS, v0=v0, method=mj.Spectral()).displacement
    implicit = mj.solve(system, TS, v0=v0,
                        method=mj.ODE(mj.StructuredKvaerno5(), rtol=1e-10)).displacement
    np.testing.assert_allclose(implicit, exact, atol=1e-8)


def test_branched_chain_refuses_bad_branches():
    masses, springs = branched()
    with pytest.raises(ValueError, match=r"springs\[1\] must have len\(masses\[1\]\) \+ 1 = 3"):
        mj.branched_chain(masses, [springs[0], springs[1][:2], springs[2]], 2.0, 1.0)
    with pytest.raises(ValueError, match="same number"):
        mj.branched_chain(masses, springs[:2], 2.0, 1.0)
    with pytest.raises(ValueError, match="hub_mass must be finite and > 0"):
        mj.branched_chain(masses, springs, 0.0, 1.0)


# -------------------------------------------------------------------- checks on construction

@pytest.mark.parametrize("arguments,message", [
    ((np.ones((3, 2)), np.eye(3)), "mass must be an"),
    ((np.ones(3), np.eye(4)), "stiffness must be 3 x 3 like mass"),
    ((np.ones(3), np.array([[2.0, 1.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]])),
     "stiffness must be symmetric"),
    ((np.array([1.0, -1.0, 1.0]), np.eye(3)), "mass must be finite and positive definite"),
    ((np.ones(3), np.diag([1.0, 1.0, -1.0])), r"stiffness must be finite and positive definite "
     r"\(a diagonal > 0\)"),
    ((np.ones(3), (np.ones(3), np.full(2, 2.0))), "stiffness must be finite and positive definite"),
    ((np.ones(3), np.array([[1.0, 2, 0], [2, 1, 0], [0, 0, 1]])), "stiffness must be finite and "
     "positive definite"),  # tridiagonal: O(n) pivots
    ((np.ones(3), np.array([[1.0, 0, 2], [0, 1, 0], [2, 0, 1]])), "stiffness must be positive "
     "definite"),  # dense: Cholesky
    ((np.ones(3), np.eye(3), -np.eye(3)), r"damping must be finite and positive semi-definite "
     r"\(a diagonal >= 0\)"),
    ((np.ones(3), np.eye(3), np.array([[1.0, 2, 0], [2, 1, 0], [0, 0, 1]])),
     "damping must be positive semi-definite"),
    ((np.ones(3), np.eye(3), np.full((3, 3), np.nan)), "damping must be finite"),
    ((np.ones(3), sp.csr_matrix(np.triu(np.ones((3, 3))) + 2 * np.eye(3))),
     "stiffness must be symmetric"),
    ((np.ones(3), (np.ones(3), np.ones(1))), "stiffness: bands must be"),
])
def test_system_refuses_bad_matrices_naming_them(arguments, message):
    with pytest.raises(ValueError, match=message):
        mj.system(*arguments)


def test_semi_definite_damping_and_bad_internal_damping():
    system = mj.system(np.ones(3), np.eye(3), np.ones((3, 3)))  # rank one: semi-definite is fine
    assert system.internal.matrix is not None
    with pytest.raises(ValueError, match="alpha must be finite and >= 0"):
        mj.Rayleigh(-1.0, 0.0)
    with pytest.raises(ValueError, match="zeta must be a scalar or have n = 3 entries"):
        mj.system(np.ones(3), np.eye(3), internal_damping=mj.ModalDamping(np.ones(2)))
    with pytest.raises(ValueError, match="at most one Rayleigh"):
        mj.chain(np.ones(3), np.ones(3), internal_damping=(mj.Rayleigh(1, 0), mj.Rayleigh(0, 1)))


def test_a_traced_dense_matrix_stays_dense_and_differentiable():
    m, k = mikota_matrices()

    def lowest(scale):
        return mj.modal_decomposition(mj.system(m, scale * jnp.asarray(k)))[0][0]

    assert isinstance(jax.jit(lambda a: mj.system(m, a * k).stiffness)(1.0), Dense)
    np.testing.assert_allclose(jax.grad(lowest)(4.0), 0.25, rtol=1e-10)  # omega = sqrt(a) l


def test_checks_hold_under_jit():
    @jax.jit
    def build(scale, zeta):
        system = mj.system(jnp.ones(3), scale * jnp.eye(3),
                           internal_damping=mj.ModalDamping(zeta))
        return system.stiffness.as_matrix(), system.internal.modal.zeta

    build(1.0, 0.1)
    with pytest.raises(Exception, match="stiffness must be positive definite"):
        jax.block_until_ready(build(-1.0, 0.1))
    with pytest.raises(Exception, match="zeta must be finite and >= 0"):
        jax.block_until_ready(build(1.0, -0.1))


# ------------------------------------------------------ POD, Galerkin and gradients, the same way

def test_a_full_rank_rom_reproduces_every_internal_damping_model():
    m, k = spd(N, 4), pentadiagonal_stiffness(N) * 4
    system = mj.system(m, sp.csr_matrix(k), np.diag(np.linspace(0, 0.1, N)), dampers=[DAMPER],
                       internal_damping=(mj.Rayleigh(0.02, 0.003), mj.ModalDamping(0.01)))
    x0 = jnp.linspace(1.0, 0.0, N)
    full = mj.solve(system, TS, x0=x0, method=mj.DenseExponential()).displacement
    basis = pod(full.T).basis(N)
    rom = mj.reduce(system, mj.Projection(basis))
    np.testing.assert_allclose(mj.solve(rom, TS, x0=x0, method=mj.DenseExponential()).displacement,
                               full, atol=1e-11)
    np.testing.assert_allclose(mj.solve(rom, TS, x0=x0, method=mj.ODE(rtol=1e-10)).displacement,
                               full,
                               atol=1e-8)


@pytest.mark.slow  # ~15 s; CI time (the exact-solve variants stay in the default run)
def test_gradients_in_alpha_beta_zeta_and_the_damper_match_central_differences():
    m, k = spd(N, 5), pentadiagonal_stiffness(N)
    x0 = jnp.linspace(1.0, -1.0, N)
    basis = jnp.asarray(np.linalg.qr(np.random.default_rng(6).standard_normal((N, N - 2)))[0])

    def energy(p, reduced):
        system = mj.system(m, k, dampers=[mj.GroundedDamper(3.0, p[3])],
                           internal_damping=(mj.Rayleigh(p[0], p[1]), mj.ModalDamping(p[2])))
        model = mj.reduce(system, mj.Projection(basis)) if reduced else system
        return mj.Energy(8.0, x0=x0)(model)

    energy = jax.jit(energy, static_argnums=1)
    p = jnp.array([0.05, 0.01, 0.02, 0.3])
    for reduced in (False, True):
        gradient = jax.grad(energy)(p, reduced)
        for i in range(4):
            h = 1e-3 * p[i]
            e = jnp.zeros(4).at[i].set(h)
            difference = (energy(p + e, reduced) - energy(p - e, reduced)) / (2 * h)
            np.testing.assert_allclose(gradient[i], difference, rtol=1e-6)


def test_sensitivities_of_a_custom_scene_name_the_internal_damping_parameters():
    scene = mj.app.load_scene("""
        [chain]
        type = "custom"
        mass = [1.0, 1.0, 1.0]
        stiffness = [[2.0, 2.0, 1.0], [-1.0, -1.0]]
        [internal_damping]
        rayleigh = [0.1, 0.01]
        modal = 0.02
        [initial]
        velocity = {1 = 1.0}
        [time]
        end = 5.0
        step = 0.5
        """)
    parameters = scene.parameters()
    assert set(parameters) == {"alpha", "beta", "zeta", "amplitude"}
    with pytest.raises(ValueError, match="'masses' does not apply: the system is not a fixed"):
        scene.parameters(["masses"])
    function = mj.SceneFunction(scene, "energy")
    result = mj.sensitivities(scene, "energy")
    for name in ("alpha", "beta", "zeta"):
        h = 1e-4 * parameters[name]
        up, down = dict(parameters), dict(parameters)
        up[name], down[name] = parameters[name] + h, parameters[name] - h
        np.testing.assert_allclose(result.jacobian[name], (function(up) - function(down)) / (2 * h),
                                   rtol=1e-6)
    np.testing.assert_allclose(result.normalised["amplitude"], 2.0, rtol=1e-12)  # J ~ a^2


@pytest.mark.slow
def test_damper_problem_keeps_the_internal_damping():
    system = mj.mikota_chain(N, dampers=[DAMPER], internal_damping=mj.Rayleigh(0.05, 0.01))
    x0 = jnp.asarray(mj.analytic.mode_shape(N, 1))
    problem = DamperProblem(system, TS, x0=x0)
    expected = mj.Energy(float(TS[-1]), x0=x0)(system)
    full = placement_objective(problem)(jnp.array([3.0]), jnp.array([0.4]))
    reduced = placement_objective(problem, jnp.eye(N))(jnp.array([3.0]), jnp.array([0.4]))
    np.testing.assert_allclose(full, expected, rtol=1e-9)
    np.testing.assert_allclose(reduced, expected, rtol=1e-9)


def test_own_matrices_page_runs_and_its_gradient_is_right(capsys):
    """docs/own_matrices.md, block by block in one namespace: the printed gradient (through the
    ROM) is the central difference of the page's ``energy``, the structures are the ones the page
    names, and the scene built from the page's files reproduces the Python-built response."""
    import re
    from pathlib import Path

    text = (Path(__file__).parents[1] / "docs" / "own_matrices.md").read_text()
    namespace, printed = {}, None
    for k, code in enumerate(re.findall(r"^```python\n(.*?)^```", text, re.S | re.M), 1):
        exec(compile(code, f"docs/own_matrices.md, python block {k}", "exec"), namespace)
        out = capsys.readouterr().out
        if "jax.grad(energy)" in code:
            printed = float(out.split()[-1])
    assert printed is not None
    energy, h = namespace["energy"], 1e-7
    np.testing.assert_allclose(printed, (energy(1e-3 + h) - energy(1e-3 - h)) / (2 * h), rtol=1e-5)
    assert isinstance(namespace["system"].stiffness, SymmetricTridiagonal)  # dia -> tridiagonal
    assert isinstance(namespace["same"].stiffness, SymmetricTridiagonal)  # read back from a file
    assert namespace["tree"].size == 31 and len(namespace["tree"].stiffness.links) == 2
    scene, full = namespace["result"].full.displacement[:, 0], namespace["full"].displacement[:, 9]
    np.testing.assert_allclose(scene, full, atol=1e-6 * float(jnp.max(jnp.abs(full))))


def test_definiteness_of_a_tridiagonal_with_links_is_checked_in_o_n(monkeypatch):
    import mikota_jax._model.user_matrices as matrices

    masses, springs = branched()
    m, k = assembled_branched(masses, springs, 2.0, 1.0)
    monkeypatch.setattr(matrices, "DENSE_CHECK_LIMIT", 4)  # no dense check possible at n = 9
    found = mj.system(sp.csr_matrix(m), sp.csr_matrix(k)).stiffness
    assert found.links == ((2, 8), (4, 8))
    with pytest.raises(ValueError, match="refused above n = 4 .* check_definite=False"):
        mj.system(np.diag(m), Sparse(*(jnp.asarray(a) for a in np.nonzero(k)), k[k != 0], 9))
    assert isinstance(mj.system(np.diag(m), Sparse(*(jnp.asarray(a) for a in np.nonzero(k)),
                                                   k[k != 0], 9), check_definite=False).stiffness,
                      Sparse)
    bad = k.copy()
    bad[8, 8] = 0.5  # less than the springs to the hub: indefinite
    with pytest.raises(ValueError, match="stiffness: checking that it is positive definite"):
        mj.system(np.diag(m), bad)  # the O(n) sufficient test fails, the dense one is refused
    monkeypatch.undo()
    with pytest.raises(ValueError, match="stiffness must be positive definite"):
        mj.system(np.diag(m), bad)


def bar(n):
    """A fixed-free bar of unit length in n linear finite elements: consistent (tridiagonal) M."""
    h, edge = 1.0 / n, np.ones(n - 1)
    main = np.full(n, 4.0)
    main[-1] = 2.0
    stiff = np.full(n, 2.0)
    stiff[-1] = 1.0
    return (h / 6 * (np.diag(main) + np.diag(edge, 1) + np.diag(edge, -1)),
            (np.diag(stiff) - np.diag(edge, 1) - np.diag(edge, -1)) / h)


@pytest.mark.slow  # 35 s in CI
def test_a_consistent_mass_is_solved_in_its_tridiagonal_structure():
    n = 20
    m, k = bar(n)
    theta = (2 * np.arange(1, n + 1) - 1) * np.pi / (2 * n)  # the discrete bar's modes
    omega = np.sqrt(6 * n**2 * (1 - np.cos(theta)) / (2 + np.cos(theta)))
    system = mj.system(m, k, dampers=[mj.GroundedDamper(10, 0.3)],
                       internal_damping=mj.Rayleigh(0.1, 1e-3))
    assert isinstance(system.mass, SymmetricTridiagonal)
    np.testing.assert_allclose(mj.modal_decomposition(system)[0], omega, rtol=1e-12)
    from mikota_jax._solver.implicit import dense_shifted_solver, shifted_solver
    from mikota_jax._solver.ode import unpack

    assert unpack(system, jnp.zeros(n), jnp.zeros(n), None)[1] is None  # no modal lift
    rhs = jnp.linspace(0.0, 1.0, n)
    np.testing.assert_allclose(shifted_solver(system, 0.01)(rhs),
                               dense_shifted_solver(system, 0.01)(rhs), rtol=1e-12)
    v0 = jnp.zeros(n).at[-1].set(1.0)
    exact = mj.solve(system, TS, v0=v0, method=mj.Spectral()).displacement
    for solver in (diffrax.Dopri8(), mj.StructuredKvaerno5()):
        simulated = mj.solve(system, TS, v0=v0, method=mj.ODE(solver, rtol=1e-10)).displacement
        np.testing.assert_allclose(simulated, exact, atol=1e-9)
    np.testing.assert_allclose(integrated_energy(system, 6.0, v0=v0, method="ode", rtol=1e-10),
                               mj.Energy(6.0, v0=v0)(system), rtol=1e-8)
