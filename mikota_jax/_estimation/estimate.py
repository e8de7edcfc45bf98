"""``estimate``: one verb for a reduced model's error in J, and the estimators as strategies.

J is the free vibration's energy int_0^T (x^T K x + x'^T M x') / 2 dt over [0, T = ``horizon``]
from (x0, v0), J_r that of the Galerkin model on an (n, r) orthonormal basis (eq. 3.4). An
estimator holds what it needs beyond the design (the basis, its fine space) and is built once for
a family of designs (the same M and K, other dampers):

* ``ResidualBound(basis)``: a rigorous bound on |J - J_r| from the residual, in the energy norm
  in which the damped flow is a contraction (Haasdonk & Ohlberger 2008; Grepl & Patera 2005):
  O(n r^2 + r^3), no full solve, first order in the residual, so pessimistic (effectivity 5 to
  2e6 on a 40-DOF chain);
* ``Hierarchical(system, basis, ...)``: J_r against the J_f of a richer Galerkin model (Hain,
  Ohlberger, Radic & Urban, Adv. Comput. Math. 45 (2019) 2191-2214), second order like the
  error itself (effectivity about its ``safety``), resting on a saturation assumption that is
  checked, not proven; it also estimates the error of dJ_r with respect to the dampers.

``certified_sweep`` takes J over many designs through the reduced model where an estimator
certifies it, through the full model only where it does not.

Conventions: 1-based DOFs; ``x0``, ``v0`` are (n,) full coordinates (default zero); every result
is float64.
"""

import abc
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Basis, Float
from .._errors import MARK
from .._model.reduced import ReducedModel
from .._model.system import SecondOrderSystem
from .._scenes.scene import Scene
from .._scenes.sensitivity import SceneFunction
from .._sweep import sweep
from .estimator import HierarchicalEstimator, HierarchicalGradient, error_bound
from .greedy import _training, relative_bounds


class Estimate(eqx.Module):
    """What ``estimate`` returns (float64 scalars): ``value`` J_r, the reduced model's energy;
    ``error`` a bound (``rigorous``) or an estimate of |J - J_r|, inf where the estimator could
    not give one; ``fine`` J_f of ``Hierarchical`` (None for ``ResidualBound``); ``state`` a bound
    on max_t |z(t) - z_r(t)|_E and ``history`` its (L,) values on L intervals of [0, T] (of
    ``ResidualBound``; None for ``Hierarchical``)."""

    value: Float[Array, ""]
    error: Float[Array, ""]
    rigorous: bool = eqx.field(static=True)
    fine: Float[Array, ""] | None = None
    state: Float[Array, ""] | None = None
    history: Float[Array, " L"] | None = None

    @property
    def relative(self) -> Float[Array, ""]:
        """|J - J_r| / J's bound or estimate: error / (J_r - error), inf where not positive."""
        floor = self.value - self.error
        return jnp.where(floor > 0, self.error / jnp.where(floor > 0, floor, 1.0), jnp.inf)


class GradientEstimate(eqx.Module):
    """What ``estimate(..., gradient=True)`` returns: ``Estimate``'s ``value``, ``fine`` and
    ``error``, and per grounded damper (dicts with keys "positions" and "coefficients", (g,)
    each, as ``SceneFunction``'s parameters) ``gradient`` dJ_r (the basis held fixed),
    ``fine_gradient`` dJ_f and ``gradient_error`` the estimate of |dJ - dJ_r|, inf where a model
    is not definite or a derivative not finite; ``design`` the positions and coefficients they
    are taken at (a position's derivative is the one within its interval, from the right at a
    DOF)."""

    value: Float[Array, ""]
    fine: Float[Array, ""]
    error: Float[Array, ""]
    gradient: dict
    fine_gradient: dict
    gradient_error: dict
    design: dict

    def _record(self) -> HierarchicalGradient:
        return HierarchicalGradient(self.value, self.fine, self.error, self.gradient,
                                    self.fine_gradient, self.gradient_error, self.design)

    @property
    def relative(self) -> Float[Array, ""]:
        """The estimate of |J - J_r| / J (as ``Estimate.relative``)."""
        return self._record().relative

    @property
    def log_sensitivity_error(self) -> Float[Array, ""]:
        """The estimate of max_i c_i |dJ/dc_i - dJ_r/dc_i| / J (J >= J_r - error), inf where
        that floor is not positive; 0 without grounded dampers."""
        return self._record().log_sensitivity_error


