"""The spectral engine's per-root work a block of roots at a time (``_spectral``).

Every step of the Aberth sweep and of the energy is per root: a row of (2n, n) or (2n, 2n)
complex work (29 GB each at n = 30000). Above n = ``BLOCK_ABOVE`` the rows are formed a block of
roots at a time (``by_rows``: a ``lax.map`` of checkpointed blocks), O(n) memory in every mode
and faster than all at once, since the blocks stay in cache (``benchmarks/engine.py``, blocks
rows; ``docs/notes/spectral_energy_large.md``). Here also the two all-pairs sums over roots:
Aberth's repulsion and the separation check.
"""

import jax
import jax.numpy as jnp
from equinox.internal import unvmap_any

from ..._errors import MARK
from ..._limits import BLOCK_ABOVE, BLOCK_ENTRIES


def row_block(n: int, block: int | None = None) -> int | None:
    """Roots per block of the O(n^2) work (None: all at once). ``block`` None: automatic, all at
    once up to n = ``BLOCK_ABOVE``, above it max(16, min(n, 2^16 / n)) roots (at least two
    blocks; O(n) memory in all). A block's (roots, n) rows then stay in cache: J + gradient of
    the Section 5 energy against all at once in ``benchmarks/engine.py``, blocks rows.
    ``block`` an int forces it (0: none)."""
    if block is not None:
        if isinstance(block, bool) or not isinstance(block, int) or block < 0:
            raise ValueError(MARK + f"block must be an int >= 0 or None, got {block!r}.")
        return block or None
    return None if n <= BLOCK_ABOVE else max(16, min(n, BLOCK_ENTRIES // n))


def balanced(m: int, block: int) -> tuple[int, int]:
    """(blocks, roots per block) for m roots at most ``block`` at a time: as few blocks, of
    equal size, so that the last is padded by fewer than ``blocks`` roots (600 roots at most 218
    at a time: 3 blocks of 200, not 3 of 218 with 54 roots of padding, which cost their work and
    their memory)."""
    count = -(-m // max(min(block, m), 1))
    return count, -(-m // count)


def by_rows(fn, block, *rows):
    """``fn(*rows)`` over the roots' leading axis: at once (``block`` None), or ``block`` roots
    at a time in a ``lax.map`` (in ``balanced`` blocks, the last padded with copies of the
    last root, cut off after). Each block is a ``jax.checkpoint``: reverse mode recomputes it
    instead of storing its (block, n) intermediates, so the memory stays O(n block) in every
    mode."""
    if block is None:
        return fn(*rows)
    m = rows[0].shape[0]
    count, block = balanced(m, block)

    def split(a):
        pad = jnp.repeat(a[-1:], count * block - m, axis=0)
        return jnp.concatenate([a, pad]).reshape((count, block) + a.shape[1:])

    out = jax.lax.map(jax.checkpoint(lambda args: fn(*args)), tuple(split(a) for a in rows))
    return jax.tree.map(lambda o: o.reshape((count * block,) + o.shape[2:])[:m], out)


def batch_cond(pred, needed, otherwise, *operands):
    """``lax.cond(pred, needed, otherwise, *operands)`` that stays a branch under ``vmap``.

    JAX batches a ``cond`` whose predicate differs between designs into a ``select`` of both
    branches, so every design of a batch paid for ``needed`` (the clusters' terms, a pass over
    all poles) whether any design needed it or not. Here ``needed`` runs where some design of
    the batch needs it (``unvmap_any``), and each design keeps its own branch's value (a
    ``where``): outside ``vmap`` exactly ``lax.cond``; under it the same values as each design
    alone, with the work skipped where no design needs it."""
    def both(*ops):
        return jax.tree.map(lambda a, b: jnp.where(pred, a, b), needed(*ops), otherwise(*ops))

    return jax.lax.cond(unvmap_any(pred), both, otherwise, *operands)


def by_rows_where(fn, block, mask, *rows):
    """``by_rows`` for the rows where ``mask`` (roots,) holds; zeros in the others. The masked
    rows are gathered first (a stable sort), and a block without one is skipped
    (``batch_cond``: under ``vmap`` where no design of the batch has one), so the cost follows
    the masked count."""
    if block is None:
        return _zero_where(fn(*rows), mask)
    order = jnp.argsort(~mask, stable=True)  # the masked rows first, in their order

    def one(live, *part):
        shape = jax.eval_shape(fn, *part)
        return batch_cond(jnp.any(live), lambda: fn(*part),
                          lambda: jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shape))

    out = by_rows(one, block, mask[order], *(a[order] for a in rows))
    inverse = jnp.argsort(order)
    return _zero_where(jax.tree.map(lambda o: o[inverse], out), mask)


def _zero_where(out, mask):
    """``out``'s rows with zeros where ``mask`` does not hold."""
    return jax.tree.map(lambda o: jnp.where(mask.reshape(mask.shape + (1,) * (o.ndim - 1)), o,
                                            jnp.zeros((), o.dtype)), out)


def sum_by_rows(fn, block, *rows):
    """sum over the roots of ``fn(*rows, weight)``, ``block`` roots at a time in a ``lax.scan``
    (one accumulator, not one output per block); ``weight`` (block,) is 1 for a root and 0 for
    the padding (copies of the last root), which ``fn`` must scale its terms by. Each block is a
    ``jax.checkpoint``."""
    m = rows[0].shape[0]
    count, block = balanced(m, block)
    weight = (jnp.arange(count * block) < m).astype(float)

    def split(a):
        pad = jnp.repeat(a[-1:], count * block - m, axis=0)
        return jnp.concatenate([a, pad]).reshape((count, block) + a.shape[1:])

    blocks = tuple(split(a) for a in rows) + (weight.reshape(count, block),)
    part = jax.checkpoint(lambda args: fn(*args))
    zero = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype),
                        jax.eval_shape(part, tuple(b[0] for b in blocks)))
    total, _ = jax.lax.scan(lambda total, args: (jax.tree.map(jnp.add, total, part(args)), None),
                            zero, blocks)
    return total


def abs2(z):
    """|z|^2 without the hypot of ``jnp.abs``: the nearest-root searches compare it over all
    pairs of roots (an argmin or a minimum orders the same), and a complex ``abs`` per pair cost
    more than the rest of such a pass (the partner search at n = 3000: 196 ms against 81 ms)."""
    return jnp.real(z) ** 2 + jnp.imag(z) ** 2


def roots_difference(poles, anchor, offset, rows_anchor, rows_offset):
    """lambda_j - lambda_k: (rows, 2n) for the roots of ``rows_anchor``, ``rows_offset`` against
    all, exact for roots on the same pole."""
    return (poles[rows_anchor][:, None] - poles[anchor][None, :]) + (rows_offset[:, None]
                                                                      - offset[None, :])


def repulsion(poles, anchor, offset, root_active, block, moving):
    """sum_(k != j, both damped) 1 / (lambda_j - lambda_k) per root j: Aberth's correction,
    for the ``moving`` roots (zero for the others; ``by_rows_where``)."""
    index = jnp.arange(anchor.shape[0])

    def rows(a, o, act, j):
        diff = roots_difference(poles, anchor, offset, a, o)
        mask = act[:, None] & root_active[None, :] & (j[:, None] != index[None, :])
        return jnp.sum(jnp.where(mask, 1 / jnp.where(mask, diff, 1.0), 0.0), axis=1)

    return by_rows_where(rows, block, moving, anchor, offset, root_active, index)


def complex_product(a, b):
    """a @ b (``jnp.matmul``, batch axes leading) for complex a (..., m, p) and b (..., p, q),
    either of which may be real, as real matrix products: of stacked real and imaginary parts
    (one product) where b is complex, of a's real and imaginary parts where b is real.
    XLA's CPU complex product ran 12x slower than a real one of the same shape and 3x slower than
    the four real products it stands for ((1602, 801) by (801, 1602): 0.23 s, 0.019 s, 0.076 s),
    and reverse mode transposes it into complex products again. Each entry is the same sums of
    real products as the complex product's, so both round alike."""
    if not jnp.iscomplexobj(a) and not jnp.iscomplexobj(b):
        return a @ b
    if not jnp.iscomplexobj(b):  # two products: no stacked copy of a
        return jax.lax.complex(jnp.real(a) @ b, jnp.imag(a) @ b)
    if not jnp.iscomplexobj(a):
        q = b.shape[-1]
        out = a @ jnp.concatenate([jnp.real(b), jnp.imag(b)], axis=-1)
        return jax.lax.complex(out[..., :q], out[..., q:])
    q = b.shape[-1]
    left = jnp.concatenate([jnp.real(a), jnp.imag(a)], axis=-1)  # (..., m, 2p)
    right = jnp.concatenate([jnp.concatenate([jnp.real(b), jnp.imag(b)], axis=-1),
                             jnp.concatenate([-jnp.imag(b), jnp.real(b)], axis=-1)],
                            axis=-2)  # (..., 2p, 2q)
    out = left @ right  # (..., m, 2q): the real parts, then the imaginary ones
    return jax.lax.complex(out[..., :q], out[..., q:])


def small_solve(a, b):
    """x with a x = b for a batch of small systems: a (..., k, k), b (..., k, m).

    Gauss-Jordan elimination with partial pivoting, unrolled over the static k in elementwise
    operations. Not ``jnp.linalg.solve``: jaxlib's batched LAPACK kernels (getrf/trsm) split
    their batch over XLA's intra-op thread pool and wait for it, and two of them running at once
    on a 2-core machine deadlocked with both pool threads waiting (seen at n = 801 and 10^4: the
    process idle at 0 % CPU, gdb showing two ``lapack_ztrsm_ffi`` in ``ParallelBatchMap``).
    For the k <= a few damper columns here, O(k^3) elementwise work per system is also cheaper.
    """
    k = a.shape[-1]
    batch = (1,) * (a.ndim - 2)
    rows = jnp.arange(k).reshape(batch + (k,))  # no implicit rank promotion
    aug = jnp.concatenate([a, b], axis=-1)
    for i in range(k):
        below = jnp.where(rows >= i, jnp.abs(aug[..., :, i]), -1.0)
        p = jnp.argmax(below, axis=-1)[..., None, None]  # (..., 1, 1)
        row_p = jnp.take_along_axis(aug, p, axis=-2)  # (..., 1, k + m)
        row_i = aug[..., i:i + 1, :]
        here = rows[..., None] == i
        aug = jnp.where(here, row_p, jnp.where(rows[..., None] == p, row_i, aug))
        pivot_row = aug[..., i:i + 1, :] / aug[..., i:i + 1, i:i + 1]
        aug = jnp.where(here, pivot_row, aug - aug[..., :, i:i + 1] * pivot_row)
    return aug[..., :, k:]
