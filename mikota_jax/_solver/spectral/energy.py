"""Energies of a system with a few dampers in closed form from its damped modes (``_spectral``).

In the scaled modal coordinates z = (Omega eta, eta') of ``_objectives`` a root lambda_j has the
state eigenvector w_j = (Omega y_j, lambda_j y_j); the energy inner product of two is the modal
Gram matrix G_jk = w_j^T w_k (``modal_gram``), and z(t) = sum_j a_j exp(lambda_j t) w_j with a
from the bi-orthogonality (``DampedModes.coefficients``). Then

* the integrated energy J = int_0^T |z|^2 / 2 dt = 1/2 sum_jk a_j a_k G_jk (e^{s_jk T} - 1) /
  s_jk, s_jk = lambda_j + lambda_k;
* Veselic's total average energy, trace X with A^T X + X A = -Z: since A^T = S A S (S = diag(I,
  -I)), trace X = sum_(i in Z) int_0^inf |exp(A t) e_i|^2 dt, twice the infinite-horizon energy
  of each unit state Z selects (O(s n^2) for the s lowest modes); for Z = I the left
  eigenvectors S w_j / (-lambda_j N_j) give trace X = -sum_jk G_jk^2 / (lambda_j lambda_k N_j N_k
  s_jk), O(n^2) (Veselic, Damped Oscillations of Linear Systems, LNM 2023, 2011, ch. 21;
  Truhar & Veselic, SIAM J. Matrix Anal. Appl. 31:18, 2009).

Both cost O(k n^2) after the modes for dampers alone, O(n^3) (one BLAS-3 product) with internal
damping (``modal_gram``). For dampers alone the energy's double sum carries its own derivative
(``_cauchy_sum``, a custom JVP from sums taken beside the value), so that reverse mode adds
O(k n) work instead of transposing the (2n, 2n) kernel. A pair of nearly coincident roots
(critical damping) is left out of these root-by-root sums and enters by contour integrals of
the resolvent instead (``_spectral_clusters``): its cross terms with every other root
(``cluster_energy``, ``cluster_trace``) cost O(NODES n^2) more per pair, and only where there
is one. Each returns whether it holds (every root converged, every nearly coincident pair in a
cluster).
"""

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp

from ..._custom_types import Array
from ..._model.modal import modal_projection
from .clusters import initial_rhs, resolvent_at, solve_at
from .modes import live_modes, live_rows, uses_rows
from .roots import DampedModes, complex_arithmetic
from .rows import abs2, by_rows, complex_product, row_block, small_solve

# --- the energy kernels: Gram matrix of the damped modes, pair sums, time integrals ----------


@complex_arithmetic
def pair_sums(modes: DampedModes):
    """(s, pair): s_jk = lambda_j + lambda_k (2n, 2n) in pole-offset form (a conjugate pair's
    imaginary parts cancel exactly), and which pairs carry energy (two damped roots, or the two
    roots of one mode no damper touches)."""
    base = modes.poles[modes.anchor]
    s = (base[:, None] + base[None, :]) + (modes.offset[:, None] + modes.offset[None, :])
    active = modes.root_active
    same_mode = modes.modes[:, None] == modes.modes[None, :]
    pair = (active[:, None] & active[None, :]) | (same_mode & ~active[:, None])
    return s, pair


@complex_arithmetic
def modal_gram(modes: DampedModes, y) -> Array:
    """G_jk = y_j^T Omega^2 y_k + lambda_j lambda_k y_j^T y_k, (2n, 2n), zero where the roots
    do not interact: the energy inner product of the state eigenvectors (Omega y_j, lambda_j
    y_j).

    From the eigen-equations of j and k (symmetric D_m), G_jk = -2 lambda_j lambda_k y_j^T D_m
    y_k / (lambda_j + lambda_k); with y^T F = -c / lambda this is -2 c_j^T diag(d) c_k /
    (lambda_j + lambda_k) for dampers alone (Cauchy-like, O(k n^2), no cancellation), plus -2
    lambda_j lambda_k y_j^T diag(gamma) y_k / (lambda_j + lambda_k) with internal damping (one
    (2n, n, 2n) product, O(n^3): internal damping breaks the low rank). A conjugate pair (and
    a real root with itself), where lambda_j + lambda_k is below the rounding of lambda, is
    summed directly, O(n) per root; a mode no damper touches has unit vectors.
    """
    omega, weights, c = modes.omega, modes.weights, modes.null
    lam = modes.eigenvalues
    s, pair = pair_sums(modes)
    active = modes.root_active
    s_safe = jnp.where(pair & (s != 0), s, 1.0)
    cauchy = (c * weights[None, :]) @ c.T
    if modes.internal:
        cauchy = cauchy + (lam[:, None] * lam[None, :]) * complex_product(
            y * modes.gamma[None, :], y.T)
    gram = -2 * cauchy / s_safe
    partner = conjugate_partners(modes, jnp.arange(lam.shape[0]), pair)
    direct = jnp.sum((omega[None, :] ** 2 + (lam * lam[partner])[:, None]) * y * y[partner],
                     axis=1)
    # a mask, not a scatter: one fused pass over the (2n, 2n) entries (a scatter, batched
    # under vmap, cost 2x)
    at_partner = (jnp.arange(lam.shape[0])[None, :] == partner[:, None]) & active[:, None]
    gram = jnp.where(at_partner, direct[:, None], gram)
    own = omega[modes.modes] ** 2
    unit = own[:, None] + lam[:, None] * lam[None, :]
    gram = jnp.where(active[:, None] | active[None, :], gram, unit)
    return jnp.where(pair, gram, 0.0)


def conjugate_partners(modes: DampedModes, roots, pair):
    """The root nearest the conjugate of each of ``roots`` among those ``pair`` allows ((roots,
    2n) bool): the pair whose Gram entry is summed directly. By the squared distance, which
    orders as the distance does and costs no complex ``abs`` (a hypot) per entry."""
    base = modes.poles[modes.anchor]
    gap = (base[None, :] - jnp.conj(base[roots])[:, None]) + (
        modes.offset[None, :] - jnp.conj(modes.offset[roots])[:, None])
    gap = jax.lax.stop_gradient(gap)
    return jnp.argmin(jnp.where(pair, abs2(gap), jnp.inf), axis=1)


