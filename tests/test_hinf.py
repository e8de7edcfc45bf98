"""The H-infinity norm (``_rom/hinf``) against closed forms and an independent grid search."""

import mpmath as mp
import numpy as np
import pytest
import scipy.linalg as sl
from scipy.optimize import minimize_scalar

import mikota_jax as mj
from mikota_jax._rom.hinf import hinf_norm


def oscillator(zeta, omega0):
    """x'' + 2 zeta omega0 x' + omega0^2 x = u, y = x: 1 / (s^2 + 2 zeta omega0 s + omega0^2)."""
    a = np.array([[0.0, 1.0], [-omega0**2, -2 * zeta * omega0]])
    return a, np.array([[0.0], [1.0]]), np.array([[1.0, 0.0]])


def sigma_max(a, b, c, e, w):
    return np.linalg.svd(c @ np.linalg.solve(1j * w * e - a, b), compute_uv=False)[0]


def mp_sigma_max(a, b, c, e, w, dps=30):
    """sigma_max(G(i w)) in mpmath at ``dps`` digits from the float64 entries (exact in mpmath):
    good to ~dps - 10 digits here (the pencil's condition number is below 1e10)."""
    with mp.workdps(dps):
        z = mp.matrix([[mp.mpc(-a[i, j], mp.mpf(w) * e[i, j]) for j in range(a.shape[1])]
                       for i in range(a.shape[0])])
        columns = [mp.lu_solve(z, mp.matrix(b[:, j].tolist())) for j in range(b.shape[1])]
        g = mp.matrix(c) * mp.matrix([[x[i] for x in columns] for i in range(a.shape[0])])
        eigenvalues = mp.eig(g.H * g, left=False, right=False)
        return float(mp.sqrt(max(mp.re(x) for x in eigenvalues)))


def grid_reference(a, b, c, e=None):
    """sup_w sigma_max(G(i w)) by an independent search: a log grid over the whole band plus 201
    points across +-10 half-widths of every pole's resonance, then scipy's bounded Brent
    (minimize_scalar) on -sigma_max around every local maximum of the grid within a factor 2 of
    its best (the grid is fine enough that no other can be the peak), in a variable scaled to the
    bracket so that its x-tolerance (sqrt(eps) |x| + xatol) is relative to the peak's width.
    Returns (the best value, its frequency, every grid value)."""
    e = np.eye(a.shape[0]) if e is None else e
    poles = sl.eigvals(a, e)
    scale = np.abs(poles)
    grids = [[0.0], np.geomspace(scale.min() * 1e-3, scale.max() * 1e3, 1000)]
    grids += [abs(p.imag) + abs(p.real) * np.linspace(-10, 10, 201) for p in poles]
    ws = np.unique(np.abs(np.concatenate(grids)))
    # a conjugate pair's grids differ in the last bit: a near-duplicate would make a bracket
    # too narrow to hold its peak
    ws = ws[np.concatenate([[True], np.diff(ws) > 1e-9 * ws[1:]])]
    values = np.array([sigma_max(a, b, c, e, w) for w in ws])
    best, where = values.max(), ws[values.argmax()]
    maxima = [i for i in range(len(ws)) if values[i] >= max(values[max(i - 1, 0)], best / 2)
              and values[i] >= values[min(i + 1, len(ws) - 1)]]
    for i in maxima:
        lo, hi = ws[max(i - 1, 0)], ws[min(i + 1, len(ws) - 1)]
        if hi == lo:
            continue
        width = hi - lo
        result = minimize_scalar(lambda t, lo=lo, width=width: -sigma_max(a, b, c, e,
                                                                          lo + width * t),
                                 bounds=(0.0, 1.0), method="bounded",
                                 options={"xatol": 1e-13, "maxiter": 500})
        if -result.fun > best:
            best, where = -result.fun, lo + width * result.x
    return best, where, values


