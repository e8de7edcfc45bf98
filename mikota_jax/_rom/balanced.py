"""Two-sided (Petrov-Galerkin) projection that keeps the second-order structure, and second-order
balanced truncation.

``TwoSided(basis, test_basis)``: with V, W (n, r), x ~ V q and the residual orthogonal to W,
W^T M V q'' + W^T D V q' + W^T K V q = W^T B u, y = C_x V q + C_v V q' (Galerkin is W = V). The
reduced matrices need not be symmetric; the result is an ``LTIModel.second_order``.

``SOBT(rank, variant)``: second-order balanced truncation (Reis & Stykel, "Balanced truncation
model reduction of second-order systems", Math. Comput. Model. Dyn. Syst. 14 (2008) 391-406;
pyMOR's ``SOBT*Reductor``). In the full system's M-orthonormal modal coordinates (M = I,
``_model/pencil``) the first-order Gramians solve A P + P A^T + B B^T = 0 and
A^T Q + Q A + C^T C = 0 with A = [[0, I], [-Omega^2, -C]], B = (0, U^T B), C = (C_x U, C_v U);
their position and velocity blocks P_p, P_v, Q_p, Q_v are balanced pairwise by the square-root
method: P_. = R R^T, Q_. = L L^T, L^T R = Z S Y^T, V = R Y_r S_r^-1/2, W = L Z_r S_r^-1/2, then
``TwoSided``'s projection with (V, W). ``variant``: "p" balances (P_p, Q_p), "v" (P_v, Q_v), "pv"
(P_p, Q_v), "vp" (P_v, Q_p). No a-priori error bound holds for these, and stability is not
preserved: an unstable result warns and says so in ``is_stable()``.

Gramians of a chain whose dampers barely touch some modes are singular in float64: a mode damped
below what a dense Lyapunov solve resolves (C_ll / 2 at most 2 n eps max omega, the rule of
``IOModel.hinf_norm``) has an unbounded Gramian entry and a Hankel value that is its resonance
peak, unresolvable too. Such modes are left out before balancing, and the result says what
that costs: ``stats.dropped`` is their part's H2 norm relative to the full one, from the decoupled
oscillators' shares b^2 (c_x^2 / omega^2 + c_v^2) / (2 C_ll), a floor under the model's H2 error
(on the Section 5 map, 167 of 300 modes and a floor of 9e-7), and a warning says so where it is
above sqrt(eps). ``stats.modes`` counts the modes balanced. Dense: O(n^3).
"""

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Float
from .._errors import MARK, check_dense_memory
from .._model.reduced import ReductionStats
from .._model.system import SecondOrderSystem
from .base import AbstractIOReduction
from .h2_optimal import _modal
from .lti import LTIModel, sylvester

VARIANTS = ("p", "v", "pv", "vp")


def _rank_check(name: str, rank) -> None:
    if isinstance(rank, bool) or not isinstance(rank, int) or rank < 1:
        raise ValueError(MARK + f"{name}: rank must be an integer >= 1, got {rank!r}.")


class TwoSided(AbstractIOReduction):
    """The Petrov-Galerkin model on ``basis`` V and ``test_basis`` W, both (n, r) float64 for
    the problem's n (module docstring): an ``LTIModel`` of 2r states, second-order structure
    kept. W^T M V must be invertible."""

    basis: Float[Array, "n r"]
    test_basis: Float[Array, "n r"]

    def __check_init__(self):
        for name in ("basis", "test_basis"):
            value = getattr(self, name)
            if value.ndim != 2 or value.dtype != jnp.float64:
                raise ValueError(MARK + f"TwoSided: {name} must be a float64 (n, r) array, got "
                                 f"{value.dtype} {value.shape}.")
        if self.basis.shape != self.test_basis.shape:
            raise ValueError(MARK + f"TwoSided: basis and test_basis must have one shape, got "
                             f"{self.basis.shape} and {self.test_basis.shape}.")

    def __init__(self, basis, test_basis):
        self.basis, self.test_basis = jnp.asarray(basis), jnp.asarray(test_basis)

    def reduce_io(self, io) -> LTIModel:
        """The two-sided model of the IOModel ``io`` of a full system."""
        system = io.model
        if self.basis.shape[0] != system.size:
            raise ValueError(MARK + f"TwoSided: basis must have n = {system.size} rows, got "
                             f"{self.basis.shape[0]}.")
        return project(system, io, self.basis, self.test_basis,
                       ReductionStats("TwoSided", self.basis.shape[1]))


def _apply(operator, v):
    if operator is None:
        return jnp.zeros_like(v)
    return jax.vmap(operator.mv, in_axes=1, out_axes=1)(v)


def project(system: SecondOrderSystem, io, v, w, stats) -> LTIModel:
    """W^T (M, D, K) V, W^T B, C_x V, C_v V as an ``LTIModel.second_order``."""
    v, w = jnp.asarray(v), jnp.asarray(w)
    mass, damping, stiffness = (w.T @ _apply(op, v) for op in (
        system.mass, system.damping_operator(), system.stiffness))
    if np.linalg.cond(np.asarray(mass)) > 1 / np.finfo(float).eps:
        raise ValueError(MARK + "TwoSided: W^T M V is singular; the test basis must not be "
                         "M-orthogonal to the basis.")
    return LTIModel.second_order(mass, damping, stiffness, w.T @ io.inputs, io.cx @ v,
                                 io.cv @ v, stats=stats)


