"""H2-optimal reduction of an input-output map: IRKA in the modal coordinates of the full system.

The iterative rational Krylov algorithm (Gugercin, Antoulas & Beattie, "H2 model reduction for
large-scale linear dynamical systems", SIAM J. Matrix Anal. Appl. 30 (2008) 609-638, Alg. 4.1)
seeks a reduced G_r of N = 2r states that meets the first-order conditions of a local minimum of
||G - G_r||_H2 (Meier & Luenberger): at the mirror image sigma_j = -lambda_j of each of its
poles, tangentially along its residue's directions (c_j, b_j),
G(sigma_j) b_j = G_r(sigma_j) b_j, c_j^T G(sigma_j) = c_j^T G_r(sigma_j),
c_j^T G'(sigma_j) b_j = c_j^T G_r'(sigma_j) b_j. Each sweep builds the two-sided (Petrov-
Galerkin) projection that interpolates so at the current shifts, V_j = (sigma_j E - A)^-1 B b_j,
W_j = (sigma_j E - A)^-T C^T c_j, G_r = (W^T E V, W^T A V, W^T B, C V), and moves the shifts to
the mirrored poles of G_r until they settle (``tolerance``, relative). A conjugate pair of shifts
gives the real columns Re and Im of one solve, so G_r is real.

The full model enters in its M-orthonormal modal coordinates (``_model/pencil``): A = [[0, I],
[-Omega^2, -C]], E = I, so each solve is sigma^2 I + sigma C + Omega^2 (Woodbury on the dampers:
O(n k^2)) and (sigma E - A)^-T needs the same matrix (C is symmetric). A sweep is O(r n k^2 + r^2
n) after the modes. The start (``shifts=None``) is the mirrored poles of the r modes with the
largest H2 share b^2 (c_x^2 / omega^2 + c_v^2) / (2 C_ll) of the decoupled modal oscillators
(modes no damper reaches carry none): a dominant-pole modal truncation, stable and close to the
optimum for a lightly damped chain. A reduced model whose pole crosses into Re s >= 0 mirrors it
back (sigma = |Re lambda| + i Im lambda), and the result says whether it is stable.
"""

import warnings

import equinox as eqx
import numpy as np

from .._errors import MARK
from .._model.pencil import modal_pencil
from .._model.reduced import ReductionStats
from .._model.system import SecondOrderSystem
from .base import AbstractIOReduction
from .lti import LTIModel


class _Modal(eqx.Module):
    """The full IO model in modal coordinates (numpy): omega; the modal damping C = diag(c) +
    G diag(w) G^T (+ a dense internal part); the inputs U^T B (n, m), outputs C_x U, C_v U."""

    omega: np.ndarray
    diagonal: np.ndarray
    factor: np.ndarray
    weights: np.ndarray
    dense: np.ndarray | None
    inputs: np.ndarray
    cx: np.ndarray
    cv: np.ndarray
    modes: np.ndarray  # U (n, n), M-orthonormal: x = U eta

    def damp(self, z):
        """C z for modal vectors z (n,) or (n, p)."""
        out = (self.diagonal * z.T).T + self.factor @ (self.weights * (self.factor.T @ z).T).T
        return out if self.dense is None else out + self.dense @ z

    def solve(self, sigma, rhs):
        """(sigma^2 I + sigma C + Omega^2)^-1 rhs: Woodbury on the dampers' rank k (O(n k^2)),
        dense with a dense internal damping."""
        delta = sigma**2 + self.omega**2 + sigma * self.diagonal
        if self.dense is not None:
            matrix = np.diag(delta) + sigma * (self.dense + (self.factor * self.weights)
                                               @ self.factor.T)
            return np.linalg.solve(matrix, rhs)
        y = (rhs.T / delta).T
        scaled = self.factor / delta[:, None]
        inner = np.eye(self.weights.size) + sigma * (self.factor.T @ scaled) * self.weights
        return y - scaled @ (sigma * (self.weights * np.linalg.solve(inner, self.factor.T @ y
                                                                        ).T).T)

    def transfer(self, sigma):
        """G(sigma) and G'(sigma), (q, m) each."""
        x = self.solve(sigma, self.inputs.astype(complex))
        out = self.cx + sigma * self.cv
        dx = -self.solve(sigma, 2 * sigma * x + self.damp(x))
        return out @ x, self.cv @ x + out @ dx


