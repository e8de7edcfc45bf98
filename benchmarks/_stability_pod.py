"""Rows of ``results/stability.md`` for POD edge cases and the hypothesis invariants, measured now.

``rows()`` returns dicts (area, case, measured, test); every number is computed when it is called
(about 20 s on one core, mostly compiling), each row names the test in ``tests/test_pod_edges.py``
or ``tests/test_properties.py`` that asserts it. The invariant rows draw their own random chains
(numpy, fixed seed; n = 5, masses and springs log-uniform over four decades, two grounded dampers
and one relative damper) in the spirit of the hypothesis tests, which draw n from 1 to 8.
"""

import logging
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scipy.linalg  # noqa: E402

import mikota_jax as mj  # noqa: E402
from mikota_jax.testing import pod  # noqa: E402

EDGES, INVARIANTS = "POD edge cases", "Invariants (hypothesis)"
ENERGIES = (0.5, 0.9, 0.99, 0.9999, 1 - 1e-8, 1 - 1e-12, 1 - 1e-14, 1.0)


def _error(fn) -> str:
    """The first line of the error ``fn`` raises (or says that it raised none)."""
    callbacks = logging.getLogger("jax._src.callback")  # it logs a failed check's traceback
    level, callbacks.level = callbacks.level, logging.CRITICAL
    try:
        jax.block_until_ready(fn())
    except (ValueError, RuntimeError) as error:
        text = str(error)
        text = text[text.index("mikota_jax: "):] if "mikota_jax: " in text else text
        kind = "ValueError" if isinstance(error, ValueError) else "runtime error"
        return f"{kind}: " + text.removeprefix("mikota_jax: ").splitlines()[0][:180]
    finally:
        callbacks.level = level
    return "NO ERROR (silent)"


def _orthonormal(n, r, rng):
    return np.linalg.qr(rng.standard_normal((n, r)))[0]


