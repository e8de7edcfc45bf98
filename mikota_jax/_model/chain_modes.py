"""Undamped modes of a fixed-free chain in O(n^2) time and O(n) memory per mode.

A chain (eq. 2.2) has K = L^T diag(k) L, L the (n, n) bidiagonal difference (x_i - x_{i-1},
x_0 = 0), and a diagonal M. Its modes K u = omega^2 M u, U^T M U = I, are computed on
T = M^-1/2 K M^-1/2 = C^T C, C = diag(sqrt k) L M^-1/2, held in the qd form T = L_T D L_T^T of the
bidiagonal C: ``q`` (the pivots k_i / m_i), ``e`` (k_i / m_{i-1}) and the off-diagonal ``t``, in
*work order* (DOF n first, so that C^T C is an L D L^T and not a U D U^T factorisation).

* Eigenvalues: for Mikota's chain (recognised from the data) exactly l^2 k / m; otherwise
  bisection on Sturm counts of L D L^T - tau I by the differential stationary qd
  transform (dstqds), vectorised over all n eigenvalues (one O(n) scan per step over an (n,) vector
  of shifts), geometric midpoints while an interval spans more than a factor 4, arithmetic after.
  The qd entries determine the eigenvalues to high relative accuracy and dstqds is mixed relatively
  stable, so each count is exact for entries perturbed by a few ulps and every eigenvalue, the
  smallest of a chain with masses over twelve decades included, comes out to a few ulps
  *relative* (Demmel & Kahan 1990, SIAM J. Sci. Stat. Comput. 11, 873; Fernando 1998, SIAM J.
  Matrix Anal. Appl. 20, 373; Dhillon & Parlett 2004, Linear Algebra Appl. 387, 1).
* Eigenvectors: one twisted factorisation L+ D+ L+^T (top) / U- D- U-^T (bottom) of T - lambda I
  per eigenvalue, twisted at r = argmin |gamma_r| (Dhillon & Parlett 2004, the MRRR kernel of
  LAPACK's dlar1v): z_r = 1 and (T - lambda I) z = gamma_r e_r, O(n) per mode, no
  reorthogonalisation (the error is O(n eps / relgap) in each vector).
* Derivatives (custom JVP): d omega_l^2 = u_l^T (dK - omega_l^2 dM) u_l and du_l from
  (K - omega_l^2 M) du_l = -(dK - omega_l^2 dM) u_l + d omega_l^2 M u_l with
  u_l^T M du_l = -u_l^T dM u_l / 2, in O(n) per mode: row r of the singular system is implied
  by the others, so it and du_r are dropped, the two tridiagonal blocks left are solved by
  Gaussian elimination with partial pivoting (dgtsv) and the M-component is set afterwards.
  Reverse mode goes through the same rules (the tangent maps are linear and transposable).

Conventions: DOFs 0-based in ``rows`` (this module is private; the public API is 1-based);
eigenvalues ascending; each mode's largest-magnitude entry positive (the package's sign rule).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Float, Matrix, Vector
from .._errors import MARK, as_float, check
from .._limits import chunk as work_chunk

_EPS = float(np.finfo(np.float64).eps)
_MAX_BISECTIONS = 200  # > 53 + log2(log2(hi / lo)) for any float64 bracket


def _validate(masses, springs):
    masses, springs = as_float(masses, "masses"), as_float(springs, "springs")
    if masses.ndim != 1 or masses.shape[0] < 1:
        raise ValueError(MARK + f"masses must be a 1-d array of length n >= 1, got {masses.shape}.")
    if springs.shape != masses.shape:
        raise ValueError(MARK + f"springs must have the shape of masses {masses.shape}, "
                         f"got {springs.shape}.")
    masses = check(masses, ~(jnp.isfinite(masses) & (masses > 0)), "masses must be finite and > 0.")
    springs = check(springs, ~(jnp.isfinite(springs) & (springs > 0)),
                    "springs must be finite and > 0.")
    return masses, springs


def _qd(masses, springs):
    """(q, e, t) of T = M^-1/2 K M^-1/2 in work order: T = L D L^T, D = diag(q), e_j = l_j^2 q_j,
    off-diagonal t_j = l_j q_j (each entry one rounding from the data)."""
    m, k = masses[::-1], springs[::-1]
    return k / m, k[:-1] / m[1:], -k[:-1] / jnp.sqrt(m[:-1] * m[1:])


def _bracket(masses, springs):
    """(lower, upper) with every eigenvalue inside: 1 / trace T^-1 and trace T, with margins.

    trace T^-1 = ||C^-1||_F^2 = sum_i m_i sum_{j <= i} 1 / k_j (C^-1 = M^1/2 L^-1 diag(k^-1/2),
    L^-1 all ones below the diagonal): sums of positive terms, so both bounds are accurate.
    """
    flexibility = jnp.sum(masses * jnp.cumsum(1 / springs))
    trace = jnp.sum(springs / masses) + jnp.sum(springs[1:] / masses[:-1])
    return 0.5 / flexibility, 2 * trace


def _ratio(numerator, pivot):
    """numerator / pivot, with LAPACK dlaneg's limit 1 where a zero pivot gave inf / inf."""
    ratio = numerator / pivot
    return jnp.where(jnp.isnan(ratio), 1.0, ratio)