def _modal(io) -> _Modal:
    from .io_model import _coordinates

    system, b, cx, cv = _coordinates(io)
    pencil = modal_pencil(system)
    modes = np.asarray(pencil.modes)
    dense = None if pencil.dense is None else np.asarray(pencil.dense)
    return _Modal(np.asarray(pencil.omega), np.asarray(pencil.diagonal),
                  np.asarray(pencil.factor), np.asarray(pencil.weights), dense,
                  modes.T @ np.asarray(b), np.asarray(cx) @ modes, np.asarray(cv) @ modes,
                  modes)


def _real_columns(columns, shifts):
    """Re and Im of each column of a shift in the upper half-plane, the real column of a real
    shift, orthonormalised (QR): the real span of the conjugate-closed set."""
    parts = []
    for column, sigma in zip(columns.T, shifts):
        parts += [column.real] if sigma.imag == 0 else [column.real, column.imag]
    q, _ = np.linalg.qr(np.stack(parts, axis=1))
    return q


def _upper(values):
    """One of each conjugate pair (Im >= 0), mirrored into Re > 0."""
    values = values[values.imag >= 0]
    return np.abs(values.real) + 1j * values.imag


def _project(modal: _Modal, shifts, right, left):
    """G_r of the two-sided projection at the shifts (upper half-plane) along the tangential
    directions ``right`` (m, s) and ``left`` (q, s): (E_r, A_r, B_r, C_r) real."""
    n = modal.omega.shape[0]
    v_cols, w_cols = [], []
    for j, sigma in enumerate(shifts):
        x = modal.solve(sigma, modal.inputs @ right[:, j])
        y = modal.solve(sigma, (modal.cx + sigma * modal.cv).T @ left[:, j])
        v_cols.append(np.concatenate([x, sigma * x]))
        w_cols.append(np.concatenate([sigma * y + modal.damp(y) - modal.cv.T @ left[:, j],
                                      y]))
    v = _real_columns(np.stack(v_cols, axis=1), shifts)
    w = _real_columns(np.stack(w_cols, axis=1), shifts)
    av = np.concatenate([v[n:], -(modal.omega**2)[:, None] * v[:n] - modal.damp(v[n:])])
    return (w.T @ v, w.T @ av, w[n:].T @ modal.inputs,
            modal.cx @ v[:n] + modal.cv @ v[n:])


def _poles_and_directions(e, a, b, c):
    """The poles of (A, E) and their residues' directions: c_j = C x_j, b_j = (X^-1 E^-1 B)_j."""
    lam, x = np.linalg.eig(np.linalg.solve(e, a))
    return lam, np.linalg.solve(x, np.linalg.solve(e, b)).T, c @ x


def _settled(new, old) -> float:
    """The largest relative distance from a new shift to the nearest old one."""
    if new.size != old.size:
        return np.inf
    return float(np.max(np.min(np.abs(new[:, None] - old[None, :]), axis=1) / np.abs(new)))


def _start(modal: _Modal, rank: int):
    """The mirrored poles of the r most dominant decoupled modal oscillators (module docstring)
    and unit directions."""
    cll = modal.diagonal + modal.factor**2 @ modal.weights
    if modal.dense is not None:
        cll = cll + np.diag(modal.dense)
    share = (np.sum(modal.inputs**2, axis=1)
             * np.sum((modal.cx / modal.omega) ** 2 + modal.cv**2, axis=0))
    share = np.where(cll > 0, share / np.where(cll > 0, 2 * cll, 1.0), 0.0)
    chosen = np.argsort(-share, kind="stable")[:rank]
    half = cll[chosen] / 2
    root = np.sqrt((modal.omega[chosen] ** 2 - half**2).astype(complex))
    shifts = half + 1j * np.abs(root)
    # an overdamped mode gives two real shifts: half -+ sqrt(half^2 - omega^2)
    over = root.imag != 0
    shifts = np.concatenate([shifts[~over].astype(complex), half[over] - root[over].imag,
                             half[over] + root[over].imag])
    return shifts