# (e^x - 1) / x = sum_m x^m / (m+1)!, and its derivative sum_m (m+1) x^m / (m+2)!, to |x| < 1/2
# (the first omitted terms below 2e-18)
_SERIES = tuple(1 / math.factorial(m + 1) for m in range(15))
_SERIES_PRIME = tuple((m + 1) / math.factorial(m + 2) for m in range(15))
_SERIES_BOUND = 0.5


def _horner(x, coefficients):
    """sum_m coefficients[m] x^m."""
    return functools.reduce(lambda total, c: c + x * total, coefficients[::-1])


def growth(s, horizon):
    """(e^{s T} - 1) / s, also for small |s T| (series) and T = inf (-1 / s, Re s < 0).

    The series holds for |s T| < 1/2 (its first omitted term below 2e-18), so that its
    derivative in s, which ``jax.grad`` takes through either side, is exact to rounding on both
    sides of the switch: the closed form's derivative T e^x / s - (e^x - 1) / s^2 cancels to
    about eps / |s T|, 1e-13 if the switch sat at |s T| = 1e-3."""
    if horizon is None:
        return -1 / jnp.where(s != 0, s, -1.0)
    x = s * horizon
    small = jnp.abs(x) < _SERIES_BOUND
    s_large = jnp.where(small, 1.0, s)  # no 0 / 0 in the branch not taken (its gradient)
    return jnp.where(small, horizon * _horner(x, _SERIES),
                     jnp.expm1(s_large * horizon) / s_large)



# --- pairs of nearly coincident roots, by contour (``_spectral_clusters``) ----------------


@complex_arithmetic
def cluster_energy(modes: DampedModes, q0, p0, horizon, a, projections=None, support=None,
                   y=None):
    """The terms of J that involve the clusters: twice cluster x simple root, plus cluster x
    cluster; (m,) for q0, p0 (n, m) and the simple roots' coefficients a (2n, m) (zero in the
    clusters). Zero without a cluster (then not computed, except under ``vmap``).

    With u(s) = Q(s)^-1 b(s), b(s) = (s I + D_m) q0 + p0, the clusters' part of the modal state is
    sum_p w_p exp(s_p t) (Omega u_p, s_p u_p) (``Clusters.nodes``), so each term is the simple
    roots' one with (lambda_j, a_j y_j) replaced by (s_p, w_p u_p). The cross terms' Gram entries
    y_j^T (Omega^2 + s_p lambda_j) u_p would take O(NODES n) per root and cluster; with
    ``projections`` (dampers alone: each root's y_j^T q0, y_j^T p0 (2n, m) and F^T y_j (2n, k), from
    the pass that made its coefficient) they take O(NODES k) by the eigen-equations: y_j^T
    Q(lambda_j) = 0 and Q(s_p) u_p = b(s_p) give y_j^T (Omega^2 + s lambda_j) u = lambda_j (y_j^T
    b(s) - 2 s y_j^T D_m u) / (s + lambda_j), where y_j^T D_m u = (F^T y_j)^T W F^T u. A circle's
    radius is at most a third of its centre's distance to the imaginary axis (``find_clusters``), so
    Re s_p <= 2/3 Re c < 0 and |s_p + lambda_j| >= 2/3 |Re c| for every root: no division near zero.
    Under ``vmap`` the cross terms are computed for every design of a batch, clusters or not: there
    this is the difference between O(NODES n^2) and O(NODES n k) per design. With internal damping
    (no ``projections``; ``y`` the (2n, n) rows) the same identity holds with D_m = Gamma + F W F^T,
    and Q(s_p) u_p = b(s_p) by Woodbury turns the one O(n)-per-entry product, y_j^T Gamma u_p, into
    y_j^T Gamma R_p b_p - s_p (y_j^T Gamma R_p F) W F^T u_p: O(NODES n (k + support m)) per root
    instead of O(NODES n m), where only the first ``support`` rows of q0 and p0 may be nonzero
    (None: all; the trace's unit states of its s lowest modes: s); the nodes' solutions are then
    formed on those rows alone (``_node_solutions``, ``_node_gram``)."""
    rows = q0.shape[0] if support is None else support

    def terms():
        s, w = modes.clusters.nodes()
        head, fu, r = _node_solutions(modes, s, q0, p0, rows)  # u_p's first rows, F^T u_p, R
        lam = modes.eigenvalues
        f = jnp.where(modes.active[:, None], modes.factor, 0.0)
        wf_u = fu * modes.weights[None, :, None]  # W F^T u_p
        wf_q = (f[:rows].T @ q0[:rows]) * modes.weights[:, None]  # W F^T q0 (k, m)
        if projections is not None:
            yq, yp, yf = projections  # (2n, m), (2n, m), (2n, k)
            # y_j^T b(s_p) = s_p y_j^T q0 + y_j^T D_m q0 + y_j^T p0
            both = _cross_terms(modes, s, w, lam, a, horizon, yq, yf @ wf_q + yp, yf, wf_u)
        else:
            both = _internal_cross(modes, s, w, q0, p0, lam, a, horizon, y, support, f, wf_u,
                                   wf_q)
        gram = _node_gram(modes, s, head, wf_q[None] - s[:, None, None] * wf_u, r, f)
        kernel = growth(s[:, None] + s[None, :], horizon)
        inner = jnp.einsum("p,q,pqm,pq->m", w, w, gram, kernel)
        return both + jnp.real(inner) / 2

    shape = jax.eval_shape(terms)
    # a plain cond, not ``batch_cond``: under vmap that skipped these terms where no design has
    # a cluster (Section 5 gradients: 41.5 -> 37.7 ms per design), but XLA then kept 23.8 MB
    # per design instead of 9.8 (the branch's residuals for the reverse pass)
    return jax.lax.cond(modes.clusters.any, terms, lambda: jnp.zeros(shape.shape, shape.dtype))


