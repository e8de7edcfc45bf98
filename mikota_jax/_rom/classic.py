"""The classic projection bases beside POD: modal truncation, and modal truncation with a static
(residual-flexibility) correction for the damper and load directions.

Both return an (n, r) basis with orthonormal columns, for ``galerkin`` and everything that takes
a ``ReducedModel`` (solvers, objectives, ``jax.grad``), like ``POD.basis``:

* **Modal truncation**: the r lowest undamped modes (``modal_decomposition``; eq. 2.4 for
  Mikota's chain), orthonormalised. Exact for an undamped free vibration that starts in their
  span; a damper couples every mode, so it converges slowly where dampers are strong.
* **Modal + static correction**: the same modes and the static responses K^-1 b of every damper
  direction b (e_j for a grounded damper at DOF j, the two DOFs of a split one, e_i - e_j for a
  relative one) and of the ``loads`` given. span(U_r, K^-1 B) = span(U_r, (K^-1 - U_r
  Omega_r^-2 U_r^T) B), the residual flexibility of Craig & Bampton's method and of the
  mode-acceleration method (Craig & Kurdila, "Fundamentals of Structural Dynamics", 2006,
  ch. 14; Besselink et al., "A comparison of model reduction techniques from structural dynamics,
  numerical mathematics and systems and control", J. Sound Vib. 332 (2013) 4403-4422): the
  damper forces act on the truncated modes through their static part. A hand-built check on
  FastOptimalDamping.jl's n = 801 example took an average-energy trace from 1.3e-2 (100 modes)
  to 1.6e-5 relative with the three damper directions added.

The static solves are O(n) for a chain (tridiagonal K), dense otherwise.
"""

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from .._custom_types import Basis
from .._errors import MARK, as_float
from .._limits import CHAIN_MODES_FROM
from .._model.chain_modes import held_chain_modes
from .._model.dampers import Dampers
from .._model.modal import modal_decomposition
from .._model.operators import Diagonal, SymmetricTridiagonal
from .._model.system import SecondOrderSystem
from .._solver.implicit import symmetric_tridiagonal_solve

# a static direction whose part outside the kept modes is below this (relative) adds nothing
_DEPENDENT = 1e-10
# a direction whose part outside a basis is as small as 1e-13 of its length can still count
# (the held modes and the third moments, Section 5, p = 150, c = 1000: dJ/dp 1.8e-2 off with it,
# 5e-2 without; see extend_basis); below this it is rounding
_KRYLOV_DEPENDENT = 1e-14


def _check(system, rank: int) -> None:
    if not isinstance(system, SecondOrderSystem):
        raise ValueError(MARK + f"system must be a SecondOrderSystem, got "
                         f"{type(system).__name__}.")
    if isinstance(rank, bool) or not isinstance(rank, int) or not 1 <= rank <= system.size:
        raise ValueError(MARK + f"rank must be an integer in 1..{system.size}, got {rank!r}.")


def modal_basis(system: SecondOrderSystem, rank: int) -> Basis:
    """The r = ``rank`` lowest undamped modes of ``system`` as an (n, r) orthonormal basis. For
    a fixed-free chain of n >= 256, eagerly and under ``jit``, O(n r): only those r modes, by
    bisection and twisted factorisations (``held_chain_modes`` with nothing held), never the
    n x n ones."""
    _check(system, rank)
    chain = _long_chain(system)
    if chain is not None:
        modes = held_chain_modes(*chain, [], rank)[1]
    else:
        modes = modal_decomposition(system)[1][:, :rank]
    q, _ = jnp.linalg.qr(modes)
    return q


def _long_chain(system: SecondOrderSystem):
    """(masses, springs) of a fixed-free chain of n >= ``CHAIN_MODES_FROM``, else None: decided
    from the structure (the operators' types and n), the same eagerly and under ``jit``."""
    stiffness, mass = system.stiffness, system.mass
    if not (isinstance(mass, Diagonal) and isinstance(stiffness, SymmetricTridiagonal)
            and stiffness.springs is not None and system.size >= CHAIN_MODES_FROM):
        return None
    return mass.diagonal, stiffness.springs


