"""The H-infinity norm of a first-order system, by the Hamiltonian level-set algorithm.

Convention: G(s) = C (s E - A)^-1 B with real a (N, N), b (N, m), c (q, N), e (N, N) invertible
(None: the identity) and no feedthrough (D = 0). ||G||_inf = sup_w sigma_max(G(i w)) over
w >= 0, in the units of the outputs per input; it is finite only for a strictly stable pencil.

For gamma > 0 the Hamiltonian H(gamma) = [[A, B B^T / gamma], [-C^T C / gamma, -A^T]] (with
A := E^-1 A, B := E^-1 B) has an eigenvalue i w exactly where some singular value of G(i w)
equals gamma (Boyd, Balakrishnan & Kabamba, "A bisection method for computing the H-infinity
norm of a transfer matrix and related problems", Math. Control Signals Systems 2 (1989)
207-219, Theorem 1). Bruinsma & Steinbuch ("A fast algorithm to compute the H-infinity norm of a
transfer function matrix", Systems & Control Letters 14 (1990) 287-293) climb instead of
bisecting: at gamma = (1 + 2 rtol) gamma_lb the imaginary eigenvalues cut the frequency axis into
intervals, sigma_max at their midpoints raises gamma_lb, and when none is left gamma_lb <= ||G||_inf
< (1 + 2 rtol) gamma_lb; the convergence is quadratic. Each imaginary eigenvalue is confirmed on
G itself, and the peak's frequency is polished by golden-section steps. numpy only (dense eigvals
and solves): O(N^3) per iteration.
"""

import numpy as np

from .._errors import MARK

EPS = np.finfo(np.float64).eps


def hinf_norm(a, b, c, e=None, *, rtol: float = 1e-12,
              max_iterations: int = 100) -> tuple[float, float]:
    """(||G||_inf, w_peak >= 0) of G(s) = C (s E - A)^-1 B; the norm to a relative ``rtol``."""
    a, b, c, e = _checked(a, b, c, e)
    if not isinstance(rtol, int | float | np.integer | np.floating) or not 0 < rtol < 1e-2:
        raise ValueError(MARK + f"rtol must be a number in (0, 1e-2), got {rtol!r}.")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int | np.integer) \
            or max_iterations < 1:
        raise ValueError(MARK + f"max_iterations must be an integer >= 1, got "
                         f"{max_iterations!r}.")
    if e is not None and (condition := np.linalg.cond(e)) * EPS >= 1:
        raise ValueError(MARK + f"e must be invertible; it is singular to rounding (condition "
                         f"number {condition:.3g}).")
    pencil = (np.eye(a.shape[0]) if e is None else e, a)
    a_hat, b_hat = (a, b) if e is None else (np.linalg.solve(e, a), np.linalg.solve(e, b))

    poles = np.linalg.eigvals(a_hat)
    worst = poles[np.argmax(poles.real)]
    if worst.real >= -100 * EPS * np.linalg.norm(a_hat, 1):
        raise ValueError(MARK + f"a, e: the pole {worst:.6g} is not strictly stable (real part "
                         ">= 0 within rounding); an unstable or marginally stable system has no "
                         "finite H-infinity norm.")
    if not (b.any() and c.any()):
        return 0.0, 0.0

    # Bruinsma & Steinbuch's start: w = 0, every pole's frequency, and |lambda| of the pole
    # with the largest |Im lambda / Re lambda| / |lambda| (the largest |lambda| if all are real)
    resonance = np.abs(poles.imag / poles.real) / np.abs(poles)
    resonant = np.abs(poles[np.argmax(resonance)]) if resonance.any() else np.abs(poles).max()
    probes = np.unique(np.concatenate([[0.0], np.abs(poles.imag), [resonant]]))
    values = np.array([_sigma_max(pencil, b, c, w) for w in probes])
    best = int(np.argmax(values))
    gamma_lb, peak, bracket = values[best], probes[best], None
    if gamma_lb == 0:  # G vanishes at every probe: G = 0 (B or C outside the dynamics)
        return 0.0, 0.0

    for _ in range(max_iterations):
        gamma = (1 + 2 * rtol) * gamma_lb
        crossings = _crossings(a_hat, b_hat, c, pencil, b, gamma)
        if crossings.size == 0:
            break
        # the crossings come in +-w pairs: the midpoints of consecutive ones, w >= 0
        signed = np.concatenate([-crossings[::-1], crossings])
        middles = (signed[:-1] + signed[1:]) / 2
        keep = middles >= 0
        middles, lower, upper = middles[keep], signed[:-1][keep], signed[1:][keep]
        values = np.array([_sigma_max(pencil, b, c, w) for w in middles])
        best = int(np.argmax(values))
        if values[best] <= gamma:  # crossings that only graze gamma: converged to rounding
            break
        gamma_lb, peak = values[best], middles[best]
        bracket = (max(lower[best], 0.0), upper[best])
    else:
        raise ValueError(MARK + f"max_iterations = {max_iterations} reached before the level "
                         f"set emptied: the norm is >= {gamma_lb:.17g} (sigma_max still crossed "
                         f"the last level tried, gamma = {gamma:.17g}). Increase max_iterations "
                         "or loosen rtol.")
    if bracket is not None:
        gamma_lb, peak = _golden_polish(pencil, b, c, bracket, gamma_lb, peak)
    return float(gamma_lb), float(peak)


