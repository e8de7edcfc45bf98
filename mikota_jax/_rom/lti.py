"""Dense first-order input-output models E z' = A z + B u, y = C z: what the input-output
reductions return.

G(s) = C (s E - A)^-1 B, N states, m inputs, q outputs, D = 0 (pyMOR's ``LTIModel``). The
H2-optimal and balanced reductions of an ``IOModel`` give such a model of N = 2r states for r
reduced DOFs; a second-order model M q'' + D q' + K q = B u, y = C_x q + C_v q' enters as
E = diag(I, M), A = [[0, I], [-K, -D]], B = (0, B), C = (C_x, C_v) (``second_order``), and the
models of other libraries enter as their matrices, so one evaluation code (``full - reduced``:
its H2 and H-infinity norms) serves them all.

The H2 norm is tr(C P C^T) with A P + P A^T + B B^T = 0 (E folded into A and B), solved as
Bartels & Stewart do ("Solution of the matrix equation AX + XB = C", Comm. ACM 15 (1972)
820-826) on the complex Schur form: stable also where poles coalesce. A model with a pole in
Re s >= 0 has no H2 or H-infinity norm and is refused in one line (``is_stable`` says which).
Everything here is O(N^3) and made for reduced orders (N up to a few thousand).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Complex, Float
from .._errors import MARK, as_float, check_x64, is_traced
from .._model.reduced import ReductionStats
from .hinf import hinf_norm as _hinf_norm


def _dense(x, name: str, shape: tuple) -> np.ndarray:
    x = np.asarray(as_float(x, name))
    if x.ndim == 1 and len(shape) == 2 and None in shape:
        x = x[:, None] if shape[0] is not None else x[None, :]
    if x.ndim != 2 or any(want is not None and got != want for got, want in zip(x.shape, shape)):
        want = ", ".join("?" if s is None else str(s) for s in shape)
        raise ValueError(MARK + f"{name} must have shape ({want}), got {x.shape}.")
    if not np.all(np.isfinite(x)):
        raise ValueError(MARK + f"{name} must be finite.")
    return x


class LTIModel(eqx.Module):
    """E z' = A z + B u, y = C z: a dense first-order model with m inputs and q outputs.

    ``a``: (N, N); ``b``: (N, m) (an (N,) vector is one input); ``c``: (q, N) (an (N,) vector is
    one output); ``e``: (N, N) invertible, default the identity; ``stats``: what built it (a
    ``ReductionStats``, or None). ``second_order`` builds one from M, D, K, B, C_x, C_v.
    ``full - reduced`` with an ``IOModel`` or another ``LTIModel`` is their ``ErrorModel``.

    >>> import numpy as np, mikota_jax as mj
    >>> oscillator = mj.LTIModel.second_order([[1.0]], [[0.1]], [[4.0]], [1.0], cx=[1.0])
    >>> round(float(oscillator.hinf_norm()), 6)  # 1 / (2 zeta omega^2 sqrt(1 - zeta^2))
    2.500781
    """

    a: Float[Array, "N N"]
    b: Float[Array, "N m"]
    c: Float[Array, "q N"]
    e: Float[Array, "N N"]
    stats: ReductionStats | None = None

    def __init__(self, a, b, c, e=None, stats: ReductionStats | None = None):
        check_x64()
        a = _dense(a, "a", (None, None))
        states = a.shape[0]
        if a.shape != (states, states) or states < 1:
            raise ValueError(MARK + f"a must be square (N, N) with N >= 1, got {a.shape}.")
        self.a = jnp.asarray(a)
        self.b = jnp.asarray(_dense(b, "b", (states, None)))
        self.c = jnp.asarray(_dense(c, "c", (None, states)))
        e = np.eye(states) if e is None else _dense(e, "e", (states, states))
        if np.linalg.cond(e) > 1 / np.finfo(float).eps:
            raise ValueError(MARK + "e must be invertible (a descriptor model with algebraic "
                             "states is not supported).")
        self.e = jnp.asarray(e)
        self.stats = stats

    @classmethod
    def second_order(cls, mass, damping, stiffness, inputs, cx=None, cv=None,
                     stats: ReductionStats | None = None) -> "LTIModel":
        """M q'' + D q' + K q = B u, y = C_x q + C_v q' (r DOFs, any square M invertible, D, K)
        as E = diag(I, M), A = [[0, I], [-K, -D]], B = (0, B), C = (C_x, C_v): 2r states."""
        m = _dense(mass, "mass", (None, None))
        r = m.shape[0]
        d = _dense(damping, "damping", (r, r))
        k = _dense(stiffness, "stiffness", (r, r))
        b = _dense(inputs, "inputs", (r, None))
        if cx is None and cv is None:
            raise ValueError(MARK + "give cx, cv or both: the (q, r) outputs on q and q'.")
        q = (cx if cx is not None else cv)
        q = _dense(q, "cx" if cx is not None else "cv", (None, r)).shape[0]
        cx = np.zeros((q, r)) if cx is None else _dense(cx, "cx", (q, r))
        cv = np.zeros((q, r)) if cv is None else _dense(cv, "cv", (q, r))
        zero, one = np.zeros((r, r)), np.eye(r)
        return cls(np.block([[zero, one], [-k, -d]]), np.vstack([np.zeros_like(b), b]),
                   np.hstack([cx, cv]), np.block([[one, zero], [zero, m]]), stats)

    @property
    def order(self) -> int:
        """N, the number of states."""
        return self.a.shape[0]

    @property
    def shape(self) -> tuple[int, int]:
        """(q, m): outputs and inputs, the shape of G(s)."""
        return self.c.shape[0], self.b.shape[1]

    def standard(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(E^-1 A, E^-1 B, C) as numpy arrays: the same G(s) with E = I."""
        e = np.asarray(self.e)
        return (np.linalg.solve(e, np.asarray(self.a)), np.linalg.solve(e, np.asarray(self.b)),
                np.asarray(self.c))

    def transfer(self, s) -> Complex[Array, "F q m"]:
        """G(s) = C (s E - A)^-1 B at the (F,) complex points ``s``: complex128 (F, q, m)."""
        s = jnp.atleast_1d(jnp.asarray(s)).astype(jnp.complex128)
        if s.ndim != 1:
            raise ValueError(MARK + f"s must be a scalar or an (F,) array, got shape {s.shape}.")
        return _transfer(self.e, self.a, self.b, self.c, s)

    def frequency_response(self, omegas) -> Complex[Array, "F q m"]:
        """G(i omega) at the (F,) angular frequencies ``omegas`` (>= 0)."""
        omegas = np.asarray(as_float(omegas, "omegas"))
        if omegas.ndim != 1 or omegas.size < 1 or not np.all(np.isfinite(omegas) & (omegas >= 0)):
            raise ValueError(MARK + "omegas must be a non-empty (F,) array of finite values "
                             f">= 0, got shape {omegas.shape}.")
        return self.transfer(1j * omegas)

    def poles(self) -> Complex[Array, " N"]:
        """The N eigenvalues of (A, E)."""
        return jnp.asarray(np.linalg.eigvals(self.standard()[0]))

    def is_stable(self) -> bool:
        """Whether every pole has Re < 0 (strictly: a pole on the axis has no H2 norm)."""
        return bool(np.all(np.asarray(self.poles()).real < 0))

    def _check_stable(self, what: str) -> None:
        poles = np.asarray(self.poles())
        worst = poles[np.argmax(poles.real)]
        if not worst.real < 0:
            raise ValueError(MARK + f"{what}: the model has a pole at {worst:.6g} (Re >= 0), so "
                             "its norm is infinite; only a stable model has one.")

    def h2_norm(self) -> Float[Array, ""]:
        """||G||_H2 = sqrt(tr(C P C^T)), A P + P A^T + B B^T = 0 (Bartels-Stewart, module
        docstring). Refused for a model with a pole in Re s >= 0, also under ``jit``.
        Differentiable in the model's matrices (``jax.grad`` through ``feedback``, say):
        d tr(C P C^T) = 2 tr(C P dC^T) + 2 tr(Q dA P) + 2 tr(Q dB B^T) with the observability
        Gramian A^T Q + Q A + C^T C = 0 (the adjoint of the Lyapunov equation; Wilson, "Optimum
        solution of model-reduction problem", Proc. IEE 117 (1970) 1161-1165)."""
        traced = is_traced(self.a)
        if not traced:  # eagerly, the one-line refusal names the pole
            self._check_stable("h2_norm")
        a, b = jnp.linalg.solve(self.e, self.a), jnp.linalg.solve(self.e, self.b)
        squared = _h2_squared(a, b, self.c)
        if traced:  # under jit or grad: the same refusal, without the pole's value
            rightmost = jnp.max(jnp.real(jnp.linalg.eigvals(jax.lax.stop_gradient(a))))
            squared = eqx.error_if(squared, ~(rightmost < 0),
                                   MARK + "h2_norm: the model has a pole in Re s >= 0, so its "
                                   "norm is infinite; only a stable model has one.")
        return jnp.sqrt(jnp.maximum(squared, 0.0))

    def feedback(self, gain, inputs, outputs) -> "LTIModel":
        """The closed loop u_I = -K y_O: inputs ``inputs`` (indices I) driven by ``gain`` K
        (len(I), len(O)) (a scalar for one loop) times outputs ``outputs`` (indices O); the
        other inputs and outputs remain, A -> A - B_I K C_O. A damper of coefficient c on a
        channel pair (a force at its DOF, the velocity across it) is the loop K = c, so a model
        reduced at one coefficient c_0 gives every other as ``feedback(c - c_0, ...)``
        (Veselic's damping as a feedback). Differentiable in ``gain`` (``jax.grad``)."""
        m, q = self.b.shape[1], self.c.shape[0]
        inputs, outputs = _channels(inputs, m, "inputs"), _channels(outputs, q, "outputs")
        rest_in = [j for j in range(m) if j not in inputs]
        rest_out = [j for j in range(q) if j not in outputs]
        if not rest_in or not rest_out:
            used = "input" if not rest_in else "output"
            raise ValueError(MARK + f"feedback: the loop uses every {used}; at least one input "
                             "and one output must remain.")
        gain = jnp.asarray(gain, dtype=float)
        if gain.ndim == 0:
            gain = jnp.full((len(inputs), len(outputs)), gain)
        if gain.shape != (len(inputs), len(outputs)):
            raise ValueError(MARK + f"feedback: gain must be a scalar or ({len(inputs)}, "
                             f"{len(outputs)}), got shape {gain.shape}.")
        gain = eqx.error_if(gain, ~jnp.all(jnp.isfinite(gain)),
                            MARK + "feedback: gain must be finite.")
        a = self.a - self.b[:, inputs] @ gain @ self.c[outputs, :]
        return eqx.tree_at(lambda model: (model.a, model.b, model.c), self,
                           (a, self.b[:, rest_in], self.c[rest_out, :]))

    def hinf_norm(self) -> Float[Array, ""]:
        """||G||_inf = sup_omega sigma_max(G(i omega)) by level sets of the Hamiltonian
        (``hinf_norm``: Boyd-Balakrishnan, Bruinsma-Steinbuch). Refused where unstable."""
        self._check_stable("hinf_norm")
        return jnp.asarray(_hinf_norm(*self.standard())[0])

    def oscillators(self) -> tuple[np.ndarray, ...]:
        """The same G(s) as r decoupled oscillators, (M, D, K, B, C_x, C_v) with M = I, D and K
        diagonal (``second_order`` takes them back): each conjugate pair of poles lambda with
        residue R gives (2 Re R s - 2 Re(R conj(lambda))) / (s^2 - 2 Re(lambda) s + |lambda|^2),
        two real poles lambda_1, lambda_2 the same with D = -(lambda_1 + lambda_2), K =
        lambda_1 lambda_2. So an ``H2Optimal`` model of a single-input map is a second-order
        model of r DOFs too. For one input (m = 1) and an even number of real poles; a
        defective pencil (a double pole with one eigenvector) is refused."""
        a, b, c = self.standard()
        if b.shape[1] != 1:
            raise ValueError(MARK + f"oscillators: only a single-input model (m = 1) has this "
                             f"form in general, got m = {b.shape[1]}.")
        lam, vectors = np.linalg.eig(a)
        if np.linalg.cond(vectors) > 1e12:
            raise ValueError(MARK + "oscillators: the poles are (nearly) defective; their "
                             "eigenvectors are not a basis.")
        residues = (c @ vectors) * np.linalg.solve(vectors, b)[:, 0]  # (q, N)
        pairs = [(j, None) for j in np.flatnonzero(lam.imag > 0)]
        real = np.flatnonzero(lam.imag == 0)
        if real.size % 2:
            raise ValueError(MARK + "oscillators: an odd number of real poles cannot pair up.")
        real = real[np.argsort(lam[real].real)]
        pairs += list(zip(real[::2], real[1::2]))
        r = len(pairs)
        damping, stiffness = np.zeros(r), np.zeros(r)
        cx, cv = np.zeros((c.shape[0], r)), np.zeros((c.shape[0], r))
        for i, (j, k) in enumerate(pairs):
            if k is None:
                damping[i], stiffness[i] = -2 * lam[j].real, abs(lam[j]) ** 2
                cv[:, i] = 2 * residues[:, j].real
                cx[:, i] = -2 * (residues[:, j] * lam[j].conj()).real
            else:
                damping[i], stiffness[i] = -(lam[j] + lam[k]).real, (lam[j] * lam[k]).real
                cv[:, i] = (residues[:, j] + residues[:, k]).real
                cx[:, i] = -(residues[:, j] * lam[k] + residues[:, k] * lam[j]).real
        return np.eye(r), np.diag(damping), np.diag(stiffness), np.ones((r, 1)), cx, cv

    def __sub__(self, other):
        """The error system ``self - other`` (``ErrorModel``)."""
        from .io_model import ErrorModel, IOModel

        if not isinstance(other, LTIModel | IOModel):
            return NotImplemented
        return ErrorModel(self, other)