def _count_below(q, e, tau, dtype):
    """Number of eigenvalues of L D L^T below each shift in ``tau``: negative pivots of dstqds."""
    def step(carry, entries):
        s, count = carry
        qj, ej = entries
        pivot = qj + s  # D+_j = q_j + s_j
        count = count + (pivot < 0).astype(dtype)
        return (_ratio(s, pivot) * ej - tau, count), None

    e = jnp.concatenate([e, jnp.zeros(1)])
    (_, count), _ = jax.lax.scan(step, (-tau, jnp.zeros(tau.shape, dtype)), (q, e), unroll=4)
    return count


_MIKOTA_ULPS = 8  # m_i i and k_i / (n - i + 1) equal to this many ulps: Mikota's chain


def _mikota_ratio(masses, springs):
    """(whether the data are Mikota's chain m_i = m / i, k_i = (n - i + 1) k to a few ulps, k / m).

    Its eigenvalues are then exactly l^2 k / m, l = 1..n (Weber & Zastrau 2018, eq. 2.4; Mikota
    2001); taken from the data m = m_1, k = k_n, they carry two roundings, as close as bisection
    gets (entries perturbed by a few ulps move each eigenvalue by a few ulps relative)."""
    i = jnp.arange(1, masses.shape[0] + 1, dtype=masses.dtype)
    m, k = masses * i, springs / (masses.shape[0] + 1 - i)
    tol = _MIKOTA_ULPS * _EPS
    same = (jnp.all(jnp.abs(m - m[0]) <= tol * m[0])
            & jnp.all(jnp.abs(k - k[-1]) <= tol * k[-1]))
    return same, springs[-1] / masses[0]


def _eigenvalues(masses, springs):
    """Ascending eigenvalues of T: l^2 k / m for Mikota's chain (``_mikota_ratio``), otherwise by
    vectorised bisection, each to about one ulp relative."""
    mikota, ratio = _mikota_ratio(masses, springs)
    squares = jnp.arange(1, masses.shape[0] + 1, dtype=masses.dtype) ** 2
    return jax.lax.cond(mikota, lambda: squares * ratio, lambda: _bisection(masses, springs))


def _bisection(masses, springs, count: int | None = None):
    """Ascending eigenvalues of T by vectorised bisection, each to about one ulp relative: all
    of them, or the ``count`` lowest."""
    q, e, _ = _qd(masses, springs)
    return _bisect_qd(q, e, *_bracket(masses, springs), q.shape[0] if count is None else count)