def damper_directions(system: SecondOrderSystem) -> jnp.ndarray:
    """(n, k) the directions B of the system's dampers (D = B diag(w) B^T): a grounded damper
    gives its one or two DOFs' unit vectors, a relative damper e_i - e_j; (n, 0) without."""
    if not isinstance(system.damping, Dampers):
        return jnp.zeros((system.size, 0))
    dampers, n = system.damping, system.size
    left, right, _, _ = dampers._grounded_weights()
    g, p = left.shape[0], dampers.pair_count
    columns = jnp.arange(2 * g + p)
    b = jnp.zeros((n, 2 * g + p)).at[jnp.concatenate([left, right]), columns[:2 * g]].set(1.0)
    if p:
        b = b.at[dampers.pairs[:, 0], columns[2 * g:]].set(1.0)
        b = b.at[dampers.pairs[:, 1], columns[2 * g:]].add(-1.0)
    return b


def _stiffness_solve(system: SecondOrderSystem):
    """Y -> K^-1 Y for (n, p) Y: O(n p) for a chain (tridiagonal K), a dense solve otherwise."""
    stiffness = system.stiffness
    if isinstance(stiffness, SymmetricTridiagonal) and not stiffness.links:
        return lambda y: symmetric_tridiagonal_solve(stiffness.diagonal, stiffness.off_diagonal, y)
    matrix = stiffness.as_matrix()
    return lambda y: jnp.linalg.solve(matrix, y)


def _force_columns(system: SecondOrderSystem, inputs, name: str) -> jnp.ndarray:
    inputs = as_float(inputs, name)
    inputs = inputs[:, None] if inputs.ndim == 1 else inputs
    if inputs.ndim != 2 or inputs.shape[0] != system.size or inputs.shape[1] < 1:
        raise ValueError(MARK + f"{name} must be (n,) or (n, s) with n = {system.size}, got "
                         f"{inputs.shape}.")
    return inputs


def static_moments(system: SecondOrderSystem, forces, count: int) -> jnp.ndarray:
    """(n, s count) the static responses R_0 = K^-1 F of the (n, s) ``forces`` and their
    mass-weighted Krylov successors R_j = K^-1 M R_(j-1), j < ``count`` (each column scaled to
    unit length): the moments at s = 0 of H(s) = (s^2 M + K)^-1 F, undamped (Bai & Su's
    second-order Krylov space with D = 0). With the r lowest modes U_r they span U_r and the
    residual flexibility (K^-1 - U_r Omega_r^-2 U_r^T) F and its higher-order terms in omega^2
    (the modal truncation augmentation vectors of Dickens, Nakagawa & Wittbrodt, Computers &
    Structures 62 (1997) 985-998). Pure jax, fixed shape: jit- and vmap-compatible."""
    solve = _stiffness_solve(system)
    moments = [solve(forces)]
    for _ in range(count - 1):
        moments.append(solve(jax.vmap(system.mass.mv, in_axes=1, out_axes=1)(moments[-1])))
    moments = jnp.concatenate(moments, axis=1)
    norms = jnp.linalg.norm(moments, axis=0)
    return moments / jnp.where(norms > 0, norms, 1.0)[None, :]


def extend_basis(basis: Basis, extra, tol: float = _KRYLOV_DEPENDENT) -> Basis:
    """``basis`` (n, r), orthonormal, followed by the directions of ``extra`` ((n,) or (n, s))
    outside its span, orthonormal: the left singular vectors of the part of ``extra`` outside
    span(basis) whose singular values exceed ``tol`` times the largest column norm of ``extra``
    (e.g. a POD basis plus undamped modes, or plus snapshots of a new design). The size depends on
    the values: call it outside ``jit``, as POD's rank rule. The default keeps every direction
    above rounding: a direction whose part outside the basis is 1e-11 of its length still
    moved a Galerkin J by 1e-7 (the Section 5 box: the hierarchical estimate's fine model 6.2e-7
    off J with the directions below 1e-10 dropped, 9.6e-8 with them), and each kept direction
    is made orthogonal to the basis once more."""
    basis = np.asarray(basis, dtype=float)
    extra = np.asarray(extra, dtype=float)
    extra = extra[:, None] if extra.ndim == 1 else extra
    if basis.ndim != 2 or extra.ndim != 2 or extra.shape[0] != basis.shape[0]:
        raise ValueError(MARK + f"extra must have shape ({basis.shape[0]},) or "
                         f"({basis.shape[0]}, s) for a basis of shape {basis.shape}, got "
                         f"{extra.shape}.")
    if not (np.isfinite(tol) and 0 <= tol < 1):
        raise ValueError(MARK + f"tol must lie in [0, 1), got {tol!r}.")
    rest = extra - basis @ (basis.T @ extra)
    rest = rest - basis @ (basis.T @ rest)  # twice is enough (Kahan-Parlett)
    u, s, _ = np.linalg.svd(rest, full_matrices=False)
    scale = float(np.max(np.linalg.norm(extra, axis=0))) if extra.size else 0.0
    u = u[:, s > tol * scale]
    # a direction from a small singular value s is orthogonal to the basis only to ~eps / s:
    # once more against the basis, then orthonormal among themselves
    u, _ = np.linalg.qr(u - basis @ (basis.T @ u))
    return jnp.asarray(np.concatenate([basis, u], axis=1))