@jax.jit
def _transfer(e, a, b, c, s):
    e, a, b, c = (x.astype(jnp.complex128) for x in (e, a, b, c))
    return jax.lax.map(lambda sigma: c @ jnp.linalg.solve(sigma * e - a, b), s)


@jax.custom_jvp
def _schur(a):
    return jax.scipy.linalg.schur(a.astype(jnp.complex128), output="complex")


@_schur.defjvp
def _schur_jvp(primals, tangents):
    raise ValueError(MARK + "ErrorModel.h2_norm is differentiable in the larger model only (a "
                     "reduced or dense model's Schur form has no derivative); keep the smaller "
                     "model fixed.")


@jax.jit
def sylvester(a1, a2, rhs):
    """X with A_1 X + X A_2^T = rhs (no eigenvalue of A_1 the negative of one of A_2): Bartels-
    Stewart on both complex Schur forms, one triangular solve per column; complex128."""
    t1, q1 = _schur(a1)  # A_1 = Q_1 T_1 Q_1^H
    t2, q2 = _schur(a2.T)  # A_2^T = Q_2 T_2 Q_2^H
    f = q1.conj().T @ rhs.astype(jnp.complex128) @ q2
    eye = jnp.eye(t1.shape[0], dtype=jnp.complex128)

    def column(y, j):  # (T_1 + t_jj I) y_j = F_j - sum_{i<j} y_i t_ij, Y = Q_1^H X Q_2
        right = f[:, j] - y @ t2[:, j]
        y_j = jax.scipy.linalg.solve_triangular(t1 + t2[j, j] * eye, right, lower=False)
        return y.at[:, j].set(y_j), None

    y, _ = jax.lax.scan(column, jnp.zeros_like(f), jnp.arange(t2.shape[0]))
    return q1 @ y @ q2.conj().T