def _bisect_qd(q, e, lower, upper, count: int):
    """The ``count`` lowest eigenvalues of L D L^T (qd data ``q``, ``e``) in [lower, upper]."""
    index = jnp.arange(count)
    lo, hi = jnp.full(index.shape, lower), jnp.full(index.shape, upper)

    def unconverged(state):
        lo, hi, step = state
        return (step < _MAX_BISECTIONS) & jnp.any(hi - lo > 2 * _EPS * hi)

    def bisect(state):
        lo, hi, step = state
        mid = jnp.where(hi > 4 * lo, jnp.sqrt(lo) * jnp.sqrt(hi), lo + (hi - lo) / 2)
        above = _count_below(q, e, mid, index.dtype) > index  # lambda_j < mid
        return jnp.where(above, lo, mid), jnp.where(above, mid, hi), step + 1

    lo, hi, _ = jax.lax.while_loop(unconverged, bisect, (lo, hi, 0))
    return lo + (hi - lo) / 2


def _nonzero(pivot, entry):
    """A zero pivot moved to eps * entry: a relative change of one ulp in the qd data, which keeps
    the recurrences finite (an exact zero occurs for integer data such as Mikota's chain)."""
    return jnp.where(pivot == 0, _EPS * entry, pivot)


def _twisted(q, e, tau):
    """(s, p, r) of the twisted factorisations of L D L^T - tau I, per shift (columns): dstqds
    from the top and dqds from the bottom (Dhillon & Parlett 2004), D+_j = q_j + s_j, D-_(j+1) =
    e_j + p_(j+1), and the twist index r = argmin |gamma_j|, gamma_j = s_j + p_j + tau, found
    inside the bottom scan. Only s and p (n, c) are kept: the pivots are made again from them
    where needed (``_ratios``: the same roundings, the same zero-pivot rule). Stacking a scan's
    (n, c) outputs costs ~20x the recurrence itself on a CPU (a fresh buffer's pages first
    touched, a row a step), so every kept array counts."""
    n = q.shape[0]

    def down(s, entries):
        qj, ej = entries
        return s / _nonzero(qj + s, qj) * ej - tau, s

    _, s = jax.lax.scan(down, -tau, (q, jnp.concatenate([e, jnp.zeros(1)])))
    last = q[-1] - tau

    def up(carry, entries):  # row j < n - 1, from the bottom: p_j and the running argmin
        p, best, twist = carry
        qj, ej, sj, j = entries
        p = p / _nonzero(ej + p, ej) * qj - tau
        gamma = jnp.abs(sj + p + tau)
        better = gamma <= best  # ties: the lowest j, as argmin
        return (p, jnp.where(better, gamma, best), jnp.where(better, j, twist)), p

    start = (last, jnp.abs(s[-1] + last + tau), jnp.full(tau.shape, n - 1))
    (_, _, twist), p = jax.lax.scan(up, start, (q[:-1], e, s[:-1], jnp.arange(n - 1)),
                                    reverse=True)
    return s, jnp.concatenate([p, last[None]]), twist


def _vector_scan(q, e, t, s, p, twist, visit, init):
    """Runs the two recurrences of z (z_r = 1, (T - lambda I) z = gamma_r e_r) in one scan of n
    steps, from the top down above r (z_j = -(t_j / D+_j) z_(j+1), j < r) and from the bottom
    up below it (z_j = -(t_(j-1) / D-_j) z_(j-1), j > r); step i meets rows j = n - 1 - i and
    j = i. ``visit(carry, (j, z_j) from the top, (j, z_j) from the bottom)`` -> (carry, out)
    sees each entry once: the top's value at j <= r (z_r = 1 there), the bottom's at j > r
    (zero elsewhere). Returns (carry, stacked outputs)."""
    n = q.shape[0]
    index = jnp.arange(n)
    zero = jnp.zeros_like(twist, dtype=s.dtype)

    def step(carry, entries):
        (top, bottom), inner = carry
        j_top, q_top, t_top, j_bottom, p_bottom, e_bottom, t_bottom = entries
        # the top's row of s read in place (a reversed copy of s would be one more (n, c)
        # buffer)
        s_top = jax.lax.dynamic_index_in_dim(s, j_top, keepdims=False)
        above = -t_top / _nonzero(q_top + s_top, q_top)
        below = -t_bottom / _nonzero(e_bottom + p_bottom, e_bottom)
        top = jnp.where(j_top == twist, 1.0, jnp.where(j_top < twist, above * top, 0.0))
        bottom = jnp.where(j_bottom == twist, 1.0,
                           jnp.where(j_bottom > twist, below * bottom, 0.0))
        inner, out = visit(inner, (j_top, top), (j_bottom, jnp.where(j_bottom > twist, bottom,
                                                                       0.0)))
        return ((top, bottom), inner), out

    # t_j couples rows j and j + 1: none above the last (top) or below the first (bottom)
    t_top = jnp.concatenate([t, jnp.zeros(1)])[::-1]
    e_bottom = jnp.concatenate([jnp.ones(1), e])  # D-_j = e_(j-1) + p_j, j >= 1
    t_bottom = jnp.concatenate([jnp.zeros(1), t])
    ((_, _), inner), out = jax.lax.scan(
        step, ((zero, zero), init),
        (index[::-1], q[::-1], t_top, index, p, e_bottom, t_bottom))
    return inner, out


