"""Proper orthogonal decomposition of a snapshot matrix (eqs. 3.5-3.8).

Conventions: the snapshot matrix Q is (n, m), one column per time instant (eq. 3.5). Its singular
values sigma_1 >= sigma_2 >= ... and left singular vectors (proper orthogonal modes, POMs) come from
a jit-compiled SVD, or for m >> n (or n >> m) from the eigendecomposition of the smaller Gram matrix
(Sirovich's method of snapshots: cheaper, but it squares the condition, so singular values below
about 1e-8 sigma_1 are lost and those below ~1e-6 sigma_1 inaccurate). Each POM's sign is fixed so
that its entry of largest magnitude is positive.

Numerical rank: the number of singular values above ``rounding_level`` * sigma_1, the level of
rounding noise: 4 max(n, m) eps for ``"svd"`` and ``"randomized"`` (a backward-stable SVD, and
snapshots rounded entry by entry, as ``numpy.linalg.matrix_rank``), its square root (1e-7 to
1e-6) for ``"snapshots"`` (the Gram matrix resolves sigma^2 to max(n, m) eps sigma_1^2). The modes
beyond it are rounding noise (Sirovich's are not even orthonormal), so no rank choice goes past it:
a rank above it is a ``ValueError`` (``basis``; under ``jit`` an ``eqx.error_if``), and an
energy fraction of 1, or one so close to 1 that only noise could reach it, gives the numerical rank.

For large snapshot sets (n >= 10^4) ``method="randomized"`` computes only the leading k singular
values and POMs with a randomized range finder (Halko, Martinsson & Tropp 2011, Algs. 4.4 and 5.1):
a Gaussian sketch Q Omega with k + p columns, q rounds of re-orthonormalised subspace iteration,
then the SVD of the small projected matrix. Its error in sigma_j shrinks roughly like
(sigma_{k+p+1} / sigma_j)^(2q+1): accurate for the leading values of a decaying spectrum, less so
near sigma_k when the spectrum is flat there; check against ``"svd"`` on a smaller problem.

Two pseudo-energy criteria for choosing the rank r (eq. 3.7 and Section 5):

* ``"squared"``: sum_{k<=r} sigma_k^2 >= e * sum_k sigma_k^2, the criterion as eq. (3.7) writes it;
* ``"paper"``: (sum_{k<=r} sigma_k / sum_k sigma_k)^2 >= e, the reading that reproduces the paper's
  numbers (its printed "sum sigma^2 = 977.5528^2" is (sum sigma_k)^2, and this criterion gives its
  n_red = 76 / 98 for e = 0.99 / 0.9999, the squared one 54 / 76).
"""

import equinox as eqx
import jax
import jax.lax as lax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Basis, Float, Snapshots
from .._errors import MARK, array_module, as_float, check, check_x64

CRITERIA = ("squared", "paper")
METHODS = ("svd", "snapshots")  # the full PODs (all a scene file may name)
ALL_METHODS = (*METHODS, "randomized")  # plus the truncated one, which needs a rank


