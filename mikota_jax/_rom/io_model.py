"""Input-output second-order models, their transfer functions, H2 norms and error systems.

M x'' + D x' + K x = B u(t), y = C_x x + C_v x': m inputs u, q outputs y, and the transfer
function G(s) = (C_x + s C_v)(s^2 M + s D + K)^-1 B (the second-order models of pyMOR's
``SecondOrderModel`` and of Reis & Stykel, "Balanced truncation model reduction of second-order
systems", Math. Comput. Model. Dyn. Syst. 14 (2008) 391-406). ``IOModel`` wraps a full system or
a reduced model (B and C stay in full coordinates; a reduced model's are B_r = Phi^T B,
C_r = C Phi) and ``full - reduced`` is the ``ErrorModel`` G_1 - G_2.

G(s) is one solve with s^2 M + s D + K per point (``_model/pencil``): O(n (m + k^2)) for a chain
with k relative dampers (a pivoted tridiagonal solve, Woodbury for the dampers that leave the
band), O(r^3) for a reduced model, O(n^3) for dense user matrices.

The H2 norm of an error system is ||G_1 - G_2||^2 = ||G_1||^2 + ||G_2||^2 - 2 Re <G_1, G_2>.
The norms are the exact ones of ``h2_norm`` (the damped modes, or a reduced model's Gramian);
the inner product is tr(C_1 X C_2^T) with the cross Gramian X of A_1 X + E_1 X A_2^T + B_1 B_2^T
= 0 (E_1 z' = A_1 z + B_1 u: the larger model in first-order form), solved as Bartels & Stewart
do ("Solution of the matrix equation AX + XB = C", Comm. ACM 15 (1972) 820-826): the smaller
model's state matrix in complex Schur form (stable also where its poles coalesce), then one
shifted solve of the larger model per column, O(r n (k^2 + r)) for a reduced model of order r.
The subtraction loses what rounding leaves of ||G_1||^2: an error below about
sqrt(eps) (||G_1|| + ||G_2||) is not resolved (it comes back as that floor or 0).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Complex, Float
from .._errors import MARK, array_module, as_float, check, check_dense_memory
from .._model.pencil import modal_pencil, pencil_solver
from .._model.reduced import ReducedModel
from .._model.system import SecondOrderSystem
from .._objective.outputs import _matrix, h2_norm, output_matrices
from .._solver.solve import AbstractMethod, Auto, solve
from .._solver.spectral.modes import damped_modes, spectral_applies
from .hinf import hinf_norm
from .lti import LTIModel, _schur, sylvester_inner

_AUTO = Auto()


class IOModel(eqx.Module):
    """M x'' + D x' + K x = B u, y = C_x x + C_v x': a system with m inputs and q outputs.

    ``model``: a ``SecondOrderSystem`` or a ``ReducedModel``; ``inputs``: B, (n, m) force
    directions (an (n,) vector is one input); ``cx``, ``cv``: (q, n) outputs on displacements
    and velocities (an (n,) vector is one output; a missing one is zero; at least one).
    Full coordinates throughout, also for a reduced model. ``reduce(io_model, strategy)``
    reduces the model and keeps B and C; ``full - reduced`` is their ``ErrorModel``.

    >>> import jax.numpy as jnp, mikota_jax as mj
    >>> system = mj.mikota_chain(40, dampers=[mj.GroundedDamper(7.0, 1.0)])
    >>> full = mj.IOModel(system, mj.unit_vector(40, 3), cx=mj.unit_vector(40, 20))
    >>> reduced = mj.reduce(full, mj.Modal(10))
    >>> error = full - reduced
    >>> bool(error.h2_norm() < full.h2_norm())
    True
    """

    model: SecondOrderSystem | ReducedModel
    inputs: Float[Array, "n m"]
    cx: Float[Array, "q n"]
    cv: Float[Array, "q n"]
    given: tuple[bool, bool] = eqx.field(static=True)  # whether cx, cv were given (else zero)

    def __init__(self, model, inputs, cx=None, cv=None):
        if not isinstance(model, SecondOrderSystem | ReducedModel):
            raise ValueError(MARK + "model must be a SecondOrderSystem or a ReducedModel, got "
                             f"{type(model).__name__}.")
        n = model.size
        if inputs is None:
            raise ValueError(MARK + f"inputs must be (n, m) or (n,) with n = {n}, got None.")
        self.model = model
        self.inputs = _matrix(inputs, n, "inputs", False)
        self.given = (cx is not None, cv is not None)
        self.cx, self.cv = output_matrices(n, cx, cv)

    @property
    def size(self) -> int:
        """n, the number of full DOFs."""
        return self.model.size

    @property
    def shape(self) -> tuple[int, int]:
        """(q, m): outputs and inputs, the shape of G(s)."""
        return self.cx.shape[0], self.inputs.shape[1]

    def transfer(self, s) -> Complex[Array, "F q m"]:
        """G(s) = (C_x + s C_v)(s^2 M + s D + K)^-1 B at the (F,) complex points ``s``: complex128
        (F, q, m). Differentiable; a point on a pole is inf or NaN (no pole lies in Re s > 0)."""
        s = jnp.asarray(s)
        if jnp.issubdtype(s.dtype, jnp.complexfloating) and s.dtype != jnp.complex128:
            raise ValueError(MARK + f"s must be complex128 or float64, got {s.dtype}.")
        s = jnp.atleast_1d(s).astype(jnp.complex128)
        if s.ndim != 1:
            raise ValueError(MARK + f"s must be a scalar or an (F,) array, got shape {s.shape}.")
        return _transfer(*_coordinates(self), s)

    def frequency_response(self, omegas) -> Complex[Array, "F q m"]:
        """G(i omega) at the (F,) angular frequencies ``omegas`` (rad per unit time, >= 0): the
        steady-state complex amplitude of the outputs under inputs e^(i omega t)."""
        omegas = as_float(omegas, "omegas")
        if omegas.ndim != 1 or omegas.shape[0] < 1:
            raise ValueError(MARK + f"omegas must be a non-empty (F,) array, got {omegas.shape}.")
        xp = array_module(omegas)
        values = np.asarray(omegas) if xp is np else omegas
        omegas = check(omegas, ~xp.all(xp.isfinite(values) & (values >= 0)),
                       "omegas must be finite and >= 0.")
        return self.transfer(jax.lax.complex(jnp.zeros_like(omegas), omegas))

    def h2_norm(self) -> Float[Array, ""]:
        """||G||_H2: the square root of the outputs' energy over the impulse responses of the
        inputs (``h2_norm``; exact from the damped modes, or a reduced model's Gramian).
        Refused where a mode that nothing damps is excited and seen."""
        return h2_norm(self.model, self.inputs, self.cx, self.cv)

    def poles(self) -> Complex[Array, " p"]:
        """The 2 r eigenvalues of s^2 M + s D + K (r = n, or a reduced model's rank): a full
        system with dampers from its damped modes (the secular equation, O(n^2)), anything else
        densely (O(r^3))."""
        if isinstance(self.model, SecondOrderSystem) and spectral_applies(self.model) is None:
            modes = damped_modes(self.model)
            roots = check(modes.eigenvalues, ~jnp.all(modes.converged),
                          "model: the damped modes did not converge.")
            return roots
        system = self.model.system if isinstance(self.model, ReducedModel) else self.model
        check_dense_memory(2 * system.size, 3, "IOModel.poles")
        return jnp.linalg.eigvals(_first_order(system)[0])

    def output(self, ts, u=None, *, x0=None, v0=None, method: AbstractMethod = _AUTO
               ) -> Float[Array, "N q"]:
        """y(t) = C_x x(t) + C_v x'(t) at the (N,) times ``ts`` under the inputs ``u`` (a
        callable t -> (m,), or None: free vibration) from x0, v0 (full coordinates, default
        zero): ``solve`` with the load B u(t) and ``method``, then C; (N, q)."""
        inputs = self.inputs
        if u is not None and not callable(u):
            raise ValueError(MARK + f"u must be None or a callable t -> (m,), got {u!r:.60}.")
        load = None if u is None else (lambda t: inputs @ jnp.atleast_1d(u(t)))
        has_x, has_v = self.given  # only the states an output reads are solved for
        trajectory = solve(self.model, ts, x0, v0, load, method=method, displacement=has_x,
                           velocity=has_v)
        parts = [trajectory.displacement @ self.cx.T] if has_x else []
        return sum(parts + ([trajectory.velocity @ self.cv.T] if has_v else []))

    def outputs(self) -> tuple:
        """(cx, cv) as given: each a (q, n) matrix, or None where it was left out."""
        return tuple(c if g else None for c, g in zip((self.cx, self.cv), self.given))

    def hinf_norm(self) -> Float[Array, ""]:
        """||G||_inf = sup_omega sigma_max(G(i omega)): level sets of the Hamiltonian on the
        model's modal realization (``LTIModel.hinf_norm``). A mode damped below rounding is
        left out where its resonance peak is below rounding of the norm, and the norm is
        refused where it is not (a peak that float64 cannot resolve). Dense: O(n^3)."""
        return jnp.asarray(hinf_norm(*_realization(self, "IOModel.hinf_norm"))[0])

    def __sub__(self, other) -> "ErrorModel":
        """The error system ``self - other`` (the same q outputs and m inputs; ``other`` an
        ``IOModel`` or an ``LTIModel``)."""
        if not isinstance(other, IOModel | LTIModel):
            return NotImplemented
        return ErrorModel(self, other)


class ErrorModel(eqx.Module):
    """G_1 - G_2 of two models with the same inputs and outputs (``first - second``, e.g.
    ``full - reduced``), each an ``IOModel`` or an ``LTIModel``: its transfer function,
    frequency response, H2 and H-infinity norms."""

    first: "IOModel | LTIModel"
    second: "IOModel | LTIModel"

    def __init__(self, first, second):
        if first.shape != second.shape:
            raise ValueError(MARK + f"the two models must have the same (outputs, inputs), got "
                             f"{first.shape} and {second.shape}.")
        self.first, self.second = first, second

    def transfer(self, s) -> Complex[Array, "F q m"]:
        """G_1(s) - G_2(s) at the (F,) complex points ``s``."""
        return self.first.transfer(s) - self.second.transfer(s)

    def frequency_response(self, omegas) -> Complex[Array, "F q m"]:
        """G_1(i omega) - G_2(i omega) at the (F,) angular frequencies ``omegas`` (>= 0)."""
        return self.first.frequency_response(omegas) - self.second.frequency_response(omegas)

    def h2_norm(self) -> Float[Array, ""]:
        """||G_1 - G_2||_H2 (module docstring: the two norms and the cross Gramian's inner
        product; resolved down to about sqrt(eps) (||G_1|| + ||G_2||)). Differentiable with
        respect to a full system's values (``jax.grad``), not a reduced or dense model's (JAX
        has no derivative of the Schur form): a reduced model held fixed while the full one
        moves."""
        first, second = self.first.h2_norm(), self.second.h2_norm()
        full = [io for io in (self.first, self.second) if _is_full(io)]
        if full:
            small, large = sorted((self.first, self.second),
                                  key=lambda io: (_is_full(io), _order(io)))
            cross = _inner(_coordinates(large), _first_order_of(small))
        else:
            cross = sylvester_inner(_first_order_of(self.first), _first_order_of(self.second))
        return jnp.sqrt(jnp.maximum(first**2 + second**2 - 2 * cross, 0.0))

    def hinf_norm(self) -> Float[Array, ""]:
        """||G_1 - G_2||_inf: level sets of the Hamiltonian (``LTIModel.hinf_norm``) on the
        two realizations side by side (``IOModel.hinf_norm``'s modal one for an IOModel)."""
        (a1, b1, c1), (a2, b2, c2) = (_realization(io, "ErrorModel.hinf_norm")
                                      for io in (self.first, self.second))
        zero = np.zeros((a1.shape[0], a2.shape[0]))
        a = np.block([[a1, zero], [zero.T, a2]])
        return jnp.asarray(hinf_norm(a, np.vstack([b1, b2]), np.hstack([c1, -c2]))[0])

    def poles(self) -> Complex[Array, " p"]:
        """The poles of both models (those of G_1 - G_2 where nothing cancels)."""
        return jnp.concatenate([self.first.poles(), self.second.poles()])


def _is_full(io) -> bool:
    return isinstance(io, IOModel) and isinstance(io.model, SecondOrderSystem)


def _order(io) -> int:
    """The order of a model's pencil: the rank of a reduced model, half a dense model's
    states, else n."""
    if isinstance(io, LTIModel):
        return io.order // 2
    return io.model.rank if isinstance(io.model, ReducedModel) else io.model.size


def _first_order_of(io):
    """(A, B, C) of G with E = I: a dense model's, or an IOModel's in its modal coordinates."""
    if isinstance(io, LTIModel):
        return tuple(jnp.asarray(x) for x in io.standard())
    return _modal_first_order(_coordinates(io))


@eqx.filter_jit
def _modal_first_order(coordinates):
    system, b, cx, cv = coordinates
    a, modes = _first_order(system)
    r = modes.shape[1]
    return (a, jnp.concatenate([jnp.zeros((r, b.shape[1])), modes.T @ b]),
            jnp.concatenate([cx @ modes, cv @ modes], axis=1))


def _realization(io, what: str):
    """(A, B, C) numpy with E = I for the H-infinity norm: an ``LTIModel``'s, or an IOModel's
    modal one. A mode damped below what a dense eigenvalue solve resolves (C_ll / 2 at most
    2 n eps max omega: the Hamiltonian's rounding) is left out where its resonance peak
    |U^T B| |C_x U / omega + C_v U| / C_ll (the decoupled oscillator's) is at most eps of the
    others' largest; where it is larger the norm is refused (it is that mode's peak, damped
    below rounding: the mode's shape zero to rounding at the dampers)."""
    if isinstance(io, LTIModel):
        io._check_stable(what)
        return io.standard()
    system, b, cx, cv = _coordinates(io)
    check_dense_memory(2 * system.size, 4, what)
    pencil = modal_pencil(system)
    omega, modes = np.asarray(pencil.omega), np.asarray(pencil.modes)
    n = omega.shape[0]
    c = np.asarray(pencil.damping_modal(jnp.eye(n, dtype=jnp.complex128)).real)
    bm, cxm, cvm = modes.T @ np.asarray(b), np.asarray(cx) @ modes, np.asarray(cv) @ modes
    eps = np.finfo(float).eps
    cll = np.diag(c)
    unresolved = cll / 2 <= 2 * n * eps * np.max(omega)
    reach = np.linalg.norm(bm, axis=1) * np.linalg.norm(cxm / omega + cvm, axis=0)
    with np.errstate(divide="ignore"):
        peak = np.where(reach > 0, reach / np.maximum(cll, 0.0), 0.0)
    others = np.max(np.where(unresolved, 0.0, peak), initial=0.0)
    refused = unresolved & (peak > eps * others)
    if np.any(refused):
        mode = int(np.flatnonzero(refused)[np.argmax(peak[refused])]) + 1
        raise ValueError(MARK + f"{what}: mode {mode} is damped below rounding (its shape is zero "
                         f"to rounding at the dampers) yet excited and seen: its resonance peak "
                         f"~{np.max(peak):.3g} is the norm and float64 cannot resolve it; move "
                         "the damper or leave that output out.")
    keep = np.flatnonzero(~unresolved)
    k = keep.size
    a = np.block([[np.zeros((k, k)), np.eye(k)],
                  [-np.diag(omega[keep] ** 2), -c[np.ix_(keep, keep)]]])
    return (a, np.vstack([np.zeros((k, bm.shape[1])), bm[keep]]),
            np.hstack([cxm[:, keep], cvm[:, keep]]))


def _coordinates(io: IOModel):
    """(system, B, C_x, C_v) in the coordinates of the model's own system: a reduced model's
    B_r = Phi^T B and C_r = C Phi; a full system's as they are."""
    model = io.model
    if isinstance(model, ReducedModel):
        basis = model.basis
        return model.system, basis.T @ io.inputs, io.cx @ basis, io.cv @ basis
    return model, io.inputs, io.cx, io.cv


@eqx.filter_jit
def _transfer(system, b, cx, cv, s):
    cx, cv = cx.astype(jnp.complex128), cv.astype(jnp.complex128)

    def one(sigma):
        solve = pencil_solver(system, sigma**2, sigma, jnp.ones((), jnp.complex128))
        return (cx + sigma * cv) @ solve(b.astype(jnp.complex128))

    return jax.lax.map(one, s)


def _first_order(system):
    """A = [[0, I], [-Omega^2, -C]] in the modal coordinates (eta, eta'), x = U eta, and U."""
    pencil = modal_pencil(system)
    n = pencil.omega.shape[0]
    c = pencil.damping_modal(jnp.eye(n, dtype=jnp.complex128)).real
    a = jnp.block([[jnp.zeros((n, n)), jnp.eye(n)], [-jnp.diag(pencil.omega**2), -c]])
    return a, pencil.modes


def _complex_mv(mv):
    """A real operator's product applied to a complex vector, part by part."""
    return lambda v: jax.lax.complex(mv(v.real), mv(v.imag))


@eqx.filter_jit
def _inner(large, small):
    """Re <G_large, G_small>_H2 = Re tr(C_1 X C_2^T), A_1 X + E_1 X A_2^T + B_1 B_2^T = 0, by
    Bartels-Stewart on the small side (module docstring). The large side is E_1 z' = A_1 z +
    B_1 u in its own coordinates z = (x, x'): E_1 = diag(I, M), A_1 = [[0, I], [-K, -D]], B_1 =
    (0, B), C_1 = (C_x, C_v), as ``_coordinates`` gives it; the small side (A_2, B_2, C_2) with
    E_2 = I (``_first_order_of``). A reduced model's stats (static) never enter, so models of
    one shape share one compiled program."""
    system, b1, cx1, cv1 = large
    n = system.size
    damping = system.damping_operator()
    damp = (lambda v: jnp.zeros_like(v)) if damping is None else _complex_mv(damping.mv)
    mass = _complex_mv(system.mass.mv)
    a2, b2, c2 = (x.astype(jnp.complex128) for x in small)
    t, q = _schur(a2.T.astype(jnp.complex128))  # A_2^T = Q T Q^H, T upper triangular
    # A_1 Y + E_1 Y T = R with Y = X Q, R = -B_1 B_2^T Q: only its velocity half is nonzero
    rhs_velocity = -(b1.astype(jnp.complex128) @ (b2.T @ q))  # (n, 2r)
    one = jnp.ones((), jnp.complex128)

    def column(y, j):
        # (A_1 - sigma E_1) y_j = R_j - E_1 sum_{i<j} y_i T_ij, sigma = -T_jj (columns >= j of
        # y are still 0); then y_2 = r_1 + sigma y_1, -(sigma^2 M + sigma D + K) y_1 = r_2 +
        # (D + sigma M) r_1
        accumulated = y @ t[:, j]
        r1 = -accumulated[:n]
        r2 = rhs_velocity[:, j] - mass(accumulated[n:])
        sigma = -t[j, j]
        solve = pencil_solver(system, sigma**2, sigma, one)
        y1 = -solve(r2 + damp(r1) + sigma * mass(r1))
        return y.at[:, j].set(jnp.concatenate([y1, r1 + sigma * y1])), None

    y, _ = jax.lax.scan(column, jnp.zeros((2 * n, a2.shape[0]), jnp.complex128),
                        jnp.arange(a2.shape[0]))
    c1 = jnp.concatenate([cx1, cv1], axis=1).astype(jnp.complex128)
    return jnp.real(jnp.trace(c1 @ y @ (q.conj().T @ c2.T)))