def _twisted_vectors(q, e, t, s, p, twist):
    """z (n, c) of ``_vector_scan``, per column (work order)."""
    _, (top, bottom) = _vector_scan(q, e, t, s, p, twist,
                                    lambda inner, top, bottom: (inner, (top[1], bottom[1])), ())
    return top[::-1] + bottom


def _modes_of(masses, springs, omega2):
    """(U, twist) for the eigenvalues ``omega2`` (c,): M-orthonormal columns, sign rule."""
    q, e, t = _qd(masses, springs)
    s, p, twist = _twisted(q, e, omega2)
    z = _twisted_vectors(q, e, t, s, p, twist)
    vectors = (z / jnp.linalg.norm(z, axis=0, keepdims=True))[::-1]
    modes = vectors / jnp.sqrt(masses)[:, None]
    return modes * _sign_rule(z, masses)[None, :], twist


def _sign_rule(z, masses):
    """(c,) +-1 that makes each mode's largest |U_i| positive (the first in DOF order among
    equals), judged on |z_j| / sqrt(m) in work order as ``_streamed_modes`` judges it in its
    scan: Mikota's modes have entries of equal size and opposite sign, and the two ways of
    rounding must not pick different ones (the derivative rule takes these modes, the values
    the streamed ones)."""
    size = (jnp.abs(z) * (1 / jnp.sqrt(masses[::-1]))[:, None])[::-1]  # DOF order
    at = jnp.argmax(size, axis=0)
    largest = jnp.take_along_axis(z[::-1], at[None, :], axis=0)[0]
    return jnp.where(largest < 0, -1.0, 1.0)


def _streamed_modes(masses, springs, omega2, rows, vectors):
    """(U[rows] (s, c), U^T vectors (c, p)) for the eigenvalues ``omega2`` (c,), the same modes as
    ``_modes_of`` without holding U or z: the vector's scan (``_vector_scan``) sums |z|^2, z's
    entries times ``vectors`` and the requested rows, and tracks the largest entry for the sign
    rule. Same z entries as ``_modes_of``; the sums in another order (rounding)."""
    q, e, t = _qd(masses, springs)
    n = q.shape[0]
    scale = 1 / jnp.sqrt(masses[::-1])  # work order: U = z / (|z| sqrt(m))
    weighted = vectors[::-1] * scale[:, None]  # (n, p) in work order
    work_rows = n - 1 - rows  # (s,)
    s, p, twist = _twisted(q, e, omega2)

    def visit(inner, *entries):
        norm, projected, picked, largest, at = inner
        for j, z in entries:
            norm = norm + z * z
            projected = projected + z[:, None] * weighted[j][None, :]
            picked = jnp.where((work_rows == j)[:, None] & (z != 0)[None, :], z[None, :], picked)
            # the sign rule's entry: the largest |U_i|, the first in DOF order (the last in work
            # order) among equals
            size = jnp.abs(z) * scale[j]
            take = (size > jnp.abs(largest)) | ((size == jnp.abs(largest)) & (j > at))
            largest = jnp.where(take, z * scale[j], largest)
            at = jnp.where(take, j, at)
        return (norm, projected, picked, largest, at), None

    zeros = jnp.zeros_like(omega2)
    init = (zeros, jnp.zeros(omega2.shape + vectors.shape[1:]),
            jnp.zeros(rows.shape + omega2.shape), zeros, jnp.full(omega2.shape, -1))
    (norm, projected, picked, largest, _), _ = _vector_scan(q, e, t, s, p, twist, visit, init)
    sign = jnp.where(largest < 0, -1.0, 1.0) / jnp.sqrt(norm)
    return picked * sign[None, :] * scale[work_rows][:, None], projected * sign[:, None]