def _node_solutions(modes: DampedModes, s, q0, p0, rows: int):
    """(u_p's first ``rows`` rows (P, rows, m), F^T u_p (P, k, m), R (P, n)) for u_p =
    Q(s_p)^-1 b(s_p),
    b(s) = (s I + D_m) q0 + p0 (``cluster_energy``), where q0 and p0 vanish below ``rows``:
    there b = F W F^T q0, so F^T R_p b_p takes the tail rows through F^T R_p F (k x k), and no
    (P, n, m) array is formed (55 MB for the FastOptimalDamping example's trace, n = 801, 54
    states): O(P (rows m + n k) k). With rows = n this is ``solve_at``'s Woodbury solve."""
    r, f, h = resolvent_at(modes, s)
    weights = modes.weights
    q_head, p_head = q0[:rows], p0[:rows]
    wf_q = (f[:rows].T @ q_head) * weights[:, None]  # W F^T q0 (k, m)
    b_head = (s[:, None, None] * q_head[None] + (modes.gamma[:rows, None] * q_head + p_head
                                                  + f[:rows] @ wf_q)[None])  # (P, rows, m)
    r_head = r[:, :rows, None]
    g = complex_product(f[:rows].T, r_head * b_head)  # F^T R b over the first rows
    tail = rows < q0.shape[0]
    if tail:
        others = f[rows:]
        frf = complex_product(r[:, rows:], (others[:, :, None] * others[:, None, :]).reshape(
            -1, others.shape[1] ** 2)).reshape(-1, others.shape[1], others.shape[1])
        g = g + complex_product(frf, wf_q)  # F^T R F W F^T q0 over the others
    z = small_solve(h, g)  # H^-1 F^T R b = F^T u
    head = r_head * (b_head - s[:, None, None] * complex_product(f[:rows] * weights[None, :], z))
    # F^T u (= z) summed over the rows, the others' as F^T R F C_p, C_p = W F^T q0 - s_p W z_p:
    # with z itself XLA kept more buffers alive under ``vmap`` (12.1 MB per design at n = 300
    # instead of 10.6, ``benchmarks/engine.py``)
    fu = complex_product(f[:rows].T, head)
    if tail:
        fu = fu + complex_product(frf, wf_q[None] - s[:, None, None] * weights[None, :, None] * z)
    return head, fu, r


def _node_gram(modes: DampedModes, s, head, spread, r, f):
    """G_pqm = u_pm^T (Omega^2 + s_p s_q) u_qm: (P, P, m), the energy inner products of the
    nodes' states (``cluster_energy``), from u_p's first rows ``head`` (P, rows, m), below which
    q0 and p0 vanish: there u_p = R_p F C_p with C_p = W F^T q0 - s_p W F^T u_p (``spread``,
    (P, k, m)) by Woodbury, and those rows enter through E_pq = F^T R_p (Omega^2 + s_p s_q) R_q
    F (k x k): O(P^2 n k^2 + P^2 k^2 m) instead of O(P^2 n m) (0.13 s of the
    FastOptimalDamping example's trace, n = 801, m = 54 states of its 27 lowest modes). ``r``:
    R (P, n) at the nodes; ``f``: the damped modes' factor (n, k)."""
    n = modes.omega.shape[0]
    rows = head.shape[1]
    omega2 = modes.omega**2
    gram = jnp.einsum("plm,qlm->pqm", head * omega2[None, :rows, None], head) + (
        s[:, None, None] * s[None, :, None]) * jnp.einsum("plm,qlm->pqm", head, head)
    if rows == n:
        return gram
    points, k = spread.shape[0], spread.shape[1]
    r, f = r[:, rows:], f[rows:]  # (P, n - rows), (n - rows, k)
    ff = (f[:, :, None] * f[:, None, :]).reshape(-1, 1, k * k)
    right = r.T[:, :, None] * ff  # (n - rows, P, k^2)
    both = complex_product(r, jnp.concatenate([right * omega2[rows:, None, None], right],
                                              axis=1).reshape(n - rows, -1))
    both = both.reshape(points, 2, points, k, k)
    tail = both[:, 0] + (s[:, None] * s[None, :])[:, :, None, None] * both[:, 1]
    return gram + jnp.einsum("pam,pqab,qbm->pqm", spread, tail, spread)


def _cross_terms(modes: DampedModes, s, w, lam, a, horizon, y_q, y_c, yf, wf_u, internal=None):
    """The cross terms sum_(p, j) w_p h(s_p + lambda_j) a_j y_j^T (Omega^2 + s_p lambda_j) u_p
    (per state m) by the identity y_j^T (Omega^2 + s lambda_j) u = lambda_j (y_j^T b(s) - 2 s
    y_j^T D_m u) / (s + lambda_j) (``cluster_energy``), with y_j^T b(s_p) = s_p ``y_q`` +
    ``y_c`` (2n, m) and y_j^T D_m u_p = (F^T y_j)^T W F^T u_p (``yf`` (2n, k), ``wf_u`` (P, k,
    m)) plus, with ``internal`` = (head (2n, s), rest (P, s, m), g_rf (P, 2n, k), W F^T q0 (k,
    m)), y_j^T Gamma u_p = head_j^T rest_p + g_rf_pj^T (W F^T q0 - s_p W F^T u_p)
    (``_internal_cross``). Each product is summed over the roots before it meets the states
    (K_pj = w_p h lambda_j / (s_p + lambda_j) against a_j times the root's factor), so no
    (P, 2n, m) array is formed: the trace's 54 unit states at n = 801 made ten of 111 MB each
    in its gradient."""
    plus = s[:, None] + lam[None, :]  # (P, 2n), |plus| >= 2/3 |Re c| (``cluster_energy``)
    plus_safe = jnp.where(plus != 0, plus, 1.0)  # an unused circle's nodes (weights 0) anywhere
    kernel = w[:, None] * growth(plus, horizon) * lam[None, :] / plus_safe
    coefficient = jnp.where(modes.simple[:, None], a, 0.0)  # (2n, m)
    roots, states = coefficient.shape
    value = (jnp.sum((s @ kernel)[:, None] * coefficient * y_q, axis=0)
             + jnp.sum(jnp.sum(kernel, axis=0)[:, None] * coefficient * y_c, axis=0))
    twice = -2 * s  # y_j^T D_m u_p enters with -2 s_p

    def against(factor):  # sum_j K_pj a_jm factor_j. (2n, ...) -> (P, ..., m)
        spread = coefficient.reshape((roots,) + (1,) * (factor.ndim - 1) + (states,))
        out = complex_product(kernel, (factor[..., None] * spread).reshape(roots, -1))
        return out.reshape((s.shape[0],) + factor.shape[1:] + (states,))

    value = value + jnp.einsum("p,pam,pam->m", twice, wf_u, against(yf))
    if internal is not None:
        head, rest, g_rf, wf_q = internal
        d = complex_product(jnp.swapaxes(kernel[:, :, None] * g_rf, 1, 2), coefficient)
        value = value + (jnp.einsum("p,plm,plm->m", twice, rest, against(head))
                         + jnp.einsum("p,am,pam->m", twice, wf_q, d)
                         - jnp.einsum("p,pam,pam->m", twice * s, wf_u, d))
    return jnp.real(value)


