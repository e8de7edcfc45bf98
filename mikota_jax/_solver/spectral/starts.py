"""Starting points of the Aberth iteration of ``_spectral``: where each damped root begins.

Good starts decide the sweep count (232 sweeps against 6 at d = 1e4 in the middle of Mikota's
n = 300 chain): ``arc_starts`` puts each root on the arc it follows as a damper grows,
``far_starts`` puts the real roots of strong dampers where they end up. Offsets are relative to
each root's anchor pole, as everywhere in ``_spectral``.
"""

import jax.numpy as jnp


def arc_starts(omega, coupling, active, sign):
    """Aberth starting offsets from each damped mode's poles: on the arc a root follows.

    A weak damper moves the root of mode l by -|g_l|^2 / 2 (first order, g_l = row l of D_m^(1/2));
    a strong one sends it back to the imaginary axis at a frequency of the constrained chain,
    which lies above omega_l, below the next frequency (Rayleigh's interlacing for one
    constraint). Between the two the root runs about a half circle in the left half plane, from
    i omega_l to i (omega_l + gap / 2), radius R = gap / 4 (gap: to the next damped frequency).
    The start is the point at angle theta = pi c / (c + 2 pi R), c = |g_l|^2 (theta ~ c / (2 R)
    for a weak damper: the first-order shift; pi for a strong one). The lower roots start at
    the mirror image, 3 % further out and with a small real offset, so that a pair can split
    onto the real axis. Starting every root at -|g_l|^2 / 2 off its pole (capped at omega_l / 2)
    cost 232 sweeps at d = 1e4 in the middle of Mikota's n = 300 chain.
    """
    n = omega.shape[0]
    order = jnp.argsort(jnp.where(active, omega, jnp.inf))
    ranked = omega[order]
    count = jnp.sum(active)
    position = jnp.argsort(order)  # each mode's rank among the damped ones
    above = ranked[jnp.minimum(position + 1, n - 1)]
    below = ranked[jnp.maximum(position - 1, 0)]
    has_above = position + 1 < count
    gap = jnp.where(has_above, above - omega, omega - below)
    gap = jnp.where((gap > 0) & (count > 1), gap, omega)
    radius = gap / 4
    c = coupling**2
    theta = jnp.pi * c / (c + 2 * jnp.pi * radius)
    arc = radius * (-jnp.sin(theta) + 1j * (1 - jnp.cos(theta)))
    upper = arc
    lower = jnp.conj(arc) * 1.03 - 0.01 * radius * theta
    return jnp.where(sign > 0, jnp.concatenate([upper, upper]), jnp.concatenate([lower, lower]))


def far_starts(poles, omega, factor, weights, active, offset):
    """Start the real roots a strong damper pushes beyond the spectrum where they end up.

    Damper i alone with d_i |f_i|^2 > 2 omega_max has a real root near -d_i |f_i|^2 (the trace
    identity: the roots sum to -tr D_m, and for a strong damper one root carries nearly all of
    its share). Started among the poles, that root travels there at the Aberth iteration's
    slow far-field pace. It starts there instead, on the lower pole of one of the highest damped
    modes (one per damper, the highest for the strongest); weaker dampers keep the arc starts.
    Measured with the arc starts on Mikota's n = 300 chain (one damper, d = 1e2 ... 1e6): 3-4
    sweeps fewer in mid-chain, 1-4 more near the ends; a small effect either way.
    """
    n = omega.shape[0]
    k = factor.shape[1]
    reach = weights * jnp.sum(factor**2, axis=0)  # d_i |f_i|^2, (k,)
    strong = reach > 2 * jnp.max(omega)
    order = jnp.argsort(-reach)  # the strongest damper takes the highest damped mode
    rank = jnp.argsort(order)
    # damped modes from the top: the j-th highest damped mode for j < k
    by_height = jnp.argsort(jnp.where(active, -omega, jnp.inf))
    for i in range(k):
        mode = by_height[jnp.minimum(rank[i], n - 1)]
        root = n + mode
        usable = strong[i] & active[mode] & (rank[i] < n)
        offset = offset.at[root].set(jnp.where(usable, -reach[i] - poles[root], offset[root]))
    return offset
