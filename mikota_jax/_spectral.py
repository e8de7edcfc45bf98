"""Damped modes of a chain with a few dampers, and the integrated energy from them in O(n^2).

Not yet wired into ``exact_solve`` or ``integrated_energy``: a first slice of the spectral engine.

Conventions: eta are the M-orthonormal modal coordinates (x = U eta, U^T M U = I, U^T K U =
Omega^2, ``generalized_modes``); the dampers in them are D_m = F diag(d) F^T with F = U^T B the
(n, k) modal damper factor (``Dampers.project``: a grounded damper is e_j, a split one
(1 - w) e_j and w e_(j+1), a relative one e_i - e_j). The 2n roots are laid out as root j < n at
+i omega_j and root j >= n at -i omega_(j - n) for an undamped chain; each is stored in the
pole-offset form lambda = i s omega_J + delta (anchor J, sign s), so that lambda^2 + omega_l^2 =
(i (s omega_J - omega_l) + delta)(i (s omega_J + omega_l) + delta) never cancels near a pole.

Method (Veselic, Damped Oscillations of Linear Systems, Springer Lecture Notes in Mathematics
vol. 2023, 2011; Jakovcevic Stor,
Slapnicar, Tomljanovic, Mathematics 10(5):790, 2022, "FastOptimalDamping"): with R(lambda) =
(lambda^2 + Omega^2)^-1 the eigenvalues of lambda^2 + lambda D_m + Omega^2 are the zeros of the
secular determinant det(I_k + lambda F^T R F diag(d)) times the poles' polynomial. Modes that no
damper touches are deflated (exact +-i omega_l); the others' 2 n_a roots are found together by the
Aberth-Ehrlich iteration (Aberth, Math. Comp. 27:339, 1973) on the characteristic polynomial, whose
logarithmic derivative is evaluated with each root's own pole removed analytically (H below), and
polished by Newton on phi_J(lambda) = lambda^2 + omega_J^2 + lambda f_J^T diag(d) H^-1 f_J, with
H = I + lambda sum_(l != J) r_l f_l f_l^T diag(d). The eigenvector y = R F diag(d) c with c =
H^-1 f_J has y_J = -1 / lambda: no huge entries.

Not yet: O(n^2) undamped modes (the SVD of ``generalized_modes`` is O(n^3)), internal damping,
responses from modes (``exact_solve``), the total average energy, a structured fallback at
near-defective pairs (today: the Van Loan path), wiring into the public functions.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp

from ._custom_types import Array, Float, Vector
from ._dampers import Dampers
from ._errors import MARK, RESULTS, as_float, check, check_x64, raise_result
from ._modal import generalized_modes, modal_projection
from ._objectives import integrated_energy, integrated_energy_exact_with_result


def _complex_arithmetic(fn):
    """Run ``fn`` with JAX's standard dtype promotion: the roots are complex and mix freely with
    the real frequencies (the tests' strict promotion guards the rest of the package)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with jax.numpy_dtype_promotion("standard"):
            return fn(*args, **kwargs)

    return wrapper


_MAX_ITERATIONS = 400
_ABERTH_TOL = 1e-13  # max |step| / |lambda| at which the simultaneous iteration stops
_POLISH_STEPS = 3
_RESIDUAL_TOL = 1e-8  # |phi| relative to its largest term, after the polish
_TRACE_TOL = 1e-9  # |sum lambda + tr D_m| relative to sum |lambda|: no root found twice
DEFECTIVE_SEPARATION = 1e-6  # two damped roots closer than this (relative): near-defective


class DampedModes(eqx.Module):
    """The 2n eigenvalues of lambda^2 I + lambda F diag(d) F^T + Omega^2 in pole-offset form.

    ``omega``: (n,) undamped frequencies; ``factor`` F: (n, k) modal damper factor; ``weights``
    d: (k,); ``active``: (n,) which modes a damper touches (the others are exactly undamped);
    ``anchor`` J: (2n,) int, ``sign`` s: (2n,) +-1, ``offset`` delta: (2n,) complex, lambda = i s
    omega_J + delta; ``null`` c: (2n, k), the eigenvector's damper amplitudes (y = R F diag(d) c);
    ``converged``: whether every root passed the residual and trace checks; ``separation``: the
    smallest |lambda_j - lambda_k| / |lambda_j| between damped roots (near-defective below
    ``DEFECTIVE_SEPARATION``); ``iterations``: Aberth sweeps used. At an exceptional point
    (one DOF, d = 2 sqrt(k m): lambda = -sqrt(k/m) twice, one eigenvector) the two roots come
    back within ~sqrt(eps) of the double root with ``separation`` below the threshold.
    """

    omega: Float[Array, " n"]
    factor: Float[Array, "n k"]
    weights: Float[Array, " k"]
    active: Array
    anchor: Array
    sign: Float[Array, " 2n"]
    offset: Array
    null: Array
    converged: Array
    separation: Float[Array, ""]
    iterations: Array

    @property
    @_complex_arithmetic
    def eigenvalues(self) -> Array:
        """lambda: (2n,) complex, in the root layout of the module docstring."""
        return 1j * self.sign * self.omega[self.anchor] + self.offset

    @property
    def root_active(self) -> Array:
        """(2n,) bool: the roots of damped modes."""
        return jnp.concatenate([self.active, self.active])

    @_complex_arithmetic
    def vectors(self) -> Array:
        """Modal eigenvectors y: (n, 2n) complex, (lambda^2 + lambda D_m + Omega^2) y = 0.

        Damped roots are scaled so that y_J = -1 / lambda; undamped ones are unit vectors.
        """
        n = self.omega.shape[0]
        r, _ = _resolvent(self.omega, self.anchor, self.sign, self.offset, self.active)
        lam = self.eigenvalues
        y = r * ((self.factor * self.weights[None, :]) @ self.null.T).T  # (2n, n)
        y = jnp.where(jnp.arange(n)[None, :] == self.anchor[:, None], (-1 / lam)[:, None], y)
        unit = jnp.eye(n)[self.anchor]
        return jnp.where(self.root_active[:, None], y, unit).T

    @_complex_arithmetic
    def normalisers(self) -> Array:
        """N_j = y_j^T (2 lambda_j I + D_m) y_j: (2n,) complex, the bi-orthogonality scale of
        ``vectors`` (y_k^T ((lambda_j + lambda_k) I + D_m) y_j = 0 for j != k). Zero at a
        defective pair (critical damping)."""
        lam = self.eigenvalues
        y = self.vectors().T  # (2n, n)
        yfw = y @ self.factor
        return 2 * lam * jnp.sum(y * y, axis=1) + jnp.sum(yfw * self.weights[None, :] * yfw,
                                                          axis=1)

    @_complex_arithmetic
    def coefficients(self, q0: Float[Array, " n"], p0: Float[Array, " n"]) -> Array:
        """a: (2n,) complex, the modal state (eta(0), eta'(0)) = (q0, p0) expanded as eta(t) =
        sum_j a_j exp(lambda_j t) y_j (every root, deflated ones included).

        a_j = y_j^T ((lambda_j I + D_m) q0 + p0) / N_j, written as y_j^T (p0 - Omega^2 q0 /
        lambda_j) / N_j by the eigen-equation: the two terms of the first form cancel for a root
        running to -infinity (a strong damper), this form does not.
        """
        lam = self.eigenvalues
        y = self.vectors().T
        numerator = y @ p0 - (y @ (self.omega**2 * q0)) / lam
        return numerator / self.normalisers()

    @_complex_arithmetic
    def load_coefficients(self, g: Float[Array, " n"]) -> Array:
        """b: (2n,) complex, b_j = y_j^T g / N_j for a constant modal force g (= U^T f): the
        response of eta'' + D_m eta' + Omega^2 eta = g from rest is eta(t) = sum_j b_j
        (exp(lambda_j t) - 1) / lambda_j y_j (the static part Omega^-2 g = -sum_j b_j y_j /
        lambda_j)."""
        y = self.vectors().T
        return (y @ g) / self.normalisers()


def _gaps(omega, anchor, sign, offset):
    """lambda_j - i omega_l and lambda_j + i omega_l without cancellation: two (2n, n) arrays."""
    base = sign * omega[anchor]
    minus = 1j * (base[:, None] - omega[None, :]) + offset[:, None]
    plus = 1j * (base[:, None] + omega[None, :]) + offset[:, None]
    return minus, plus


def _resolvent(omega, anchor, sign, offset, active):
    """r_jl = 1 / (lambda_j^2 + omega_l^2) over damped l != J_j (0 elsewhere), and the mask."""
    minus, plus = _gaps(omega, anchor, sign, offset)
    n = omega.shape[0]
    mask = active[None, :] & (jnp.arange(n)[None, :] != anchor[:, None])
    product = minus * plus
    return jnp.where(mask, 1 / jnp.where(mask, product, 1.0), 0.0), mask


def _secular(omega, factor, weights, active, anchor, sign, offset):
    """Per root: (phi, phi', sum of the other poles' log-derivative + tr H^-1 H', c = H^-1 f_J)."""
    k = factor.shape[1]
    lam = 1j * sign * omega[anchor] + offset
    r, mask = _resolvent(omega, anchor, sign, offset, active)
    r_prime = r - 2 * lam[:, None] ** 2 * r**2  # d/dlambda (lambda r) = r - 2 lambda^2 r^2
    ff = factor[:, :, None] * factor[:, None, :] * weights[None, None, :]  # (n, k, k)
    h = jnp.eye(k)[None] + lam[:, None, None] * jnp.einsum("jl,lab->jab", r, ff)
    h_prime = jnp.einsum("jl,lab->jab", r_prime, ff)
    f = factor[anchor]  # (2n, k)
    solved = jnp.linalg.solve(h, jnp.stack([f.astype(h.dtype)] + [h_prime[:, :, i] for i in
                                                                  range(k)], axis=-1))
    c = solved[..., 0]  # H^-1 f_J
    h_inv_h_prime = solved[..., 1:]
    trace = jnp.trace(h_inv_h_prime, axis1=-2, axis2=-1)
    wf = f * weights[None, :]
    quad = jnp.sum(wf * c, axis=-1)  # f^T W H^-1 f
    quad_prime = -jnp.sum(wf * jnp.einsum("jab,jb->ja", h_inv_h_prime, c), axis=-1)
    pole = offset * (offset + 2j * sign * omega[anchor])  # lambda^2 + omega_J^2
    phi = pole + lam * quad
    phi_prime = 2 * lam + quad + lam * quad_prime
    scale = jnp.abs(pole) + jnp.abs(lam * quad)
    others = jnp.sum(jnp.where(mask, 2 * lam[:, None] * r, 0.0), axis=1) + trace
    return phi, phi_prime, others, c, scale


def _reanchor(omega, active, anchor, sign, offset):
    """Move each root's anchor to its nearest damped pole i s omega_J (same lambda)."""
    lam_imag = jnp.imag(offset) + sign * omega[anchor]
    new_sign = jnp.where(lam_imag >= 0, 1.0, -1.0)
    distance = jnp.abs(1j * (sign * omega[anchor])[:, None] + offset[:, None]
                       - 1j * new_sign[:, None] * omega[None, :])
    new_anchor = jnp.argmin(jnp.where(active[None, :], distance, jnp.inf), axis=1)
    new_offset = offset + 1j * (sign * omega[anchor] - new_sign * omega[new_anchor])
    return new_anchor, new_sign, new_offset


def _roots_difference(omega, anchor, sign, offset):
    """lambda_j - lambda_k: (2n, 2n), exact for roots on the same pole."""
    base = sign * omega[anchor]
    return 1j * (base[:, None] - base[None, :]) + (offset[:, None] - offset[None, :])


@eqx.filter_jit
@_complex_arithmetic
def modal_damped_modes(omega: Float[Array, " n"], factor: Float[Array, "n k"],
                       weights: Float[Array, " k"]) -> DampedModes:
    """All 2n eigenvalues of lambda^2 I + lambda F diag(d) F^T + Omega^2, O(k^2 n^2) per sweep.

    ``omega``: (n,) distinct positive frequencies; ``factor`` F: (n, k); ``weights`` d: (k,)
    >= 0. See the module docstring for the method and the returned layout. Not differentiable
    through the iteration: ``spectral_energy`` differentiates by one Newton step at the roots.
    """
    n = omega.shape[0]
    coupling = jnp.sqrt(jnp.sum(weights[None, :] * factor**2, axis=1))  # |row l of D_m^(1/2)|
    eps = jnp.finfo(omega.dtype).eps
    # pitfall 1 of the notes: a mode no damper touches has its root on the pole (0 / 0). Which
    # modes are touched is decided at a damper's coefficient, or at omega_max / |f_i|^2 if that
    # is larger (then: |f_li| > eps |f_i|): a weak (or zero) damper's first-order effect on a
    # mode, and its derivative (d -> 0), are kept instead of being deflated away
    columns = jnp.sum(factor**2, axis=0)
    scale = jnp.max(omega) / jnp.where(columns > 0, columns, 1.0)
    reach = jnp.sqrt(jnp.sum(jnp.maximum(weights, scale)[None, :] * factor**2, axis=1))
    total = jnp.sqrt(jnp.sum(reach**2))
    active = reach * total > eps * jnp.maximum(jnp.max(omega), total**2)
    modes = jnp.arange(n)
    anchor = jnp.concatenate([modes, modes])
    sign = jnp.concatenate([jnp.ones(n), -jnp.ones(n)])
    # start inside the left half plane, off the poles, asymmetric so pairs can split onto the
    # real axis; the first-order shift -|g_l|^2 / 2 of a weak damper, capped
    shift = jnp.minimum(jnp.concatenate([coupling, coupling]) ** 2 / 2, 0.5 * omega[anchor])
    start = -shift * (1 + 0.1j * sign) * jnp.where(sign > 0, 1.0, 1.03)
    offset = jnp.where(jnp.concatenate([active, active]), start, 0.0).astype(jnp.complex128)
    root_active = jnp.concatenate([active, active])
    pair_mask = root_active[None, :] & root_active[:, None] & ~jnp.eye(2 * n, dtype=bool)

    def sweep(carry):
        anchor, sign, offset, it, _ = carry
        phi, phi_prime, others, _, _ = _secular(omega, factor, weights, active, anchor, sign,
                                                offset)
        diff = _roots_difference(omega, anchor, sign, offset)
        repel = jnp.sum(jnp.where(pair_mask, 1 / jnp.where(pair_mask, diff, 1.0), 0.0), axis=1)
        denominator = phi * (others - repel) + phi_prime
        step = jnp.where(root_active & (denominator != 0),
                         phi / jnp.where(denominator != 0, denominator, 1.0), 0.0)
        offset = offset - step
        lam = 1j * sign * omega[anchor] + offset
        size = jnp.max(jnp.where(root_active, jnp.abs(step) / jnp.abs(lam), 0.0))
        anchor, sign, offset = _reanchor(omega, active, anchor, sign, offset)
        offset = jnp.where(root_active, offset, 0.0)
        return anchor, sign, offset, it + 1, size

    def not_done(carry):
        *_, it, size = carry
        return (it < _MAX_ITERATIONS) & ((size > _ABERTH_TOL) | ~jnp.isfinite(size))

    init = (anchor, sign, offset, jnp.array(0), jnp.array(jnp.inf))
    anchor, sign, offset, iterations, _ = jax.lax.while_loop(not_done, sweep, init)
    anchor = jnp.where(root_active, anchor, jnp.concatenate([modes, modes]))
    sign = jnp.where(root_active, sign, jnp.concatenate([jnp.ones(n), -jnp.ones(n)]))
    for _ in range(_POLISH_STEPS):
        phi, phi_prime, *_ = _secular(omega, factor, weights, active, anchor, sign, offset)
        offset = jnp.where(root_active & (phi_prime != 0),
                           offset - phi / jnp.where(phi_prime != 0, phi_prime, 1.0), offset)
    phi, _, _, c, scale = _secular(omega, factor, weights, active, anchor, sign, offset)
    lam = 1j * sign * omega[anchor] + offset
    residual_ok = jnp.all(jnp.where(root_active, jnp.abs(phi) <= _RESIDUAL_TOL * scale, True))
    trace = jnp.sum(jnp.where(active, coupling**2, 0.0))
    trace_ok = (jnp.abs(jnp.sum(jnp.where(root_active, lam, 0.0)) + trace)
                <= _TRACE_TOL * jnp.sum(jnp.where(root_active, jnp.abs(lam), 0.0)))
    diff = jnp.abs(_roots_difference(omega, anchor, sign, offset)) / jnp.abs(lam)[:, None]
    separation = jnp.min(jnp.where(pair_mask, diff, jnp.inf))
    converged = residual_ok & trace_ok & jnp.all(jnp.isfinite(lam)) & jnp.all(jnp.isfinite(c))
    return DampedModes(omega, factor, weights, active, anchor, sign, offset, c, converged,
                       separation, iterations)


def _modal_data(system):
    """(omega, U, F, d) of a ``SecondOrderSystem`` with dampers only."""
    if system.internal is not None:
        raise ValueError(MARK + "system: internal damping is not supported by the spectral "
                         "path yet (dampers only); use integrated_energy(method='exact').")
    if not isinstance(system.damping, Dampers):
        raise ValueError(MARK + "system: the spectral path needs discrete dampers "
                         "(GroundedDamper, RelativeDamper), got "
                         f"{type(system.damping).__name__}.")
    omega2, modes = generalized_modes(system)
    omega2 = check(omega2, omega2 <= 0, RESULTS[RESULTS.not_definite])
    low_rank = system.damping.project(modes)
    return jnp.sqrt(omega2), modes, low_rank.factor, low_rank.weights


def damped_modes(system) -> DampedModes:
    """The damped modes of a ``SecondOrderSystem`` with dampers (no internal damping).

    All 2n eigenvalues lambda of lambda^2 M + lambda D + K in the layout of ``DampedModes``
    (modal eigenvectors by ``.vectors()``, x = U y). Roots a damper does not touch are exactly
    +-i omega_l. Check ``converged`` and ``separation``: the iteration reports, and never
    hides, roots it did not find or pairs that nearly coincide (critical damping).
    """
    check_x64()
    omega, _, factor, weights = _modal_data(system)
    return modal_damped_modes(omega, factor, weights)


@_complex_arithmetic
def _energy_from_modes(modes: DampedModes, q0, p0, horizon):
    """J from the damped modes and the modal initial state (eta0, eta0'), O(n^2 k)."""
    omega, factor, weights = modes.omega, modes.factor, modes.weights
    lam = modes.eigenvalues
    c = modes.null
    y = modes.vectors().T  # (2n, n)
    active = modes.root_active
    a = jnp.where(active, modes.coefficients(q0, p0), 0.0)
    # lambda_j + lambda_k in pole-offset form: for a conjugate pair the +-i omega_J cancel
    # exactly
    base = modes.sign * omega[modes.anchor]
    s = 1j * (base[:, None] + base[None, :]) + (modes.offset[:, None] + modes.offset[None, :])
    pair = active[:, None] & active[None, :]
    s_safe = jnp.where(pair, s, -1.0)
    # (e^{sT} - 1) / s, for tiny |s T| too
    small = jnp.abs(s_safe * horizon) < 1e-3
    s_large = jnp.where(small, 1.0, s_safe)  # no 0 / 0 in the branch not taken (its gradient)
    growth = jnp.where(small,
                       horizon * (1 + s_safe * horizon / 2 + (s_safe * horizon) ** 2 / 6
                                  + (s_safe * horizon) ** 3 / 24),
                       jnp.expm1(s_large * horizon) / s_large)
    # G_jk = y_j^T Omega^2 y_k + lambda_j lambda_k y_j^T y_k = -2 c_j^T W c_k / (lambda_j +
    # lambda_k) (from the eigen-equations of j and k): no cancellation, except for a conjugate
    # pair (or a real root with itself) of a mode the dampers barely touch, where s = 2 Re lambda
    # is below the rounding of lambda; there the direct sum of positive terms
    # (omega_l^2 + |lambda|^2) |y_l|^2 is exact, O(n) per root
    gram = -2 * ((c * weights[None, :]) @ c.T) / jnp.where(s_safe == 0, 1.0, s_safe)
    conj_gap = jnp.abs(1j * (base[None, :] + base[:, None])
                       + modes.offset[None, :] - jnp.conj(modes.offset)[:, None])
    partner = jnp.argmin(jnp.where(pair, conj_gap, jnp.inf), axis=1)
    y_partner = y[partner]
    direct = jnp.sum((omega[None, :] ** 2 + (lam * lam[partner])[:, None]) * y * y_partner,
                     axis=1)
    rows = jnp.arange(lam.shape[0])
    gram = gram.at[rows, partner].set(jnp.where(active, direct, gram[rows, partner]))
    damped = jnp.sum(jnp.where(pair, a[:, None] * a[None, :] * gram * growth, 0.0)) / 2
    undamped = jnp.where(modes.active, 0.0, (omega * q0) ** 2 + p0**2)
    return jnp.real(damped) + horizon * jnp.sum(undamped) / 2


@_complex_arithmetic
def _differentiable_roots(modes: DampedModes) -> DampedModes:
    """The same roots with the derivative of one Newton step on phi_J at them (implicit
    differentiation: dlambda = -dphi / phi'); the iteration itself carries no derivative."""
    frozen = jax.lax.stop_gradient(modes)
    phi, phi_prime, *_ = _secular(modes.omega, modes.factor, modes.weights, frozen.active,
                                  frozen.anchor, frozen.sign, frozen.offset)
    active = frozen.root_active
    step = jnp.where(active, phi / jnp.where(active, phi_prime, 1.0), 0.0)
    offset = frozen.offset - (step - jax.lax.stop_gradient(step))
    _, _, _, c, _ = _secular(modes.omega, modes.factor, modes.weights, frozen.active,
                             frozen.anchor, frozen.sign, offset)
    return eqx.tree_at(lambda m: (m.omega, m.factor, m.weights, m.offset, m.null), frozen,
                       (modes.omega, modes.factor, modes.weights, offset, c))


@eqx.filter_jit
def spectral_energy_with_result(system, horizon, x0, v0):
    """(J, ok, ``DampedModes``): the spectral energy and whether it holds (ok: every root
    converged and no two damped roots nearly coincide); where not ok, J must not be used."""
    omega, modes_u, factor, weights = _modal_data(system)
    frozen = modal_damped_modes(*jax.lax.stop_gradient((omega, factor, weights)))
    modes = _differentiable_roots(eqx.tree_at(lambda m: (m.omega, m.factor, m.weights), frozen,
                                              (omega, factor, weights)))
    project = modal_projection(system, modes_u)
    q0, p0 = project(x0), project(v0)
    ok = frozen.converged & (frozen.separation > DEFECTIVE_SEPARATION)
    value = _energy_from_modes(modes, q0, p0, horizon)
    return value, ok & jnp.isfinite(value), frozen


@eqx.filter_jit
def _energy_or_fallback(system, horizon, x0, v0):
    """Under a caller's ``jit``: the spectral value, or the Van Loan path where it does not hold."""
    value, ok, _ = spectral_energy_with_result(system, horizon, x0, v0)
    return jax.lax.cond(
        ok, lambda: (value, RESULTS.successful),
        lambda: integrated_energy_exact_with_result(system, horizon, x0, v0))


def spectral_energy(system, horizon: float, x0: Vector | None = None,
                    v0: Vector | None = None) -> Float[Array, ""]:
    """The integrated energy J = int_0^T (x^T K x + x'^T M x') / 2 dt of free vibration, from the
    damped modes in closed form.

    J = 1/2 sum_jk a_j a_k G_jk (e^{s_jk T} - 1) / s_jk, s_jk = lambda_j + lambda_k, over the
    damped roots (a_j the coefficients of (x0, v0) by the bi-orthogonality y_k^T (lambda_j +
    lambda_k + D_m) y_j = 0), with the modal Gram matrix G_jk = y_j^T Omega^2 y_k + lambda_j
    lambda_k y_j^T y_k = -2 c_j^T diag(d) c_k / s_jk (Cauchy-like; a conjugate pair summed
    directly), plus T (omega_l^2 eta0_l^2 + eta0'_l^2) / 2 for each mode no damper touches:
    O(k n^2) after the modes, no matrix exponential. ``system``: a ``SecondOrderSystem`` with
    dampers and no internal damping; ``horizon`` T > 0; ``x0``, ``v0``: (n,) (default zero). A
    scalar in energy x time. Where the roots did not converge or two damped roots nearly
    coincide (relative separation below 1e-6: critical damping of a mode), it falls back to
    ``integrated_energy(method="exact")`` (Van Loan, O(n^3)); ``spectral_energy_with_result``
    says which. Differentiable (``jax.grad``) in the dampers' coefficients and positions and the
    initial state, by implicit differentiation of the secular equation at the roots.
    """
    check_x64()
    n = system.size
    horizon = as_float(horizon, "horizon")
    horizon = check(horizon, ~(jnp.isfinite(horizon) & (horizon > 0)), "horizon must be > 0.")
    x0 = jnp.zeros(n) if x0 is None else as_float(x0, "x0")
    v0 = jnp.zeros(n) if v0 is None else as_float(v0, "v0")
    if x0.shape != (n,) or v0.shape != (n,):
        raise ValueError(MARK + f"x0 and v0 must have shape ({n},), got {x0.shape} and "
                         f"{v0.shape}.")
    value, ok, _ = spectral_energy_with_result(system, horizon, x0, v0)
    try:
        holds = bool(ok)  # concrete eagerly and under jax.grad: no Van Loan compiled
    except jax.errors.ConcretizationTypeError:
        value, result = _energy_or_fallback(system, horizon, x0, v0)
        return raise_result(value, result)
    if holds:
        return value
    return integrated_energy(system, horizon, x0, v0)