def edge_rows() -> list[dict]:
    rows = []

    def row(case, measured, test):
        rows.append(dict(area=EDGES, case=case, measured=measured, test=test))

    # a single-mode excitation: x(t) = u_1 cos t, rank 1
    n, ts = 20, np.linspace(0.0, 20.0, 2001)
    shape = np.asarray(mj.analytic.mode_shape(n, 1))
    q = mj.solve(mj.mikota_chain(n), ts, shape, method=mj.DenseExponential()).displacement.T
    for method in ("svd", "snapshots"):
        result = pod(q, method=method)
        s = np.asarray(result.singular_values)
        pom = np.max(np.abs(np.asarray(result.modes[:, 0]) - shape / np.linalg.norm(shape)))
        ranks = {result.rank_for_energy(e, c) for e in ENERGIES for c in ("squared", "paper")}
        row(f"x0 = u_1, Mikota n = {n}, 2001 samples, {method}",
            f"sigma_2/sigma_1 = {s[1] / s[0]:.1e} (noise level {result.rounding_level:.1e}), "
            f"numerical rank {result.numerical_rank()}, r(e) = {sorted(ranks)} for e in 0.5..1 "
            f"(both criteria), |POM_1 - u_1/|u_1|| = {pom:.0e}",
            "test_a_single_mode_excitation_gives_rank_one_with_the_mode_shape_as_first_pom")
    result = pod(q)
    row("rank 2 requested of rank-1 snapshots", _error(lambda: result.basis(2)),
        "test_a_rank_above_the_numerical_rank_is_refused_eagerly_for_every_method")
    row("the same under jax.jit", _error(lambda: jax.jit(lambda q: pod(q).basis(2))(q)),
        "test_a_rank_above_the_numerical_rank_is_refused_under_jit")

    # exact rank 3 of 8: energies up to 1
    rng = np.random.default_rng(2)
    u, v = _orthonormal(8, 8, rng), _orthonormal(40, 8, rng)
    exact3 = pod(u @ np.diag([3.0, 2.0, 1.0, 0, 0, 0, 0, 0]) @ v.T)
    paper = [exact3.rank_for_energy(e, "paper") for e in ENERGIES]
    row("Q of exact rank 3 (8 x 40): energy e -> 1",
        f"numerical rank {exact3.numerical_rank()} of 8 values; r(e) = {paper} for "
        "e = 0.5 ... 1 - 1e-14, 1 (paper criterion): monotone, e = 1 gives the numerical rank",
        "test_energy_one_gives_the_exact_rank_and_no_energy_goes_past_it")
    refused = [e for e in (0.0, 1 + 1e-15, float("nan"))
               if _error(lambda e=e: exact3.rank_for_energy(e)).startswith("ValueError: energy")]
    row("energy = 0, 1 + 1e-15, NaN",
        f"{len(refused)} of 3 refused: {_error(lambda: exact3.rank_for_energy(float('nan')))}",
        "test_energies_outside_0_1_are_refused_by_full_and_truncated_pods")
    zero = pod(np.zeros((4, 7)))
    row("all-zero snapshots (a chain at rest)",
        f"numerical rank {zero.numerical_rank()}; basis(1): {_error(lambda: zero.basis(1))}",
        "test_all_zero_snapshots_have_rank_zero_and_give_no_basis")

    # repeated singular values: compare projectors of each cluster
    s = np.array([3.0, 2.0, 2.0, 2.0, 1.0, 1.0, 0.5])
    u, v = _orthonormal(9, 7, rng), _orthonormal(25, 7, rng)
    for method in ("svd", "snapshots"):
        result = pod(u @ np.diag(s) @ v.T, method=method)
        modes = np.asarray(result.modes)
        projector = max(np.max(np.abs(modes[:, c] @ modes[:, c].T - u[:, c] @ u[:, c].T))
                        for c in (slice(0, 1), slice(1, 4), slice(4, 6), slice(6, 7)))
        row(f"sigma = (3, 2, 2, 2, 1, 1, 0.5), {method}",
            f"max |sigma - s| = {np.max(np.abs(np.asarray(result.singular_values)[:7] - s)):.0e}, "
            f"max projector error {projector:.0e}",
            "test_repeated_singular_values_are_exact_and_their_poms_span_the_right_subspace")

    # one sample: the Rayleigh-quotient ROM
    n = 7
    system = mj.mikota_chain(n)
    x0 = np.linspace(0.2, 1.0, n) ** 2
    result = pod(mj.solve(system, jnp.zeros(1), x0,
                             method=mj.DenseExponential()).displacement.T)
    M, _, K = (np.asarray(a) for a in system.dense())
    omega = np.sqrt(x0 @ K @ x0 / (x0 @ M @ x0))
    ts = np.linspace(0.0, 10.0, 101)
    rom = mj.solve(mj.reduce(system, mj.Projection(result.basis(1))), ts, x0,
                   method=mj.DenseExponential()).displacement
    rom_error = np.max(np.abs(rom - np.cos(omega * ts)[:, None] * x0))
    row("one-sample window (Q is 7 x 1)",
        f"|sigma_1 - |x0|| = {abs(float(result.singular_values[0]) - np.linalg.norm(x0)):.0e}, "
        f"ROM vs x0 cos(sqrt(R(x0)) t): {rom_error:.0e}",
        "test_a_one_sample_window_gives_one_pom_and_the_rayleigh_quotient_rom")

    # one mass: x(t) = x0 cos(sqrt(k/m) t)
    one = mj.chain([2.0], [8.0])
    ts = np.linspace(0.0, 10.0, 201)
    truth = 0.3 * np.cos(2.0 * ts)[:, None]
    exact = mj.solve(one, ts, np.array([0.3]), method=mj.DenseExponential()).displacement
    simulated = mj.solve(one, ts, np.array([0.3]),
                         method=mj.ODE(rtol=1e-12, atol=1e-14)).displacement
    reduced = mj.solve(mj.reduce(one, mj.Projection(pod(exact.T).basis(1))), ts, np.array([0.3]),
                       method=mj.DenseExponential()).displacement
    error = {name: np.max(np.abs(np.asarray(out) - truth))
             for name, out in (("exact", exact), ("simulate", simulated), ("rom", reduced))}
    row("n = 1 (m = 2, k = 8, x0 = 0.3)",
        f"max error: exact_solve {error['exact']:.0e}, simulate (rtol 1e-12) "
        f"{error['simulate']:.0e}, POD + Galerkin {error['rom']:.0e}",
        "test_a_one_mass_chain_is_simulated_solved_reduced_and_agrees_with_the_cosine")

    # bases Galerkin must refuse
    chain = mj.mikota_chain(8, dampers=[mj.GroundedDamper(3.0, 0.4)])
    basis = _orthonormal(8, 4, rng)
    bad = {"a duplicated column": np.column_stack([basis, basis[:, :1]]),
           "columns scaled by 2": 2.0 * basis,
           "columns orthonormal to 1e-5 only": basis + 1e-5 * rng.standard_normal((8, 4))}
    for case, b in bad.items():
        gram = np.max(np.abs(b.T @ b - np.eye(b.shape[1])))
        row(f"Galerkin basis with {case} (max |B^T B - I| = {gram:.0e})",
            _error(lambda b=b: mj.reduce(chain, mj.Projection(jnp.asarray(b)))),
            "test_a_singular_or_non_orthonormal_basis_is_refused_eagerly")
    row("the same (columns scaled by 2) under jax.jit",
        _error(lambda: jax.jit(lambda b: mj.reduce(chain, mj.Projection(b)).system.mass
                               .as_matrix())(jnp.asarray(2.0 * basis))),
        "test_a_non_orthonormal_basis_is_refused_under_jit_and_vmap")
    return rows


def _random_chain(n, rng, damped=True):
    masses, springs = 10.0 ** rng.uniform(-2, 2, n), 10.0 ** rng.uniform(-2, 2, n)
    dampers = []
    if damped:
        dampers = [mj.GroundedDamper(rng.uniform(1, n), 10.0 ** rng.uniform(-2, 1))
                   for _ in range(2)] + [mj.RelativeDamper((1, n), 10.0 ** rng.uniform(-2, 1))]
    return mj.chain(masses, springs, dampers)


