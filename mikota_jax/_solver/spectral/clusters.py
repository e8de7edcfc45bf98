"""Damped roots that nearly coincide (critical damping), summed as a pair by a contour integral.

Where two damped roots lambda_1, lambda_2 meet (a mode passing through critical damping, the
1-DOF trace optimum), the modal expansion's coefficients blow up like 1 / (lambda_1 -
lambda_2) and cancel in the sum: summed one root at a time the energy lost all its digits at a
relative distance of 1e-12 from the meeting point. The pair is therefore never summed root by
root. Every quantity of the expansion is a sum of residues of the resolvent,

    sum_j y_j y_j^T h(lambda_j) / N_j = (1 / 2 pi i) contour_integral Q(s)^-1 h(s) ds,

Q(s) = s^2 I + s D_m + Omega^2 (Lancaster's expansion of Q^-1; the contour encloses the pair and
nothing else), and the integral is taken by the trapezoidal rule on a circle, which converges
geometrically for a periodic analytic integrand and does not care whether the two roots inside
are apart, equal (a Jordan block) or a conjugate pair about to split onto the real axis (Beyn,
Linear Algebra Appl. 436:3839, 2012, for the same integrals in nonlinear eigenproblems;
Trefethen & Weideman, SIAM Review 56:385, 2014, for the trapezoidal rule). Q(s)^-1 b costs O(n
k) by the Woodbury identity Q^-1 = R - s R F W H^-1 F^T R, R = (s^2 + Gamma s + Omega^2)^-1,
H = I + s F^T R F W (the secular matrix of ``_spectral``).

The circle: centre c = (lambda_1 + lambda_2) / 2, radius rho = min(distance from c to any other
root or to a pole of R, |Re c|) / 3, and the pair is taken as a cluster where |lambda_1 -
lambda_2| / 2 <= rho / 3. With ``NODES`` = 40 points the rule's error is below 3^-40 = 8e-20 of
the pair's terms from each side (the other singularities are 3 radii out, the pair at most a
third of one in; |Re c| bounds the growth of exp(s t) on the circle by the decay of the pair
itself), and the rounding on the circle is amplified at most ~(3/2)^2. Outside the rule
(|lambda_1 - lambda_2| / 2 > rho / 3) the two roots are separated by at least 1/9 of their
distance to every other singularity, where the root-by-root sum is as accurate as anywhere
(its coefficients are then no larger than ~9 / |lambda|): the two sides agree to rounding,
and nothing switches with the physics.

At most ``MAX_CLUSTERS`` pairs are taken (static shapes), the worst conditioned first; a root
left to the root-by-root sums must be well conditioned, 2 |lambda| |y|^2 / |N| <=
``CONDITION_LIMIT`` (about 1 / its relative distance from a double root), else the result is
not ok (``Clusters.ok``): three roots meeting, more pairs than slots, or a pair touching a pole.
Nearly equal roots with well-conditioned eigenvectors (the identical branches of a branched
chain) are no such case and stay simple. A pair the rule wants but no slot took is held to the
far tighter ``PAIR_LIMIT``: summed root by root, its coefficients lose ~eps cond^2 of J and
~eps cond^4 of dJ/dc. Mikota's chain with the damper on its middle DOF meets every mode pair at
once at c = 2 sqrt(k m) (n / 2 double roots): summed root by root under ``CONDITION_LIMIT``,
J came back 4e-2 off at n = 20 for c = 2 (1 + 1e-9); held to ``PAIR_LIMIT`` it is refused within
2e-3 of that c (J to 3e-12, dJ/dc to 1.5e-8 just outside, n = 8 to 300). Crowded roots of
long chains are no such case either: the largest bound seen on a grid of designs, ~90 at n =
1000, belongs to roots the rule does not want (their neighbours lie as close as their partner),
and J and dJ/dc there agree with the dense path to 1e-11 (n = 300).
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from ..._custom_types import Array
from .rows import abs2, by_rows, complex_product, roots_difference, small_solve

NODES = 40  # trapezoidal points on each circle (error 3^-NODES)
MAX_CLUSTERS = 2  # pairs summed by contour at once (a conjugate pair of pairs takes two)
_ISOLATION = 3.0  # radius = distance to anything else / 3; members within radius / 3
CONDITION_LIMIT = 1e6  # a simple root's 2 |lambda| |y|^2 / |N| above this: not ok
PAIR_LIMIT = 20.0  # ... and above this for a root of an isolated pair left without a slot
NEAR_COINCIDENT = 1e-6  # a mode no damper touches with its two poles this close: not ok


class Clusters(eqx.Module):
    """Pairs of damped roots summed by a contour integral (see the module docstring).

    ``center`` (K,) complex, ``radius`` (K,), ``valid`` (K,) bool: the circles (K =
    ``MAX_CLUSTERS``; an invalid slot contributes nothing); ``member`` (2n,) bool: the roots
    inside a valid circle, left out of every root-by-root sum; ``mate`` (2n,) int: the other
    root of a member's pair (itself for the others); ``ok``: every root left to the
    root-by-root sums is well conditioned."""

    center: Array
    radius: Array
    valid: Array
    member: Array
    mate: Array
    ok: Array

    def nodes(self):
        """(s, w): the (K * NODES,) points on the circles and the weights with which sum_p
        w_p f(s_p) is (1 / 2 pi i) times the integral of f around the valid circles."""
        theta = 2 * jnp.pi * (jnp.arange(NODES) + 0.5) / NODES
        unit = jnp.exp(1j * theta)[None, :]
        s = self.center[:, None] + self.radius[:, None] * unit
        w = jnp.where(self.valid[:, None], self.radius[:, None] * unit / NODES, 0.0)
        return s.reshape(-1), w.reshape(-1)

    @property
    def any(self) -> Array:
        return jnp.any(self.valid)


def find_clusters(poles, anchor, offset, active, condition, block=None):
    """(the pairs of damped roots to sum by contour, the roots' smallest separation), from the
    frozen roots (no derivative: the circles are fixed, the integrands carry the derivatives);
    ``condition`` (2n,) each root's 2 |lambda| |y|^2 / |N|.

    The separation is min |lambda_j - lambda_k| / |lambda_j| over roots that interact: two
    damped ones, or the two poles of one undamped-by-dampers mode (critical internal damping
    makes that pair defective); taken in the same pass over the pairs as the clusters."""
    poles, anchor, offset, active, condition = jax.lax.stop_gradient(
        (poles, anchor, offset, active, condition))
    size = anchor.shape[0]
    n = size // 2
    root_active = jnp.concatenate([active, active])
    index = jnp.arange(size)
    mode = anchor % n
    lam = poles[anchor] + offset

    def rows(a, o, act, j):
        """Nearest other root, its distance, the distance of the next one; the separation."""
        # squared distances (``abs2``), square roots of the few kept
        distance = abs2(roots_difference(poles, anchor, offset, a, o))
        distance = jnp.where(index[None, :] == j[:, None], jnp.inf, distance)
        nearest = jnp.argmin(distance, axis=1)
        first = jnp.take_along_axis(distance, nearest[:, None], axis=1)[:, 0]
        rest = jnp.where(index[None, :] == nearest[:, None], jnp.inf, distance)
        same_mode = (a % n)[:, None] == mode[None, :]
        interacting = (act[:, None] & root_active[None, :]) | (same_mode & ~act[:, None])
        closest = jnp.min(jnp.where(interacting, distance, jnp.inf), axis=1)
        return (nearest, jnp.sqrt(first), jnp.sqrt(jnp.min(rest, axis=1)),
                jnp.sqrt(closest) / jnp.abs(poles[a] + o))

    nearest, first, second, separation = by_rows(rows, block, anchor, offset, root_active,
                                                 index)
    mutual = nearest[nearest] == index
    candidate = root_active & root_active[nearest] & mutual & (index < nearest)
    half = first / 2
    center = (lam + lam[nearest]) / 2
    # distance from the centre to any third root, at least min(second distances) - half
    room = jnp.minimum(second, second[nearest]) - half
    room = jnp.minimum(room, jnp.abs(jnp.real(center)))
    score = jnp.where(candidate & (room > 0), half / jnp.where(room > 0, room, 1.0), jnp.inf)
    wanted = score <= 1 / _ISOLATION**2
    worst = jnp.maximum(condition, condition[nearest])
    _, pick = jax.lax.top_k(jnp.where(wanted, worst, -jnp.inf), MAX_CLUSTERS)
    c = center[pick]
    pole_live = jnp.concatenate([active, active])
    to_poles = jnp.min(jnp.where(pole_live[None, :], jnp.abs(c[:, None] - poles[None, :]),
                                 jnp.inf), axis=1)
    to_roots = jnp.min(jnp.where((index[None, :] == pick[:, None])
                                 | (index[None, :] == nearest[pick][:, None]), jnp.inf,
                                 jnp.abs(c[:, None] - lam[None, :])), axis=1)
    radius = jnp.minimum(jnp.minimum(to_poles, to_roots), jnp.abs(jnp.real(c))) / _ISOLATION
    valid = wanted[pick] & (half[pick] <= radius / _ISOLATION) & (radius > 0)
    radius = jnp.where(valid, radius, 1.0)
    hits = jnp.zeros(size, int).at[pick].add(valid).at[nearest[pick]].add(valid)
    member = hits > 0
    mate = jnp.where(member, nearest, index)
    # a mode no damper touches at critical internal damping: its two poles meet (not summed
    # by contour here)
    n = size // 2
    double_pole = ~active & (jnp.abs(poles[:n] - poles[n:]) <= NEAR_COINCIDENT
                             * jnp.abs(poles[:n]))
    # a pair the rule wants but no slot took (more pairs than slots) is summed root by root:
    # held to ``PAIR_LIMIT``
    in_pair = wanted | (mutual & wanted[nearest])
    limit = jnp.where(in_pair, PAIR_LIMIT, CONDITION_LIMIT)
    ill = root_active & ~member & ~(condition <= limit)
    ok = ~jnp.any(ill) & ~jnp.any(double_pole)
    return Clusters(c, radius, valid, member, mate, ok), jnp.min(separation)


def resolvent_at(modes, s):
    """At the points s (P,): R (P, n) = 1 / (s^2 + gamma s + omega^2), the damper factor F of
    the damped modes (n, k) (rows of modes no damper touches zero: they are decoupled) and H =
    I + s F^T R F W (P, k, k)."""
    r, f, h, _ = _secular_matrix(modes.poles, modes.factor, modes.weights, modes.active, s)
    return r, f, h


def _secular_matrix(poles, factor, weights, active, s):
    """``resolvent_at`` from the raw modal data, and dH/ds (P, k, k)."""
    n = poles.shape[0] // 2
    r = 1 / ((s[:, None] - poles[None, :n]) * (s[:, None] - poles[None, n:]))
    f = jnp.where(active[:, None], factor, 0.0)
    rate = (s[:, None] - poles[None, :n]) + (s[:, None] - poles[None, n:])  # 2 s + gamma
    m1 = jnp.einsum("pl,la,lb->pab", r, f, f) * weights[None, None, :]
    m1_prime = -jnp.einsum("pl,la,lb->pab", rate * r**2, f, f) * weights[None, None, :]
    h = jnp.eye(f.shape[1])[None] + s[:, None, None] * m1
    return r, f, h, m1 + s[:, None, None] * m1_prime


def cluster_roots(poles, factor, weights, active, clusters: Clusters):
    """(count, sum): for each circle, the number of roots inside and their sum, (K,) each, by
    the argument principle on det H (the poles of R lie outside, so det Q and det H have the
    same roots inside): (1 / 2 pi i) contour_integral s^p tr(H^-1 H') ds, p = 0, 1. A cluster
    is a pair only where the count is 2; the sum stands for the pair in the trace check (its
    two roots are only sqrt(eps)-accurate one by one at a double root, their sum is not)."""
    s, w = clusters.nodes()
    _, _, h, h_prime = _secular_matrix(poles, factor, weights, active, s)
    log_derivative = jnp.trace(small_solve(h, h_prime), axis1=-2, axis2=-1)
    terms = (w * log_derivative).reshape(MAX_CLUSTERS, NODES)
    return jnp.sum(terms, axis=1), jnp.sum(terms * s.reshape(MAX_CLUSTERS, NODES), axis=1)


def solve_at(modes, s, rhs):
    """u = Q(s_p)^-1 rhs_p: (P, n, m) from rhs (P, n, m), O(P n k m) by Woodbury."""
    r, f, h = resolvent_at(modes, s)
    g = complex_product(f.T, r[:, :, None] * rhs)  # F^T R b
    z = small_solve(h, g)  # H^-1 F^T R b = F^T u
    correction = complex_product(f * modes.weights[None, :], z)
    return r[:, :, None] * (rhs - s[:, None, None] * correction)


def damping_times(modes, q):
    """D_m q for q (n, m) in modal coordinates: (Gamma + F W F^T) q over the damped modes."""
    f = jnp.where(modes.active[:, None], modes.factor, 0.0)
    return modes.gamma[:, None] * q + f @ (modes.weights[:, None] * (f.T @ q))


def initial_rhs(modes, s, q0, p0):
    """b(s) = (s I + D_m) q0 + p0 (P, n, m), the Laplace transform's right-hand side of free
    vibration from (q0, p0), each (n, m)."""
    return s[:, None, None] * q0[None] + (damping_times(modes, q0) + p0)[None]