def _solve_deflated(q, e, t, omega2, twist, rhs):
    """y with y_r = 0 solving every row but r of (T - lambda I) y = rhs (work order, per column).

    Row r is implied by the others for rhs orthogonal to the eigenvector; dropping it and y_r
    leaves two tridiagonal blocks, solved here as one matrix (row and column r set to e_r) by
    Gaussian elimination with partial pivoting (LAPACK dgtsv): stable where the unpivoted pivots
    D+ / D- vanish, as they do exactly for integer data such as Mikota's chain.
    """
    n = q.shape[0]
    index, r = jnp.arange(n)[:, None], twist[None, :]
    diagonal = jnp.where(index == r, 1.0,
                         (q + jnp.concatenate([jnp.zeros(1), e]))[:, None] - omega2[None, :])
    # coupling (j, j+1) = (j+1, j) = t_j, cut where j == r or j + 1 == r; padded to n rows
    off = jnp.where((index[:-1] == r) | (index[:-1] + 1 == r), 0.0, t[:, None])
    off = jnp.concatenate([off, jnp.zeros_like(off[:1])])
    rhs = jnp.where(index == r, 0.0, rhs)

    def eliminate(carry, row):  # carry: row i after elimination (d_i, u_i, b_i)
        d, u, b = carry
        lower, d_next, u_next, b_next = row  # (i+1, i), (i+1, i+1), (i+1, i+2), rhs_{i+1}
        swap = jnp.abs(d) < jnp.abs(lower)
        pivot = jnp.where(swap, lower, d)
        fact = jnp.where(swap, d, lower) / jnp.where(pivot == 0, 1.0, pivot)
        final = (pivot, jnp.where(swap, d_next, u), jnp.where(swap, u_next, 0.0),
                 jnp.where(swap, b_next, b))
        carry = (jnp.where(swap, u - fact * d_next, d_next - fact * u),
                 jnp.where(swap, -fact * u_next, u_next),
                 jnp.where(swap, b - fact * b_next, b_next - fact * b))
        return carry, final

    rows = (off[:-1], diagonal[1:], off[1:], rhs[1:])
    (d, _, b), (pivots, first, second, values) = jax.lax.scan(
        eliminate, (diagonal[0], off[0], rhs[0]), rows)
    pivots = jnp.concatenate([pivots, d[None]])
    first, second = (jnp.concatenate([a, jnp.zeros_like(a[:1])]) for a in (first, second))
    values = jnp.concatenate([values, b[None]])

    def substitute(carry, row):
        x1, x2 = carry  # x_{i+1}, x_{i+2}
        pivot, u1, u2, value = row
        x = (value - u1 * x1 - u2 * x2) / pivot
        return (x, x1), x

    zeros = jnp.zeros_like(rhs[0])
    return jax.lax.scan(substitute, (zeros, zeros), (pivots, first, second, values),
                        reverse=True)[1]


def _tangents(masses, springs, omega2, modes, twist, dmasses, dsprings):
    """(d omega^2, dU) of the modes in ``modes`` (n, c) for tangents (dm, dk), O(n) per mode."""
    q, e, t = _qd(masses, springs)
    zero = jnp.zeros_like(modes[:1])
    stretch = modes - jnp.concatenate([zero, modes[:-1]])  # (L u)_i = u_i - u_{i-1}
    inertia = jnp.sum(dmasses[:, None] * modes**2, axis=0)  # u^T dM u
    domega2 = jnp.sum(dsprings[:, None] * stretch**2, axis=0) - omega2 * inertia
    force = dsprings[:, None] * stretch
    stiff = force - jnp.concatenate([force[1:], zero])  # dK u = L^T (dk * L u)
    rhs = (omega2[None, :] * dmasses[:, None] * modes - stiff
           + domega2[None, :] * masses[:, None] * modes)
    scale = jnp.sqrt(masses)[:, None]
    y = _solve_deflated(q, e, t, omega2, twist, (rhs / scale)[::-1])[::-1]
    w = y / scale  # (K - omega^2 M) w = rhs, up to a multiple of u
    along = jnp.sum(modes * masses[:, None] * w, axis=0)
    return domega2, w - (along + inertia / 2)[None, :] * modes