def _channels(indices, count: int, name: str) -> list[int]:
    indices = [indices] if isinstance(indices, int) else list(indices)
    if not indices or any(isinstance(j, bool) or not isinstance(j, int) or not 0 <= j < count
                          for j in indices) or len(set(indices)) < len(indices):
        raise ValueError(MARK + f"feedback: {name} must be distinct indices in [0, {count - 1}],"
                         f" got {indices!r}.")
    return indices


@jax.custom_jvp
def _h2_squared(a, b, c):
    """tr(C P C^T) with A P + P A^T + B B^T = 0 (E = I, every pole stable)."""
    gramian = jnp.real(sylvester(a, a, -b @ b.T))
    return jnp.trace(c @ gramian @ c.T)


@_h2_squared.defjvp
def _h2_squared_jvp(primals, tangents):
    a, b, c = primals
    da, db, dc = tangents
    gramian = jnp.real(sylvester(a, a, -b @ b.T))
    observability = jnp.real(sylvester(a.T, a.T, -c.T @ c))
    value = jnp.trace(c @ gramian @ c.T)
    return value, 2 * (jnp.sum(c @ gramian * dc) + jnp.sum(observability * (da @ gramian).T)
                       + jnp.sum(observability * (db @ b.T).T))


@jax.jit
def sylvester_inner(first, second) -> Float[Array, ""]:
    """Re tr(C_1 X C_2^T) with A_1 X + X A_2^T + B_1 B_2^T = 0 for two dense models (a, b, c)
    with E = I, every pole of each stable: the H2 inner product <G_1, G_2> (``sylvester``),
    O(N_1^3 + N_2^3 + N_1 N_2^2)."""
    a1, b1, c1 = first
    a2, b2, c2 = second
    x = sylvester(a1, a2, -b1 @ b2.T)
    return jnp.real(jnp.trace(c1.astype(jnp.complex128) @ x @ c2.T.astype(jnp.complex128)))
