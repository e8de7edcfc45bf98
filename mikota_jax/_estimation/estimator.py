"""A posteriori error bounds for a Galerkin reduced model: no full solve, O(n r^2 + r^3).

For free vibration M x'' + D x' + K x = 0 (eq. 3.1, D >= 0) and the reduced model on an
orthonormal basis Phi (eq. 3.4), x ~ Phi q, x' ~ Phi p, the error e = (x - Phi q, x' - Phi p)
of the state z = (x, x') obeys e' = A e + rho with rho = (0, -M^-1 R) and the force residual

    R(t) = M Phi p' + D Phi p + K Phi q      (Phi^T R = 0: Galerkin).

In the energy norm |z|_E^2 = x^T K x + x'^T M x' the free flow is a contraction (d|z|_E^2/dt =
-2 x'^T D x' <= 0), and |rho|_E = |R|_{M^-1}, so (Duhamel)

    |e(t)|_E <= eps(t) := |e(0)|_E + int_0^t |R|_{M^-1} ds,

with eps_0 = |e(0)|_E the initial state's part outside span Phi. R = Z (q, p) with Z = (I - M
Phi M_r^-1 Phi^T) [K Phi, D Phi] (O(n r^2) to form; its triangular factor keeps the norm free
of the cancellation a Gram matrix would have). [0, T] is cut into L intervals I_l of length h;
on each, int_{I_l} |R|^2 and int_{I_l} |z_r|_E^2 are quadratic forms of the reduced state at
the interval's start with finite-horizon Gramians over h (Van Loan's block exponential, O(r^3)
once, as the energies of ``integrated_energy``), so with Cauchy-Schwarz per interval
int_{I_l} |R| <= sqrt(h int_{I_l} |R|^2) and eps <= E_l on I_l (eps is nondecreasing). For the
energy objective J = int_0^T |z|_E^2 / 2 dt, |J - J_r| = |int (|z| - |z_r|)(|z| + |z_r|)| / 2
<= int eps |z_r| + int eps^2 / 2, so

    |J - J_r| <= sum_l E_l sqrt(h int_{I_l} |z_r|^2) + h sum_l E_l^2 / 2.

Both bounds are rigorous up to rounding (no sampling in time); the energy bound adds
``ROUNDING`` J_r, the level at which two exact computations of J already differ. This is the
residual bound of reduced-basis methods for linear evolution problems (Haasdonk & Ohlberger,
"Reduced basis method for finite volume approximations of parametrized linear evolution
equations", M2AN 42 (2008) 277-302; Grepl & Patera, M2AN 39 (2005) 157-181), in the energy
norm in which the damped mechanical flow is dissipative. It bounds the error of the whole
state history, so it is first order in the residual, while a Galerkin model's error in J is
often second order: the bound on J is pessimistic by far more than the state's (measured on a
40-DOF chain: state effectivity 2 to 35, energy effectivity 5 to 2e6 as the basis improves).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from .._custom_types import Array, Basis, Float, Vector
from .._errors import MARK, as_float, positive_scalar
from .._model.dampers import Dampers
from .._model.modal import generalized_modes, scaled_modal, state_matrix
from .._model.operators import Diagonal
from .._model.reduced import check_basis
from .._model.system import SecondOrderSystem
from .._objective.functions import finite_gramian
from .._rom.classic import damper_directions, extend_basis, modal_basis, static_moments
from .._solver.spectral.energy import energy_from_modes
from .._solver.spectral.roots import differentiable_roots, modal_damped_modes

# [0, T] is cut into this many intervals: Cauchy-Schwarz is applied on each, not on [0, T]
INTERVALS = 64
# relative rounding level of J_r and of the full model's J (Van Loan's doubling, the spectral
# sums: measured 1e-10 .. 4e-10 apart): the energy bound never claims less than this
ROUNDING = 1e-9


class ErrorBound(eqx.Module):
    """What ``error_bound`` returns (all scalars, float64).

    ``value``: J_r, the reduced model's energy int_0^T |z_r|_E^2 / 2 dt (exact);
    ``energy``: a bound on |J - J_r| (J the full model's); ``state``: a bound on
    max_t |z(t) - z_r(t)|_E, the energy norm of the state error over [0, T]; ``initial``:
    eps_0 = |z(0) - z_r(0)|_E; ``residual``: sqrt(G), the L2(0, T) norm of the residual;
    ``history``: (L,) the state bound on each of the L intervals of [0, T] (nondecreasing).
    """

    value: Float[Array, ""]
    energy: Float[Array, ""]
    state: Float[Array, ""]
    initial: Float[Array, ""]
    residual: Float[Array, ""]
    history: Float[Array, " L"]

    @property
    def relative(self) -> Float[Array, ""]:
        """A bound on |J - J_r| / J: energy / (J_r - energy), inf where that is not positive."""
        floor = self.value - self.energy
        return jnp.where(floor > 0, self.energy / jnp.where(floor > 0, floor, 1.0), jnp.inf)


def _columns(operator, basis):
    return jax.vmap(operator.mv, in_axes=1, out_axes=1)(basis)


def _residual_factor(system: SecondOrderSystem, basis):
    """C with |R(t)|_{M^-1} = |C (q, p)|: the triangular factor of M^-1/2 Z (module docstring)."""
    r = basis.shape[1]
    mass_basis = _columns(system.mass, basis)
    damping = system.damping_operator()
    forces = jnp.concatenate([_columns(system.stiffness, basis),
                              jnp.zeros_like(basis) if damping is None
                              else _columns(damping, basis)], axis=1)
    reduced_mass = basis.T @ mass_basis
    z = forces - mass_basis @ jnp.linalg.solve(reduced_mass, basis.T @ forces)
    if isinstance(system.mass, Diagonal):
        scaled = z / jnp.sqrt(system.mass.diagonal)[:, None]
    else:
        scaled = jsl.solve_triangular(jnp.linalg.cholesky(system.mass.as_matrix()), z, lower=True)
    factor = jnp.linalg.qr(scaled, mode="r")
    return factor.reshape(-1, 2 * r)


def _reduced_flow(system, basis, x0, v0):
    """(A, w0, Omega, U, not definite): the Galerkin model on the orthonormal ``basis`` as the
    first-order flow w' = A w in its scaled modal coordinates w = (Omega eta, eta'), q = U eta,
    from the orthogonal projection of (x0, v0), as ``reduce`` projects it."""
    rom = system.project(basis)
    mass_r = rom.mass.as_matrix()
    omega, modes, damping_modal, not_definite = scaled_modal(rom)
    w0 = jnp.concatenate([omega * (modes.T @ (mass_r @ (basis.T @ x0))),
                          modes.T @ (mass_r @ (basis.T @ v0))])
    return state_matrix(omega, damping_modal), w0, omega, modes, not_definite


def _flow_energy(a, w0, horizon):
    """J = 1/2 int_0^T |w|^2 of w' = A w, w(0) = w0: one finite-horizon Gramian."""
    whole, _ = finite_gramian(a, jnp.eye(a.shape[0]), horizon)
    return w0 @ ((whole + whole.T) / 2) @ w0 / 2