class _Decomposition(eqx.Module):
    """Singular values (descending) and proper orthogonal modes of a snapshot matrix (eq. 3.6).

    ``singular_values``: sigma_1 >= ... >= sigma_k, (k,) with k = min(n, m) (or the requested
    rank of a randomized POD), in snapshot units; ``modes``: the POMs phi_1..phi_k, (n, k) with
    orthonormal columns (the left singular vectors P of eq. 3.6).

    ``rounding_level`` is the sigma_k / sigma_1 at or below which a singular value is rounding
    noise (set by ``pod``; None for a POD built by hand: 4 max(modes.shape) eps). ``total_energy``
    is None when ``singular_values`` are all min(n, m) of them (``"svd"``, ``"snapshots"``). A
    ``"randomized"`` POD holds only the leading k values and modes, so ``basis(r)`` needs
    r <= k, ``numerical_rank()`` counts among those k only, and ``total_energy`` = ||Q||_F^2 =
    sum of *all* sigma_k^2 supplies the denominator of the ``"squared"`` energy fraction; the
    ``"paper"`` criterion needs sum of all sigma_k, which a truncated POD does not know, so it is
    refused.
    """

    singular_values: Float[Array, " k"]
    modes: Float[Array, "n k"]
    total_energy: Float[Array, ""] | None = None
    rounding_level: float | None = eqx.field(default=None, static=True)

    def _level(self) -> float:
        if self.rounding_level is not None:
            return self.rounding_level
        return 4 * max(self.modes.shape) * float(np.finfo(np.float64).eps)

    def basis(self, rank: int) -> Basis:
        """The projection matrix Phi = [phi_1, ..., phi_r] (eq. 3.8): (n, r), orthonormal columns.

        A rank above the numerical rank (``numerical_rank``) is a ``ValueError``: the modes past it
        are rounding noise. Under ``jit`` (traced singular values) the same check is an
        ``eqx.error_if``.
        """
        if isinstance(rank, bool) or not isinstance(rank, int | np.integer):
            raise ValueError(MARK + f"rank must be an integer, got {rank!r}.")
        available = self.modes.shape[1]
        if not 1 <= rank <= available:
            raise ValueError(MARK + f"rank must lie in 1..{available} (the number of modes), "
                             f"got {rank}.")
        s = self.singular_values
        if isinstance(s, jax.core.Tracer) or isinstance(self.modes, jax.core.Tracer):
            # sorted descending: the rank exceeds the numerical rank iff sigma_rank is noise
            return check(self.modes[:, :rank], ~(s[rank - 1] > self._level() * s[0]),
                         f"rank = {rank} exceeds the numerical rank of the snapshots (sigma_{rank} "
                         f"<= {self._level():.1e} sigma_1 is rounding noise); choose a smaller "
                         "rank.")
        numerical = self.numerical_rank()
        if numerical == 0:
            raise ValueError(MARK + f"rank = {rank} exceeds the numerical rank 0 of the snapshots: "
                             "they are zero (up to rounding), so there is no basis; check the "
                             "excitation and the snapshot window.")
        if rank > numerical:
            raise ValueError(MARK + f"rank = {rank} exceeds the numerical rank {numerical} of "
                             "the snapshots (the other singular values are rounding noise); "
                             f"choose rank <= {numerical}.")
        return self.modes[:, :rank]

    def energy_fraction(self, criterion: str = "squared") -> Float[Array, " k"]:
        """Captured pseudo-energy fraction for r = 1..k under ``criterion`` (eq. 3.7): (k,).

        Entry r - 1 is the fraction of the first r modes (see the module docstring's criteria).
        """
        if self.total_energy is None:
            return energy_fraction(self.singular_values, criterion)
        _check_truncated_criterion(criterion, len(self.singular_values))
        return jnp.cumsum(self.singular_values**2) / self.total_energy

    def rank_for_energy(self, energy: float, criterion: str = "squared") -> int:
        """Smallest rank r whose pseudo-energy fraction (eq. 3.7) is at least ``energy``.

        0 < energy <= 1 (the paper's eq. 5.3: 0.99, and 0.9999); a Python integer, at most the
        numerical rank (``energy = 1`` gives it). ``criterion``: "squared" (eq. 3.7) or "paper"
        (the reading that gives the paper's 76 and 98; see the module docstring).

        For a truncated (randomized) POD, "squared" only, and an error when the k leading modes
        do not reach ``energy``.
        """
        if self.total_energy is None:
            return _rank_for_energy(self.singular_values, energy, criterion, self._level())
        _check_energy(energy)
        fraction = np.asarray(self.energy_fraction(criterion))
        slack = 4 * max(self.modes.shape) * np.finfo(np.float64).eps
        if not np.all(np.isfinite(fraction)) or fraction[-1] < energy - slack:
            raise ValueError(MARK + f"the {fraction.size} computed modes capture a fraction "
                             f"{fraction[-1]:.6g} of the energy, below energy = {energy!r}; "
                             "compute more (a larger rank) or use method='svd'.")
        return _capped(fraction, energy, slack, self.numerical_rank())

    def numerical_rank(self) -> int:
        """Number of singular values above ``rounding_level`` * sigma_1 (the rest is rounding).

        A Python integer; the largest rank ``basis`` accepts.
        """
        return _count_above(self.singular_values, self._level())


def _count_above(singular_values, level: float) -> int:
    """The numerical rank: the number of singular values above level * sigma_1."""
    s = np.asarray(singular_values)
    if s.size == 0 or s[0] == 0:
        return 0
    return int(np.sum(s > level * s[0]))