def _optimality(modal: _Modal, model, lam, right, left) -> float:
    """The largest relative mismatch of the first-order H2 conditions (module docstring) at the
    mirrored poles of G_r."""
    e, a, b, c = model
    worst = 0.0
    for j in np.flatnonzero(lam.imag >= 0):
        sigma = -lam[j]
        g, dg = modal.transfer(sigma)
        inverse = np.linalg.solve(sigma * e - a, np.concatenate([b, e], axis=1))
        x, dxe = inverse[:, : b.shape[1]], inverse[:, b.shape[1]:]
        gr, dgr = c @ x, -(c @ dxe @ x)
        l_j, r_j = left[:, j], right[:, j]
        scale = np.linalg.norm(l_j) * np.linalg.norm(r_j)
        terms = [(np.linalg.norm((g - gr) @ r_j), np.linalg.norm(g) * scale),
                 (np.linalg.norm(l_j @ (g - gr)), np.linalg.norm(g) * scale),
                 (abs(l_j @ (dg - dgr) @ r_j), np.linalg.norm(dg) * scale)]
        worst = max(worst, *(gap / size for gap, size in terms))
    return worst


def irka(project, shifts, right, left, tolerance: float, iterations: int):
    """IRKA's sweeps (module docstring) with ``project(shifts, right, left) -> (E, A, B, C)``:
    (the model at the final shifts, those shifts, the relative change per sweep)."""
    changes = []
    for _ in range(iterations):
        lam, right_all, left_all = _poles_and_directions(*project(shifts, right, left))
        keep = lam.imag >= 0
        new = _upper(lam)
        changes.append(_settled(new, shifts))
        # sigma = -conj(lambda) in the upper half-plane interpolates along the conjugate
        # directions (the conditions at -lambda along (b, c), conjugated)
        shifts, right, left = new, right_all[:, keep].conj(), left_all[:, keep].conj()
        if changes[-1] < tolerance:
            break
    # the model at the settled shifts (its own poles are the shifts' mirror to tolerance)
    return project(shifts, right, left), shifts, changes


class H2Optimal(AbstractIOReduction):
    """IRKA (module docstring): a reduced model of 2 ``rank`` states meeting the first-order
    H2-optimality conditions, as an ``LTIModel``. ``tolerance``: the shifts' relative change
    at which it stops; ``iterations``: the most sweeps (a run that does not settle within
    them warns, and its model is the last sweep's); ``shifts``: a start of your own (one
    of each conjugate pair, Re > 0; default the dominant modes). Stats: ``shifts``,
    ``iterations``, ``converged``, ``changes``, and ``optimality``: the largest relative
    mismatch of the interpolation conditions at the mirrored poles."""

    rank: int = eqx.field(static=True)
    tolerance: float = eqx.field(static=True, default=1e-8)
    iterations: int = eqx.field(static=True, default=100)
    shifts: tuple[complex, ...] | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if isinstance(self.rank, bool) or not isinstance(self.rank, int) or self.rank < 1:
            raise ValueError(MARK + f"H2Optimal: rank must be an integer >= 1, got {self.rank!r}.")
        if not 0 < self.tolerance < 1:
            raise ValueError(MARK + f"H2Optimal: tolerance must be in (0, 1), got "
                             f"{self.tolerance!r}.")
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, int) or (
                self.iterations < 1):
            raise ValueError(MARK + f"H2Optimal: iterations must be an integer >= 1, got "
                             f"{self.iterations!r}.")

    def reduce_io(self, io) -> LTIModel:
        """The IRKA model of the IOModel ``io`` of a full system."""
        _, model, stats = self._irka(io)
        return LTIModel(*model[1:], model[0], stats)

    def _irka(self, io):
        """(the modal data, the model (E, A, B, C) at the settled shifts, its stats)."""
        if not isinstance(io.model, SecondOrderSystem):
            raise ValueError(MARK + f"{type(self).__name__}: the IOModel must be that of a full "
                             "system.")
        n = io.size
        if self.rank > n:
            raise ValueError(MARK + f"{type(self).__name__}: rank = {self.rank} is out of "
                             f"reach: the system has n = {n} DOFs; choose rank <= {n}.")
        modal = _modal(io)
        q, m = io.shape
        if self.shifts is None:
            shifts = _start(modal, self.rank)
        else:
            shifts = np.asarray(self.shifts, dtype=complex)
            if np.any(shifts.real <= 0) or np.any(~np.isfinite(shifts)):
                raise ValueError(MARK + f"{type(self).__name__}: shifts must be finite with "
                                 "Re > 0.")
        right = np.ones((m, shifts.size), complex) / np.sqrt(m)
        left = np.ones((q, shifts.size), complex) / np.sqrt(q)
        model, shifts, changes = irka(lambda *data: _project(modal, *data), shifts, right, left,
                                      self.tolerance, self.iterations)
        lam, right_all, left_all = _poles_and_directions(*model)
        stats = ReductionStats(
            "H2Optimal", self.rank, shifts=tuple(complex(z) for z in shifts),
            iterations=len(changes), converged=bool(changes[-1] < self.tolerance),
            changes=tuple(changes),
            optimality=float(_optimality(modal, model, lam, right_all, left_all)))
        if model[0].shape[0] != 2 * self.rank:
            raise ValueError(MARK + f"{type(self).__name__}: rank = {self.rank} is out of "
                             f"reach: the shifts gave {model[0].shape[0]} states, not "
                             f"{2 * self.rank}.")
        if not stats.converged:
            warnings.warn(f"{type(self).__name__}: the shifts did not settle to {self.tolerance:g} "
                          f"in {len(changes)} sweeps (last change {changes[-1]:.1e}); the model "
                          "is the last sweep's and misses the H2 optimality conditions by "
                          f"{stats.optimality:.1e} (stats.optimality). Try another rank or a "
                          "start of your own (shifts=...).", stacklevel=6)
        return modal, model, stats