@eqx.filter_jit
def _bound(system, basis, horizon, x0, v0, intervals: int = INTERVALS):
    ex, ev = x0 - basis @ (basis.T @ x0), v0 - basis @ (basis.T @ v0)
    initial = jnp.sqrt(jnp.maximum(ex @ system.stiffness.mv(ex) + ev @ system.mass.mv(ev), 0.0))
    a, w0, omega, modes, not_definite = _reduced_flow(system, basis, x0, v0)
    # (q, p) = T w with T = diag(U Omega^-1, U): the residual as a form in w
    r = basis.shape[1]
    lift = jnp.block([[modes / omega[None, :], jnp.zeros((r, r))], [jnp.zeros((r, r)), modes]])
    c = _residual_factor(system, basis) @ lift
    h = horizon / intervals
    energy_gramian, step = finite_gramian(a, jnp.eye(2 * r), h)
    residual_gramian, _ = finite_gramian(a, c.T @ c, h)
    energy_gramian = (energy_gramian + energy_gramian.T) / 2
    residual_gramian = (residual_gramian + residual_gramian.T) / 2

    def interval(w, _):  # int over one interval of |z_r|^2 and of |R|^2: exact quadratic forms
        return step @ w, (w @ energy_gramian @ w, jnp.maximum(w @ residual_gramian @ w, 0.0))

    _, (energies, residuals) = jax.lax.scan(interval, w0, None, length=intervals)
    # J_r itself over [0, T] in one Gramian, as ``integrated_energy`` computes it (the sum over
    # the intervals is ~4e-10 relative off: enough for the bound, not for J_r)
    value = _flow_energy(a, w0, horizon)
    # eps(t) <= eps_0 + int_0^t |R| <= E_l on interval l (Cauchy-Schwarz per interval)
    states = initial + jnp.cumsum(jnp.sqrt(h * residuals))
    energy = jnp.sum(states * jnp.sqrt(h * jnp.maximum(energies, 0.0))) + h * jnp.sum(
        states**2) / 2 + ROUNDING * jnp.abs(value)
    bad = not_definite | ~jnp.isfinite(energy)
    return ErrorBound(value, jnp.where(bad, jnp.inf, energy),
                      jnp.where(bad, jnp.inf, states[-1]), initial,
                      jnp.sqrt(jnp.sum(residuals)), jnp.where(bad, jnp.inf, states))