def _energy(system, trajectory):
    M, _, K = (np.asarray(a) for a in system.dense())
    x, v = np.asarray(trajectory.displacement), np.asarray(trajectory.velocity)
    return (np.einsum("ti,ij,tj->t", x, K, x) + np.einsum("ti,ij,tj->t", v, M, v)) / 2


def invariant_rows(cases: int = 20, n: int = 5) -> list[dict]:
    rng = np.random.default_rng(0)
    ts = np.linspace(0.0, 5.0, 41)
    worst = dict(definite=np.inf, semidefinite=np.inf, grows=-np.inf, drift=0.0, galerkin=0.0,
                 interlace=np.inf)
    for _ in range(cases):
        damped, undamped = _random_chain(n, rng), _random_chain(n, rng, damped=False)
        x0, v0 = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
        M, D, K = (np.asarray(a) for a in damped.dense())
        worst["definite"] = min(worst["definite"], *(np.min(np.linalg.eigvalsh(a))
                                                     / np.max(np.linalg.eigvalsh(a))
                                                     for a in (M, K)))
        worst["semidefinite"] = min(worst["semidefinite"],
                                    np.min(np.linalg.eigvalsh(D)) / np.max(np.abs(D)))
        full = mj.solve(damped, ts, x0, v0, velocity=True, method=mj.Spectral())
        e = _energy(damped, full)
        worst["grows"] = max(worst["grows"], np.max(np.diff(e)) / e[0])
        e = _energy(undamped, mj.solve(undamped, ts, x0, v0, velocity=True,
                                       method=mj.DenseExponential()))
        worst["drift"] = max(worst["drift"], np.max(np.abs(e - e[0])) / e[0])
        rom = mj.reduce(damped, mj.Projection(jnp.asarray(_orthonormal(n, n, rng))))
        reduced = mj.solve(rom, ts, x0, v0, velocity=True, method=mj.DenseExponential())
        for quantity in ("displacement", "velocity"):
            reference = np.asarray(getattr(full, quantity))
            worst["galerkin"] = max(worst["galerkin"], np.max(np.abs(
                np.asarray(getattr(reduced, quantity)) - reference)) / np.max(np.abs(reference)))
        r = int(rng.integers(1, n))
        rom = mj.reduce(undamped, mj.Projection(jnp.asarray(_orthonormal(n, r, rng))))
        Mr, _, Kr = (np.asarray(a) for a in rom.system.dense())
        Ms, _, Ks = (np.asarray(a) for a in undamped.dense())
        lam = scipy.linalg.eigh(Ks, Ms, eigvals_only=True)
        mu = scipy.linalg.eigh(Kr, Mr, eigvals_only=True)
        # margin of Poincare separation lambda_k <= mu_k <= lambda_{k+n-r}, relative to lambda_n
        worst["interlace"] = min(worst["interlace"], np.min(mu - lam[:r]) / lam[-1],
                                 np.min(lam[n - r:] - mu) / lam[-1])
    where = f"{cases} random chains, n = {n}"

    def verdict(holds, text):
        return text if holds else "VIOLATED"

    table = (
        (f"M, K SPD; D PSD ({where})",
         f"min eig/max eig of M, K: {worst['definite']:.1e} "
         f"({verdict(worst['definite'] > 0, '> 0')}); min eig(D)/max|D| = "
         f"{worst['semidefinite']:.0e} ({verdict(worst['semidefinite'] > -1e-13, 'rounding')})",
         "test_mass_and_stiffness_are_definite_and_damping_semidefinite"),
        (f"damped free vibration energy ({where}, 41 times)",
         f"max (E_k+1 - E_k)/E_0 = {worst['grows']:.0e} "
         f"({verdict(worst['grows'] <= 1e-10, 'never grows')}; test: <= 1e-10)",
         "test_energy_never_grows_in_damped_free_vibration"),
        (f"undamped free vibration energy ({where})",
         f"max |E - E_0|/E_0 = {worst['drift']:.0e} (test: 1e-10)",
         "test_energy_is_constant_in_undamped_free_vibration"),
        (f"Galerkin with a random orthogonal n x n basis ({where})",
         f"max |x_ROM - x|/max|x| = {worst['galerkin']:.0e} (test: 1e-9)",
         "test_galerkin_with_a_full_orthonormal_basis_is_the_full_model"),
        (f"ROM eigenvalues, random orthonormal rank r < n ({where})",
         f"min margin of lambda_k <= mu_k <= lambda_k+n-r: {worst['interlace']:.0e} lambda_n "
         f"({verdict(worst['interlace'] >= 0, 'inside the full spectrum')})",
         "test_reduced_eigenvalues_interlace_the_full_spectrum"),
    )
    return [dict(area=INVARIANTS, case=case, measured=measured, test=test)
            for case, measured, test in table]


def rows() -> list[dict]:
    return edge_rows() + invariant_rows()


if __name__ == "__main__":
    import time

    start = time.perf_counter()
    for r in rows():
        print(f"{r['area']} | {r['case']} | {r['measured']} | {r['test']}")
    print(f"({time.perf_counter() - start:.1f} s)")