def _internal_cross(modes: DampedModes, s, w, q0, p0, lam, a, horizon, y, support, f, wf_u,
                    wf_q):
    """``cluster_energy``'s cross terms with internal damping, from the rows ``y`` (2n, n): the
    eigen-equations' identity with D_m = Gamma + F W F^T, and y_j^T Gamma u_p by Woodbury
    (``cluster_energy``), O(NODES n (k + support m)) per root. ``f``: the damped modes' factor;
    ``wf_u``, ``wf_q``: W F^T u_p (P, k, m) and W F^T q0 (k, m)."""
    rows = q0.shape[0] if support is None else support
    gamma = modes.gamma
    r, _, _ = resolvent_at(modes, s)  # (P, n)
    yf = y @ f  # F^T y_j (2n, k)
    head, q_head, p_head = y[:, :rows], q0[:rows], p0[:rows]
    # y_j^T b(s_p) = s_p y_j^T q0 + y_j^T Gamma q0 + (F^T y_j) W F^T q0 + y_j^T p0
    y_c = head @ (gamma[:rows, None] * q_head) + yf @ wf_q + head @ p_head
    # y_j^T Gamma u_p = y_j^T Gamma R_p ((s_p + Gamma) q0 + p0) + (y_j^T Gamma R_p F) W F^T q0
    #                   - s_p (y_j^T Gamma R_p F) W F^T u_p
    points, k = s.shape[0], f.shape[1]
    g_rf = complex_product(y * gamma[None, :], (r.T[:, :, None] * f[:, None, :]).reshape(
        -1, points * k)).reshape(-1, points, k).swapaxes(0, 1)  # (P, 2n, k)
    rest = r[:, :rows, None] * gamma[None, :rows, None] * (
        (s[:, None, None] + gamma[None, :rows, None]) * q_head[None] + p_head[None])
    return _cross_terms(modes, s, w, lam, a, horizon, head @ q_head, y_c, yf, wf_u,
                        (head, rest, g_rf, wf_q))


@complex_arithmetic
def cluster_trace(modes: DampedModes, y, scale):
    """The terms of ``trace_from_modes``'s double sum that involve the clusters (zero
    without one): sum over a cluster's roots of G_jk^2 h(lambda_j) / N_j is the contour
    integral of beta_k(s)^T Q(s)^-1 beta_k(s) h(s), beta_k(s) = (Omega^2 + s lambda_k) y_k, of
    which only the singular part -s R F W H^-1 F^T R of Q^-1 contributes (the rest is analytic
    inside the circle); cluster x cluster likewise with both singular parts (O(NODES^2 n k^2)).
    ``y`` (2n, n) the vectors as rows, ``scale`` (2n,) lambda_k N_k (1 in the clusters)."""
    def terms():
        s, w = modes.clusters.nodes()
        r, f, h = resolvent_at(modes, s)
        lam = modes.eigenvalues
        omega2 = modes.omega**2
        rf = r[:, :, None] * f[None]  # R F (P, n, k)
        e1 = jnp.einsum("pla,kl->pak", rf * omega2[None, :, None], y)
        e2 = jnp.einsum("pla,kl->pak", rf, y)
        beta = e1 + (s[:, None] * lam[None, :])[:, None, :] * e2  # F^T R beta_k (P, k, 2n)
        quad = jnp.sum(beta * modes.weights[None, :, None] * small_solve(h, beta), axis=1)
        factor = -1 / (scale[None, :] * s[:, None] * (s[:, None] + lam[None, :]))
        cross = jnp.einsum("p,pk,pk->", w, -s[:, None] * quad,
                           jnp.where(modes.simple[None, :], factor, 0.0))
        k = f.shape[1]
        eye = jnp.broadcast_to(jnp.eye(k, dtype=h.dtype), h.shape)
        c = -s[:, None, None] * modes.weights[None, :, None] * small_solve(h, eye)  # (P, k, k)
        b = jnp.einsum("pla,qlb->pqab", rf * omega2[None, :, None], rf) + (
            s[:, None, None, None] * s[None, :, None, None]) * jnp.einsum(
                "pla,qlb->pqab", rf, rf)
        traces = jnp.einsum("pab,pqbc,qcd,pqad->pq", c, b, c, b)
        inner = jnp.einsum("p,q,pq,pq->", w, w, traces,
                           -1 / (s[:, None] * s[None, :] * (s[:, None] + s[None, :])))
        return jnp.real(2 * cross + inner)

    return jax.lax.cond(modes.clusters.any, terms, lambda: jnp.zeros(()))


# --- the objectives --------------------------------------------------------------------------




