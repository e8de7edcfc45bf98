"""Invariants of random chains (hypothesis): definite operators, energy that never grows, a full
Galerkin basis that changes nothing, and reduced eigenvalues interlaced with the full spectrum.

Masses and springs are log-uniform over four decades. Every solve compiles once per static
structure (n, the number of grounded dampers, the relative dampers' DOF pairs), so the solver
properties take n in SOLVED_SIZES, two grounded dampers and one relative damper on DOFs (1, n) --
their positions and coefficients, zero included, are drawn -- while the operator properties, which
compile no solver, draw n in SIZES and dampers on any DOFs. Derandomized: CI sees the same cases.
Over wide ranges (issue 18: k/m 1e-8..1e8, damper coefficients 0 and 1e-4..1e16 in units of
m sqrt(k/m)): the energy integral stays within 0 < J <= E0 T, the energy never grows, and the
exact and Dopri8 integrals agree where Dopri8 is not stiff.
"""

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import mikota_jax as mj
from mikota_jax._objective.functions import integrated_energy

SIZES = (1, 2, 3, 5, 8)
SOLVED_SIZES = (1, 2, 5)  # each size compiles every solve once more: ~3 s each on a laptop core
SETTINGS = settings(max_examples=25, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow])
TS = np.linspace(0.0, 5.0, 41)  # uniform: exact_solve of a damped system needs it

exponents = st.floats(-2.0, 2.0)  # log10 of a mass or a spring
coefficients = st.one_of(st.just(0.0), st.floats(-2.0, 1.0).map(lambda e: 10.0**e))


def vectors(n, low=-1.0, high=1.0):
    return st.lists(st.floats(low, high), min_size=n, max_size=n).map(np.array)


@st.composite
def chains(draw, damped=True, any_dampers=False, sizes=SIZES):
    """(system, masses, springs, grounded [(position, c)], relative [((i, j), c)], x0, v0)."""
    n = draw(st.sampled_from(sizes))
    masses, springs = 10.0 ** draw(vectors(n, -2.0, 2.0)), 10.0 ** draw(vectors(n, -2.0, 2.0))
    grounded, relative = [], []
    if damped:
        positions = st.floats(1.0, float(n))
        count = draw(st.integers(0, 2)) if any_dampers else 2
        grounded = [(draw(positions), draw(coefficients)) for _ in range(count)]
        if n >= 2:
            pairs = st.lists(st.integers(1, n), min_size=2, max_size=2, unique=True).map(tuple)
            count = draw(st.integers(0, 2)) if any_dampers else 1
            relative = [(draw(pairs) if any_dampers else (1, n), draw(coefficients))
                        for _ in range(count)]
    dampers = ([mj.GroundedDamper(p, c) for p, c in grounded]
               + [mj.RelativeDamper(pair, c) for pair, c in relative])
    system = mj.chain(masses, springs, dampers)
    return system, masses, springs, grounded, relative, draw(vectors(n)), draw(vectors(n))


def orthonormal(n, r, seed):
    return np.linalg.qr(np.random.default_rng(seed).standard_normal((n, r)))[0]


def energy(system, trajectory):
    """(x^T K x + v^T M v) / 2 at every saved time."""
    M, _, K = (np.asarray(a) for a in system.dense())
    x, v = np.asarray(trajectory.displacement), np.asarray(trajectory.velocity)
    return (np.einsum("ti,ij,tj->t", x, K, x) + np.einsum("ti,ij,tj->t", v, M, v)) / 2


@SETTINGS
@given(case=chains(any_dampers=True), y=vectors(8))
def test_mass_and_stiffness_are_definite_and_damping_semidefinite(case, y, close):
    system, masses, springs, grounded, relative, _, _ = case
    n = masses.size
    y = y[:n]
    M, D, K = (None if a is None else np.asarray(a) for a in system.dense())
    for matrix in (M, K) + ((D,) if D is not None else ()):
        np.testing.assert_array_equal(matrix, matrix.T)
    # the quadratic forms are the kinetic, spring and damper energies of the chain (eq. 2.2)
    close(y @ M @ y, np.sum(masses * y**2), rtol=1e-13)
    close(y @ K @ y, np.sum(springs * np.diff(y, prepend=0.0) ** 2), rtol=1e-12,
          atol=1e-14 * np.sum(springs) * (y @ y))
    for matrix in (M, K):
        np.linalg.cholesky(matrix)  # positive definite, or LinAlgError
        assert np.min(np.linalg.eigvalsh(matrix)) > 0
    assert (D is None) == (not grounded and not relative)
    if D is not None:
        dissipation = sum(c * (y[i - 1] - y[j - 1]) ** 2 for (i, j), c in relative)
        for position, c in grounded:  # a fractional position splits c between two DOFs
            j = min(int(np.floor(position)), max(n - 1, 1))
            w = position - j if n > 1 else 0.0
            dissipation += c * ((1 - w) * y[j - 1] ** 2 + (w * y[j] ** 2 if n > 1 else 0.0))
        scale = (sum(c for _, c in grounded) + 4 * sum(c for _, c in relative)) * (y @ y)
        close(y @ D @ y, dissipation, rtol=1e-12, atol=1e-14 * scale)
        assert np.min(np.linalg.eigvalsh(D)) >= -1e-13 * max(1.0, np.max(np.abs(D)))


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
@SETTINGS
@given(case=chains(sizes=SOLVED_SIZES))
def test_energy_never_grows_in_damped_free_vibration(case):
    system, *_, x0, v0 = case
    e = energy(system, mj.solve(system, TS, x0, v0, velocity=True, method=mj.Spectral()))
    assert np.all(np.diff(e) <= 1e-10 * e[0]), np.max(np.diff(e)) / e[0]