class AbstractEstimator(eqx.Module):
    """How ``estimate`` measures a reduced model's error in J. Subclass it and implement
    ``estimate`` (and ``gradient``, if the estimator has one) to add one."""

    @abc.abstractmethod
    def estimate(self, system: SecondOrderSystem, horizon, x0, v0) -> Estimate:
        """The ``Estimate`` at the design ``system`` (checked (n,) ``x0``, ``v0``)."""

    def gradient(self, system: SecondOrderSystem, horizon, x0, v0):
        """The estimate of dJ_r's error with respect to the dampers; not every estimator has
        one."""
        raise ValueError(MARK + f"estimator: {type(self).__name__} has no gradient estimate; "
                         "use Hierarchical(...).")


class ResidualBound(AbstractEstimator):
    """A rigorous bound on |J - J_r| and on the state's energy-norm error, from the residual
    of the Galerkin model on ``basis`` ((n, r) orthonormal, or a ``ReducedModel``): see
    ``mikota_jax._estimation.estimator``. Jit-, vmap- and grad-compatible in the design's values;
    inf where the stiffness is not positive definite."""

    basis: Basis

    def __init__(self, basis: Basis | ReducedModel):
        self.basis = basis.basis if isinstance(basis, ReducedModel) else basis

    def estimate(self, system, horizon, x0, v0) -> Estimate:
        """The bound at the design ``system`` (``estimate``'s arguments)."""
        b = error_bound(system, self.basis, horizon, x0, v0)
        return Estimate(b.value, b.energy, True, state=b.state, history=b.history)


class Hierarchical(AbstractEstimator):
    """J_r against J_f of the Galerkin model on span(``basis``, the ``modes`` lowest undamped
    modes, ``moments`` static moments per damper direction): |J - J_r| ~ ``safety`` |J_f - J_r|
    (Hain, Ohlberger, Radic & Urban 2019). Built once from any design ``system`` of the family
    (its M and K); ``basis_moments`` > 0 adds that many moments of each design's dampers to the
    reduced basis too. Defaults: ``modes`` min(n, 2 r), ``moments`` 3, ``safety`` 2. See
    ``mikota_jax._estimation.estimator.HierarchicalEstimator`` for the measured effectivities."""

    estimator: HierarchicalEstimator

    def __init__(self, system: SecondOrderSystem, basis: Basis | ReducedModel,
                 modes: int | None = None, moments: int = 3, safety: float = 2.0, *,
                 basis_moments: int = 0):
        basis = basis.basis if isinstance(basis, ReducedModel) else basis
        self.estimator = HierarchicalEstimator(system, basis, modes, moments, safety,
                                               basis_moments=basis_moments)

    def reduced_basis(self, system: SecondOrderSystem) -> Basis:
        """The reduced model's (n, r') orthonormal basis at ``system``'s design."""
        return self.estimator.reduced_basis(system)

    def fine_basis(self, system: SecondOrderSystem) -> Basis:
        """The (n, r_f) orthonormal fine basis at ``system``'s design (a fixed shape)."""
        return self.estimator.fine_basis(system)

    def estimate(self, system, horizon, x0, v0) -> Estimate:
        """J_r, J_f and the estimate at the design ``system`` (``estimate``'s arguments)."""
        e = self.estimator(system, horizon, x0, v0)
        return Estimate(e.value, e.energy, False, fine=e.fine)

    def gradient(self, system, horizon, x0, v0) -> GradientEstimate:
        """dJ_r, dJ_f and the estimate of |dJ - dJ_r| per grounded damper (positions and
        coefficients), the bases held fixed: forward mode through both reduced models'
        spectral J, no full solve."""
        g = self.estimator.gradient(system, horizon, x0, v0)
        return GradientEstimate(g.value, g.fine, g.energy, g.gradient, g.fine_gradient, g.error,
                                g.design)


def _checked(system, estimator, horizon, x0, v0):
    if not isinstance(system, SecondOrderSystem):
        raise ValueError(MARK + f"system must be a SecondOrderSystem, got {type(system).__name__}.")
    if not isinstance(estimator, AbstractEstimator):
        raise ValueError(MARK + "estimator must be ResidualBound(...), Hierarchical(...) or "
                         f"another AbstractEstimator, got {type(estimator).__name__}.")
    n = system.size
    x0 = jnp.zeros(n) if x0 is None else jnp.asarray(x0, dtype=jnp.float64)
    v0 = jnp.zeros(n) if v0 is None else jnp.asarray(v0, dtype=jnp.float64)
    for name, x in (("x0", x0), ("v0", v0)):
        if x.shape != (n,):
            raise ValueError(MARK + f"{name} must have shape ({n},), got {x.shape}.")
    return x0, v0