@jax.custom_jvp
def _chain_modes(masses, springs):
    omega2 = _eigenvalues(masses, springs)
    return omega2, _modes_of(masses, springs, omega2)[0]


@_chain_modes.defjvp
def _chain_modes_jvp(primals, tangents):
    (masses, springs), (dmasses, dsprings) = primals, tangents
    omega2 = _eigenvalues(masses, springs)
    modes, twist = _modes_of(masses, springs, omega2)
    domega2, dmodes = _tangents(masses, springs, omega2, modes, twist, dmasses, dsprings)
    return (omega2, modes), (domega2, dmodes)


# compiled once per shape: called eagerly, the scans inside would be traced again on every call
# (their bodies are fresh closures), so modal_decomposition retraced for each new chain
_compiled_chain_modes = jax.jit(_chain_modes)


def chain_modes(masses: Vector, springs: Vector) -> tuple[Vector, Matrix]:
    """(omega^2, U) of a fixed-free chain: K U = M U diag(omega^2), U^T M U = I, ascending.

    ``masses`` m_1..m_n and ``springs`` k_1..k_n, each (n,), finite and > 0 (spring k_i ties
    DOF i to DOF i - 1, k_1 to the support). O(n^2) time, no dense decomposition; every omega^2
    to a few ulps relative (bisection with relatively accurate Sturm counts), the modes by twisted
    factorisations (see the module docstring). Differentiable (JVP and VJP) in both arguments.
    """
    masses, springs = _validate(masses, springs)
    return _compiled_chain_modes(masses, springs)


def unchecked_chain_modes(masses: Vector, springs: Vector) -> tuple[Vector, Matrix]:
    """``chain_modes`` without its checks, for a system whose masses and springs were checked
    when it was built (no host callback in a compiled caller)."""
    return _compiled_chain_modes(masses, springs)