def _dampers_energy(modes: DampedModes, q0, p0, horizon, block):
    """``energy_from_modes`` for dampers alone, all roots at once (``block`` None) or ``block``
    roots at a time (O(n block) memory, no (2n, n) or (2n, 2n) array: n = 30000 gives 29 GB
    each). Two passes: the coefficients a_j and each root's conjugate-pair term of G from its
    eigenvector row, then the Cauchy-like double sum (``_cauchy_sum``)."""
    n = modes.omega.shape[0]
    batch = q0.shape[1:]
    q0, p0 = q0.reshape(n, -1), p0.reshape(n, -1)
    poles, anchor, offset = modes.poles, modes.anchor, modes.offset
    active = modes.root_active
    allowed = active & ~modes.clusters.member
    omega2 = modes.omega**2
    f = jnp.where(modes.active[:, None], modes.factor, 0.0)

    def first(j):
        lam = poles[anchor[j]] + offset[j]
        act = active[j]
        y = modes.vector_rows(j)
        norm = modes.safe_normalisers(j, modes.normaliser_rows(j, y))
        yp = y @ p0
        coefficient = (yp - (y @ (omega2[:, None] * q0)) / lam[:, None]) / norm[:, None]
        coefficient = jnp.where(modes.clusters.member[j][:, None], 0.0, coefficient)
        partner = conjugate_partners(modes, j, act[:, None] & active[None, :])
        # the conjugate partner's Gram entry, from the root's own row: a real system's
        # partner has a_p w_p = conj(a_j w_j) (w = (Omega y, lambda y)), so a_j a_p G_jp =
        # |a_j|^2 |w_j|^2, a sum of positive terms (a real root is its own partner)
        size = jnp.sum((omega2[None, :] + (lam.real**2 + lam.imag**2)[:, None])
                       * (y.real**2 + y.imag**2), axis=1)
        # for the clusters' cross terms (``cluster_energy``)
        return coefficient, partner, size, (y @ q0, yp, y @ f)

    a, partner, size, projections = by_rows(first, block, jnp.arange(2 * n))
    # G_jk = -2 c_j^T diag(d) c_k / s_jk off the partners: -sum_i d_i u_i^T Phi u_i, u = a c
    u = modes.null[:, :, None] * a[:, None, :]  # (2n, k, batch)
    value = -jnp.real(_cauchy_sum(poles[anchor], offset, u, modes.weights, horizon, allowed,
                                  partner, block))
    # the pair's own term, summed directly (lambda_j + lambda_p below rounding): s = 2 Re
    # lambda_j, exact in the pole-offset form
    s_partner = 2 * (jnp.real(poles[anchor]) + jnp.real(offset))
    own = allowed & allowed[partner]
    kernel = jnp.where(own, size * growth(jnp.where(own, s_partner, -1.0), horizon), 0.0)
    value = value + jnp.sum((a.real**2 + a.imag**2) * kernel[:, None], axis=0) / 2
    value = value + cluster_energy(modes, q0, p0, horizon, a, projections)
    value = value.reshape(batch)
    q0, p0 = q0.reshape((n,) + batch), p0.reshape((n,) + batch)
    return value + _idle_energy(modes, q0, p0, horizon)


def _phi(s, mask, horizon, derivatives: bool, rows, columns):
    """Phi(s) = (e^{s T} - 1) / s^2 (``growth`` / s; -1 / s^2 for T = inf) on ``mask``, and
    with ``derivatives`` its s- and T-derivatives too, from one reciprocal of s (a complex
    division costs several products).

    s = lambda_j + lambda_k, and for finite T the exponential comes from the roots' own:
    ``rows`` (E_j, P_j) as columns and ``columns`` (E_k, P_k) as rows, with E = e^{lambda T} - 1
    and P = e^{lambda T} per root. Then e^{s T} - 1 = E_j + E_k + E_j E_k and e^{s T} = P_j P_k:
    complex products per entry instead of a complex ``expm1``, which cost more than the rest of
    the double sum. The first's rounding error, a few eps (|E_j| + |E_k|) with |E| <=
    min(|lambda T|, 2), is that of s itself: lambda_j + lambda_k carries eps |lambda| from the
    frequencies' own rounding, which ``expm1`` of s T magnifies alike; the second is relative,
    so the derivatives keep their digits where e^{s T} has decayed. |s T| < 1/2 takes the
    series, as ``growth``: the closed form of the s-derivative, (T e^{s T} - g) / s, cancels to
    eps / |s T| below it."""
    s_d = jnp.where(mask & (s != 0), s, 1.0)
    inverse = 1 / s_d
    if horizon is None:
        g = jnp.where(mask & (s != 0), -inverse, 1.0)
        g_s, g_t = g * g, None
    else:
        (grown_j, power_j), (grown_k, power_k) = rows, columns
        x = jnp.where(mask, s, -1.0) * horizon
        small = jnp.abs(x) < _SERIES_BOUND  # as ``growth``
        # 1 / s where not small (and on the mask; off it any finite value does)
        inverse_large = jnp.where(small | ~mask, 1.0, inverse)
        e1 = grown_j + grown_k + grown_j * grown_k
        g = jnp.where(small, horizon * _horner(x, _SERIES), e1 * inverse_large)
        if derivatives:
            g_t = power_j * power_k  # e^{s T}
            g_s = jnp.where(small, horizon**2 * _horner(x, _SERIES_PRIME),
                            (horizon * g_t - g) * inverse_large)
    phi = g * inverse
    if not derivatives:
        return phi
    phi_s = (g_s - jnp.where(s != 0, phi, 0.0)) * inverse
    return phi, phi_s, (None if g_t is None else g_t * inverse)


def _split(a):
    """a = high + low with high holding a's leading 26 bits (Veltkamp's splitting)."""
    scaled = 134217729.0 * a  # 2^27 + 1
    high = scaled - (scaled - a)
    return high, a - high