def modal_static_basis(system: SecondOrderSystem, rank: int, *, loads=None,
                       dampers: bool = True, moments: int = 1, states=None) -> Basis:
    """The ``rank`` lowest undamped modes and the static responses K^-1 b of the damper
    directions (``dampers=True``) and of ``loads`` ((n,) or (n, s) force directions), as an
    orthonormal (n, r + s') basis: s' the static directions not already in the modes' span (to
    1e-10 relative), so the size can be below rank + s and depends on the values (call it
    outside ``jit``, as POD's rank rule). ``moments`` > 1 adds (K^-1 M)^j K^-1 b for
    j < ``moments`` (``static_moments``): the static correction to higher order in omega^2,
    which a damper strong enough to pin its DOF can need (Section 5 scene, x_3(0) = 1, the
    damper at p = 45.6 with c = 62: J 2.6e-3 off with 98 modes + one moment, 2.6e-5 with two;
    8.2e-4 and 2.2e-6 with 120 modes; where the start is smooth it changes little). Moments
    that add nothing above 1e-10 are dropped. ``states`` ((n,) or (n, s)) are displacement
    directions kept as they are (``extend_basis``), e.g. the initial displacement and velocity:
    see ``craig_bampton_basis``. See the module docstring."""
    _check(system, rank)
    if isinstance(moments, bool) or not isinstance(moments, int) or moments < 1:
        raise ValueError(MARK + f"moments must be an integer >= 1, got {moments!r}.")
    columns = [damper_directions(system)] if dampers else []
    if loads is not None:
        columns.append(_force_columns(system, loads, "loads"))
    states = None if states is None else _force_columns(system, states, "states")
    basis = _modal_static(system, rank, columns, moments)
    return basis if states is None else extend_basis(basis, states)[:, : system.size]


def _modal_static(system: SecondOrderSystem, rank: int, columns: list, moments: int) -> Basis:
    modes = modal_basis(system, rank)
    if not columns or rank == system.size:
        return modes
    forces = jnp.concatenate(columns, axis=1)
    static = static_moments(system, forces, moments)
    scale = float(jnp.max(jnp.linalg.norm(static, axis=0)))
    # the part outside the kept modes, twice (classical Gram-Schmidt loses orthogonality once)
    for _ in range(2):
        static = static - modes @ (modes.T @ static)
    q, r = jnp.linalg.qr(static)
    keep = np.flatnonzero(np.abs(np.diag(np.asarray(r))) > _DEPENDENT * scale)
    return jnp.concatenate([modes, q[:, keep]], axis=1)[:, : system.size]


def _damper_weights(system: SecondOrderSystem) -> np.ndarray:
    """(k,) the weights w of D = B diag(w) B^T, in ``damper_directions``' column order."""
    if not isinstance(system.damping, Dampers):
        return np.zeros(0)
    _, _, c_left, c_right = system.damping._grounded_weights()
    return np.concatenate([np.asarray(c_left), np.asarray(c_right),
                           np.asarray(system.damping.pair_coefficients)])


