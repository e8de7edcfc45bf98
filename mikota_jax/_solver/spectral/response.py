"""Responses from the damped modes: ``exact_solve``'s spectral path, on any increasing time grid.

Conventions as in ``_spectral``: eta are the M-orthonormal modal coordinates (x = U eta), the 2n
damped roots lambda_j with modal eigenvectors y_j (``DampedModes.vectors()``). Free vibration
from (q0, p0) = (U^T M x0, U^T M v0) at t0 = ts[0] is eta(t) = sum_j a_j exp(lambda_j (t - t0))
y_j, a = ``coefficients(q0, p0)``. A constant modal force g = U^T f switched on at t_b from rest
adds sum_j b_j (exp(lambda_j (t - t_b)) - 1) / lambda_j y_j for t >= t_b, b =
``load_coefficients(g)``; a ``Pulse`` on [start, start + duration) is its switch-on minus its
switch-off, written as b_j / lambda_j expm1(lambda_j w) exp(lambda_j (t - t_off)) after the pulse
(w its width): the static parts cancel analytically, so a short pulse loses no digits. Velocities
are the time derivatives of the same sums.

Cost: the modes (one n x n eigendecomposition, then the secular equation, O(k^2 n^2) a sweep),
O(n^2) coefficients, the (2n, N) table of exp(lambda_j t), and the outputs of d requested DOFs at
all N times as one real matrix product: X = Re[(U[dofs] Y) C] with C_jt = a_j exp(lambda_j t) (+
the load's terms), O(N d n) in BLAS-3, no time stepping. The roots are grouped in n slots by
their values (each root's partner is the root nearest its conjugate, not a layout rule): a
conjugate pair fills one slot, counted twice; two real roots share one, packed as Re c1 + i Re c2
(exact by linearity, no threshold on a rounding-level imaginary part); an inconsistent pairing
makes the result not ok.

A pair of nearly coincident roots (critical damping, where the expansion's coefficients blow up
like 1 / separation) is not summed root by root but by a contour integral around it
(``_spectral_clusters``): its part of eta(t) is sum_p w_p exp(s_p t) u_p, u_p = Q(s_p)^-1 b(s_p),
NODES pseudo-roots s_p per pair with the load's terms in the same form (``_cluster_history``).

For a ``SecondOrderSystem`` whose damping is discrete dampers, with or without internal damping
diagonal in modal coordinates (``_spectral.spectral_applies``). The result is a pair
(``Trajectory``, ok); where not ok (a root did not converge, roots nearly coincide outside a
pair, or a non-finite output) the caller must use the dense path.
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from ..._limits import chunk
from ..._model.chain_combine import chain_mode_combination
from ..._model.modal import modal_projection
from ..._model.system import SecondOrderSystem
from ..trajectory import Trajectory
from .clusters import initial_rhs, solve_at
from .modes import live_modes, live_rows, uses_rows
from .modes import spectral_applies as system_applies
from .roots import complex_arithmetic
from .rows import abs2, batch_cond, by_rows, sum_by_rows


def spectral_applies(model) -> str | None:
    """Why the spectral path does not apply to ``model`` (one phrase), or None when it does."""
    if not isinstance(model, SecondOrderSystem):
        return f"model is a {type(model).__name__}, not a full SecondOrderSystem"
    if not model.damped:
        return "the system is undamped"
    return system_applies(model)


def _exp(lam, tau):
    """exp(lambda tau), real or complex, as exp(Re) (cos, sin) for complex (cheaper than XLA's
    complex exp)."""
    if not jnp.iscomplexobj(lam):
        return jnp.exp(lam * tau)
    magnitude = jnp.exp(jnp.real(lam) * tau)
    phase = jnp.imag(lam) * tau
    return jax.lax.complex(magnitude * jnp.cos(phase), magnitude * jnp.sin(phase))


@complex_arithmetic
def _modal_tables(lam, a, b, ts, load, displacement: bool, velocity: bool):
    """The (N, m) coefficient tables C_x, C_v of m roots: eta(t_k) = sum_j C_x[k, j] y_j (time
    major, as the outputs: the matrix product needs no transpose).

    ``lam``, ``a``, ``b``: (m,), real or complex (the real ones for roots on the real axis)."""
    # Re lambda <= 0 (D_m is positive semi-definite); a rounding-level positive real part is
    # cut so that exp never overflows on a long grid (where, not minimum: at a tie minimum would
    # halve the derivative of a root that sits on the imaginary axis, a switched-off damper)
    lam = jnp.where(jnp.real(lam) > 0, lam - jnp.real(lam), lam)[None, :]
    tau = (ts - ts[0])[:, None]
    free = a[None, :] * _exp(lam, tau)
    cx = free if displacement else None
    cv = lam * free if velocity else None
    if load is None:
        return cx, cv
    # a jump at or before ts[0] belongs to the initial load value: the pulse acts on
    # [max(start, t0), max(end, t0)); times before a jump are clipped to it (no exp overflow
    # in the branch not taken)
    on = jnp.maximum(load.start, ts[0])
    off = jnp.maximum(load.start + load.duration, ts[0])
    since_on = jnp.maximum(ts - on, 0.0)[:, None]
    since_off = jnp.maximum(ts - off, 0.0)[:, None]
    width = off - on
    decay = _exp(lam, since_off)
    b = b[None, :]
    if displacement:
        # (exp(lambda (t - on)) - 1) / lambda while on; after: exp(lambda (t - off)) (exp(lambda
        # w) - 1) / lambda, the switch-on and switch-off terms combined without cancellation
        cx = cx + (b / lam) * jnp.expm1(lam * jnp.minimum(since_on, width)) * decay
    if velocity:
        after = (ts >= off)[:, None]
        during = ((ts >= on) & (ts < off))[:, None]
        cv = cv + b * jnp.where(after, jnp.expm1(lam * width) * decay,
                                jnp.where(during, _exp(lam, since_on), 0.0))
    return cx, cv


@complex_arithmetic
def _conjugate_slots(lam, block=None, mate=None):
    """n slots for the 2n roots, so that the real sum needs n terms, not 2n.

    Each root's partner is the root nearest its conjugate (itself for a root on the real axis),
    found from the values, not from the root layout. A conjugate pair fills one slot (its first
    root, counted twice: Re(c w) of the pair is 2 Re(c_1 w_1)); two real roots share one, packed
    as c = Re c_1 + i Re c_2, w = Re w_1 - i Re w_2 (Re(c w) = Re(c_1 w_1) + Re(c_2 w_2)). The
    number of real roots is even when the partners pair up; ``consistent`` says they do.
    Returns (first, second, real, consistent): (n,) indices, (n,) bool, a bool. ``block``: the
    partners ``block`` roots at a time (``by_rows``), O(n block) memory. ``mate``: the roots
    of a cluster (``Clusters.mate``, whose coefficients are zero) are each other's partners
    (at a double root their values are equal and the nearest-conjugate rule cannot pair them).
    """
    size = lam.shape[0]
    n = size // 2
    index = jnp.arange(size)

    partner = by_rows(  # argmin_k |lambda_k - conj(lambda_j)|, squared (``abs2``)
        lambda z: jnp.argmin(abs2(lam[None, :] - jnp.conj(z)[:, None]), axis=1), block, lam)
    if mate is not None:
        partner = jnp.where(mate != index, mate, partner)
    consistent = jnp.all(partner[partner] == index)
    self_conjugate = partner == index
    key = jnp.where(self_conjugate, 1, jnp.where(index < partner, 0, 2))
    order = jnp.argsort(key, stable=True)  # pairs' first roots, then the real roots
    pairs = jnp.sum(key == 0)
    slot = jnp.arange(n)
    packed = jnp.clip(pairs + 2 * (slot - pairs), 0, size - 2)
    real = slot >= pairs
    first = jnp.where(real, order[packed], order[slot])
    second = order[packed + 1]
    return first, second, real, consistent


@complex_arithmetic
def _cluster_history(modes, q0, p0, g, ts, load, displacement, velocity):
    """The clusters' part of the modal history: ((N, P) tables, (P, n) modal vectors) pairs
    whose ``Re(table @ vectors)`` add up to eta(t) (and eta'(t)) of the pairs of nearly
    coincident roots: free vibration sum_p w_p exp(s_p t) Q(s_p)^-1 b(s_p), and a load's
    sum_p w_p (its switch-on/off terms at s_p) Q(s_p)^-1 g, exactly as ``_modal_tables`` writes
    them for roots (the residues at the pair of the same integrands)."""
    s, w = modes.clusters.nodes()
    free = solve_at(modes, s, initial_rhs(modes, s, q0[:, None], p0[:, None]))[..., 0]
    cx, cv = _modal_tables(s, w, None, ts, None, displacement, velocity)
    parts = [(cx, cv, free)]
    if load is not None:
        forced = solve_at(modes, s, jnp.broadcast_to(g[None, :, None], free.shape + (1,)))
        lx, lv = _modal_tables(s, jnp.zeros_like(w), w, ts, load, displacement, velocity)
        parts.append((lx, lv, forced[..., 0]))
    return parts


def _real_product(c, w):
    """Re(c w^T): (N, d) from c (N, m) and w (d, m) complex, as one real matrix product."""
    stacked = jnp.concatenate([jnp.real(c), jnp.imag(c)], axis=1)  # (N, 2m)
    rows = jnp.concatenate([jnp.real(w).T, -jnp.imag(w).T], axis=0)  # (2m, d)
    return stacked @ rows


def modal_first(times: int, n: int, dofs: int) -> bool:
    """Whether the history of ``dofs`` outputs at ``times`` is cheaper as the modal history
    eta = Re(C Y^T) (N, n) followed by U[dofs] eta, 2 N n^2 + N n d real multiply-adds, than as
    U[dofs] Y (three real (d, n) x (n, n) products) followed by Re(C (U[dofs] Y)^T), 3 d n^2 +
    2 N n d: the same sums associated the other way, chosen from the shapes alone (all DOFs at
    2001 times: eta first from n = 668 on, 2.2x fewer flops at n = 3000)."""
    return 2 * times * n * n + times * n * dofs < 3 * dofs * n * n + 2 * times * n * dofs


@eqx.filter_jit
def spectral_solve_with_result(system, ts, x0, v0, load, *, dofs, displacement, velocity,
                               block=None):
    """(``Trajectory``, ok): the response from the damped modes on any increasing grid ``ts``.

    ``system``: a ``SecondOrderSystem`` with dampers only (``spectral_applies``); ``ts`` (N,);
    ``x0``, ``v0`` (n,); ``load`` None or a ``Pulse``; ``dofs`` a tuple of 1-based DOFs. ok is
    False where the roots did not converge, a root outside a cluster is ill-conditioned
    (``Clusters.ok``) or an output is not finite: then the trajectory must not be used. A
    critically damped pair enters by contour (``_cluster_history``). Differentiable in the
    system's values and the initial state, through one Newton step on the secular equation at
    the roots (``differentiable_roots``).

    A chain that ``uses_rows`` (n > 4096, dampers only) takes ``rows_response``: no U and no
    (n, 2n) vectors (``block`` 0: all at once from U, as below).
    """
    return spectral_solve_with_roots(system, ts, x0, v0, load, dofs=dofs,
                                     displacement=displacement, velocity=velocity,
                                     block=block)[:2]


@eqx.filter_jit
def spectral_solve_with_roots(system, ts, x0, v0, load, *, dofs, displacement, velocity,
                              block=None, start=None):
    """(``Trajectory``, ok, roots): ``spectral_solve_with_result``, its sweeps started at
    ``start`` (a ``RootStart``, None for the arc starts), and the roots found as the next
    design's start."""
    if block != 0 and uses_rows(system):
        return rows_response(system, ts, x0, v0, load, dofs=dofs, displacement=displacement,
                             velocity=velocity, block=block, start=start)
    modes, modes_u, modes_ok = live_modes(system, start=start)
    project = modal_projection(system, modes_u)
    q0, p0 = project(x0), project(v0)
    a = modes.coefficients(q0, p0)
    g = None if load is None else modes_u.T @ load.direction
    b = None if load is None else modes.load_coefficients(g)
    lam = modes.eigenvalues
    first, second, real, consistent = _conjugate_slots(jax.lax.stop_gradient(lam),
                                                       mate=modes.clusters.mate)
    real_part = lambda z: None if z is None else jnp.real(z[second])  # noqa: E731
    # the first root of every slot in complex arithmetic; the second (real roots only) in real
    cx, cv = _modal_tables(lam[first], a[first], None if b is None else b[first], ts, load,
                           displacement, velocity)
    rx, rv = _modal_tables(real_part(lam), real_part(a), real_part(b), ts, load, displacement,
                           velocity)
    index = None if dofs == tuple(range(1, system.size + 1)) else jnp.asarray(dofs) - 1
    rows = modes_u if index is None else modes_u[index]
    y = modes.vectors()  # (n, 2n)
    y_first = y[:, first]

    def pack(c, r):
        return jnp.where(real[None, :], jax.lax.complex(jnp.real(c), r), 2 * c)

    if modal_first(ts.shape[0], system.size, rows.shape[0]):
        # the modal history eta (N, n) first, then U[dofs] eta: fewer flops for many DOFs
        w = jnp.where(real[None, :], jax.lax.complex(jnp.real(y_first), -jnp.real(y[:, second])),
                      y_first)  # (n, slots), packed as the tables
        x = None if cx is None else _real_product(pack(cx, rx), w) @ rows.T
        v = None if cv is None else _real_product(pack(cv, rv), w) @ rows.T
    else:
        w1 = jax.lax.complex(rows @ jnp.real(y_first), rows @ jnp.imag(y_first))  # U[dofs] Y
        w2 = rows @ jnp.real(y[:, second])
        w = jnp.where(real[None, :], jax.lax.complex(jnp.real(w1), -w2), w1)
        x = None if cx is None else _real_product(pack(cx, rx), w)
        v = None if cv is None else _real_product(pack(cv, rv), w)

    @complex_arithmetic
    def clusters(x, v):
        for tx, tv, vectors in _cluster_history(modes, q0, p0, g, ts, load, displacement,
                                                velocity):
            out = rows @ vectors.T  # (d, P)
            x = None if x is None else x + _real_product(tx, out)
            v = None if v is None else v + _real_product(tv, out)
        return x, v

    x, v = batch_cond(modes.clusters.any, clusters, lambda x, v: (x, v), x, v)
    finite = jnp.all(jnp.asarray([jnp.all(jnp.isfinite(y)) for y in (x, v) if y is not None]))
    ok = modes_ok & consistent & finite
    return Trajectory(ts, x, v, dofs, None), ok, modes.start


def response_block(n: int, block: int | None = None) -> int:
    """Roots per block of ``rows_response``: ``block``, or ~2^24 / n (a (block, n) complex work
    array of ~256 MB; each block is a rank-2 block update of the (N, n) modal history, so larger
    blocks than the roots' ``row_block`` keep the matrix product efficient)."""
    return block if block else chunk(n, 16)


@complex_arithmetic
def rows_response(system, ts, x0, v0, load, *, dofs, displacement, velocity, block=None,
                  start=None):
    """(``Trajectory``, ok, roots) of a chain that ``uses_rows``, in O(n (N + block)) memory.

    The same sums as ``spectral_solve_with_result`` in the other order: the modal history
    eta(t_k) = Re sum_j C_kj y_j (N, n) first, a block of conjugate slots at a time
    (``sum_by_rows``; each block's eigenvector rows, normalisers and coefficients a_j, b_j made
    there), then x = U eta for the requested DOFs by ``chain_mode_combination`` (U a chunk at a
    time). O(N n^2) flops either way; the (n, 2n) vectors, the (2n, 2n) partner search and U
    are never held. For few outputs (``modal_first`` false, as for the path with U) the rows
    U[dofs] come with the chain's modes, and each block adds its outputs directly: O(n^2 d +
    N n d), no modal history; there a block forms no eigenvector rows either: U[dofs] y_j,
    y_j^T p0, y_j^T Omega^2 q0 (y_j^T g) and N_j come from the resolvent's rows in two real
    matrix products (``DampedModes.row_products``). ``block``: roots per block
    (``response_block``; the secular equation's own blocks are ``row_block``'s).
    """
    n = system.size
    masses = system.mass.diagonal
    columns = [x0, v0] + ([] if load is None else [load.direction / masses])  # U^T M (f / m)
    index = jnp.asarray(dofs) - 1
    # few outputs (``modal_first`` false): U[dofs] from the chain's modes, and each block adds
    # its outputs (N, d) directly, O(n^2 d + N n d), instead of the modal history (N, n)
    direct = not modal_first(ts.shape[0], n, len(dofs))
    modes, projected, modes_ok, out_rows = live_rows(system, jnp.stack(columns, axis=1),
                                                     dofs=index if direct else None,
                                                     start=start)
    q0, p0 = projected[:, 0], projected[:, 1]
    g = None if load is None else projected[:, 2]
    lam = modes.eigenvalues
    size = response_block(n, block)
    first, second, real, consistent = _conjugate_slots(jax.lax.stop_gradient(lam), size,
                                                       modes.clusters.mate)
    stiff = modes.omega**2 * q0
    # the columns each root's eigenvector meets: y^T p0, y^T Omega^2 q0 (y^T g) and, for few
    # outputs, U[dofs] y, from the resolvent rows without forming y (``row_products``)
    columns = jnp.stack([p0, stiff] + ([] if g is None else [g]), axis=1)
    if direct:
        columns = jnp.concatenate([columns, out_rows.T], axis=1)

    def coefficients(roots):
        """(the roots' rows, (roots, n) y or (roots, d) (U[dofs] y)^T; a; b)."""
        if direct:
            products, norm = modes.row_products(roots, columns)
            y = products[:, columns.shape[1] - out_rows.shape[0]:]
        else:
            y = modes.vector_rows(roots)
            norm = modes.normaliser_rows(roots, y)
            products = y @ columns
        norm = modes.safe_normalisers(roots, norm)
        member = modes.clusters.member[roots]
        a = jnp.where(member, 0.0, (products[:, 0] - products[:, 1] / lam[roots]) / norm)
        return y, a, None if g is None else jnp.where(member, 0.0, products[:, 2] / norm)

    def slots(one, two, is_real, weight):
        y1, a1, b1 = coefficients(one)
        # the second root of a slot counts for real roots only (packed at the end): a block of
        # conjugate pairs skips it
        y2, a2, b2 = batch_cond(
            jnp.any(is_real), coefficients,
            lambda two: jax.tree.map(jnp.zeros_like, (y1, a1, b1)), two)
        cx, cv = _modal_tables(lam[one], a1, b1, ts, load, displacement, velocity)
        rx, rv = _modal_tables(jnp.real(lam[two]), jnp.real(a2),
                               None if b2 is None else jnp.real(b2), ts, load, displacement,
                               velocity)
        w = jnp.where(is_real[:, None], jax.lax.complex(jnp.real(y1), -jnp.real(y2)), y1)
        w = (weight[:, None] * w).T  # (n or d, block); padded slots add nothing

        def history(c, r):
            packed = jnp.where(is_real[None, :], jax.lax.complex(jnp.real(c), r), 2 * c)
            return _real_product(packed, w)  # (N, n)

        return tuple(history(c, r) for c, r in ((cx, rx), (cv, rv)) if c is not None)

    etas = sum_by_rows(slots, size, first, second, real)

    def clusters(etas):
        parts = _cluster_history(modes, q0, p0, g, ts, load, displacement, velocity)
        tables = [[t for t in (tx, tv) if t is not None] for tx, tv, _ in parts]
        outs = [vectors.T if out_rows is None else out_rows @ vectors.T
                for *_, vectors in parts]  # (n or d, P)
        return tuple(e + sum(_real_product(t[i], out) for t, out in zip(tables, outs))
                     for i, e in enumerate(etas))

    etas = batch_cond(modes.clusters.any, clusters, lambda e: e, etas)
    if direct:
        outputs = etas  # (N, d) each
    else:
        outputs = chain_mode_combination(masses, system.stiffness.springs, index,
                                         jnp.concatenate([e.T for e in etas], axis=1))
        outputs = jnp.split(outputs.T, len(etas))  # (N, d) each
    x = outputs[0] if displacement else None
    v = outputs[-1] if velocity else None
    finite = jnp.all(jnp.asarray([jnp.all(jnp.isfinite(y)) for y in (x, v) if y is not None]))
    return Trajectory(ts, x, v, dofs, None), modes_ok & consistent & finite, modes.start