def _chunked(omega2, size):
    """omega^2 (n,) padded with its last entry to (count, size)."""
    count = -(-omega2.shape[0] // size)
    padding = jnp.full(count * size - omega2.shape[0], omega2[-1])
    return jnp.concatenate([omega2, padding]).reshape(count, size)


def _unchunked(stacked, n, axis):
    """Undo ``_chunked`` along ``axis`` (0: mode rows of (count, size, ...); 1: columns)."""
    if axis == 0:
        return stacked.reshape(-1, *stacked.shape[2:])[:n]
    return jnp.moveaxis(stacked, 0, 1).reshape(stacked.shape[1], -1)[:, :n]


@jax.custom_jvp
def _mode_data(masses, springs, rows, vectors, size):
    n = masses.shape[0]
    omega2 = _eigenvalues(masses, springs)

    def chunk(lam):
        return _streamed_modes(masses, springs, lam, rows, vectors)

    picked, projected = jax.lax.map(chunk, _chunked(omega2, size.shape[0]))
    return omega2, _unchunked(picked, n, 1), _unchunked(projected, n, 0)


@_mode_data.defjvp
def _mode_data_jvp(primals, tangents):
    (masses, springs, rows, vectors, size), (dmasses, dsprings, _, dvectors, _) = primals, tangents
    n = masses.shape[0]
    omega2 = _eigenvalues(masses, springs)

    @jax.checkpoint  # reverse mode recomputes each chunk's modes rather than storing all of U
    def chunk(lam):
        modes, twist = _modes_of(masses, springs, lam)
        dlam, dmodes = _tangents(masses, springs, lam, modes, twist, dmasses, dsprings)
        return (modes[rows], modes.T @ vectors, dlam, dmodes[rows],
                dmodes.T @ vectors + modes.T @ dvectors)

    picked, projected, domega2, dpicked, dprojected = jax.lax.map(
        chunk, _chunked(omega2, size.shape[0]))
    primal = omega2, _unchunked(picked, n, 1), _unchunked(projected, n, 0)
    tangent = (_unchunked(domega2, n, 0), _unchunked(dpicked, n, 1),
               _unchunked(dprojected, n, 0))
    return primal, tangent


def chain_mode_data(masses: Vector, springs: Vector, rows, vectors: Float[Array, "n p"], *,
                    chunk: int | None = None
                    ) -> tuple[Vector, Float[Array, "s n"], Float[Array, "n p"]]:
    """(omega^2, U[rows, :], U^T vectors) of a fixed-free chain without storing U.

    ``rows``: 0-based DOF indices (s,), ints (static or traced); ``vectors``: (n, p). The modes are
    made ``chunk`` at a time (default: about 2^24 / n, so each (n, chunk) work array is ~128 MB)
    in a ``lax.map``; memory O(n chunk + n p + s n). Same modes and sign rule as ``chain_modes``;
    differentiable in masses, springs and vectors (reverse mode recomputes each chunk).
    """
    masses, springs = _validate(masses, springs)
    n = masses.shape[0]
    rows = jnp.asarray(rows)
    if rows.ndim != 1 or not jnp.issubdtype(rows.dtype, jnp.integer):
        raise ValueError(MARK + f"rows must be a 1-d array of int DOF indices (0-based), got "
                         f"shape {rows.shape} and dtype {rows.dtype}.")
    rows = check(rows, (rows < 0) | (rows >= n), f"rows must lie in [0, {n - 1}] (0-based).")
    vectors = as_float(vectors, "vectors")
    if vectors.ndim != 2 or vectors.shape[0] != n:
        raise ValueError(MARK + f"vectors must be (n, p) = ({n}, p), got {vectors.shape}.")
    if chunk is None:
        chunk = work_chunk(n, 64)
    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise ValueError(MARK + f"chunk must be an int >= 1 or None, got {chunk!r}.")
    size = jnp.zeros((min(chunk, n), 0))  # the chunk size as a shape: static through custom_jvp
    return _mode_data(masses, springs, rows, vectors, size)


def unchecked_chain_mode_data(masses: Vector, springs: Vector, rows, vectors, chunk=None):
    """``chain_mode_data`` without its checks, for a system whose masses and springs were
    checked when it was built (no host callback in a compiled caller); ``rows`` traced ints."""
    n = masses.shape[0]
    chunk = work_chunk(n, 64) if chunk is None else chunk
    return _mode_data(masses, springs, rows, vectors, jnp.zeros((min(chunk, n), 0)))


def _lowest_of_pieces(q, e, t, lower, upper, count: int):
    """Per piece (rows of the (pieces, N) qd data, padded): the ``count`` lowest eigenvalues
    and their unit eigenvectors of L D L^T, in work order."""
    def one(q, e, t, lower, upper):
        omega2 = _bisect_qd(q, e, lower, upper, count)
        z = _twisted_vectors(q, e, t, *_twisted(q, e, omega2))
        return omega2, z / jnp.linalg.norm(z, axis=0, keepdims=True)

    return jax.vmap(one)(q, e, t, lower, upper)


def _as_fixed_free(masses, springs, right):
    """(masses', springs', s) of a chain piece held at both ends (``right``: the spring that
    ties its last DOF to a held one; None: a free end) as a fixed-free chain in the coordinates
    x = diag(s) x'. The piece's K = L^T D L with L unit lower bidiagonal (-a_i below the
    diagonal) is the backward Cholesky factorisation: D = k + e with e_(P-1) = ``right`` and
    e_i = 1 / (1 / k_(i+1) + 1 / e_(i+1)) (the springs from i on to the held end in series: sums
    of positive terms, no cancellation), a_i = k_i / d_i. With s_0 = 1, s_i = a_i s_(i-1),
    L diag(s) = diag(s) L_1 for the chain's difference matrix L_1, so S K S = L_1^T diag(d s^2)
    L_1 and S M S = diag(m s^2): a fixed-free chain of masses m s^2 and springs d s^2, whose
    M'-orthonormal modes u' give the piece's as u = s u'."""
    if right is None:
        return masses, springs, jnp.ones_like(masses)
    flexibility = 1 / right + jnp.concatenate([jnp.cumsum((1 / springs[1:])[::-1])[::-1],
                                               jnp.zeros(1)])
    d = springs + 1 / flexibility
    s = jnp.cumprod(jnp.concatenate([jnp.ones(1), springs[1:] / d[1:]]))
    return masses * s**2, d * s**2, s


def held_chain_modes(masses, springs, held, count: int) -> tuple[Array, Array]:
    """(omega^2, U) of the ``count`` lowest modes of a fixed-free chain with the DOFs ``held``
    (0-based, concrete) fixed: K U = M U diag(omega^2) on the other DOFs, U zero on the held
    ones, U^T M U = I, ascending. O(n count) time and memory per piece, no dense eigenproblem:
    the held DOFs cut the chain into pieces; each piece is a chain held at one or both ends,
    written as a fixed-free chain (``_as_fixed_free``) and its qd data padded to length n with
    decoupled entries (a zero coupling, a pivot above every eigenvalue of the piece), so that
    one batched kernel finds each piece's ``count`` lowest modes by bisection and twisted
    factorisations as in ``chain_modes`` (a piece's eigenvalues are simple: an unreduced
    tridiagonal); the pieces' modes are merged by frequency, the padding's dropped. One
    compiled program per n, held DOFs and ``count``, the same eagerly and under ``jit`` (masses
    and springs may be traced; not differentiable)."""
    held = tuple(int(i) for i in np.unique(np.asarray(held, dtype=int)))
    return _held_chain_modes(jnp.asarray(masses, dtype=float), jnp.asarray(springs, dtype=float),
                             held, int(count))


@functools.partial(jax.jit, static_argnums=(2, 3))  # one program per n, held DOFs and count
def _held_chain_modes(masses, springs, held, count):
    n = masses.shape[0]
    held = np.asarray(held, dtype=int)
    starts, stops = np.concatenate([[0], held + 1]), np.concatenate([held, [n]])
    qs, es, ts, roots, scales, lowers, uppers = [], [], [], [], [], [], []
    for start, stop in zip(starts, stops):
        size = stop - start
        m, k, s = (_as_fixed_free(masses[start:stop], springs[start:stop],
                                  springs[stop] if stop < n else None) if size
                   else (jnp.ones(1), jnp.ones(1), jnp.zeros(1)))
        size = m.shape[0]
        q, e, t = _qd(m, k)
        lower, upper = _bracket(m, k)
        pad = n - size
        qs.append(jnp.concatenate([q, jnp.full(pad, 2 * upper)]))
        es.append(jnp.concatenate([e, jnp.zeros(pad)]))
        ts.append(jnp.concatenate([t, jnp.zeros(pad)]))
        roots.append(jnp.concatenate([jnp.ones(pad), jnp.sqrt(m)]))  # physical order, pad first
        scales.append(jnp.concatenate([jnp.zeros(pad), s]))
        lowers.append(lower)
        uppers.append(4 * upper)
    omega2, z = _lowest_of_pieces(*(jnp.stack(a) for a in (qs, es, ts)), jnp.stack(lowers),
                                  jnp.stack(uppers), count)
    values, vectors = [], []
    for piece, (start, stop) in enumerate(zip(starts, stops)):
        kept = min(count, stop - start)  # the rest are the padding's eigenvalues
        if kept <= 0:
            continue
        u = z[piece][::-1, :kept] * (scales[piece] / roots[piece])[:, None]
        block = jnp.zeros((n, kept)).at[start:stop].set(u[n - (stop - start):])
        values.append(omega2[piece, :kept])
        vectors.append(block)
    omega2, modes = jnp.concatenate(values), jnp.concatenate(vectors, axis=1)
    order = jnp.argsort(omega2, stable=True)[:count]
    return omega2[order], modes[:, order]