def fixed_interface_modes(system: SecondOrderSystem, interface, rank: int) -> jnp.ndarray:
    """(n, r) the ``rank`` lowest undamped modes of ``system`` held by the constraints
    C^T x = 0, C = ``interface`` ((n,) or (n, k): e_j holds DOF j, e_i - e_j ties DOF i to j):
    the fixed-interface (normal) modes of Craig & Bampton, M-orthonormal within the constrained
    space. A fixed-free chain (diagonal M, K = L^T diag(k) L, n >= 256) with held DOFs only:
    O(n r), no dense eigenproblem (``held_chain_modes``: each piece between held DOFs a chain
    held at one or both ends, rewritten as a fixed-free chain by a backward Cholesky step and a
    diagonal scaling, its lowest modes by bisection and twisted factorisations; the Section 5
    chain held at DOF 150: frequencies within 5e-13 of a dense eigh, the modes' residual 5e-15 of
    ||K||); otherwise dense: O(n^3) for the (n - k) eigenproblem."""
    c = np.asarray(_force_columns(system, interface, "interface"))
    n = system.size
    held = None
    if np.all(np.count_nonzero(c, axis=0) == 1):  # held DOFs: their rows and columns go
        held = np.unique(np.flatnonzero(np.any(c != 0, axis=1)))
        keep = np.setdiff1d(np.arange(n), held)
        size = keep.size
    else:  # an orthonormal basis Z of the null space of C^T: Z^T K Z, Z^T M Z
        u, sigma, _ = np.linalg.svd(c, full_matrices=True)
        free = jnp.asarray(u[:, int(np.sum(sigma > 1e-12 * sigma[0])):])
        size = free.shape[1]
    if isinstance(rank, bool) or not isinstance(rank, int) or not 1 <= rank <= size:
        raise ValueError(MARK + f"rank must be an integer in 1..{size} (n less the "
                         f"interface constraints), got {rank!r}.")
    chain = _long_chain(system)
    if held is not None and chain is not None:
        return held_chain_modes(*chain, held, rank)[1]
    stiffness, mass = system.stiffness.as_matrix(), system.mass.as_matrix()
    if held is not None:
        stiffness, mass = stiffness[np.ix_(keep, keep)], mass[np.ix_(keep, keep)]
        lift = lambda y: jnp.zeros((n, y.shape[1])).at[keep].set(y)  # noqa: E731
    else:
        stiffness, mass = free.T @ stiffness @ free, free.T @ mass @ free
        lift = lambda y: free @ y  # noqa: E731
    lower = jnp.linalg.cholesky(mass)
    half = jsl.solve_triangular(lower, stiffness, lower=True)
    symmetric = jsl.solve_triangular(lower, half.T, lower=True)
    _, vectors = jnp.linalg.eigh((symmetric + symmetric.T) / 2)
    return lift(jsl.solve_triangular(lower.T, vectors[:, :rank], lower=False))


def craig_bampton_basis(system: SecondOrderSystem, rank: int, *, loads=None,
                        moments: int = 3, states=None) -> Basis:
    """A Craig-Bampton basis with the dampers as the interface: the ``rank`` lowest modes of
    the system with every damper that acts held (``fixed_interface_modes``: a grounded damper's
    DOF fixed, a relative damper's two DOFs tied) and ``moments`` static moments
    (``static_moments``) of all damper directions and of ``loads``: the constraint modes
    K^-1 B and their mass-weighted successors; then ``states`` ((n,) or (n, s)), displacement
    directions kept as they are: pass the initial displacement and velocity, so the reduced
    model starts exactly where the full one does. Orthonormal, (n, <= rank + moments x columns
    + s); directions that add nothing above rounding (1e-14 of their length, ``extend_basis``)
    are dropped, so call it outside ``jit``.

    Craig & Bampton, "Coupling of substructures for dynamic analyses", AIAA J. 6 (1968)
    1313-1319. Where a damper is strong enough to pin its DOF the held modes are the limit the
    damped motion takes, where the free modes of ``modal_static_basis`` have a kink to learn; the
    constraint modes and their successors give back the free motion where it is weak. A start
    that is not smooth (x_3(0) = 1) has a tail in every mode; a truncated basis starts the ROM
    with that tail cut, and the gradient of a pinned design, a small difference of two large
    terms, feels it first. Section 5 scene, 25 designs spanning p = 7..290, c = 0.1..1000
    (``benchmarks/rom_gradients.py``): the ROM's dJ/dp and dJ/dc within 1e-3 of the full
    model's at **all 25** with r = 98 (91 held modes + 3 moments of the damper's two DOFs + x0;
    worst 2.1e-4, 0.036 s per design), at 23 without the start (92 modes: 1.8e-2 and 1.1e-2 at
    c = 1000, p = 150 and 225), against 19 with 94 free modes + 2 moments, with or without it.
    For a chain of n >= 256 with grounded dampers O(n r) (``fixed_interface_modes``; n = 30000,
    r = 100: 1.6 s), else dense O(n^3) (the held eigenproblem)."""
    _check(system, rank)
    if isinstance(moments, bool) or not isinstance(moments, int) or moments < 1:
        raise ValueError(MARK + f"moments must be an integer >= 1, got {moments!r}.")
    directions = np.asarray(damper_directions(system))
    states = None if states is None else _force_columns(system, states, "states")
    interface = directions[:, _damper_weights(system) > 0]
    if interface.shape[1]:
        modes = fixed_interface_modes(system, interface, rank)
    else:
        _, modes = modal_decomposition(system)
        modes = modes[:, :rank]
    modes, _ = jnp.linalg.qr(modes)
    columns = [jnp.asarray(directions)] if directions.shape[1] else []
    if loads is not None:
        columns.append(_force_columns(system, loads, "loads"))
    if columns:
        static = static_moments(system, jnp.concatenate(columns, axis=1), moments)
        modes = extend_basis(modes, static, _KRYLOV_DEPENDENT)
    if states is not None:
        modes = extend_basis(modes, states, _KRYLOV_DEPENDENT)
    return modes[:, : system.size]