def _product_error(a, b, product):
    """a b - product exactly (Dekker's two-product: product = fl(a b))."""
    a_high, a_low = _split(a)
    b_high, b_low = _split(b)
    return ((a_high * b_high - product) + a_high * b_low + a_low * b_high) + a_low * b_low


def _root_exponentials(base, offset, horizon):
    """(e^{lambda T} - 1, e^{lambda T}) per root, lambda = ``base`` + ``offset`` with base a pole
    +-i omega: the phase omega T is carried to twice the working precision (``_product_error``),
    so each exponential is exact to rounding for the given root, as e^{s T} of the pole-offset
    sum s = lambda_j + lambda_k is; a plain fl(lambda T) would cost eps |lambda| T in the phase
    (1e-12 at omega T = 6000)."""
    phase = base.imag * horizon
    rest = (1j * _product_error(base.imag, horizon, phase) + base.real * horizon
            + offset * horizon)
    turn = jnp.exp(1j * phase)
    rest_grown = jnp.expm1(rest)
    return jnp.expm1(1j * phase) + turn * rest_grown, turn * (1 + rest_grown)


def _cauchy_sums(base, offset, u, horizon, allowed, partner, block, derivatives: bool):
    """S = (W Phi) u, with W_jk = [k != p_j] + [j != p_k] on the pairs of two ``allowed`` roots
    (p the conjugate partner): S_j = R_j + C_j, the row and the column sums of the masked
    double sum, so that Q = sum_j u_j S_j / 2 and dQ / du_j = S_j (W is symmetric where p is an
    involution, as for conjugate pairs; this stays right where it is not). With
    ``derivatives`` also (W Phi') u and (W dPhi/dT) u (None for T = inf). Each (2n, k, batch);
    ``block`` roots at a time (``by_rows``), one matrix product per kernel and block."""
    index = jnp.arange(base.shape[0])
    flat = u.reshape(u.shape[0], -1)
    if horizon is not None:  # e^{lambda T} - 1 and e^{lambda T} per root (``_phi``)
        grown, power = _root_exponentials(jnp.where(allowed, base, 0.0),
                                          jnp.where(allowed, offset, 0.0), horizon)

    def rows(j):
        s = (base[j][:, None] + base[None, :]) + (offset[j][:, None] + offset[None, :])
        both = allowed[j][:, None] & allowed[None, :]
        weight = ((both & (index[None, :] != partner[j][:, None])).astype(float)
                  + (both & (partner[None, :] != j[:, None])).astype(float))
        factors = (None, None) if horizon is None else (
            (grown[j][:, None], power[j][:, None]), (grown[None, :], power[None, :]))
        if not derivatives:
            return ((weight * _phi(s, weight > 0, horizon, False, *factors)) @ flat,)
        # one product per kernel: stacked into one array first, the copy cost more than the
        # products
        return tuple((weight * x) @ flat for x in _phi(s, weight > 0, horizon, True, *factors)
                     if x is not None)

    sums = by_rows(rows, block, index)
    sums = tuple(x.reshape(u.shape) for x in sums)
    return sums + (None,) * (derivatives and horizon is None)


def _cauchy_sum(base, offset, u, weights, horizon, allowed, partner, block):
    """Q = sum_i d_i sum_jk u_ji u_ki Phi(lambda_j + lambda_k) over the allowed pairs (j, k both
    ``allowed``, k != p_j the conjugate partner), per batch column; lambda = ``base`` +
    ``offset`` (s_jk in pole-offset form, exact for conjugates). u: (2n, k, batch).

    A custom JVP: the derivative is sum_j S_j du_j + u_j S'_j dlambda_j (+ the weights' and
    T's terms, ``_cauchy_sums``), from sums taken in the same pass as the value, so reverse
    mode transposes O(n k) vectors instead of the (2n, 2n) kernel's elementwise derivative
    (which cost more than the value; the ``engine`` benchmark)."""
    fn = _cauchy_sum_function(block, horizon is None)
    return fn(base, offset, u, weights, jnp.zeros(()) if horizon is None else horizon,
              allowed, partner)


@functools.cache
def _cauchy_sum_function(block, infinite: bool):
    """``_cauchy_sum``'s custom-JVP function for a static ``block`` and horizon kind."""
    @jax.custom_jvp
    @complex_arithmetic  # both traced where JAX differentiates, outside the caller's promotion
    def fn(base, offset, u, weights, horizon, allowed, partner):
        (total,) = _cauchy_sums(base, offset, u, None if infinite else horizon, allowed,
                                partner, block, False)
        return jnp.einsum("i,jim,jim->m", weights, u, total) / 2

    @fn.defjvp
    @complex_arithmetic
    def fn_jvp(primals, tangents):
        base, offset, u, weights, horizon, allowed, partner = primals
        d_base, d_offset, d_u, d_weights, d_horizon, _, _ = tangents
        total, total_s, total_t = _cauchy_sums(base, offset, u, None if infinite else horizon,
                                               allowed, partner, block, True)
        value = jnp.einsum("i,jim,jim->m", weights, u, total) / 2
        tangent = (jnp.einsum("i,jim,jim->m", weights, d_u, total)
                   + jnp.einsum("j,i,jim,jim->m", d_base + d_offset, weights, u, total_s)
                   + jnp.einsum("i,jim,jim->m", d_weights, u, total) / 2)
        if not infinite:
            tangent = tangent + d_horizon * jnp.einsum("i,jim,jim->m", weights, u, total_t) / 2
        return value, tangent

    return fn


def _idle_energy(modes: DampedModes, q0, p0, horizon):
    """The energy of the modes no damper touches (dampers alone): T E_l(0), inf for T = inf."""
    idle = jnp.where(modes.active[:, None] if q0.ndim > 1 else modes.active, 0.0,
                     (modes.omega.reshape((-1,) + (1,) * (q0.ndim - 1)) * q0) ** 2 + p0**2)
    if horizon is None:  # an undamped mode's energy never decays
        return jnp.where(jnp.any(idle > 0, axis=0), jnp.inf, 0.0)
    return horizon * jnp.sum(idle, axis=0) / 2


