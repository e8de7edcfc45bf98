"""Damped modes of a chain with a few dampers, and energies from them in closed form, O(k n^2).

Conventions: eta are the M-orthonormal modal coordinates (x = U eta, U^T M U = I, U^T K U =
Omega^2, ``generalized_modes``); internal damping diagonal in them (Rayleigh, modal) is Gamma =
diag(gamma); the dampers are D_m = F diag(d) F^T with F = U^T B the (n, k) modal damper factor
(``Dampers.project``: a grounded damper is e_j, a split one (1 - w) e_j and w e_(j+1), a relative
one e_i - e_j). Mode l alone has the poles p_l, p_(n+l), the roots of lambda^2 + gamma_l lambda +
omega_l^2 (+-i omega_l undamped; two real ones when overdamped). Each of the 2n roots is stored
in the pole-offset form lambda = p_A + delta (anchor A), so that lambda^2 + gamma_l lambda +
omega_l^2 = (p_A - p_l + delta)(p_A - p_(n+l) + delta) never cancels near a pole; for an undamped
chain root j < n lies near +i omega_j and root n + j near -i omega_j.

Method (Veselic, Damped Oscillations of Linear Systems, Springer Lecture Notes in Mathematics
vol. 2023, 2011; Jakovcevic Stor, Slapnicar, Tomljanovic, Mathematics 10(5):790, 2022,
"FastOptimalDamping"): with R(lambda) = (lambda^2 + lambda Gamma + Omega^2)^-1 the eigenvalues
of lambda^2 + lambda (Gamma + D_m) + Omega^2 are the zeros of the secular determinant
det(I_k + lambda F^T R F diag(d)) times the poles' polynomial. Modes that no damper touches are
deflated (their own poles); the others' 2 n_a roots are found together by the Aberth-Ehrlich
iteration (Aberth, Math. Comp. 27:339, 1973) on the characteristic polynomial, whose logarithmic
derivative is evaluated with each root's own pole removed analytically (H below), and polished by
Newton on phi_J(lambda) = lambda^2 + gamma_J lambda + omega_J^2 + lambda f_J^T diag(d) H^-1 f_J,
with H = I + lambda sum_(l != J) r_l f_l f_l^T diag(d). The eigenvector y = R F diag(d) c with c =
H^-1 f_J has y_J = -1 / lambda: no huge entries. Gradients: one Newton step at the frozen roots
(implicit differentiation of phi_J = 0), so ``jax.grad`` never enters the iteration.

The undamped modes of a fixed-free chain come from ``chain_modes`` (O(n^2), relative accuracy);
other systems use ``generalized_modes`` (dense, O(n^3)).
Memory: every step is per root, and above n = 64 the rows are formed a block of roots at a
time (``rows``): O(n) memory (J + gradient at n = 30000 in 1.7 GiB).
Two roots that nearly coincide (critical damping) are found like any others and then summed
as a pair by a contour integral of the resolvent, never root by root (``clusters``:
``DampedModes.clusters``).
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp

from ..._custom_types import Array, Float
from .clusters import Clusters, cluster_roots, find_clusters
from .rows import (
    abs2,
    batch_cond,
    by_rows,
    by_rows_where,
    complex_product,
    repulsion,
    row_block,
    small_solve,
)
from .starts import arc_starts, far_starts


def complex_arithmetic(fn):
    """Run ``fn`` with JAX's standard dtype promotion: the roots are complex and mix freely with
    the real frequencies (the tests' strict promotion guards the rest of the package)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with jax.numpy_dtype_promotion("standard"):
            return fn(*args, **kwargs)

    return wrapper


_MAX_ITERATIONS = 400
_ABERTH_TOL = 1e-13  # max |step| / |lambda| at which the simultaneous iteration stops
_POLISH_STEPS = 3  # Newton steps at most after the sweeps ...
_POLISHED = 1e-14  # ... stopped once every root's step is below this (relative to |lambda|)
_RESIDUAL_TOL = 1e-8  # |phi| relative to its largest term, after the polish
_SETTLED_STEP = 1e-13  # ... or a Newton step below this (relative to |lambda|)
_SETTLED_RESIDUAL = 1e-5  # ... with |phi| relative to its terms below this
_TRACE_TOL = 1e-9  # |sum lambda + tr D_m| relative to sum |lambda|: no root found twice
_RESTART_STEPS = 12  # Newton steps for a missing root restarted from the trace
_WARM_ASYMMETRY = 1e-2  # a warm start's lower roots moved by this part of their offset


class DampedModes(eqx.Module):
    """The 2n eigenvalues of lambda^2 I + lambda (diag(gamma) + F diag(d) F^T) + Omega^2.

    ``omega``: (n,) undamped frequencies; ``gamma``: (n,) internal damping rates in modal
    coordinates (Rayleigh alpha + beta omega^2, modal 2 zeta omega; zero without); ``factor`` F:
    (n, k) modal damper factor; ``weights`` d: (k,); ``active``: (n,) which modes a damper
    touches (the others keep their own two roots, the poles); ``anchor`` A: (2n,) int, the pole
    each root is written from, lambda = ``poles``[A] + ``offset``; ``null`` c: (2n, k), the
    eigenvector's damper amplitudes (y = R F diag(d) c); ``converged``: whether every root passed
    the residual and trace checks; ``separation``: the smallest |lambda_j - lambda_k| /
    |lambda_j| between two roots that interact (a diagnostic); ``iterations``: Aberth sweeps
    used; ``clusters``: the pairs of nearly coincident roots that every sum over the roots takes
    by a contour integral instead (``_spectral_clusters``; their ``coefficients`` are zero
    here). At an exceptional point (one DOF, d = 2 sqrt(k m): lambda = -sqrt(k/m) twice, one
    eigenvector) the two roots come back within ~sqrt(eps) of the double root, as one cluster.
    """

    omega: Float[Array, " n"]
    gamma: Float[Array, " n"]
    factor: Float[Array, "n k"]
    weights: Float[Array, " k"]
    active: Array
    anchor: Array
    offset: Array
    null: Array
    converged: Array
    separation: Float[Array, ""]
    iterations: Array
    clusters: Clusters
    internal: bool = eqx.field(static=True, default=False)  # whether gamma may be nonzero

    @property
    def start(self) -> "RootStart":
        """These roots as the start of another design's sweeps (``modal_damped_modes``), usable
        where they converged; no derivative."""
        return jax.lax.stop_gradient(RootStart(self.anchor, self.offset, self.converged))

    @property
    def poles(self) -> Array:
        """(2n,) complex: the roots of lambda^2 + gamma_l lambda + omega_l^2, the upper (or
        larger real) one of mode l at l and the other at n + l."""
        return _poles(self.omega, self.gamma)

    @property
    def modes(self) -> Array:
        """(2n,) int: the undamped mode each root is anchored to."""
        return self.anchor % self.omega.shape[0]

    @property
    @complex_arithmetic
    def eigenvalues(self) -> Array:
        """lambda: (2n,) complex; an undamped chain's root j < n near +i omega_j."""
        return self.poles[self.anchor] + self.offset

    @property
    def root_active(self) -> Array:
        """(2n,) bool: the roots of modes a damper touches."""
        return jnp.concatenate([self.active, self.active])

    @property
    def undamped(self) -> Array:
        """(n,) bool: the modes that nothing damps, decided from the structure up to rounding:
        no internal damping and sum_i d_i F_li^2 at most (n eps)^2 sum_i d_i max_l F_li^2 (a
        damper of coefficient 0, or one on a node of the mode, where the chain's mode shape
        is zero to rounding). Their roots stay on the imaginary axis: the infinite-horizon
        objectives (the trace) do not exist where one is seen."""
        n = self.omega.shape[0]
        eps = jnp.finfo(self.omega.dtype).eps
        coupling = jnp.sum(self.weights[None, :] * self.factor**2, axis=1)
        scale = jnp.sum(self.weights * jnp.max(self.factor**2, axis=0))
        return (self.gamma == 0) & (coupling <= (n * eps) ** 2 * scale)

    @property
    def simple(self) -> Array:
        """(2n,) bool: the damped roots summed one by one (not in a cluster)."""
        return self.root_active & ~self.clusters.member

    def safe_normalisers(self, roots, norm) -> Array:
        """N_j with 1 for the roots in a cluster (theirs vanish at a double root; they are
        summed by contour, and a 1 / 0 would poison the gradient through ``where``)."""
        return jnp.where(self.clusters.member[roots], 1.0, norm)

    @complex_arithmetic
    def vector_rows(self, roots) -> Array:
        """Modal eigenvectors of the roots ``roots`` (int indices), as rows: (roots, n) complex.
        Damped roots are scaled so that y_J = -1 / lambda; the others are unit vectors."""
        n = self.omega.shape[0]
        anchor, offset = self.anchor[roots], self.offset[roots]
        r, _ = _resolvent(self.poles, anchor, offset, self.active)
        y = r * ((self.null[roots] * self.weights[None, :]) @ self.factor.T)
        own = jnp.arange(n)[None, :] == (anchor % n)[:, None]
        y = jnp.where(own, (-1 / (self.poles[anchor] + offset))[:, None], y)
        return jnp.where(self.root_active[roots][:, None], y, own.astype(y.dtype))

    @complex_arithmetic
    def normaliser_rows(self, roots, y) -> Array:
        """N_j of the roots ``roots`` from their ``vector_rows`` y: (roots,) complex."""
        lam = self.poles[self.anchor[roots]] + self.offset[roots]
        yfw = y @ self.factor
        return (jnp.sum((2 * lam[:, None] + self.gamma[None, :]) * y * y, axis=1)
                + jnp.sum(yfw * self.weights[None, :] * yfw, axis=1))

    @complex_arithmetic
    def row_products(self, roots, columns) -> tuple[Array, Array]:
        """(y_j^T X (roots, p), N_j (roots,)) of the roots ``roots`` for real columns X (n, p),
        without forming the rows ``vector_rows``.

        Off its own entry (-1 / lambda_j) a damped root's y_j is R_j F diag(d) c_j, so y_j^T X
        = (d c_j)^T (R_j (F (x) X)) - X_J / lambda_j and N_j = (d c_j)^T ((2 lambda_j + gamma)
        R_j^2 (F (x) F)) (d c_j) + (2 lambda_j + gamma_J) / lambda_j^2 + (y_j^T F) diag(d)
        (F^T y_j): the resolvent's (roots, n) rows meet the columns in two real matrix products
        (``complex_product``), O(n k (k + p)) per root, instead of forming y and reading it once
        per column (a memory-bound pass each at n = 10^4)."""
        n, k = self.factor.shape
        anchor, offset = self.anchor[roots], self.offset[roots]
        mode = anchor % n
        lam = self.poles[anchor] + offset
        r, _ = _resolvent(self.poles, anchor, offset, self.active)
        stacked = jnp.concatenate([self.factor, columns], axis=1)  # (n, k + p)
        width = stacked.shape[1]
        spread = (self.factor[:, :, None] * stacked[:, None, :]).reshape(n, k * width)
        wc = self.null[roots] * self.weights[None, :]

        products = complex_product(r, spread).reshape(-1, k, width)
        yx = jnp.einsum("ja,jab->jb", wc, products) - stacked[mode] / lam[:, None]
        rate = 2 * lam[:, None] + self.gamma[None, :]
        quad = complex_product(rate * r * r, (self.factor[:, :, None]
                                              * self.factor[:, None, :]).reshape(n, k * k))
        yf = yx[:, :k]
        norm = (jnp.einsum("ja,jab,jb->j", wc, quad.reshape(-1, k, k), wc)
                + (2 * lam + self.gamma[mode]) / lam**2
                + jnp.sum(yf * self.weights[None, :] * yf, axis=1))
        # a root of a mode no damper touches: y_j the unit vector of its mode
        own = stacked[mode]
        own_norm = 2 * lam + self.gamma[mode] + jnp.sum(own[:, :k] ** 2 * self.weights[None, :],
                                                            axis=1)
        active = self.root_active[roots]
        return (jnp.where(active[:, None], yx, own)[:, k:],
                jnp.where(active, norm, own_norm))

    def vectors(self) -> Array:
        """Modal eigenvectors y: (n, 2n) complex, (lambda^2 + lambda D_m + Omega^2) y = 0.

        Damped roots are scaled so that y_J = -1 / lambda; the others are unit vectors.
        """
        return self.vector_rows(jnp.arange(self.anchor.shape[0])).T

    def normalisers(self) -> Array:
        """N_j = y_j^T (2 lambda_j I + D_m) y_j: (2n,) complex, the bi-orthogonality scale of
        ``vectors`` (y_k^T ((lambda_j + lambda_k) I + D_m) y_j = 0 for j != k). Zero at a
        defective pair (critical damping)."""
        return self.normaliser_rows(jnp.arange(self.anchor.shape[0]), self.vectors().T)

    @complex_arithmetic
    def coefficients(self, q0: Float[Array, "n ..."], p0: Float[Array, "n ..."]) -> Array:
        """a: (2n, *p) complex, the modal state (eta(0), eta'(0)) = (q0, p0) expanded as
        eta(t) = sum_j a_j exp(lambda_j t) y_j (every root, deflated ones included); q0, p0 may
        carry a trailing batch axis.

        a_j = y_j^T ((lambda_j I + D_m) q0 + p0) / N_j, written as y_j^T (p0 - Omega^2 q0 /
        lambda_j) / N_j by the eigen-equation: the two terms of the first form cancel for a root
        running to -infinity (a strong damper), this form does not.
        """
        lam = self.eigenvalues
        y = self.vectors().T
        stiff = (self.omega**2).reshape((-1,) + (1,) * (q0.ndim - 1)) * q0
        lam = lam.reshape((-1,) + (1,) * (q0.ndim - 1))
        roots = jnp.arange(lam.shape[0])
        norm = self.safe_normalisers(roots, self.normalisers()).reshape(lam.shape)
        member = self.clusters.member.reshape(lam.shape)
        n = q0.shape[0]
        both = complex_product(y, jnp.concatenate([p0.reshape(n, -1), stiff.reshape(n, -1)],
                                                  axis=1))
        yp, ys = (part.reshape(lam.shape[:1] + q0.shape[1:]) for part in jnp.split(both, 2, 1))
        return jnp.where(member, 0.0, (yp - ys / lam) / norm)

    @complex_arithmetic
    def load_coefficients(self, g: Float[Array, " n"]) -> Array:
        """b: (2n,) complex, b_j = y_j^T g / N_j for a constant modal force g (= U^T f): the
        response of eta'' + D_m eta' + Omega^2 eta = g from rest is eta(t) = sum_j b_j
        (exp(lambda_j t) - 1) / lambda_j y_j (the static part Omega^-2 g = -sum_j b_j y_j /
        lambda_j); zero for the roots in a cluster, as ``coefficients``."""
        y = self.vectors().T
        roots = jnp.arange(y.shape[0])
        norm = self.safe_normalisers(roots, self.normalisers())
        return jnp.where(self.clusters.member, 0.0, (y @ g) / norm)


class RootStart(eqx.Module):
    """Where the sweeps of ``modal_damped_modes`` start: another design's roots (a warm start,
    ``DampedModes.start``), used where ``usable``; else the arc starts. A search's successive
    designs are close, so their roots are: on FastOptimalDamping.jl's example the sweeps fall
    from 14 to 8 at a 1 % step, in the middle of Mikota's n = 60 chain from 14 to 4 (a start
    five decades of damping away costs more). The lower half's roots (n + j, near -i omega_j
    undamped) start 1 % of their offset off their old places: from exactly symmetric starts a
    pair that has to split onto the real axis never did (on the same example with 40 masses
    per chain, a 1 % step took 33 sweeps from the old roots, 8 from the moved ones, 13 from
    the arcs). The roots found are the same to rounding from either start (the same checks
    pass or fail them); a search that meets a failure from a warm start evaluates that design
    once more from the arc starts, so that a start changes the time, never the value.
    ``cold(n)``: no start (same shapes, one compiled program for both)."""

    anchor: Array  # (2n,) int
    offset: Array  # (2n,) complex
    usable: Array  # () bool

    @classmethod
    def cold(cls, n: int) -> "RootStart":
        return cls(jnp.arange(2 * n), jnp.zeros(2 * n, jnp.complex128), jnp.array(False))


def _poles(omega, gamma):
    """(2n,) roots of lambda^2 + gamma lambda + omega^2 without cancellation: -gamma/2 +-
    i sqrt((omega - gamma/2)(omega + gamma/2)) below critical, -omega^2 / (gamma/2 + root) and
    -(gamma/2 + root) above (overdamped mode: two real poles)."""
    half = gamma / 2
    under = (omega - half) * (omega + half)
    root = jnp.sqrt(jnp.abs(under))
    over = under < 0
    big = -(half + root)
    small = -(omega**2) / jnp.where(half + root > 0, half + root, 1.0)
    upper = jnp.where(over, small + 0j, -half + 1j * root)
    lower = jnp.where(over, big + 0j, -half - 1j * root)
    return jnp.concatenate([upper, lower])


def _gaps(poles, anchor, offset):
    """lambda_j - p_l and lambda_j - p_(n+l) without cancellation: two (2n, n) arrays."""
    n = poles.shape[0] // 2
    base = poles[anchor]
    return (base[:, None] - poles[None, :n]) + offset[:, None], (
        (base[:, None] - poles[None, n:]) + offset[:, None])


@jax.custom_jvp
def _reciprocal(x):
    """1 / x, whose tangent -dx r^2 reuses r = 1 / x (JAX's own rule divides once more: a
    complex division per entry of the resolvent's derivative)."""
    return 1 / x


@_reciprocal.defjvp
def _reciprocal_jvp(primals, tangents):
    r = 1 / primals[0]
    return r, -tangents[0] * r * r


def _resolvent(poles, anchor, offset, active):
    """r_jl = 1 / (lambda_j^2 + gamma_l lambda_j + omega_l^2) over damped l != J_j (0
    elsewhere), and the mask."""
    upper, lower = _gaps(poles, anchor, offset)
    n = poles.shape[0] // 2
    mask = active[None, :] & (jnp.arange(n)[None, :] != (anchor % n)[:, None])
    product = upper * lower
    return jnp.where(mask, _reciprocal(jnp.where(mask, product, 1.0)), 0.0), mask


def _partner(anchor, n):
    """The other pole of the same mode."""
    return (anchor + n) % (2 * n)


def _secular(poles, gamma, factor, weights, active, anchor, offset, block=None, moving=None,
             spread=False):
    """Per root: (phi, phi', sum of the other poles' log-derivative + tr H^-1 H', c = H^-1 f_J,
    the size of phi's terms, dc/dlambda = -H^-1 H' c); ``block`` roots at a time
    (``by_rows``); with ``moving`` (2n,) only for those roots, zeros for the others
    (``by_rows_where``). ``spread``: also sum_(l != J) |r_l|^2 f_l f_l^T (roots, k, k), whence
    the eigenvector's size |y|^2 (``_vector_size``)."""
    def rows(a, o):
        return _secular_rows(poles, gamma, factor, weights, active, a, o, spread)

    if moving is None:
        return by_rows(rows, block, anchor, offset)
    return by_rows_where(rows, block, moving, anchor, offset)


def _secular_rows(poles, gamma, factor, weights, active, anchor, offset, spread=False):
    """``_secular`` for the roots ``anchor``, ``offset`` (any number of them)."""
    k = factor.shape[1]
    n = gamma.shape[0]
    mode = anchor % n
    lam = poles[anchor] + offset
    r, mask = _resolvent(poles, anchor, offset, active)
    rate = 2 * lam[:, None] + gamma[None, :]  # d/dlambda (lambda^2 + gamma_l lambda + omega_l^2)
    r_prime = r - lam[:, None] * rate * r**2  # d/dlambda (lambda r)
    ff = (factor[:, :, None] * factor[:, None, :] * weights[None, None, :]).reshape(n, k * k)
    h = jnp.eye(k)[None] + lam[:, None, None] * complex_product(r, ff).reshape(-1, k, k)
    h_prime = complex_product(r_prime, ff).reshape(-1, k, k)
    f = factor[mode]  # (2n, k)
    solved = small_solve(h, jnp.stack([f.astype(h.dtype)] + [h_prime[:, :, i] for i in
                                                             range(k)], axis=-1))
    c = solved[..., 0]  # H^-1 f_J
    h_inv_h_prime = solved[..., 1:]
    trace = jnp.trace(h_inv_h_prime, axis1=-2, axis2=-1)
    wf = f * weights[None, :]
    quad = jnp.sum(wf * c, axis=-1)  # f^T W H^-1 f
    quad_prime = -jnp.sum(wf * jnp.einsum("jab,jb->ja", h_inv_h_prime, c), axis=-1)
    # lambda^2 + gamma_J lambda + omega_J^2 = delta (delta + p_A - p_partner)
    pole = offset * (offset + poles[anchor] - poles[_partner(anchor, n)])
    phi = pole + lam * quad
    phi_prime = 2 * lam + gamma[mode] + quad + lam * quad_prime
    scale = jnp.abs(pole) + jnp.abs(lam * quad)
    others = jnp.sum(jnp.where(mask, rate * r, 0.0), axis=1) + trace
    out = (phi, phi_prime, others, c, scale, -jnp.einsum("jab,jb->ja", h_inv_h_prime, c))
    if spread:
        plain = (factor[:, :, None] * factor[:, None, :]).reshape(n, k * k)
        out += ((abs2(r) @ plain).reshape(-1, k, k),)
    return out


def _vector_size(lam, c, weights, spread):
    """|y|^2 of the eigenvectors y = R F diag(d) c with y_J = -1 / lambda (``DampedModes``) from
    ``_secular``'s ``spread`` S: 1 / |lambda|^2 + (d c)^H S (d c), O(k^2) per root."""
    wc = c * weights[None, :]
    quad = jnp.einsum("ja,jab,jb->j", jnp.conj(wc), spread, wc)
    return 1 / abs2(lam) + jnp.real(quad)


def _axis_order(poles, candidates):
    """For poles on the imaginary axis (no internal damping: +-i omega): (order, values), the
    indices of the poles sorted by imaginary part with the candidates first (stable: equal
    values in index order) and their sorted imaginary parts (inf for the others)."""
    key = jnp.where(candidates, jnp.imag(poles), jnp.inf)
    order = jnp.argsort(key, stable=True)
    return order, key[order]


def _axis_nearest(poles, axis, lam, count: int):
    """(roots, count) indices of the ``count`` candidate poles nearest each root ``lam``, for
    poles on the imaginary axis (``_axis_order``'s ``axis``), in O(log n) per root instead of a
    pass over all 2n poles: the distance to i w grows with |Im lambda - w|, so the nearest lie
    among the ``count`` below and above Im lambda in the sorted order. Picked by (distance,
    index), as successive argmins over all poles pick them; for one pole the lower neighbour is
    the first of its run of equal values (the lowest index), so that the pick is the argmin's
    even where frequencies repeat exactly."""
    order, values = axis
    size = values.shape[0]
    above = jnp.searchsorted(values, jnp.imag(lam), side="left")  # (roots,)
    slots = above[:, None] + jnp.arange(-count, count)[None, :]
    if count == 1:
        below = jnp.searchsorted(values, values[jnp.clip(above - 1, 0, size - 1)], side="left")
        slots = jnp.stack([jnp.where(above > 0, below, -1), above], axis=1)
    return _slot_picks(poles, axis, lam, slots, count, jnp.abs)[0]


def _slot_picks(poles, axis, lam, slots, count: int, measure):
    """(picks (roots, count), the last pick's ``measure`` of distance): the ``count`` poles at
    ``slots`` (roots, w) of the sorted order nearest each root, by (distance, index) as successive
    argmins over all poles pick them (ties to the lowest index)."""
    order, values = axis
    size = values.shape[0]
    clipped = jnp.clip(slots, 0, size - 1)
    index = order[clipped]
    valid = (slots >= 0) & (slots < size) & jnp.isfinite(values[clipped])
    distance = jnp.where(valid, measure(lam[:, None] - poles[index]), jnp.inf)
    rows = jnp.arange(lam.shape[0])
    picks = []
    for _ in range(count):
        best = jnp.min(distance, axis=1)
        column = jnp.argmin(jnp.where(distance == best[:, None], index, size), axis=1)
        picks.append(index[rows, column])
        distance = distance.at[rows, column].set(jnp.inf)
    return jnp.stack(picks, axis=1), best


def _window_nearest(poles, order, lam, count: int = 1, width: int = 32):
    """(nearest (roots, count), certified (roots,)) for roots ``lam`` among candidate poles
    anywhere in the plane (internal damping), from ``order`` = ``_axis_order`` (sorted by
    imaginary part): the ``count`` nearest of the 2 ``width`` poles around Im lambda in that
    order, by (distance, index) as successive argmins over all poles pick them, and whether they
    are those argmins' picks: every pole outside the window is at least its imaginary gap away,
    and rounding keeps that order (|z|^2 >= (Im z)^2, and Im lambda - Im p is rounded
    monotonically in Im p), so picks strictly nearer than the gap at the window's edges are the
    picks over all poles. A low root of the FastOptimalDamping example sits 0.02 left of poles
    0.0003 apart: 32 on each side certify all but its far real roots."""
    order, values = order
    size = values.shape[0]
    above = jnp.searchsorted(values, jnp.imag(lam), side="left")  # (roots,)
    slots = above[:, None] + jnp.arange(-width, width)[None, :]
    picks, best = _slot_picks(poles, (order, values), lam, slots, count, abs2)
    low = above - width - 1  # the last pole below the window, and the first above it
    high = above + width
    gap_low = jnp.where(low >= 0, jnp.imag(lam) - values[jnp.clip(low, 0, size - 1)], jnp.inf)
    gap_high = jnp.where(high < size, values[jnp.clip(high, 0, size - 1)] - jnp.imag(lam),
                         jnp.inf)
    gap = jnp.minimum(gap_low, gap_high)
    return picks, best < gap * gap


def _reanchor(poles, active, anchor, offset, block=None, axis=None, order=None):
    """Move each root's anchor to its nearest pole of a damped mode (same lambda). ``axis``:
    ``_axis_order`` where the poles lie on the imaginary axis (no internal damping; sorted once
    per system, not per sweep), found by ``_axis_nearest``; else ``order`` (the same sort of
    poles anywhere, internal damping): ``_window_nearest``, and a pass over all poles for a block
    of roots it does not certify (real roots far from the poles: their nearest pole need not lie
    near their imaginary part); both None: a pass over all poles. Every route picks the same
    pole, the argmin over all (at n = 801 with modal damping the pass cost 6.6 ms a sweep)."""
    candidates = jnp.concatenate([active, active])

    def everywhere(lam):
        distance = abs2(lam[:, None] - poles[None, :])
        return jnp.argmin(jnp.where(candidates[None, :], distance, jnp.inf), axis=1)

    def rows(anchor, offset):
        lam = poles[anchor] + offset
        if axis is not None:
            new_anchor = _axis_nearest(poles, axis, lam, 1)[:, 0]
        elif order is not None:
            pick, certified = _window_nearest(poles, order, lam)
            new_anchor = batch_cond(~jnp.all(certified),
                                    lambda: jnp.where(certified, pick[:, 0], everywhere(lam)),
                                    lambda: pick[:, 0])
        else:
            new_anchor = everywhere(lam)
        return new_anchor, offset + (poles[anchor] - poles[new_anchor])

    return by_rows(rows, block, anchor, offset)


_ANCHOR_CANDIDATES = 4
_ANCHOR_SETTLED = 1e-13  # |phi_J| / (its terms) at which no further anchor is tried


def _nearest_anchors(poles, active, anchor, offset, block=None, axis=None, order=None):
    """(candidates, 2n): each root's ``_ANCHOR_CANDIDATES`` nearest poles of damped modes, the
    nearest first. ``axis``, ``order``: as ``_reanchor``."""
    n = poles.shape[0] // 2
    candidates = jnp.concatenate([active, active])
    columns = jnp.arange(2 * n)[None, :]
    count = min(_ANCHOR_CANDIDATES, 2 * n)

    def rows(anchor, offset):
        lam = poles[anchor] + offset
        if axis is not None:
            return _axis_nearest(poles, axis, lam, count)
        if order is not None:
            picks, certified = _window_nearest(poles, order, lam, count)
            return batch_cond(~jnp.all(certified),
                              lambda: jnp.where(certified[:, None], picks, everywhere(lam)),
                              lambda: picks)
        return everywhere(lam)

    def everywhere(lam):
        distance = jnp.where(candidates[None, :], abs2(lam[:, None] - poles[None, :]), jnp.inf)
        # successive argmins, not ``lax.top_k``: XLA's CPU top_k sorts each row (40 ms at
        # n = 300, a third of one spectral value), a few masked argmins cost a pass each
        nearest = []
        for _ in range(count):
            pick = jnp.argmin(distance, axis=1)
            nearest.append(pick)
            distance = jnp.where(columns == pick[:, None], jnp.inf, distance)
        return jnp.stack(nearest, axis=1)

    return by_rows(rows, block, anchor, offset).T


def _finish(poles, gamma, factor, weights, active, anchor, offset, trace, block=None,
            axis=None, order=None):
    """After the sweeps: each root's anchor, a Newton polish, and a restart of a missing root, in
    one loop of secular passes (one copy of ``_secular`` to compile, not three). Returns
    (anchor, offset, lambda, c, per-root residual ok, phi_J', |y|^2), the last three from the
    last pass, at the returned roots; ``trace``: tr D_m + sum gamma over the damped modes, which
    the damped roots sum to minus; ``axis``, ``order``: as ``_reanchor``.

    1. **Anchors.** Each root is re-anchored (same lambda) at the one of its nearest poles where
       phi_J vanishes. phi_J is zero at a root only if H_J = H - lambda r_J f_J f_J^T W stays
       regular there. Where modes lie closer together than the dampers' coupling (two nearly
       decoupled chains), a root's nearest pole may belong to a weakly coupled mode whose
       removal leaves H_J as singular as H: phi_J is then O(1) at the (correct) root and Newton
       on it jumps to another root. So the ``_ANCHOR_CANDIDATES`` nearest poles of damped modes
       are tried in order, each root keeping the first smallest relative residual |phi_J| /
       (its terms) (the argmin's pick); a root whose residual is at rounding level
       (``_ANCHOR_SETTLED``) tries no further pole (usually after the nearest one: one pass,
       not four). A pass that settles every anchor at the nearest pole evaluated each root at
       its final anchor, and is the polish's first.
    2. **Polish.** Newton steps on phi_J, until every step is below ``_POLISHED`` |lambda|
       (the roots sit at their fixed point to rounding: this pass's values are the last, the
       step is not taken; a root whose own step is below it stays where it is meanwhile) or
       ``_POLISH_STEPS`` were taken (the last pass only evaluates). After
       the sweeps the first step is usually at rounding level already (below 5e-15 |lambda|
       on seven chains checked, the multi-damper notebook's triple chain among them): the
       anchors' pass and the polish are then one pass, not two.
    3. **Restart.** Where exactly one root fails its residual and the roots' sum misses the
       trace, that root is restarted from the trace (minus the sum of the others) and gets up to
       ``_RESTART_STEPS`` Newton steps. On the triple chain (d_3 = 229 at DOF 101) Aberth
       parked a second copy beside a real root, -27.9 + 7e-5 i, while a far real root went
       missing: 21 of the multi-damper notebook's 441 landscape points.

    Each pass evaluates only the roots whose point (anchor, offset) moved since their last
    evaluation (``by_rows_where``: blocks without one are skipped outside ``vmap``): the
    FastOptimalDamping example (n = 801) has six low roots settling at 1e-13 to 2e-13, above
    ``_ANCHOR_SETTLED``; they alone try the further poles, and its finish took 47 ms instead of
    141 ms (eight passes over all 1602 roots).
    """
    n = gamma.shape[0]
    root_active = jnp.concatenate([active, active])
    nearest = _nearest_anchors(poles, active, anchor, offset, block, axis, order)
    count = nearest.shape[0]

    def assess(anchor, offset, phi, phi_prime, scale):
        """(lambda, per-root residual ok, trace ok). A root holds where phi_J is small against
        its terms, or where Newton cannot move it any more (a step at rounding level) with phi_J
        small against a looser bar: phi_J's terms do not show the cancellation inside H^-1 f_J,
        which on the triple chain of the multi-damper notebook (n = 151, d_1 ~ 10 at DOF 1) left
        a converged real root at |phi| / terms = 1e-7 while Newton's steps alternated in the
        last bit. And a root holds where Newton would move it by less than one rounding of
        lambda: its residual is what lambda's own last bit makes. phi_J's terms can be far
        smaller than that: a root on the pole of a mode the dampers barely reach (a near node,
        coupling 1e-14) has both terms near 1e-26 while the offset's last bit gives |phi| ~
        1e-14 (Mikota's n = 60 chain with modal damping, a damper at DOF 60). A Newton step
        that small away from a root needs lambda within rounding of a singularity of phi_J."""
        lam = poles[anchor] + offset
        newton_step = jnp.abs(phi) / jnp.where(phi_prime != 0, jnp.abs(phi_prime), jnp.inf)
        settled = (newton_step <= _SETTLED_STEP * jnp.abs(lam)) & (
            jnp.abs(phi) <= _SETTLED_RESIDUAL * scale)
        rounding = newton_step <= jnp.finfo(newton_step.dtype).eps * jnp.abs(lam)
        root_ok = (~root_active | (jnp.abs(phi) <= _RESIDUAL_TOL * scale) | settled
                   | rounding)
        trace_ok = (jnp.abs(jnp.sum(jnp.where(root_active, lam, 0.0)) + trace)
                    <= _TRACE_TOL * jnp.sum(jnp.where(root_active, jnp.abs(lam), 0.0)))
        return lam, root_ok, trace_ok

    def restart_point(lam, root_ok):
        """The failing roots' (anchor, offset) restarted from the trace: minus the sum of the
        others. Its anchor: the mode with the largest eigenvector entry y_l = r_l f_l^T diag(d)
        c, c the null vector of det(I + lambda F^T R F diag(d)) there (the nearest poles can all
        be weakly coupled modes whose phi_J does not vanish at a far root)."""
        missing = -trace - jnp.sum(jnp.where(root_active & root_ok, lam, 0.0))
        r = 1 / ((missing - poles[:n]) * (missing - poles[n:]))
        h = jnp.eye(factor.shape[1]) + missing * (factor.T @ (r[:, None] * factor)) * (
            weights[None, :])
        null = jnp.conj(jnp.linalg.svd(h)[2][-1])
        y = jnp.where(active, jnp.abs(r * (factor @ (weights * null))), -1.0)
        mode = jnp.argmax(y)
        own = jnp.where(jnp.abs(missing - poles[mode]) <= jnp.abs(missing - poles[n + mode]),
                        mode, n + mode)
        return own, missing - poles[own]

    def body(carry):
        (trying, t, anchor, offset, best, best_anchor, best_offset, moving, steps, restarted, _,
         at, values) = carry
        candidate = nearest[jnp.minimum(t, count - 1)]
        trial_offset = offset + (poles[anchor] - poles[candidate])
        # a root of a mode no damper touches keeps its own pole; a root settled at rounding
        # level tries no further anchor
        trial = trying & root_active & ~(best <= _ANCHOR_SETTLED)
        at_anchor = jnp.where(trial, candidate, anchor)
        at_offset = jnp.where(trial, trial_offset, offset)
        # only the roots whose point moved since their last evaluation (``by_rows_where``)
        stale = (at_anchor != at[0]) | (at_offset != at[1])
        fresh = _secular(poles, gamma, factor, weights, active, at_anchor, at_offset, block,
                         stale, spread=True)
        values = tuple(jnp.where(stale.reshape((-1,) + (1,) * (new.ndim - 1)), new, old)
                       for new, old in zip((fresh[i] for i in (0, 1, 3, 4, 6)), values))
        phi, phi_prime, c, scale, spread = values
        at = (at_anchor, at_offset)
        # 1. anchors: keep the first smallest residual (NaN as argmin treats it)
        value = jnp.where(scale > 0, jnp.abs(phi) / scale, jnp.inf)
        better = trial & jnp.where(jnp.isnan(best), False, jnp.isnan(value) | (value < best))
        best = jnp.where(better, value, best)
        best_anchor = jnp.where(better, candidate, best_anchor)
        best_offset = jnp.where(better, trial_offset, best_offset)
        tried = trying & ((t + 1 >= count)
                          | ~jnp.any(root_active & ~(best <= _ANCHOR_SETTLED)))
        anchor = jnp.where(tried & root_active, best_anchor, anchor)
        offset = jnp.where(tried & root_active, best_offset, offset)
        moving = jnp.where(tried, root_active, moving)
        # anchors settled at the first candidate: every root was evaluated at its final anchor,
        # and this pass is also the polish's first (usually its only one: one pass, not two)
        first = tried & (t == 0)
        polish = ~trying | first
        # 2. Newton on the moving roots, until every step is at rounding level (then this
        # pass's evaluation is the last) or after ``steps`` steps (the next pass only evaluates).
        # A root whose step is at rounding level already stays (and is not evaluated again)
        newton = jnp.where(moving & (phi_prime != 0),
                           phi / jnp.where(phi_prime != 0, phi_prime, 1.0), 0.0)
        lam = poles[anchor] + offset
        small = jnp.abs(newton) <= _POLISHED * jnp.abs(lam)
        quiet = jnp.all(small)
        finished = polish & ((t >= steps) | quiet)
        offset = offset - jnp.where(polish & ~finished & ~small, newton, 0.0)
        # 3. after the last pass: a restart, once, where one root is missing
        lam, root_ok, trace_ok = assess(anchor, offset, phi, phi_prime, scale)
        again = finished & ~restarted & (jnp.sum(~root_ok) == 1) & ~trace_ok
        own, restart_offset = restart_point(lam, root_ok)
        bad = again & ~root_ok
        anchor = jnp.where(bad, own, anchor)
        offset = jnp.where(bad, restart_offset, offset)
        moving = jnp.where(again, ~root_ok, moving)
        steps = jnp.where(again, _RESTART_STEPS, steps)
        t = jnp.where(again | (tried & ~first), 0, t + 1)
        return (trying & ~tried, t, anchor, offset, best, best_anchor, best_offset, moving,
                steps, restarted | again, finished & ~again, at, values)

    shapes = jax.eval_shape(lambda o: _secular(poles, gamma, factor, weights, active, anchor, o,
                                               block, spread=True), offset)
    empty = tuple(jnp.zeros(shapes[i].shape, shapes[i].dtype) for i in (0, 1, 3, 4, 6))
    # the nearest pole's offset from the start, so that anchor and offset always match (a
    # root whose every residual is inf keeps the first candidate, as the argmin did); no root
    # evaluated yet (anchor -1)
    init = (jnp.array(True), jnp.array(0), anchor, offset, jnp.full(2 * n, jnp.inf), nearest[0],
            offset + (poles[anchor] - poles[nearest[0]]), root_active,
            jnp.array(_POLISH_STEPS), jnp.array(False), jnp.array(False),
            (jnp.full_like(anchor, -1), offset), empty)
    final = jax.lax.while_loop(lambda carry: ~carry[10], body, init)
    anchor, offset = final[2], final[3]
    phi, phi_prime, c, scale, spread = final[12]
    lam, root_ok, _ = assess(anchor, offset, phi, phi_prime, scale)
    return anchor, offset, lam, c, root_ok, phi_prime, _vector_size(lam, c, weights, spread)


@eqx.filter_jit
@complex_arithmetic
def modal_damped_modes(omega: Float[Array, " n"], factor: Float[Array, "n k"],
                       weights: Float[Array, " k"],
                       gamma: Float[Array, " n"] | None = None, *,
                       block: int | None = None,
                       start: RootStart | None = None) -> DampedModes:
    """All 2n eigenvalues of lambda^2 I + lambda (diag(gamma) + F diag(d) F^T) + Omega^2,
    O(k^2 n^2) per sweep.

    ``omega``: (n,) distinct positive frequencies; ``factor`` F: (n, k); ``weights`` d: (k,)
    >= 0; ``gamma``: (n,) >= 0 modal internal damping rates (default zero); ``block``: roots
    per block of the O(n^2) work (``row_block``: automatic, O(n) memory above n = 64);
    ``start``: where the sweeps start (``RootStart``: a nearby design's roots), None for the arc
    starts. See the module docstring for the method and the returned layout. Not
    differentiable through the iteration: ``spectral_energy`` differentiates by one Newton
    step at the roots.
    """
    n = omega.shape[0]
    block = row_block(n, block)
    internal = gamma is not None
    gamma = jnp.zeros_like(omega) if gamma is None else gamma
    poles = _poles(omega, gamma)
    coupling = jnp.sqrt(jnp.sum(weights[None, :] * factor**2, axis=1))  # |row l of D_m^(1/2)|
    eps = jnp.finfo(omega.dtype).eps
    # pitfall 1 of the notes: a mode no damper touches has its roots on its poles (0 / 0).
    # Which modes are touched is decided at a damper's coefficient, or at omega_max / |f_i|^2 if
    # that is larger (then: |f_li| > eps |f_i|): a weak (or zero) damper's first-order effect on
    # a mode, and its derivative (d -> 0), are kept instead of being deflated away
    columns = jnp.sum(factor**2, axis=0)
    scale = jnp.max(omega) / jnp.where(columns > 0, columns, 1.0)
    reach = jnp.sqrt(jnp.sum(jnp.maximum(weights, scale)[None, :] * factor**2, axis=1))
    total = jnp.sqrt(jnp.sum(reach**2))
    active = reach * total > eps * jnp.maximum(jnp.max(omega), total**2)
    anchor = jnp.arange(2 * n)
    # the poles sorted by imaginary part once here; without internal damping they lie on the
    # imaginary axis (+-i omega), where the sort alone finds the nearest
    order = _axis_order(poles, jnp.concatenate([active, active]))
    axis = None if internal else order
    sign = jnp.concatenate([jnp.ones(n), -jnp.ones(n)])
    # start inside the left half plane, off the poles, asymmetric so pairs can split onto the
    # real axis: on the arc each root follows as the dampers grow (``arc_starts``)
    arc = arc_starts(omega, coupling, active, sign)
    root_active = jnp.concatenate([active, active])
    offset = jnp.where(root_active, arc, 0.0).astype(jnp.complex128)
    offset = far_starts(poles, omega, factor, weights, active, offset)
    if start is not None:  # a nearby design's converged roots, each where its pole is damped
        warm = (start.usable & root_active & root_active[start.anchor]
                & jnp.isfinite(start.offset))
        # conjugate roots are symmetric starts, which the iteration keeps symmetric: a pair
        # that has to split onto the real axis (past critical damping) would not. The lower
        # half's roots move by a fraction of their offset, as the arc starts' do
        lower = jnp.arange(2 * n) >= n
        moved = jnp.where(lower, start.offset * (1 + _WARM_ASYMMETRY)
                          - _WARM_ASYMMETRY * jnp.abs(start.offset), start.offset)
        anchor = jnp.where(warm, start.anchor, anchor)
        offset = jnp.where(warm, moved, offset)

    def sweep(carry):
        anchor, offset, it, _, moving = carry
        phi, phi_prime, others, _, _, _ = _secular(poles, gamma, factor, weights, active, anchor,
                                                offset, block, moving)
        repel = repulsion(poles, anchor, offset, root_active, block, moving)
        denominator = phi * (others - repel) + phi_prime
        step = jnp.where(moving & (denominator != 0),
                         phi / jnp.where(denominator != 0, denominator, 1.0), 0.0)
        # a root parked at its place but anchored to a mode the dampers barely reach (a node)
        # leaves H_J singular there, its step 0 / 0: it stays, the others go on (a NaN would
        # reach every root through the repulsion); ``_finish`` re-anchors it afterwards
        finite = jnp.isfinite(step)
        step = jnp.where(finite, step, 0.0)
        offset = offset - step
        lam = poles[anchor] + offset
        relative = jnp.abs(step) / jnp.abs(lam)
        size = jnp.max(jnp.where(root_active, relative, 0.0))
        anchor, offset = _reanchor(poles, active, anchor, offset, block, axis, order)
        offset = jnp.where(root_active, offset, 0.0)
        # a root whose step and own Newton step fell to the stopping size sits at its fixed
        # point to rounding: the next sweeps skip it (its value still repels the others), so
        # that they cost what the roots still moving cost (blocks of them, ``by_rows_where``).
        # The Newton step too: beside a nearly double root the repulsion shrinks the step of
        # one of the pair long before it settles, and the other then crawled alone (36 sweeps
        # instead of 18 on FastOptimalDamping.jl's example at its optimum)
        newton = jnp.abs(phi) / jnp.where(phi_prime != 0, jnp.abs(phi_prime), jnp.inf)
        moving = moving & ~(finite & (relative <= _ABERTH_TOL)
                            & (newton <= _ABERTH_TOL * jnp.abs(lam)))
        return anchor, offset, it + 1, size, moving

    def not_done(carry):
        _, _, it, size, _ = carry
        return (it < _MAX_ITERATIONS) & ((size > _ABERTH_TOL) | ~jnp.isfinite(size))

    init = (anchor, offset, jnp.array(0), jnp.array(jnp.inf), root_active)
    anchor, offset, iterations, _, _ = jax.lax.while_loop(not_done, sweep, init)
    anchor = jnp.where(root_active, anchor, jnp.arange(2 * n))
    trace = jnp.sum(jnp.where(active, coupling**2 + gamma, 0.0))
    anchor, offset, lam, c, root_ok, phi_prime, size = _finish(
        poles, gamma, factor, weights, active, anchor, offset, trace, block, axis, order)
    # a pair summed by contour: its two roots need not pass one by one (at a double root they
    # are only sqrt(eps)-accurate and Newton's residual stays at rounding), but the circle must
    # hold exactly two, and their sum (by contour) stands for them in the trace check
    # each root's conditioning 2 |lambda| |y|^2 / |N| (~1 / separation near a double root),
    # from the last secular pass: N_j = y^T (2 lambda_j + D_m) y = phi_J'(lambda_j) / lambda_j^2
    # (phi_J is the Schur complement of lambda^2 + lambda D_m + Omega^2 onto the anchor's
    # entry, whose derivative at a root is y^T Q'(lambda) y for y_J = 1; here y_J = -1 /
    # lambda), so no pass forms the eigenvector rows
    norm = jnp.abs(phi_prime)
    growth = 2 * jnp.abs(lam) ** 3 * size
    condition = jnp.where(norm > 0, growth / jnp.where(norm > 0, norm, 1.0), jnp.inf)
    clusters, separation = find_clusters(poles, anchor, offset, active, condition, block)
    count, inside = cluster_roots(poles, factor, weights, active, clusters)
    paired = jnp.all(~clusters.valid | (jnp.abs(count - 2) < 1e-6))
    residual_ok = jnp.all(root_ok | clusters.member)
    simple = root_active & ~clusters.member
    total = jnp.sum(jnp.where(simple, lam, 0.0)) + jnp.sum(jnp.where(clusters.valid, inside, 0.0))
    trace_ok = (jnp.abs(total + trace)
                <= _TRACE_TOL * jnp.sum(jnp.where(root_active, jnp.abs(lam), 0.0)))
    converged = (residual_ok & trace_ok & paired & jnp.all(jnp.isfinite(lam))
                 & jnp.all(jnp.isfinite(c)))
    return DampedModes(omega, gamma, factor, weights, active, anchor, offset, c, converged,
                       separation, iterations, clusters, internal)


@complex_arithmetic
def differentiable_roots(modes: DampedModes, block: int | None = None) -> DampedModes:
    """The same roots with the derivative of one Newton step on phi_J at them (implicit
    differentiation: dlambda = -dphi / phi'); the iteration itself carries no derivative.
    ``block``: as ``modal_damped_modes``.

    The values are the frozen roots' own; the derivative is a ``custom_jvp`` rule
    (``_implicit``), so a call without derivatives costs nothing here. One evaluation of the
    secular terms gives both derivatives: c = H^-1 f_J moves with the system at fixed lambda
    (c's own tangent) and with lambda, by dc/dlambda = -H^-1 H' c taken beside it, so dc = (dc
    at fixed lambda) + dc/dlambda dlambda, exact to first order."""
    block = row_block(modes.omega.shape[0], block)
    frozen = jax.lax.stop_gradient(modes)
    offset, null = _implicit(block, modes.omega, modes.gamma, modes.factor, modes.weights,
                             frozen)
    return eqx.tree_at(lambda m: (m.omega, m.gamma, m.factor, m.weights, m.offset, m.null),
                       frozen, (modes.omega, modes.gamma, modes.factor, modes.weights, offset,
                                null))


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _implicit(block, omega, gamma, factor, weights, frozen):
    """(offset, c) of the frozen roots, whose tangents follow the system's (``_implicit_jvp``)."""
    return frozen.offset, frozen.null


@_implicit.defjvp
@complex_arithmetic
def _implicit_jvp(block, primals, tangents):
    """d offset = -dphi / phi' at fixed offset (the anchor's pole moves with the system, the
    offset by the Newton step), dc = dc at fixed offset + dc/dlambda d offset; zero for a root in
    a cluster (1 / 0 there: its pair is summed by contour)."""
    omega, gamma, factor, weights, frozen = primals

    def secular(omega, gamma, factor, weights):
        return _secular(_poles(omega, gamma), gamma, factor, weights, frozen.active,
                        frozen.anchor, frozen.offset, block)

    (_, phi_prime, _, _, _, c_prime), (dphi, _, _, dc, _, _) = jax.jvp(
        secular, (omega, gamma, factor, weights), tangents[:4])
    active = frozen.simple
    d_offset = jnp.where(active, -dphi / jnp.where(active, phi_prime, 1.0), 0.0)
    d_null = dc + jnp.where(active[:, None], c_prime, 0.0) * d_offset[:, None]
    return (frozen.offset, frozen.null), (d_offset, d_null)
