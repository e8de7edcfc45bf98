"""Proper orthogonal decomposition of a snapshot matrix (eqs. 3.5-3.8).

Conventions: the snapshot matrix Q is (n, m), one column per time instant (eq. 3.5). Its singular
values sigma_1 >= sigma_2 >= ... and left singular vectors (proper orthogonal modes, POMs) come from
a jit-compiled SVD, or for m >> n (or n >> m) from the eigendecomposition of the smaller Gram matrix
(Sirovich's method of snapshots: cheaper, but it squares the condition, so singular values below
about 1e-8 sigma_1 are lost). Each POM's sign is fixed so that its entry of largest magnitude is
positive.

Two pseudo-energy criteria for choosing the rank r (eq. 3.7 and Section 5):

* ``"squared"``: sum_{k<=r} sigma_k^2 >= e * sum_k sigma_k^2, the criterion as eq. (3.7) writes it;
* ``"paper"``: (sum_{k<=r} sigma_k / sum_k sigma_k)^2 >= e, the reading that reproduces the paper's
  numbers (its printed "sum sigma^2 = 977.5528^2" is (sum sigma_k)^2, and this criterion gives its
  n_red = 76 / 98 for e = 0.99 / 0.9999, the squared one 54 / 76).
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._custom_types import Array, Basis, Float, Snapshots
from ._errors import MARK, as_float, check_x64

CRITERIA = ("squared", "paper")
METHODS = ("svd", "snapshots")


class POD(eqx.Module):
    """All singular values (descending) and proper orthogonal modes of a snapshot matrix."""

    singular_values: Float[Array, " k"]
    modes: Float[Array, "n k"]

    def basis(self, rank: int) -> Basis:
        """Phi = [phi_1, ..., phi_r] (eq. 3.8), orthonormal columns."""
        if isinstance(rank, bool) or not isinstance(rank, int | np.integer):
            raise ValueError(MARK + f"rank must be an integer, got {rank!r}.")
        available = self.modes.shape[1]
        if not 1 <= rank <= available:
            raise ValueError(MARK + f"rank must lie in 1..{available} (the number of modes), "
                             f"got {rank}.")
        if not isinstance(self.singular_values, jax.core.Tracer):
            numerical = self.numerical_rank()
            if rank > numerical:
                raise ValueError(MARK + f"rank = {rank} exceeds the numerical rank {numerical} of "
                                 "the snapshots (the other singular values are rounding noise); "
                                 f"choose rank <= {numerical}.")
        return self.modes[:, :rank]

    def energy_fraction(self, criterion: str = "squared") -> Float[Array, " k"]:
        """Captured pseudo-energy fraction for r = 1, 2, ... under ``criterion`` (eq. 3.7)."""
        return energy_fraction(self.singular_values, criterion)

    def rank_for_energy(self, energy: float, criterion: str = "squared") -> int:
        """Smallest r whose captured fraction is at least ``energy`` (0 < energy <= 1)."""
        return rank_for_energy(self.singular_values, energy, criterion)

    def numerical_rank(self) -> int:
        """Number of singular values above max(n, m) * eps * sigma_1 (the rest is rounding)."""
        return numerical_rank(self.singular_values, max(self.modes.shape))


def numerical_rank(singular_values, size: int) -> int:
    """Count singular values above 4 size eps sigma_1 (size = max(n, m)); the rest is rounding."""
    s = np.asarray(singular_values)
    if s.size == 0 or s[0] == 0:
        return 0
    return int(np.sum(s > 4 * size * np.finfo(np.float64).eps * s[0]))


def _fix_signs(modes):
    """Make the entry of largest magnitude of every column positive (deterministic POMs)."""
    index = jnp.argmax(jnp.abs(modes), axis=0)
    signs = jnp.sign(modes[index, jnp.arange(modes.shape[1])])
    return modes * jnp.where(signs == 0, 1.0, signs)[None, :]


@jax.jit
def _pod_svd(q):
    u, s, _ = jnp.linalg.svd(q, full_matrices=False)
    return s, _fix_signs(u)


@jax.jit
def _pod_snapshots(q):
    n, m = q.shape
    if n <= m:  # correlation matrix Q Q^T (n x n): the POMs directly
        w, u = jnp.linalg.eigh(q @ q.T)
        w, u = w[::-1], u[:, ::-1]
    else:  # Sirovich: Q^T Q (m x m), POMs phi_k = Q v_k / sigma_k
        w, v = jnp.linalg.eigh(q.T @ q)
        w, v = w[::-1], v[:, ::-1]
        s = jnp.sqrt(jnp.clip(w, 0.0))
        u = (q @ v) / jnp.where(s > 0, s, 1.0)[None, :]
    s = jnp.sqrt(jnp.clip(w, 0.0))
    return s, _fix_signs(u)


def pod(snapshots: Snapshots, *, method: str = "svd") -> POD:
    """POD of the (n, m) snapshot matrix Q = [x_1, ..., x_m] (eqs. 3.5-3.6).

    ``method="svd"`` (default) is the accurate thin SVD; ``"snapshots"`` uses the eigenvectors of
    the smaller of Q Q^T and Q^T Q, for snapshot sets much longer (or much taller) than the other
    side. Returns all min(n, m) singular values and modes; choose the rank with
    ``POD.rank_for_energy`` or pass it to ``POD.basis``. Jit-compiled; may itself be jit-ed,
    vmap-ed and differentiated.
    """
    check_x64()
    if method not in METHODS:
        raise ValueError(MARK + f"method must be one of {METHODS}, got {method!r}.")
    q = as_float(snapshots, "snapshots")
    if q.ndim != 2 or min(q.shape) < 1:
        raise ValueError(MARK + f"snapshots must be a non-empty (n, m) matrix, got {q.shape}.")
    if not isinstance(q, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(q))):
        raise ValueError(MARK + "snapshots must be finite (the simulation produced NaN or inf).")
    s, u = (_pod_svd if method == "svd" else _pod_snapshots)(q)
    return POD(s, u)


def energy_fraction(singular_values, criterion: str = "squared"):
    """Captured pseudo-energy fraction for r = 1..k (eq. 3.7), under one of ``CRITERIA``."""
    if criterion not in CRITERIA:
        raise ValueError(MARK + f"criterion must be one of {CRITERIA}, got {criterion!r}.")
    s = jnp.asarray(singular_values)
    if criterion == "squared":
        return jnp.cumsum(s**2) / jnp.sum(s**2)
    return (jnp.cumsum(s) / jnp.sum(s)) ** 2


def rank_for_energy(singular_values, energy: float, criterion: str = "squared") -> int:
    """Smallest r with captured fraction >= ``energy`` (0 < energy <= 1); a concrete integer."""
    if isinstance(energy, bool) or not isinstance(energy, float | int) or not 0 < energy <= 1:
        raise ValueError(MARK + f"energy must be a number in (0, 1], got {energy!r}.")
    fraction = np.asarray(energy_fraction(singular_values, criterion))
    if fraction.size == 0 or not np.all(np.isfinite(fraction)):
        raise ValueError(MARK + "singular values must be finite and not all zero.")
    if energy == 1:
        # e = 1 exactly: every mode that carries energy above rounding, never more than exist.
        return max(1, numerical_rank(singular_values, len(fraction)))
    # A fraction within rounding of the target counts as reaching it (cumsum error ~ k eps).
    slack = 4 * fraction.size * np.finfo(np.float64).eps
    return int(np.argmax(fraction >= energy - slack)) + 1