def _factor(gramian):
    """R with R R^T = the symmetric positive semidefinite ``gramian`` (rounding's negative
    eigenvalues set to zero)."""
    values, vectors = np.linalg.eigh((gramian + gramian.T) / 2)
    return vectors * np.sqrt(np.maximum(values, 0.0))


class SOBT(AbstractIOReduction):
    """Second-order balanced truncation to ``rank`` DOFs (module docstring), ``variant`` one of
    "p", "v", "pv" (default), "vp": an ``LTIModel`` of 2 ``rank`` states. Stats: ``modes``
    (the modes balanced; the others were damped below rounding), ``dropped`` (the relative H2
    norm of those left out: a floor under the error) and ``bounds`` (the singular values of
    L^T R kept, the variant's Hankel-like values)."""

    rank: int = eqx.field(static=True)
    variant: str = eqx.field(static=True, default="pv")

    def __check_init__(self):
        _rank_check("SOBT", self.rank)
        if self.variant not in VARIANTS:
            raise ValueError(MARK + f"SOBT: variant must be one of {VARIANTS}, got "
                             f"{self.variant!r}.")

    def reduce_io(self, io) -> LTIModel:
        """The balanced truncation of the IOModel ``io`` of a full system."""
        if not isinstance(io.model, SecondOrderSystem):
            raise ValueError(MARK + "SOBT: the IOModel must be that of a full system.")
        check_dense_memory(4 * io.size, 4, "SOBT")
        modal = _modal(io)
        n = modal.omega.shape[0]
        eps = np.finfo(float).eps
        cll = modal.diagonal + modal.factor**2 @ modal.weights
        if modal.dense is not None:
            cll = cll + np.diag(modal.dense)
        unresolved = cll / 2 <= 2 * n * eps * np.max(modal.omega)
        share = (np.sum(modal.inputs**2, axis=1)
                 * np.sum((modal.cx / modal.omega) ** 2 + modal.cv**2, axis=0))
        with np.errstate(divide="ignore", invalid="ignore"):
            share = np.where(share > 0, share / (2 * np.maximum(cll, 0.0)), 0.0)
        dropped = float(np.sqrt(np.sum(share[unresolved]) / np.sum(share)))
        if dropped > np.sqrt(eps):  # above what an H2 error resolves: say what it costs
            warnings.warn(f"SOBT: {int(np.sum(unresolved))} modes damped below what a dense "
                          f"Gramian resolves carry {dropped:.2g} of the H2 norm; they are left "
                          "out, so the model's relative H2 error cannot go below that "
                          "(stats.dropped).", stacklevel=3)
        keep = np.flatnonzero(~unresolved)
        k = keep.size
        if self.rank > k:
            raise ValueError(MARK + f"SOBT: rank = {self.rank} is out of reach: {k} modes are "
                             f"damped above rounding; choose rank <= {k}.")
        damping = np.eye(n)[keep]
        damping = modal.damp(damping.T)[keep]  # C restricted to the kept modes
        a = np.block([[np.zeros((k, k)), np.eye(k)],
                      [-np.diag(modal.omega[keep] ** 2), -damping]])
        b = np.vstack([np.zeros((k, modal.inputs.shape[1])), modal.inputs[keep]])
        c = np.hstack([modal.cx[:, keep], modal.cv[:, keep]])
        p = np.asarray(sylvester(jnp.asarray(a), jnp.asarray(a), jnp.asarray(-b @ b.T)).real)
        q = np.asarray(sylvester(jnp.asarray(a.T), jnp.asarray(a.T),
                                 jnp.asarray(-c.T @ c)).real)
        pick = {"p": slice(0, k), "v": slice(k, 2 * k)}
        r_factor = _factor(p[pick[self.variant[0]], pick[self.variant[0]]])
        l_factor = _factor(q[pick[self.variant[-1]], pick[self.variant[-1]]])
        z, values, y_t = np.linalg.svd(l_factor.T @ r_factor)
        reachable = int(np.sum(values > k * eps * values[0]))
        if self.rank > reachable:
            raise ValueError(MARK + f"SOBT: rank = {self.rank} is out of reach: the Gramians' "
                             f"product has numerical rank {reachable}; choose rank <= "
                             f"{reachable}.")
        scale = 1 / np.sqrt(values[: self.rank])
        v = r_factor @ y_t[: self.rank].T * scale
        w = l_factor @ z[:, : self.rank] * scale
        mass, damping_r = w.T @ v, w.T @ damping @ v
        stiffness = w.T @ (modal.omega[keep, None] ** 2 * v)
        stats = ReductionStats("SOBT", self.rank, modes=k, dropped=dropped,
                               bounds=tuple(float(x) for x in values[: self.rank]))
        model = LTIModel.second_order(mass, damping_r, stiffness, w.T @ modal.inputs[keep],
                                      modal.cx[:, keep] @ v, modal.cv[:, keep] @ v, stats=stats)
        if not model.is_stable():
            warnings.warn(f"SOBT: the reduced model of rank {self.rank} ({self.variant}) has a "
                          "pole with Re >= 0 (second-order balanced truncation does not keep "
                          "stability); is_stable() is False.", stacklevel=2)
        return model