@complex_arithmetic
def energy_from_modes(modes: DampedModes, q0, p0, horizon, block: int | None = None,
                      support: int | None = None):
    """J from the modes and the modal initial state (eta0, eta0'), O(n^2 k) (O(n^3) with
    internal damping, see ``modal_gram``); q0, p0 may carry a trailing batch axis (then one J
    per column); ``horizon`` None: T = inf. ``block``: roots at a time for dampers alone
    (``row_block``: automatic, O(n) memory above n = 512). ``support``: only the first
    ``support`` rows of q0 and p0 may be nonzero (None: any; with internal damping the clusters'
    cross terms then cost O(NODES n support) per root and state, ``cluster_energy``)."""
    block = row_block(modes.omega.shape[0], block)
    if not modes.internal:
        return _dampers_energy(modes, q0, p0, horizon, block)
    y = modes.vectors().T  # (2n, n)
    s, pair = pair_sums(modes)
    apart = ~modes.clusters.member
    pair = pair & apart[:, None] & apart[None, :]
    a = modes.coefficients(q0, p0)
    kernel = jnp.where(pair, modal_gram(modes, y) * growth(jnp.where(pair, s, -1.0), horizon),
                       0.0)
    batch = q0.shape[1:]
    n = q0.shape[0]
    columns = a.reshape(2 * n, -1)
    value = jnp.real(jnp.sum(columns * complex_product(kernel, columns), axis=0)) / 2
    clusters = cluster_energy(modes, q0.reshape(n, -1), p0.reshape(n, -1), horizon, columns,
                              support=support, y=y)
    return (value + clusters).reshape(batch)


@eqx.filter_jit
def spectral_energy_with_result(system, horizon, x0, v0, *, block: int | None = None):
    """(J, ok): the integrated energy of free vibration from (x0, v0) on [0, T] and whether it
    holds; where not ok, J must not be used. Differentiable in everything the system carries
    (damper positions and coefficients, internal damping, M and K through the modes) and x0, v0,
    by implicit differentiation of the secular equation at the roots.

    ``block``: roots per block of the O(n^2) work (``row_block``). None (the library's
    choice): blocks above n = 512, and a chain above n = 4096 (``uses_rows``) without U, O(n)
    memory; 0: all at once from U (the benchmarks' comparison)."""
    return spectral_energy_with_roots(system, horizon, x0, v0, block=block)[:2]


@eqx.filter_jit
def spectral_energy_with_roots(system, horizon, x0, v0, *, block: int | None = None,
                               start=None):
    """(J, ok, roots): ``spectral_energy_with_result``, its sweeps started at ``start`` (a
    ``RootStart``, None for the arc starts), and the roots found as the next design's start."""
    if block != 0 and uses_rows(system):  # a large chain: no U, the roots a block at a time
        modes, projected, ok, _ = live_rows(system, jnp.stack([x0, v0], axis=1), block,
                                            start=start)
        q0, p0 = projected[:, 0], projected[:, 1]
    else:
        modes, modes_u, ok = live_modes(system, block, start)
        project = modal_projection(system, modes_u)
        q0, p0 = project(x0), project(v0)
    value = energy_from_modes(modes, q0, p0, horizon, block)
    return value, ok & jnp.isfinite(value), modes.start


def _unit_states(omega, lowest):
    """(q0, p0), each (n, 2s): the 2s unit states of the s lowest modes in scaled modal
    coordinates, Omega eta = e_i (eta = e_i / omega_i) and eta' = e_i."""
    select = jnp.eye(omega.shape[0])[:, :lowest]
    return (jnp.concatenate([select / omega[:, None], jnp.zeros_like(select)], axis=1),
            jnp.concatenate([jnp.zeros_like(select), select], axis=1))


@complex_arithmetic
def trace_from_modes(modes: DampedModes, lowest):
    """trace X, A^T X + X A = -Z, Z = I (``lowest`` None) or the s = ``lowest`` lowest modes."""
    if lowest is not None:
        value = 2 * jnp.sum(energy_from_modes(modes, *_unit_states(modes.omega, lowest), None,
                                              support=lowest))
        return jnp.where(jnp.any(modes.undamped[:lowest]), jnp.inf, value)
    y = modes.vectors().T
    s, pair = pair_sums(modes)
    apart = ~modes.clusters.member
    pair = pair & apart[:, None] & apart[None, :]
    roots = jnp.arange(y.shape[0])
    scale = modes.eigenvalues * modes.safe_normalisers(roots, modes.normalisers())
    scale = jnp.where(modes.clusters.member, 1.0, scale)
    gram = modal_gram(modes, y)
    # G_jk^2 / (lambda_j lambda_k N_j N_k) as G_jk (G_jk / (lambda_j N_j)) / (lambda_k N_k):
    # no overflow of the squared Gram entries
    terms = jnp.where(pair, gram * (gram / scale[:, None] / scale[None, :])
                      * growth(jnp.where(pair, s, -1.0), None), 0.0)
    value = jnp.real(jnp.sum(terms)) + cluster_trace(modes, y, scale)
    # a mode nothing damps never decays: X does not exist (decided from the structure, not
    # from a huge value: a node of the mode or a zero coefficient gave 1e32 or a finite 12)
    undamped = jnp.any(modes.undamped)
    if not modes.internal:
        undamped = undamped | ~jnp.all(modes.active)
    return jnp.where(undamped, jnp.inf, value)


@eqx.filter_jit
def spectral_trace_with_result(system, *, lowest):
    """(trace X, ok) of ``total_average_energy``; where not ok, the value must not be used."""
    return spectral_trace_with_roots(system, lowest=lowest)[:2]


@eqx.filter_jit
def spectral_trace_with_roots(system, *, lowest, start=None):
    """(trace X, ok, roots): ``spectral_trace_with_result`` from ``start`` (as
    ``spectral_energy_with_roots``)."""
    modes, _, ok = live_modes(system, start=start)
    value = trace_from_modes(modes, lowest)
    return value, ok & jnp.isfinite(value), modes.start