def error_bound(system: SecondOrderSystem, basis: Basis, horizon: float,
                x0: Vector | None = None, v0: Vector | None = None) -> ErrorBound:
    """Rigorous bounds on the error of the Galerkin model of ``system`` on ``basis`` for free
    vibration from (``x0``, ``v0``) over [0, ``horizon``], without solving the full model (see
    the module docstring): an ``ErrorBound`` with the reduced energy J_r, a bound on |J - J_r|
    and one on the state's energy-norm error.

    ``basis``: (n, r) orthonormal (checked as ``reduce`` checks it); ``x0``, ``v0``: (n,)
    full coordinates (default zero). Cost O(n r^2) for the residual and O(r^3) for two
    finite-horizon Gramians of size 2r: no full solve. Jit-, vmap- and grad-compatible in the
    system's values (a design sweep: ``mj.sweep`` over a function that builds the system). A
    bound that would not be finite (a stiffness not positive definite) is inf.
    """
    if not isinstance(system, SecondOrderSystem):
        raise ValueError(MARK + f"system must be a SecondOrderSystem, got {type(system).__name__}.")
    basis = check_basis(basis, system.size)
    horizon = positive_scalar(horizon, "horizon")
    n = system.size
    x0 = jnp.zeros(n) if x0 is None else as_float(x0, "x0")
    v0 = jnp.zeros(n) if v0 is None else as_float(v0, "v0")
    for name, x in (("x0", x0), ("v0", v0)):
        if x.shape != (n,):
            raise ValueError(MARK + f"{name} must have shape ({n},), got {x.shape}.")
    return _bound(system, basis, horizon, x0, v0)


# --------------------------------------------------------------------------- hierarchical


def _reduced_energy(system, basis, horizon, x0, v0):
    """(J_r, not definite) of the Galerkin model on the orthonormal ``basis``: ``_bound``'s J_r
    (the initial state projected orthogonally, as ``reduce`` does)."""
    a, w0, _, _, not_definite = _reduced_flow(system, basis, x0, v0)
    return _flow_energy(a, w0, horizon), not_definite