def krylov_basis(system: SecondOrderSystem, rank: int, inputs) -> Basis:
    """A second-order Krylov basis (moment matching at s = 0) of ``rank`` orthonormal columns.

    The transfer function H(s) = (s^2 M + s D + K)^-1 B of the force directions B = ``inputs``
    ((n,) or (n, s)) has the moments of the second-order Krylov subspace G_k(A, C; R0) with
    A = -K^-1 D, C = -K^-1 M, R0 = K^-1 B: R1 = A R0, R_j = A R_(j-1) + C R_(j-2) (Bai & Su,
    "SOAR: a second-order Arnoldi method for the solution of the quadratic eigenvalue problem",
    SIAM J. Matrix Anal. Appl. 26 (2005) 640-659; "Dimension reduction of large-scale
    second-order dynamical systems via a second-order Arnoldi method", SIAM J. Sci. Comput. 26
    (2005) 1692-1709): a Galerkin model on a basis that holds G_k matches the first k moments of
    H at s = 0 (the static response and its first k - 1 derivatives). Built stably as the top
    halves of a block Arnoldi basis of the linearisation L = [[A, C], [I, 0]] started from
    [R0; 0] (full reorthogonalisation), then orthonormalised with dependent directions dropped;
    O(n) per solve for a chain. For free vibration from x0 the forcing is (s M + D) x0 + M v0:
    pass M x0 (and the damper directions, ``damper_directions``) as inputs. The basis may have
    fewer than ``rank`` columns when the subspace is exhausted (its size depends on the values:
    call it outside ``jit``)."""
    _check(system, rank)
    forces = _force_columns(system, inputs, "inputs")
    n = system.size
    push = _linearisation(system)  # one compiled function per block width
    start = np.asarray(_stiffness_solve(system)(forces))
    vectors = _orthonormal_in_order(np.concatenate([start, np.zeros_like(start)]), 2 * n)
    block = vectors
    while block.shape[1] and vectors.shape[1] < 2 * rank + start.shape[1]:
        new = np.asarray(push(jnp.asarray(block)))
        scale = np.max(np.linalg.norm(new, axis=0))
        for _ in range(2):  # full reorthogonalisation, twice
            new = new - vectors @ (vectors.T @ new)
        new[:, np.linalg.norm(new, axis=0) <= _DEPENDENT * scale] = 0.0
        block = _orthonormal_in_order(new, 2 * n) if np.any(new) else new[:, :0]
        vectors = np.concatenate([vectors, block], axis=1)
    return jnp.asarray(_orthonormal_in_order(vectors[:n], rank))


def _linearisation(system: SecondOrderSystem):
    """[u; w] -> L [u; w] = [-K^-1 (D u + M w); u], for (2n, p) blocks, compiled."""
    solve = _stiffness_solve(system)
    damping = system.damping_operator()
    n = system.size

    @jax.jit
    def push(block):
        top, bottom = block[:n], block[n:]
        force = jax.vmap(system.mass.mv, in_axes=1, out_axes=1)(bottom)
        if damping is not None:
            force = force + jax.vmap(damping.mv, in_axes=1, out_axes=1)(top)
        return jnp.concatenate([-solve(force), top])

    return push


def _orthonormal_in_order(columns: np.ndarray, rank: int) -> np.ndarray:
    """Gram-Schmidt (twice) in column order, dropping a column whose new part is below
    ``_DEPENDENT`` of the largest column: nested spans are kept nested."""
    scale = float(np.max(np.linalg.norm(columns, axis=0))) if columns.size else 0.0
    kept = np.zeros((columns.shape[0], 0))
    for column in columns.T:
        for _ in range(2):
            column = column - kept @ (kept.T @ column)
        norm = np.linalg.norm(column)
        if norm > _DEPENDENT * scale:
            kept = np.concatenate([kept, (column / norm)[:, None]], axis=1)
        if kept.shape[1] == rank:
            break
    return kept