def _capped(fraction, energy, slack, numerical: int) -> int:
    """The smallest r reaching ``energy``, never past the numerical rank: the modes beyond it are
    noise, and an e near 1 that only their sum reaches (the ``"paper"`` criterion sums sigma_k,
    so noise weighs more) gets the same rank as e = 1 (monotone in e)."""
    if energy == 1:
        return max(1, numerical)
    return min(int(np.argmax(fraction >= energy - slack)) + 1, max(1, numerical))


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


@jax.jit(static_argnames=("rank", "sketch", "power_iterations"))
def _pod_randomized(q, key, *, rank, sketch, power_iterations):
    # Halko et al. (2011) Alg. 4.4: range of (Q Q^T)^p Q Omega with a QR after every product
    # (plain powers lose the small directions to rounding), then Alg. 5.1: SVD of B = U^T Q.
    omega = jax.random.normal(key, (q.shape[1], sketch), dtype=jnp.float64)
    range_basis = jnp.linalg.qr(q @ omega)[0]

    def power_step(_, u):
        return jnp.linalg.qr(q @ jnp.linalg.qr(q.T @ u)[0])[0]

    range_basis = lax.fori_loop(0, power_iterations, power_step, range_basis)
    w, s, _ = jnp.linalg.svd(range_basis.T @ q, full_matrices=False)
    return s[:rank], _fix_signs(range_basis @ w[:, :rank]), jnp.sum(q * q)


def _count(value, name: str, low: int, high: int | None = None) -> int:
    """A Python integer in low..high (a shape: must be static, never traced)."""
    allowed = f"{low}..{high}" if high is not None else f">= {low}"
    if (isinstance(value, bool) or not isinstance(value, int | np.integer)
            or value < low or (high is not None and value > high)):
        raise ValueError(MARK + f"{name} must be an integer {allowed}, got {value!r}.")
    return int(value)


def _prng_key(key):
    if key is None:
        return jax.random.key(0)
    dtype = getattr(key, "dtype", None)
    if dtype is not None and jnp.issubdtype(dtype, jax.dtypes.prng_key) and key.shape == ():
        return key
    if dtype == jnp.uint32 and key.shape == (2,):  # a raw jax.random.PRNGKey
        return key
    raise ValueError(MARK + f"key must be a jax.random.key (or PRNGKey), got {key!r}.")


def pod(snapshots: Snapshots, *, method: str = "svd", rank: int | None = None,
        oversampling: int = 10, power_iterations: int = 2, key=None) -> "_Decomposition":
    """POD of the (n, m) snapshot matrix Q = [x_1, ..., x_m] (eqs. 3.5-3.6): a decomposition
    (``ReductionStats.decomposition`` of a ``POD`` reduction).

    One column per time instant (n DOFs, m snapshots): from a ``Trajectory``, Q =
    ``displacement.T`` (its rows are times). ``method="svd"`` (default) is the accurate thin SVD;
    ``"snapshots"`` uses the eigenvectors of the smaller of Q Q^T and Q^T Q, for snapshot sets
    much longer (or much taller) than the other side. Returns all min(n, m) singular values and
    modes; choose the rank with ``rank_for_energy`` or pass it to ``basis``: a rank above
    the numerical rank (the values above rounding noise, ``numerical_rank``) is a
    ``ValueError``, never silently capped, and ``energy = 1`` gives the numerical rank.
    Jit-compiled; may itself be jit-ed, vmap-ed and differentiated.

    ``"randomized"`` returns only the leading ``rank`` values and modes (1 <= rank <= min(n, m),
    required), from a Gaussian sketch of ``rank + oversampling`` columns (capped at min(n, m);
    oversampling >= 0) refined by ``power_iterations`` >= 0 subspace iterations; ``key`` (a
    ``jax.random.key``, default ``key(0)``) makes it deterministic. These three counts fix array
    shapes: pass Python integers (static under ``jit``). See ``_Decomposition`` for what a
    truncated POD can and cannot tell about the energy.
    """
    check_x64()
    if method not in ALL_METHODS:
        raise ValueError(MARK + f"method must be one of {ALL_METHODS}, got {method!r}.")
    q = as_float(snapshots, "snapshots")
    if q.ndim != 2 or min(q.shape) < 1:
        raise ValueError(MARK + f"snapshots must be a non-empty (n, m) matrix, got {q.shape}.")
    if not isinstance(q, jax.core.Tracer) and not np.all(np.isfinite(q)):
        raise ValueError(MARK + "snapshots must be finite (the simulation produced NaN or inf).")
    level = 4 * max(q.shape) * float(np.finfo(np.float64).eps)  # see the module docstring
    if method != "randomized":
        if rank is not None or key is not None:
            raise ValueError(MARK + "rank and key apply to method='randomized' only; choose the "
                             "rank of a full POD with the decomposition's basis(rank).")
        if method == "svd":
            return _Decomposition(*_pod_svd(q), rounding_level=level)
        return _Decomposition(*_pod_snapshots(q), rounding_level=float(np.sqrt(level)))
    smaller = min(q.shape)
    rank = _count(rank, "rank (required for method='randomized')", 1, smaller)
    oversampling = _count(oversampling, "oversampling", 0)
    power_iterations = _count(power_iterations, "power_iterations", 0)
    s, u, total = _pod_randomized(q, _prng_key(key), rank=rank, power_iterations=power_iterations,
                                  sketch=min(rank + oversampling, smaller))
    return _Decomposition(s, u, total, rounding_level=level)