def _spectral_reduced_energy(system, basis, horizon, x0, v0):
    """(J_r, ok, not definite) of the Galerkin model on ``basis`` by the spectral path on its
    own modes: (K_r, M_r) -> (Omega_r, U_r) by one symmetric eigenproblem (O(r^3)), the
    projected dampers F = U_r^T Phi^T B stay low rank, so the damped roots and J are O(k r^2)
    (``modal_damped_modes``, ``energy_from_modes``; Veselic's low-rank structure, as the full
    model's spectral path). The roots are found without derivatives, then carry the implicit
    derivative of the secular equation (``differentiable_roots``, as ``live_modes``), so J_r is
    differentiable in the dampers with ``basis`` held fixed; where ``ok`` is False (no
    convergence, nearly coincident roots) the value must not be used."""
    rom = system.project(basis)
    omega2, modes = generalized_modes(rom)
    not_definite = jnp.any(omega2 <= 0)
    omega = jnp.sqrt(jnp.where(omega2 > 0, omega2, 1.0))
    factor, weights = modes.T @ rom.damping.factor, rom.damping.weights
    frozen = modal_damped_modes(*jax.lax.stop_gradient((omega, factor, weights)))
    roots = differentiable_roots(eqx.tree_at(lambda m: (m.omega, m.factor, m.weights), frozen,
                                             (omega, factor, weights)))
    mass_r = rom.mass.as_matrix()
    value = energy_from_modes(roots, modes.T @ (mass_r @ (basis.T @ x0)),
                              modes.T @ (mass_r @ (basis.T @ v0)), horizon)
    ok = frozen.converged & frozen.clusters.ok & jnp.isfinite(value)
    return value, ok & ~not_definite, not_definite


def _checked_horizon(horizon):
    return eqx.error_if(horizon, ~(jnp.isfinite(horizon) & (horizon > 0)),
                        MARK + "horizon must be finite and > 0.")


def _estimator_energy(system, basis, horizon, x0, v0):
    """(J_r, bad), the method chosen from the structure: the spectral value for a system with
    only discrete dampers (bad where it is not definite or its damped modes were not found:
    the estimate is then inf, nothing else is run), else ``_reduced_energy``'s Van Loan value."""
    if not isinstance(system.damping, Dampers) or system.internal is not None:
        return _reduced_energy(system, basis, horizon, x0, v0)
    value, ok, not_definite = _spectral_reduced_energy(system, basis, horizon, x0, v0)
    return value, not_definite | ~ok


class HierarchicalEstimate(eqx.Module):
    """What ``HierarchicalEstimator`` returns (scalars, float64): ``value`` J_r (the reduced
    model's energy), ``fine`` J_f (the enriched model's), ``energy`` the estimate of |J - J_r|
    (``safety`` |J_f - J_r| + ``ROUNDING`` |J_r|; inf where either model is not definite or
    its damped modes were not found)."""

    value: Float[Array, ""]
    fine: Float[Array, ""]
    energy: Float[Array, ""]

    @property
    def relative(self) -> Float[Array, ""]:
        """The estimate of |J - J_r| / J: energy / (J_r - energy), inf where not positive (as
        ``ErrorBound.relative``)."""
        floor = self.value - self.energy
        return jnp.where(floor > 0, self.energy / jnp.where(floor > 0, floor, 1.0), jnp.inf)


class HierarchicalGradient(eqx.Module):
    """What ``HierarchicalEstimator.gradient`` returns: ``HierarchicalEstimate``'s ``value``,
    ``fine`` and ``energy``, and per grounded damper (dicts with keys "positions" and
    "coefficients", (g,) each, as ``SceneFunction``'s parameters) ``gradient`` dJ_r, the
    reduced model's derivative with its basis held fixed, ``fine_gradient`` dJ_f, and ``error``
    the estimate of |dJ - dJ_r|: ``safety`` |dJ_f - dJ_r| + ``ROUNDING`` (|dJ_r| + |J_r| / h),
    h the parameter's scale (c for a coefficient, n - 1 for a position: the floor of c dJ/dc /
    J and of (n - 1) dJ/dp / J is ``ROUNDING``, also at an optimum where dJ_r ~ 0; inf where
    either model is not definite or a derivative is not finite); ``design`` the positions and
    coefficients they are taken at. A position's derivative is the one within its interval
    between DOFs (from the right at a DOF)."""

    value: Float[Array, ""]
    fine: Float[Array, ""]
    energy: Float[Array, ""]
    gradient: dict
    fine_gradient: dict
    error: dict
    design: dict

    @property
    def relative(self) -> Float[Array, ""]:
        """The estimate of |J - J_r| / J (as ``HierarchicalEstimate.relative``)."""
        return HierarchicalEstimate(self.value, self.fine, self.energy).relative

    @property
    def log_sensitivity_error(self) -> Float[Array, ""]:
        """The estimate of the largest error of the logarithmic coefficient sensitivities,
        max_i c_i |dJ/dc_i - dJ_r/dc_i| / J (what ``ScreenAndCertify`` certifies; J >= J_r -
        energy), inf where that floor is not positive; 0 without grounded dampers."""
        floor = self.value - self.energy
        coefficients = self.error["coefficients"] * jnp.abs(self.design["coefficients"])
        worst = jnp.max(coefficients, initial=0.0)
        return jnp.where(floor > 0, worst / jnp.where(floor > 0, floor, 1.0), jnp.inf)