@SETTINGS
@given(case=chains(damped=False, sizes=SOLVED_SIZES))
def test_energy_is_constant_in_undamped_free_vibration(case, close):
    system, *_, x0, v0 = case
    e = energy(system, mj.solve(system, TS, x0, v0, velocity=True, method=mj.DenseExponential()))
    close(e, np.full_like(e, e[0]), rtol=1e-10)


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
@SETTINGS
@given(case=chains(sizes=SOLVED_SIZES), seed=st.integers(0, 2**32 - 1))
def test_galerkin_with_a_full_orthonormal_basis_is_the_full_model(case, seed, close):
    system, masses, *_, x0, v0 = case
    basis = orthonormal(masses.size, masses.size, seed)
    full = mj.solve(system, TS, x0, v0, velocity=True, method=mj.Spectral())
    rom = mj.reduce(system, mj.Projection(jnp.asarray(basis)))
    reduced = mj.solve(rom, TS, x0, v0, velocity=True, method=mj.DenseExponential())
    for quantity in ("displacement", "velocity"):
        reference = np.asarray(getattr(full, quantity))
        close(getattr(reduced, quantity), reference, atol=1e-9 * np.max(np.abs(reference)))


@SETTINGS
@given(case=chains(damped=False, sizes=SIZES[1:]), seed=st.integers(0, 2**32 - 1),
       data=st.data())
def test_reduced_eigenvalues_interlace_the_full_spectrum(case, seed, data):
    system, masses, *_ = case
    n = masses.size
    r = data.draw(st.integers(1, n - 1), label="rank")
    basis = orthonormal(n, r, seed)
    M, _, K = (np.asarray(a) for a in system.dense())
    full = scipy.linalg.eigh(K, M, eigvals_only=True)
    rom = mj.reduce(system, mj.Projection(jnp.asarray(basis)))
    Mr, _, Kr = (np.asarray(a) for a in rom.system.dense())
    reduced = scipy.linalg.eigh(Kr, Mr, eigvals_only=True)
    # Poincare separation (Rayleigh-Ritz): lambda_k <= mu_k <= lambda_{k+n-r}, so every reduced
    # eigenvalue lies in [lambda_1, lambda_n]
    slack = 1e-9 * np.abs(full) + 1e-13 * full[-1]
    assert np.all(reduced >= (full - slack)[:r]), (reduced, full)
    assert np.all(reduced <= (full + slack)[n - r:]), (reduced, full)


# ---------------------------------------------------------------- wide ranges (issue 18)

WIDE = settings(SETTINGS, max_examples=6)


@st.composite
def wide_chains(draw):
    """(system, x0, v0, T, d, k/m): Mikota's chain (n = 4) with k / m over sixteen decades and a
    grounded damper of coefficient 0 or 1e-4 .. 1e16 (relative to m sqrt(k/m)) anywhere."""
    ratio = 10.0 ** draw(st.floats(-8.0, 8.0))  # k / m
    m = 10.0 ** draw(st.floats(-3.0, 3.0))
    scale = m * np.sqrt(ratio)  # a damper coefficient of order one for the chain
    d = draw(st.one_of(st.just(0.0), st.floats(-4.0, 16.0).map(lambda e: 10.0**e)))
    position = draw(st.floats(1.0, 4.0))
    system = mj.mikota_chain(4, m, m * ratio, [mj.GroundedDamper(position, d * scale)])
    horizon = 10.0 / np.sqrt(ratio)  # about two periods of the lowest mode
    return system, draw(vectors(4)), draw(vectors(4)), horizon, d, ratio


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
@WIDE
@given(case=wide_chains())
def test_over_wide_ranges_the_energy_integral_is_bounded_and_the_energy_never_grows(case):
    system, x0, v0, horizon, d, ratio = case
    assume(np.any(x0 != 0) or np.any(v0 != 0))
    M, _, K = (np.asarray(a) for a in system.dense())
    e0 = (x0 @ K @ x0 + v0 @ M @ v0) / 2
    j = float(mj.Energy(horizon, x0, v0)(system))
    # a damped free chain dissipates: 0 < J <= E0 T (equality only without damping)
    assert 0 < j <= e0 * horizon * (1 + 1e-12), (j, e0 * horizon)
    ts = np.linspace(0.0, horizon, 41)
    e = energy(system, mj.solve(system, ts, x0, v0, velocity=True, method=mj.Spectral()))
    assert np.all(np.isfinite(e)) and abs(e[0] / e0 - 1) < 1e-10
    assert np.all(np.diff(e) <= 1e-10 * e0), np.max(np.diff(e)) / e0


@pytest.mark.slow
@WIDE
@given(case=wide_chains())
def test_over_wide_ranges_the_exact_and_dopri8_energies_agree_where_both_apply(case, close):
    system, x0, v0, horizon, d, ratio = case
    assume(d <= 1e2)  # stiffer: Dopri8 needs ~d steps; the bound test above covers those
    assume(np.any(x0 != 0) or np.any(v0 != 0))
    exact = mj.Energy(horizon, x0, v0)(system)
    ode = integrated_energy(system, horizon, x0, v0, method="ode", rtol=1e-11, atol=1e-14)
    close(ode, exact, rtol=1e-8)