def energy_fraction(singular_values, criterion: str = "squared"):
    """Captured pseudo-energy fraction for r = 1..k (eq. 3.7) of (k,) singular values: (k,).

    ``criterion``: "squared", sum_{j<=r} sigma_j^2 / sum_j sigma_j^2 (eq. 3.7 literally), or
    "paper", (sum_{j<=r} sigma_j / sum_j sigma_j)^2 (the reading of Section 5, eqs. 5.2-5.3).
    """
    if criterion not in CRITERIA:
        raise ValueError(MARK + f"criterion must be one of {CRITERIA}, got {criterion!r}.")
    xp = array_module(singular_values)  # concrete: numpy, as the rank rules read it
    s = xp.asarray(singular_values)
    with np.errstate(invalid="ignore", divide="ignore"):  # all zero: NaN, refused by the rules
        fraction = (xp.cumsum(s**2) / xp.sum(s**2) if criterion == "squared"
                    else (xp.cumsum(s) / xp.sum(s)) ** 2)
    return jnp.asarray(fraction)


def _check_energy(energy) -> None:
    if isinstance(energy, bool) or not isinstance(energy, float | int) or not 0 < energy <= 1:
        raise ValueError(MARK + f"energy must be a number in (0, 1], got {energy!r}.")


def _check_truncated_criterion(criterion: str, k: int) -> None:
    if criterion not in CRITERIA:
        raise ValueError(MARK + f"criterion must be one of {CRITERIA}, got {criterion!r}.")
    if criterion != "squared":
        raise ValueError(MARK + f"criterion {criterion!r} needs the sum of all singular values, "
                         f"but this (randomized) POD holds only the leading {k}; use "
                         "criterion='squared' (its total, ||Q||_F^2, is known) or method='svd'.")


def rank_for_energy(singular_values, energy: float, criterion: str = "squared") -> int:
    """Smallest rank r whose pseudo-energy fraction (eq. 3.7) is at least ``energy``: an integer.

    ``singular_values``: (k,), descending; 0 < energy <= 1 (eq. 5.3: 0.99); ``criterion`` as in
    ``energy_fraction`` ("paper" gives the paper's r = 76 and 98 for 0.99 and 0.9999).

    Never past the numerical rank (here: values above 4 k eps sigma_1, k of them; the
    decomposition's own method knows the snapshot shape and method); ``energy = 1`` gives it.
    ``singular_values`` are taken as all of them: for a truncated (randomized) POD use the
    decomposition's ``rank_for_energy``, which knows the total energy.
    """
    level = 4 * np.size(singular_values) * float(np.finfo(np.float64).eps)
    return _rank_for_energy(singular_values, energy, criterion, level)


def _rank_for_energy(singular_values, energy, criterion: str, level: float) -> int:
    _check_energy(energy)
    fraction = np.asarray(energy_fraction(singular_values, criterion))
    if fraction.size == 0 or not np.all(np.isfinite(fraction)):
        raise ValueError(MARK + "singular values must be finite and not all zero.")
    # A fraction within rounding of the target counts as reaching it (cumsum error ~ k eps).
    slack = 4 * fraction.size * np.finfo(np.float64).eps
    return _capped(fraction, energy, slack, _count_above(singular_values, level))