class HierarchicalEstimator(eqx.Module):
    """A hierarchical a posteriori estimate of a reduced model's error in J: J_r against the J
    of a richer Galerkin model whose space holds the basis (Hain, Ohlberger, Radic & Urban, "A
    hierarchical a posteriori error estimator for the reduced basis method", Adv. Comput. Math.
    45 (2019) 2191-2214).

    The fine space is span(basis, the ``modes`` lowest undamped modes, static moments of the
    design's damper directions: K^-1 B, (K^-1 M) K^-1 B, ... , ``moments`` of them). The modes
    do not depend on the dampers, so the union of the basis and the modes is built once (here);
    per design only the damper moments are added (O(n) for a chain) and the fine model solved:
    O(n r_f^2 + r_f^3), r_f = r + modes + moments x columns less what the basis already holds;
    no full solve. If the fine model is closer to J than the reduced one by a factor theta
    (saturation: |J - J_f| <= theta |J - J_r|), then |J - J_r| <= |J_f - J_r| / (1 - theta): the
    estimate ``safety`` |J_f - J_r| never under-estimates for theta <= 1 - 1 / safety (1/2 at
    the default 2) and over-estimates by at most safety (1 + theta) (3). Saturation is an
    assumption, checked, not proven: on 1000 random designs of the Section 5 box
    (``docs/notes/hierarchical.md``) it never under-estimated, with effectivities 1.34-3.06
    (the paper's POD, errors up to 121 %: 2.0-2.01); the fine models were within 1.2e-7 of J.
    (With 4 of the fixed basis' directions dropped as "below 1e-10" the fine model was 6.2e-7
    off and 5 designs were under-estimated: saturation is what fails first.) Unlike
    ``error_bound`` it is not rigorous, but second order like the error itself: its
    effectivity is ~``safety`` where the residual bound's was 1e4-1e6. Both J's are computed
    by the spectral path on the reduced models' own modes (``_spectral_reduced_energy``: one
    r x r symmetric eigenproblem, then O(k r^2) damped roots, Veselic's low-rank structure),
    with the Van Loan value where that path does not hold: 0.049 s per design at n = 300
    against 0.096 s for the full model's spectral J.

    ``system``: any design of the family (its M and K, which the dampers do not change);
    ``basis``: (n, r) orthonormal; ``modes``: how many undamped modes (default min(n, 2 r)),
    ``moments``: static moments per damper direction (default 3), ``safety``: >= 1 (default 2);
    ``basis_moments``: the reduced model's basis is ``basis`` united with that many static
    moments of the design's dampers (``reduced_basis``; default 0: ``basis`` alone). No fixed
    basis of <= 200 columns holds J to 1e-4 over the Section 5 box (a strong damper pins its
    DOF, anywhere: the POD with 200 modes has an estimated error of 8.5 %), while the POD
    united with 40 modes (r = 113) and the damper's two moments (4 columns) is certified to
    1e-4 on 755 training designs, 1.6e-5 off at worst at 1000 random ones.
    Call it with a design's system (same M and K), the horizon and the initial state:
    jit- and vmap-compatible in the system's values (``mj.sweep``). Not to be differentiated
    directly (the fine space's QR at dependent columns); ``gradient`` gives dJ_r and dJ_f with
    respect to the dampers, the bases held fixed, and the estimate of dJ_r's error.
    """

    basis: jax.Array
    fixed: jax.Array
    moments: int = eqx.field(static=True)
    basis_moments: int = eqx.field(static=True)
    safety: float = eqx.field(static=True)

    def __init__(self, system: SecondOrderSystem, basis: Basis, modes: int | None = None,
                 moments: int = 3, safety: float = 2.0, *, basis_moments: int = 0):
        if not isinstance(system, SecondOrderSystem):
            raise ValueError(MARK + f"system must be a SecondOrderSystem, got "
                             f"{type(system).__name__}.")
        basis = check_basis(basis, system.size)
        n, r = basis.shape
        modes = min(n, 2 * r) if modes is None else modes
        if isinstance(modes, bool) or not isinstance(modes, int) or not 1 <= modes <= n:
            raise ValueError(MARK + f"modes must be an integer in 1..{n}, got {modes!r}.")
        if isinstance(moments, bool) or not isinstance(moments, int) or moments < 0:
            raise ValueError(MARK + f"moments must be an integer >= 0, got {moments!r}.")
        if not (isinstance(safety, float | int) and np.isfinite(safety) and safety >= 1):
            raise ValueError(MARK + f"safety must be a number >= 1, got {safety!r}.")
        if (isinstance(basis_moments, bool) or not isinstance(basis_moments, int)
                or not 0 <= basis_moments <= moments):
            raise ValueError(MARK + f"basis_moments must be an integer in 0..moments = "
                             f"{moments} (the fine space holds the reduced one), got "
                             f"{basis_moments!r}.")
        self.basis = basis
        self.fixed = extend_basis(basis, modal_basis(system, modes))
        self.moments = moments
        self.basis_moments = basis_moments
        self.safety = float(safety)

    def _with_moments(self, system, columns, count):
        forces = damper_directions(system)
        if count == 0 or forces.shape[1] == 0:
            return columns
        extra = static_moments(system, forces, count)
        q, _ = jnp.linalg.qr(jnp.concatenate([columns, extra], axis=1)[:, : system.size])
        return q

    def reduced_basis(self, system: SecondOrderSystem) -> jax.Array:
        """The reduced model's (n, r') orthonormal basis at ``system``'s design: ``basis``, with
        ``basis_moments`` > 0 united with that many static moments of the design's damper
        directions (a basis rebuilt per design in O(n) for a chain; fixed shape)."""
        return self._with_moments(system, self.basis, self.basis_moments)

    def fine_basis(self, system: SecondOrderSystem) -> jax.Array:
        """The (n, r_f) orthonormal fine basis at ``system``'s design (fixed shape: a moment
        already in the span adds an arbitrary orthonormal direction, harmless to a Galerkin
        model; r_f <= n)."""
        return self._with_moments(system, self.fixed, self.moments)

    def _arguments(self, system, horizon, x0, v0):
        n = system.size
        if system.size != self.basis.shape[0]:
            raise ValueError(MARK + f"system has {system.size} DOFs, the estimator's basis "
                             f"{self.basis.shape[0]} rows.")
        x0 = jnp.zeros(n) if x0 is None else jnp.asarray(x0, dtype=jnp.float64)
        v0 = jnp.zeros(n) if v0 is None else jnp.asarray(v0, dtype=jnp.float64)
        for name, x in (("x0", x0), ("v0", v0)):
            if x.shape != (n,):
                raise ValueError(MARK + f"{name} must have shape ({n},), got {x.shape}.")
        # an array, so that a new horizon is a new value, not a new compilation
        return system, jnp.asarray(horizon, dtype=jnp.float64), x0, v0

    def __call__(self, system: SecondOrderSystem, horizon, x0=None, v0=None
                 ) -> HierarchicalEstimate:
        return self._estimate(*self._arguments(system, horizon, x0, v0))

    def gradient(self, system: SecondOrderSystem, horizon, x0=None, v0=None
                 ) -> HierarchicalGradient:
        """The estimate of J's error (as calling the estimator) and of its derivatives'
        error, with respect to the grounded dampers' positions and coefficients: a
        ``HierarchicalGradient``.

        The same hierarchy applied to the derivatives: |dJ - dJ_r| ~ ``safety`` |dJ_f - dJ_r|,
        both derivatives with their bases held fixed (exact for a damper: its directions
        e_j, e_j+1, and so the design's moments, do not change with its coefficient, nor with
        its position between two DOFs). Saturation of the derivatives (dJ_f closer to dJ than
        dJ_r) is a separate assumption from J's: ``docs/notes/hierarchical_gradient.md``
        checks it on the Section 5 box. Forward mode (2 g tangents) through both reduced
        models' spectral J (implicit differentiation of their secular equations,
        ``differentiable_roots``), still no full solve. Jit- and vmap-compatible.
        """
        if not isinstance(system.damping, Dampers):
            raise ValueError(MARK + "system must have dampers (GroundedDamper) for the "
                             "gradient's estimate; it has "
                             + ("none." if system.damping is None else
                                f"{type(system.damping).__name__}."))
        return self._gradient(*self._arguments(system, horizon, x0, v0))

    @eqx.filter_jit
    def _gradient(self, system, horizon, x0, v0) -> HierarchicalGradient:
        horizon = _checked_horizon(horizon)
        design = {"positions": system.damping.positions,
                  "coefficients": system.damping.coefficients}

        def with_gradient(basis):
            basis = jax.lax.stop_gradient(basis)

            def energy(values):
                at = eqx.tree_at(lambda s: (s.damping.positions, s.damping.coefficients),
                                 system, (values["positions"], values["coefficients"]))
                value, bad = _estimator_energy(at, basis, horizon, x0, v0)
                return value, (value, bad)

            # forward mode, 2 g tangents: 2.4x / 3.5x faster than reverse at n = 1000 / 3000
            # (one damper, r_f = 335 / 577; measured), the same derivatives to 2e-15
            gradient, (value, bad) = jax.jacfwd(energy, has_aux=True)(design)
            return (value, bad), gradient

        (value, bad), gradient = with_gradient(self.reduced_basis(system))
        (fine, bad_fine), fine_gradient = with_gradient(self.fine_basis(system))
        energy = self.safety * jnp.abs(fine - value) + ROUNDING * jnp.abs(value)
        # rounding: relative to dJ_r and to J_r over the parameter's scale (c; n - 1 DOFs for
        # a position), so that at an optimum (dJ_r/dc ~ 0) the floor is ROUNDING in c dJ/dc / J
        c = jnp.abs(design["coefficients"])
        scale = {"positions": jnp.full_like(c, max(system.size - 1, 1)),
                 "coefficients": jnp.where(c > 0, c, 1.0)}
        error = jax.tree.map(lambda f, r, h: self.safety * jnp.abs(f - r)
                             + ROUNDING * (jnp.abs(r) + jnp.abs(value) / h),
                             fine_gradient, gradient, scale)
        finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(e)) for e in jax.tree.leaves(error)]))
        bad = bad | bad_fine | ~jnp.isfinite(energy)
        error = jax.tree.map(lambda e: jnp.where(bad | ~finite, jnp.inf, e), error)
        return HierarchicalGradient(value, fine, jnp.where(bad, jnp.inf, energy), gradient,
                                    fine_gradient, error, design)

    @eqx.filter_jit
    def _estimate(self, system, horizon, x0, v0) -> HierarchicalEstimate:
        horizon = _checked_horizon(horizon)
        value, bad = _estimator_energy(system, self.reduced_basis(system), horizon, x0, v0)
        fine, bad_fine = _estimator_energy(system, self.fine_basis(system), horizon, x0, v0)
        energy = self.safety * jnp.abs(fine - value) + ROUNDING * jnp.abs(value)
        bad = bad | bad_fine | ~jnp.isfinite(energy)
        return HierarchicalEstimate(value, fine, jnp.where(bad, jnp.inf, energy))