@pytest.mark.parametrize("zeta", [1e-3, 1e-6])
@pytest.mark.parametrize("omega0", [1.0, 3.7])
def test_a_lightly_damped_oscillator_peaks_at_the_closed_form(close, zeta, omega0):
    # exact: |G(i w)|^-2 = (omega0^2 - w^2)^2 + (2 zeta omega0 w)^2 is smallest at
    # w^2 = omega0^2 (1 - 2 zeta^2), where |G| = 1 / (2 zeta omega0^2 sqrt(1 - zeta^2))
    norm, peak = hinf_norm(*oscillator(zeta, omega0))
    close(norm, 1 / (2 * zeta * omega0**2 * np.sqrt(1 - zeta**2)), rtol=1e-10)
    # |G| falls by delta^2 / (2 zeta^2 omega0^2) at delta from the peak: a value within 2 rtol
    # (rtol = 1e-12) of the top confines the frequency to 2 sqrt(rtol) half-widths zeta omega0
    assert abs(peak - omega0 * np.sqrt(1 - 2 * zeta**2)) <= 2e-6 * zeta * omega0


def test_an_overdamped_system_peaks_at_zero_frequency(close):
    # exact: G(s) = 1/(s + 1) - 1/(s + 3) = 2 / ((s + 1)(s + 3)), |G(i w)| decreasing in w
    # from G(0) = 2/3; a descriptor form E x' = A x (E diagonal) gives the same G
    a, b, c = np.diag([-1.0, -3.0]), np.ones((2, 1)), np.array([[1.0, -1.0]])
    for e in (None, np.diag([2.0, 0.5])):
        a_e = a if e is None else e @ a
        norm, peak = hinf_norm(a_e, b if e is None else e @ b, c, e)
        close(norm, 2 / 3, rtol=1e-14)
        assert peak == 0.0


def random_stable_system(seed, n=20, inputs=2, outputs=3):
    """A = T J T^-1 with J block-diagonal (3 lightly damped pairs, zeta 1e-4..1e-2; 5 pairs with
    zeta 0.05..0.5; 4 real poles) and T well conditioned, and a random invertible E: a = E A."""
    rng = np.random.default_rng(seed)
    blocks = []
    for zeta in np.concatenate([10 ** rng.uniform(-4, -2, 3), rng.uniform(0.05, 0.5, 5)]):
        w = 10 ** rng.uniform(-1, 1)
        blocks.append(np.array([[-zeta * w, w], [-w, -zeta * w]]))
    blocks += [[[-10 ** rng.uniform(-1, 1)]] for _ in range(n - 16)]
    t = np.linalg.qr(rng.standard_normal((n, n)))[0] @ np.diag(rng.uniform(0.5, 2, n))
    a = t @ sl.block_diag(*blocks) @ np.linalg.inv(t)
    e = np.eye(n) + 0.3 * rng.standard_normal((n, n)) / np.sqrt(n)
    b, c = rng.standard_normal((n, inputs)), rng.standard_normal((outputs, n))
    return e @ a, e @ b, c, e


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_random_mimo_systems_match_an_independent_grid_search(close, seed):
    # the reference: bounded Brent on a scaled variable, at each grid maximum; it matches the
    # true supremum to ~1e-13 relative when the grid has caught every peak (201 points across
    # each resonance's +-10 half-widths), and it is a lower bound in any case
    a, b, c, e = random_stable_system(seed)
    norm, peak = hinf_norm(a, b, c, e)
    reference, where, samples = grid_reference(a, b, c, e)
    close(norm, reference, rtol=1e-9)
    assert norm >= samples.max() * (1 - 1e-11)  # a supremum, up to rtol and rounding
    # in mpmath (~20 digits): the value is attained at our peak to the float64 solve's rounding
    # (~1e-11 on a resonance with zeta ~ 1e-4), and our peak is as high as the reference's to
    # 2 rtol (the frequency is right, not only the value)
    at_peak = mp_sigma_max(a, b, c, e, peak)
    close(norm, at_peak, rtol=1e-10)
    assert at_peak >= mp_sigma_max(a, b, c, e, where) * (1 - 2e-12)