@complex_arithmetic
def output_energy_from_modes(modes: DampedModes, q0, p0, cx, cv, horizon):
    """sum over the columns of (q0, p0) of int_0^T |cx eta(t) + cv eta'(t)|^2 dt, O(q n^2 + m
    n^2): eta(t) = sum_j a_j exp(lambda_j t) y_j, so the output is sum_j a_j exp(lambda_j t) w_j
    with w_j = (cx + lambda_j cv) y_j, and the integral sum_jk a_j a_k w_j^T w_k (e^{s_jk T} -
    1) / s_jk. ``cx``, ``cv``: (q, n) output matrices in modal coordinates; q0, p0: (n, m);
    ``horizon`` None: T = inf (infinite where an undamped mode reaches the output).

    Every pair of roots interacts here (a general output is not orthogonal in the energy inner
    product, so ``modal_gram``'s identity does not apply): w_j^T w_k is formed directly, which is
    accurate while the outputs are not much smaller than the modal components of y_j (checked
    against dense Lyapunov solutions up to d = 1e3 in the tests, 3e-7 apart at d = 1e4).
    """
    y = modes.vectors()  # (n, 2n)
    lam = modes.eigenvalues
    w = cx @ y + (cv @ y) * lam[None, :]  # (q, 2n)
    base = modes.poles[modes.anchor]
    s = (base[:, None] + base[None, :]) + (modes.offset[:, None] + modes.offset[None, :])
    a = modes.coefficients(q0, p0)  # (2n, m)
    weight = (a @ a.T) * (w.T @ w)  # sum over the states of a_j a_k, times w_j^T w_k
    clusters = _cluster_output(modes, q0, p0, cx, cv, w, a, horizon)
    if horizon is None:
        # two roots of an undamped mode (decided from the structure, ``DampedModes.undamped``):
        # its output never decays, so the value is infinite where the inputs and outputs see
        # it, and it is dropped where they do not (an uncontrollable or unobservable mode;
        # seen: above rounding relative to the largest term)
        undamped = modes.undamped[modes.modes]
        still = (s == 0) | (undamped[:, None] & undamped[None, :]
                            & (modes.modes[:, None] == modes.modes[None, :]))
        n = modes.omega.shape[0]
        seen = jnp.abs(weight) > (n * jnp.finfo(s.real.dtype).eps) ** 2 * jnp.max(jnp.abs(
            jnp.where(still, 0.0, weight)))
        value = jnp.real(jnp.sum(jnp.where(still, 0.0, weight * growth(jnp.where(still, -1.0, s),
                                                                      None))))
        return jnp.where(jnp.any(still & seen), jnp.inf, value + clusters)
    return jnp.real(jnp.sum(weight * growth(s, horizon))) + clusters


@complex_arithmetic
def _cluster_output(modes: DampedModes, q0, p0, cx, cv, w, a, horizon):
    """The clusters' terms of ``output_energy_from_modes`` (zero without one): their output is
    sum_p w_p exp(s_p t) (cx + s_p cv) u_p with u_p = Q(s_p)^-1 b(s_p) (``cluster_energy``),
    crossed with the simple roots' outputs w_j a_j and with itself."""
    def terms():
        s, weights = modes.clusters.nodes()
        u = solve_at(modes, s, initial_rhs(modes, s, q0, p0))  # (P, n, m)
        out = jnp.einsum("ql,plm->pqm", cx, u) + s[:, None, None] * jnp.einsum("ql,plm->pqm",
                                                                               cv, u)
        lam = modes.eigenvalues
        simple = jnp.where(modes.simple[:, None], a, 0.0)
        cross = jnp.einsum("p,pqm,qk,km,pk->", weights, out, w, simple,
                           growth(s[:, None] + lam[None, :], horizon))
        inner = jnp.einsum("p,r,pqm,rqm,pr->", weights, weights, out, out,
                           growth(s[:, None] + s[None, :], horizon))
        return jnp.real(2 * cross + inner)

    return jax.lax.cond(modes.clusters.any, terms, lambda: jnp.zeros(()))


@eqx.filter_jit
def spectral_output_energy_with_result(system, x0, v0, forces, cx, cv, horizon, lowest):
    """(value, ok) of ``output_energy``: the initial states are the 2s unit modal states of the
    ``lowest`` s modes (as ``trace_from_modes``), or the columns of x0, v0 (n, m) plus the
    impulses of the columns of ``forces`` (n, m) (v0 += M^-1 forces; each None for none; all
    None and no ``lowest``: all 2n unit states);
    ``cx``, ``cv`` (q, n) physical output matrices. Where not ok, the value must not be used."""
    return spectral_output_energy_with_roots(system, x0, v0, forces, cx, cv, horizon,
                                             lowest)[:2]


@eqx.filter_jit
def spectral_output_energy_with_roots(system, x0, v0, forces, cx, cv, horizon, lowest, *,
                                      start=None):
    """(value, ok, roots): ``spectral_output_energy_with_result`` from ``start`` (as
    ``spectral_energy_with_roots``)."""
    modes, modes_u, ok = live_modes(system, start=start)
    n = modes_u.shape[0]
    if lowest is None and x0 is None and v0 is None and forces is None:
        lowest = n  # no state given: all 2n unit states
    if lowest is not None:
        q0, p0 = _unit_states(modes.omega, lowest)
    else:
        project = jax.vmap(modal_projection(system, modes_u), in_axes=1, out_axes=1)
        columns = next(c for c in (x0, v0, forces) if c is not None).shape[1]
        zero = jnp.zeros((n, columns))
        q0 = zero if x0 is None else project(x0)
        p0 = zero if v0 is None else project(v0)
        if forces is not None:
            p0 = p0 + modes_u.T @ forces  # eta'(0+) = U^T M M^-1 f
    value = output_energy_from_modes(modes, q0, p0, cx @ modes_u, cv @ modes_u, horizon)
    # inf: an undamped mode is seen (the caller says so)
    return value, ok & ~jnp.isnan(value), modes.start