def _checked(a, b, c, e):
    """The matrices as float64, with their shapes and finiteness checked."""
    arrays = {}
    for name, x in (("a", a), ("b", b), ("c", c), ("e", e)):
        if x is None:
            arrays[name] = None
            continue
        x = np.asarray(x)
        if not (np.issubdtype(x.dtype, np.number) or x.dtype == np.bool_) \
                or np.iscomplexobj(x):
            raise ValueError(MARK + f"{name} must be a real matrix, got dtype {x.dtype}.")
        arrays[name] = x.astype(np.float64)
    a, b, c, e = arrays.values()
    n = a.shape[0] if a.ndim == 2 else -1
    if n < 1 or a.shape != (n, n):
        raise ValueError(MARK + f"a must be a square matrix of shape (N, N), N >= 1; got shape "
                         f"{a.shape}.")
    if b.ndim != 2 or b.shape[0] != n or b.shape[1] < 1:
        raise ValueError(MARK + f"b must have shape ({n}, m), m >= 1; got shape {b.shape}.")
    if c.ndim != 2 or c.shape[1] != n or c.shape[0] < 1:
        raise ValueError(MARK + f"c must have shape (q, {n}), q >= 1; got shape {c.shape}.")
    if e is not None and e.shape != (n, n):
        raise ValueError(MARK + f"e must be None or of shape ({n}, {n}); got shape {e.shape}.")
    for name, x in arrays.items():
        if x is not None and not np.all(np.isfinite(x)):
            raise ValueError(MARK + f"{name} must have finite entries (found inf or nan).")
    return a, b, c, e


def _singular_values(pencil, b, c, w):
    """The singular values of G(i w), by a dense solve with the pencil (i w E - A)."""
    e, a = pencil
    return np.linalg.svd(c @ np.linalg.solve(1j * w * e - a, b), compute_uv=False)


def _sigma_max(pencil, b, c, w):
    return _singular_values(pencil, b, c, w)[0]


def _crossings(a_hat, b_hat, c, pencil, b, gamma):
    """The frequencies w >= 0 (sorted) where a singular value of G(i w) equals gamma: H(gamma)'s
    imaginary eigenvalues, each confirmed on G itself (a lightly damped pole's eigenvalue pair
    lies within the |Re| tolerance of the axis without being a crossing)."""
    hamiltonian = np.block([[a_hat, b_hat @ b_hat.T / gamma], [-c.T @ c / gamma, -a_hat.T]])
    eigenvalues = np.linalg.eigvals(hamiltonian)
    near = np.abs(eigenvalues.real) <= 1e-8 * np.linalg.norm(hamiltonian, 1)
    candidates = np.unique(np.abs(eigenvalues[near].imag))
    confirmed = [w for w in candidates
                 if np.min(np.abs(_singular_values(pencil, b, c, w) - gamma)) <= 1e-6 * gamma]
    return np.asarray(confirmed, dtype=np.float64)


def _golden_polish(pencil, b, c, bracket, value, peak, steps: int = 80):
    """Golden-section steps for the peak's frequency around the last interval above gamma; the
    value moves only upward (it was already within rtol; the frequency gains digits). The
    interval is widened by its width on each side: near the top its ends are a nearly double
    eigenvalue pair of H, accurate only to about their distance (a peak 1e-11 outside it was
    missed)."""
    ratio = (np.sqrt(5.0) - 1) / 2
    lo, hi = bracket
    lo, hi = max(lo - (hi - lo), 0.0), hi + (hi - lo)
    x1, x2 = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
    f1, f2 = _sigma_max(pencil, b, c, x1), _sigma_max(pencil, b, c, x2)
    for _ in range(steps):
        if hi - lo <= 4 * EPS * hi:
            break
        if f1 >= f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - ratio * (hi - lo)
            f1 = _sigma_max(pencil, b, c, x1)
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + ratio * (hi - lo)
            f2 = _sigma_max(pencil, b, c, x2)
        for x, f in ((x1, f1), (x2, f2)):
            if f > value:
                value, peak = f, x
    return value, peak