def test_a_mikota_chain_matches_an_independent_grid_search(close):
    # n = 30 with the damper at DOF 7: every pole is strictly stable (the slowest decays at
    # Re = -4.7e-5, near w = 30: a peak of half-width 5e-5), DOF 3 in, DOF 20 out. The grid
    # reference evaluates the same dense solve; rounding moves a pole by ~eps ||A|| / |Re| (~1e-10
    # relative), so the truth is good to ~1e-10
    n = 30
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(7.0, 1.0)])
    m, d, k = (np.asarray(x) for x in system.dense())
    e = sl.block_diag(np.eye(n), m)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-k, -d]])
    b = np.zeros((2 * n, 1))
    b[n + 2, 0] = 1.0  # a force at DOF 3 (1-based)
    c = np.zeros((1, 2 * n))
    c[0, 19] = 1.0  # the displacement of DOF 20
    assert sl.eigvals(a, e).real.max() < -4e-5
    norm, peak = hinf_norm(a, b, c, e)
    reference, where, samples = grid_reference(a, b, c, e)
    close(norm, reference, rtol=1e-8)
    assert norm >= samples.max() * (1 - 1e-11)
    close(norm, mp_sigma_max(a, b, c, e, where), rtol=1e-10)  # the reference's value, 20 digits
    assert abs(peak - where) <= 1e-6 * where


def test_refusals_name_the_argument():
    a, b, c = oscillator(0.0, 2.0)  # poles +-2i: no finite norm
    with pytest.raises(ValueError, match=r"^mikota_jax: a, e: the pole .* not strictly stable"):
        hinf_norm(a, b, c)
    a, b, c = oscillator(0.1, 2.0)
    with pytest.raises(ValueError, match=r"^mikota_jax: b must have finite entries"):
        hinf_norm(a, np.array([[np.nan], [1.0]]), c)
    with pytest.raises(ValueError, match=r"^mikota_jax: c must have shape \(q, 2\)"):
        hinf_norm(a, b, c.T)
    with pytest.raises(ValueError, match=r"^mikota_jax: e must be invertible"):
        hinf_norm(a, b, c, np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"^mikota_jax: max_iterations = 1 reached .* norm is >= "):
        hinf_norm(*random_stable_system(0), max_iterations=1)
    with pytest.raises(ValueError, match=r"^mikota_jax: rtol must be a number in \(0, 1e-2\)"):
        hinf_norm(a, b, c, rtol=0.0)


def test_an_io_model_and_its_error_systems_norms_match_the_grid_search(close):
    # the same chain through IOModel (its modal realization) and the error system of an H2
    # optimal model of 4 DOFs, against the grid search of the dense first-order forms (~1e-10)
    n = 30
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(7.0, 1.0)])
    io = mj.IOModel(system, mj.unit_vector(n, 3), cx=mj.unit_vector(n, 20))
    m, d, k = (np.asarray(x) for x in system.dense())
    e = sl.block_diag(np.eye(n), m)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-k, -d]])
    b = np.vstack([np.zeros((n, 1)), np.asarray(io.inputs)])
    c = np.hstack([np.asarray(io.cx), np.zeros((1, n))])
    close(float(io.hinf_norm()), grid_reference(a, b, c, e)[0], rtol=1e-8)
    reduced = mj.reduce(io, mj.H2Optimal(4))
    ar, br, cr = reduced.standard()
    error = (sl.block_diag(a, ar), np.vstack([b, br]), np.hstack([c, -cr]),
             sl.block_diag(e, np.eye(ar.shape[0])))
    close(float((io - reduced).hinf_norm()), grid_reference(*error)[0], rtol=1e-8)
    close(float(reduced.hinf_norm()), grid_reference(ar, br, cr)[0], rtol=1e-9)


def test_a_peak_that_rounding_cannot_resolve_is_refused():
    # n = 60, damper at DOF 7: mode 60's shape at the damper is ~1e-9, so it decays at ~1e-18,
    # below a dense solve's rounding, yet DOF 3 excites it and DOF 30 sees it (a peak ~830)
    system = mj.mikota_chain(60, dampers=[mj.GroundedDamper(7.0, 1.0)])
    io = mj.IOModel(system, mj.unit_vector(60, 3), cx=mj.unit_vector(60, 30))
    with pytest.raises(ValueError, match="mode 60 is damped below rounding"):
        io.hinf_norm()