def estimate(system: SecondOrderSystem, estimator: AbstractEstimator, horizon, x0=None, v0=None,
             *, gradient: bool = False):
    """The error in J of a reduced model at the design ``system``, without solving the full model.

    ``estimator``: ``ResidualBound(basis)`` or ``Hierarchical(system, basis, ...)`` (built once,
    evaluated at many designs with the same M and K); ``horizon``: T > 0; ``x0``, ``v0``: (n,)
    (default zero). Returns an ``Estimate`` (``value`` J_r, ``error``, ``relative``); with
    ``gradient=True`` a ``GradientEstimate`` (of ``Hierarchical``: J_r, J_f, dJ_r, dJ_f and the
    estimate of |dJ - dJ_r| per grounded damper). Jit- and vmap-compatible
    in the design's values (``mj.sweep`` over a function that builds the system).

    >>> import jax.numpy as jnp, mikota_jax as mj
    >>> system = mj.mikota_chain(6, dampers=[mj.GroundedDamper(3.0, 1.0)])
    >>> e = mj.estimate(system, mj.ResidualBound(jnp.eye(6)), 5.0, x0=jnp.ones(6))
    >>> bool(e.error <= 1e-6 * e.value)  # the whole space: exact up to rounding
    True
    """
    x0, v0 = _checked(system, estimator, horizon, x0, v0)
    if gradient:
        return estimator.gradient(system, horizon, x0, v0)
    return estimator.estimate(system, horizon, x0, v0)


# ---------------------------------------------------------------- sweeps over designs


def _check_scene(scene) -> None:
    if not isinstance(scene, Scene):
        raise ValueError(MARK + f"scene must be a Scene (see mj.app.load_scene), got "
                         f"{type(scene).__name__}.")
    if scene.load is not None:
        raise ValueError(MARK + "scene: the error estimates cover free vibration only (no "
                         "[load]).")


class _EstimateFunction(eqx.Module):
    """parameters -> (J_r, error) of ``scene``'s free vibration by ``estimator``: a pure function
    for ``mj.sweep`` (the scene's values where a name is missing, as ``SceneFunction``)."""

    function: SceneFunction
    estimator: AbstractEstimator

    def __call__(self, parameters: dict) -> jax.Array:
        function = self.function
        n = function.scene.size
        x0, v0, _ = function.excitation(parameters)
        x0 = jnp.zeros(n) if x0 is None else x0
        v0 = jnp.zeros(n) if v0 is None else v0
        horizon = function.scene.ts[-1] - function.scene.ts[0]
        e = self.estimator.estimate(function.system(parameters), horizon, x0, v0)
        return jnp.stack([e.value, e.error])


@dataclass(frozen=True)
class CertifiedSweep:
    """What ``certified_sweep`` returns, per design (S,): ``values`` J (the reduced model's
    where ``certified``, else the full model's), ``certified`` whether the estimate met the
    tolerance there, ``estimates`` the relative estimate of |J - J_r| / J, ``reduced`` J_r
    everywhere; ``full_solves`` the full-model solves taken (the designs not certified)."""

    values: np.ndarray
    certified: np.ndarray
    estimates: np.ndarray
    reduced: np.ndarray
    tolerance: float
    full_solves: int


def certified_sweep(scene: Scene, points: dict, estimator: AbstractEstimator,
                    tolerance: float = 1e-4, *, batch: str = "map",
                    progress: bool = False) -> CertifiedSweep:
    """J of ``scene``'s free vibration at every design of ``points`` (``mj.grid``), through the
    reduced model where ``estimator`` certifies it to ``tolerance`` (relative) and by the full
    model (its exact integral, the spectral path for chains) only where it does not: the sweep
    decides by the estimate, not by full solves. ``batch``: as ``mj.sweep``'s. With
    ``Hierarchical`` the certificate rests on saturation (checked in the benchmarks), with
    ``ResidualBound`` it is rigorous.
    """
    _check_scene(scene)
    if not isinstance(estimator, AbstractEstimator):
        raise ValueError(MARK + "estimator must be ResidualBound(...), Hierarchical(...) or "
                         f"another AbstractEstimator, got {type(estimator).__name__}.")
    if not (isinstance(tolerance, float | int) and 0 < tolerance < 1):
        raise ValueError(MARK + f"tolerance must be in (0, 1), got {tolerance!r}.")
    points, _ = _training(scene, points)
    values = sweep(_EstimateFunction(SceneFunction(scene, "energy"), estimator), points,
                   batch=batch, progress=progress)
    estimates = relative_bounds(values)
    certified = estimates <= tolerance
    result = np.array(values[:, 0])
    missing = np.flatnonzero(~certified)
    if missing.size:
        subset = {name: v[missing] for name, v in points.items()}
        result[missing] = np.asarray(sweep(SceneFunction(scene, "energy"), subset, batch=batch,
                                           progress=progress))
    return CertifiedSweep(result, certified, estimates, np.asarray(values[:, 0]),
                          float(tolerance), int(missing.size))

