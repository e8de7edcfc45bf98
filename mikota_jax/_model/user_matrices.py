"""``system``: a second-order system from a user's matrices, converted once to structured operators.

Accepted forms of M, K and D, and the operator each becomes (what structure it keeps):

- a 1-d (n,) array: a diagonal (``Diagonal``, O(n) products, M^-1 elementwise);
- a tuple of 1-d arrays ``(main, first super-diagonal, second, ...)`` of lengths n, n - 1, ...:
  symmetric banded (``SymmetricTridiagonal`` for two bands, ``SymmetricBanded`` beyond: O(n b));
- a scipy.sparse matrix or array: ``Diagonal``/``SymmetricTridiagonal`` when its entries lie on
  those bands (a tridiagonal may carry up to 32 off-band springs, entries <= 0, as "links": a
  branched chain), else coordinate ``Sparse`` (O(nnz) products); scipy is needed only to hand
  one in;
- a 2-d (n, n) array: the same detection when its values are concrete, else ``Dense`` (O(n^2)
  products; a traced matrix, e.g. one being differentiated, stays dense);
- an operator of this package, as it is.

A tridiagonal mass (a consistent finite-element mass of a bar) is solved in its structure, one
O(n) tridiagonal solve per evaluation; any other non-diagonal mass in modal coordinates, after one
dense n x n eigendecomposition per solve. Checks on construction: shapes, finite entries, symmetry
(to 1e-12 of the largest entry), M and K positive definite, D positive semi-definite; each error
names the matrix.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import MARK, as_float, check, is_traced
from .dampers import DamperArgument
from .internal_damping import ModalDamping, Rayleigh, as_internal
from .operators import Dense, Diagonal, Sparse, SymmetricBanded, SymmetricTridiagonal
from .system import SecondOrderSystem, dampers_operator

# definiteness of a non-tridiagonal matrix is checked densely (Cholesky / eigvalsh) up to this n
DENSE_CHECK_LIMIT = 4000
SYMMETRY = 1e-12  # relative to the largest |entry|
MAX_LINKS = 32  # off-band springs a tridiagonal operator carries (Woodbury rank in stiff solves)
_STRUCTURED = (Diagonal, SymmetricTridiagonal, SymmetricBanded, Sparse, Dense)


def _is_scipy_sparse(x) -> bool:
    return type(x).__module__.startswith("scipy.sparse")


def _from_bands(bands, name: str):
    bands = [as_float(b, f"{name} band {j}") for j, b in enumerate(bands)]
    n = bands[0].shape[0] if bands and bands[0].ndim == 1 else 0
    if n < 1 or any(b.shape != (n - j,) for j, b in enumerate(bands)) or len(bands) > n:
        raise ValueError(MARK + f"{name}: bands must be 1-d arrays of lengths n, n - 1, ... (the "
                         f"main diagonal first), got shapes {[tuple(b.shape) for b in bands]}.")
    if len(bands) == 1:
        return Diagonal(bands[0])
    if len(bands) == 2:
        return SymmetricTridiagonal(bands[0], bands[1])
    return SymmetricBanded(jnp.stack([jnp.pad(b, (0, j)) for j, b in enumerate(bands)]))


def _from_scipy(matrix, name: str):
    coo = matrix.tocoo()
    coo.sum_duplicates()
    if coo.shape[0] != coo.shape[1]:
        raise ValueError(MARK + f"{name} must be square, got shape {coo.shape}.")
    if not np.issubdtype(coo.dtype, np.floating) and not np.issubdtype(coo.dtype, np.integer):
        raise ValueError(MARK + f"{name} must be real, got {coo.dtype}.")
    rows, cols = coo.row.astype(np.int64), coo.col.astype(np.int64)
    values = np.asarray(coo.data, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        raise ValueError(MARK + f"{name} must be finite.")
    n = coo.shape[0]
    scale = np.max(np.abs(values), initial=0.0)
    difference = (coo - coo.T).tocoo()
    asymmetry = np.max(np.abs(difference.data), initial=0.0)
    if asymmetry > SYMMETRY * scale:
        raise ValueError(MARK + f"{name} must be symmetric: max |A - A^T| = {asymmetry:.3g} "
                         f"against max |A| = {scale:.3g}.")
    structured = _banded_structure(rows, cols, values, n)
    if structured is not None:
        return structured
    return Sparse(jnp.asarray(rows), jnp.asarray(cols), jnp.asarray(values), n)


def _banded_structure(rows, cols, values, n: int):
    """``Diagonal``, or ``SymmetricTridiagonal`` (with links: at most ``MAX_LINKS`` off-band
    pairs, each <= 0 like a spring's) for symmetric entries at 0-based (rows, cols); else None."""
    main = np.zeros(n)
    np.add.at(main, rows[rows == cols], values[rows == cols])
    if np.all(rows == cols):
        return Diagonal(jnp.asarray(main))
    upper = np.zeros(max(n - 1, 0))
    np.add.at(upper, rows[cols == rows + 1], values[cols == rows + 1])
    far = (cols > rows + 1) & (values != 0)
    if far.sum() > MAX_LINKS or np.any(values[far] > 0):
        return None
    links = tuple((int(i), int(j)) for i, j in zip(rows[far], cols[far]))
    springs = jnp.asarray(-values[far]) if links else None
    return SymmetricTridiagonal(jnp.asarray(main), jnp.asarray(upper), None, links, springs)


def _from_dense(array, name: str):
    """A concrete dense matrix that is diagonal or tridiagonal (with a few links) in that
    structure; anything else, or a traced one, stays ``Dense``."""
    if is_traced(array):
        return Dense(array)
    host = np.asarray(array)
    rows, cols = np.nonzero(host)
    if not (np.all(np.isfinite(host)) and np.array_equal(host, host.T)):
        return Dense(array)  # the checks name what is wrong
    structured = _banded_structure(rows, cols, host[rows, cols], host.shape[0])
    return Dense(array) if structured is None else structured


def as_matrix_operator(x, name: str):
    """One of the accepted forms (see the module docstring) as an operator, shape-checked."""
    if isinstance(x, _STRUCTURED):
        return x
    if _is_scipy_sparse(x):
        return _from_scipy(x, name)
    if isinstance(x, tuple):
        return _from_bands(x, name)
    array = as_float(x, name)
    if array.ndim == 1 and array.shape[0] >= 1:
        return Diagonal(array)
    if array.ndim == 2 and array.shape[0] == array.shape[1] and array.shape[0] >= 1:
        return _from_dense(array, name)
    raise ValueError(MARK + f"{name} must be an (n, n) matrix, an (n,) diagonal, a tuple of bands "
                     f"or a scipy.sparse matrix, got shape {array.shape}.")


def _smallest_pivot(diagonal, off):
    """min_i d_i of the LDL^T factorization of a symmetric tridiagonal matrix, O(n)."""
    def step(d, pair):
        a, b = pair
        d_next = a - b * b / d
        return d_next, d_next

    _, rest = jax.lax.scan(step, diagonal[0], (diagonal[1:], off))
    return jnp.minimum(diagonal[0], jnp.min(rest, initial=jnp.inf))


def _attach(operator, bad, message: str):
    """``operator`` with the check ``bad`` -> ``message`` on its array (eager or traced)."""
    field = next(f for f in ("diagonal", "bands", "values", "matrix")
                 if getattr(operator, f, None) is not None)
    return eqx.tree_at(lambda op: getattr(op, field), operator,
                       check(getattr(operator, field), bad, message))


def _check(operator, name: str, definite: bool, check_definite: bool):
    """``operator`` checked finite, symmetric and positive (semi-)definite (``definite``)."""
    what = "positive definite" if definite else "positive semi-definite"
    if isinstance(operator, Diagonal):
        d = operator.diagonal
        bad = ~jnp.all(jnp.isfinite(d) & ((d > 0) if definite else (d >= 0)))
        return _attach(operator, bad, f"{name} must be finite and {what} (a diagonal "
                                      f"{'> 0' if definite else '>= 0'}).")
    if isinstance(operator, SymmetricTridiagonal) and definite:
        # with links k (e_i - e_j)(e_i - e_j)^T, k >= 0: the tridiagonal rest positive definite
        # is enough (O(n)); a branched chain's is (each branch is grounded)
        d, e = operator.diagonal, operator.off_diagonal
        finite = jnp.all(jnp.isfinite(d)) & jnp.all(jnp.isfinite(e))
        if operator.links:
            k = operator.link_springs
            i, j = (np.asarray(a) for a in zip(*operator.links))
            d = d.at[i].add(-k).at[j].add(-k)
            finite = finite & jnp.all(jnp.isfinite(k)) & jnp.all(k >= 0)
        bad = ~finite | ~(_smallest_pivot(d, e) > 0)
        if not operator.links or is_traced(bad) or not bool(bad):
            return _attach(operator, bad, f"{name} must be finite and {what}.")
    if not check_definite:
        return operator
    if operator.size > DENSE_CHECK_LIMIT:
        raise ValueError(MARK + f"{name}: checking that it is {what} needs a dense "
                         f"factorization, refused above n = {DENSE_CHECK_LIMIT} (n = "
                         f"{operator.size}); check it yourself and pass check_definite=False.")
    matrix = operator.as_matrix()
    scale = jnp.max(jnp.abs(matrix))
    operator = _attach(operator, ~jnp.all(jnp.isfinite(matrix)), f"{name} must be finite.")
    operator = _attach(operator, jnp.max(jnp.abs(matrix - matrix.T)) > SYMMETRY * scale,
                       f"{name} must be symmetric (to {SYMMETRY:g} of its largest entry).")
    if definite:
        bad = ~jnp.all(jnp.isfinite(jnp.linalg.cholesky(matrix)))
    else:
        eigenvalues = jnp.linalg.eigvalsh((matrix + matrix.T) / 2)
        bad = jnp.min(eigenvalues) < -1e-12 * jnp.max(jnp.abs(eigenvalues))
    return _attach(operator, bad, f"{name} must be {what}.")


def system(mass, stiffness, damping=None, *,
           dampers: DamperArgument = (),
           internal_damping: Rayleigh | ModalDamping | tuple | None = None,
           check_definite: bool = True) -> SecondOrderSystem:
    """A second-order system M x'' + D x' + K x = f (eq. 3.1) from a user's matrices.

    ``mass`` M and ``stiffness`` K: symmetric positive definite, (n, n); ``damping`` D: symmetric
    positive semi-definite, or None. Each given as a dense (n, n) array, an (n,) diagonal, a tuple
    of bands (main diagonal, then super-diagonals), a scipy.sparse matrix or one of this package's
    operators; the module docstring lists the structure each keeps. ``dampers``:
    ``GroundedDamper``/``RelativeDamper`` (1-based DOFs; a list, or one alone) added to D;
    ``internal_damping``: ``Rayleigh(alpha, beta)``, ``ModalDamping(zeta)`` or both, added to D.
    Consistent units.

    Checks: shapes, finite entries, symmetry, definiteness (dense above tridiagonal, so refused
    beyond n = 4000 unless ``check_definite=False``); a ``ValueError`` names the matrix.
    """
    mass = _check(as_matrix_operator(mass, "mass"), "mass", True, check_definite)
    n = mass.size
    stiffness = as_matrix_operator(stiffness, "stiffness")
    matrix = None if damping is None else as_matrix_operator(damping, "damping")
    for name, operator in (("stiffness", stiffness), ("damping", matrix)):
        if operator is not None and operator.size != n:
            raise ValueError(MARK + f"{name} must be {n} x {n} like mass, got size "
                             f"{operator.size}.")
    stiffness = _check(stiffness, "stiffness", True, check_definite)
    if matrix is not None:
        matrix = _check(matrix, "damping", False, check_definite)
    return SecondOrderSystem(mass, stiffness, dampers_operator(n, dampers),
                             as_internal(internal_damping, n, matrix))