class StructuredH2(H2Optimal):
    """Structure-preserving interpolation at the H2-optimal shifts: ``H2Optimal(rank)``'s IRKA
    (same arguments) gives the shifts sigma_j and tangential directions (b_j, c_j) of a
    first-order H2-optimal model; the reduced model is then the Galerkin (one-sided) model of
    M, D, K on the span of Re and Im of the right and left responses X_j = (sigma_j^2 M +
    sigma_j D + K)^-1 B b_j and Y_j = (sigma_j^2 M + sigma_j D + K)^-1 (C_x + sigma_j C_v)^T c_j,
    orthonormalised. M, D and K are symmetric, so V = W and the model interpolates G
    bitangentially, with its derivative, at every shift (Beattie & Gugercin, "Interpolatory
    projection methods for structure-preserving model reduction", Systems & Control Letters 58
    (2009) 225-232, where the shifts come from IRKA on the first-order form, as here).

    What it keeps that ``H2Optimal`` does not: the result is an ``IOModel`` of a second-order
    Galerkin ``ReducedModel`` (symmetric M_r, D_r, K_r; D_r >= 0, so no pole in Re s > 0 for
    any coefficients), and its dampers stay dampers: ``galerkin`` of any other design on its
    basis is that design's reduced model, which is how ``Coefficients(through=...)`` searches
    coefficients on it. What it costs: up to 4 ``rank`` DOFs (two per side per complex shift;
    the columns that are independent, ``stats.rank``) for the interpolation of ``rank``
    shifts. Stats: the IRKA's ``shifts``, ``iterations``, ``converged``, ``changes``, and
    ``optimality``: the largest relative mismatch of that interpolation (G b_j, c_j^T G,
    c_j^T G' b_j at the shifts) of the returned model."""

    def reduce_io(self, io):
        """The IOModel of the Galerkin model of ``io``'s full system (class docstring)."""
        from .._model.reduced import ReducedModel, galerkin
        from .interpolatory import kept_directions
        from .io_model import IOModel, _first_order_of

        modal, model, stats = self._irka(io)
        lam, right_all, left_all = _poles_and_directions(*model)
        columns = []
        for j in np.flatnonzero(lam.imag >= 0):
            sigma = -lam[j]  # the mirrored pole, with the directions of lambda_j's residue
            x = modal.solve(sigma, modal.inputs @ right_all[:, j])
            y = modal.solve(sigma, (modal.cx + sigma * modal.cv).T @ left_all[:, j])
            columns += [x.real, x.imag, y.real, y.imag] if sigma.imag else [x.real, y.real]
        columns = modal.modes @ np.stack(columns, axis=1)
        basis = kept_directions(np.zeros((columns.shape[0], 0)), columns,
                                float(np.max(np.linalg.norm(columns, axis=0))))
        reduced = galerkin(io.model, basis)
        out = IOModel(reduced, io.inputs, *io.outputs())
        first = _first_order_of(out)
        e = np.eye(first[0].shape[0])
        stats = ReductionStats(
            "StructuredH2", int(basis.shape[1]), shifts=stats.shifts,
            iterations=stats.iterations, converged=stats.converged, changes=stats.changes,
            optimality=float(_optimality(modal, (e, *(np.asarray(x) for x in first)), lam,
                                         right_all, left_all)))
        return IOModel(ReducedModel(reduced.system, reduced.basis, stats), io.inputs,
                       *io.outputs())

