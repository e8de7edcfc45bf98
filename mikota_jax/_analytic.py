"""Closed-form facts of Mikota's chain: eigenfrequencies (eq. 2.4) and polynomial mode shapes.

The mode shape u_l has coordinates u_{l,i} = p_l(i), a polynomial of degree l in the 1-based DOF
index i (eq. 2.5). With m_i = m/i and k_i = (n-i+1)k, multiplying row i of K u = lambda M u by i/k
turns the eigen-equation into a linear difference equation in i,

    L[p](i) = i * [ (n+1-i) (p(i) - p(i-1)) - (n-i) (p(i+1) - p(i)) ] = (lambda m / k) p(i),

which maps polynomials of degree d to degree d with leading factor d^2. In the monomial basis L is
upper triangular with diagonal 0, 1, 4, ..., so lambda = l^2 k/m and the coefficients of p_l follow
by back substitution, exactly, in rational arithmetic. Since L[p](0) = 0, p_l(0) = 0: the fixed
support is satisfied automatically. The mode shapes do not depend on m and k.
"""

import functools
from fractions import Fraction
from math import comb

import jax.numpy as jnp
import numpy as np

from ._custom_types import ScalarLike, Vector
from ._errors import MARK, positive_scalar


def _check_nl(n: int, l: int) -> None:
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(MARK + f"n must be an integer >= 1, got {n!r}.")
    if isinstance(l, bool) or not isinstance(l, int) or not 1 <= l <= n:
        raise ValueError(MARK + f"mode number l must be an integer in 1..{n}, got {l!r}.")


def eigenfrequencies(n: int, m: ScalarLike = 1.0, k: ScalarLike = 1.0) -> Vector:
    """Mikota's eigenfrequencies Omega_l = l sqrt(k/m), l = 1..n (eq. 2.4): an (n,) array.

    ``m`` is the first mass and ``k`` the last spring's stiffness (eq. 2.3), in consistent units
    (the paper's are dimensionless); the result is in rad per unit time, ascending.
    """
    _check_nl(n, 1)
    m, k = positive_scalar(m, "m"), positive_scalar(k, "k")
    return jnp.arange(1, n + 1, dtype=jnp.float64) * jnp.sqrt(k / m)


@functools.lru_cache(maxsize=8)
def _difference_operator(n: int, degree: int) -> tuple[tuple[int, ...], ...]:
    """T[j][d] = coefficient of i^j in L[i^d], for d, j <= degree (integers)."""
    table = []
    for d in range(degree + 1):
        back = [comb(d, j) * (-1) ** (d - j) for j in range(d + 1)]  # (i-1)^d
        fwd = [comb(d, j) for j in range(d + 1)]  # (i+1)^d
        nabla = [(1 if j == d else 0) - back[j] for j in range(d + 1)]  # p(i) - p(i-1)
        delta = [fwd[j] - (1 if j == d else 0) for j in range(d + 1)]  # p(i+1) - p(i)
        inner = [0] * (d + 2)  # (n+1-i) nabla - (n-i) delta
        for j in range(d + 1):
            inner[j] += (n + 1) * nabla[j] - n * delta[j]
            inner[j + 1] += -nabla[j] + delta[j]
        column = [0] + inner  # times i
        table.append(tuple(column[: degree + 1]) + (0,) * max(0, degree + 1 - len(column)))
    return tuple(tuple(table[d][j] for d in range(degree + 1)) for j in range(degree + 1))


def mode_shape_coefficients(n: int, l: int) -> tuple[Fraction, ...]:
    """Exact coefficients (c_0, ..., c_l) of the monic mode polynomial p_l(i) = sum_j c_j i^j.

    The mode shape u_l of Mikota's n-DOF chain has coordinates u_{l,i} = p_l(i) at the 1-based
    DOFs i = 1..n (eq. 2.5; eq. 2.6 prints l = 1, 2, 3). ``l`` is the 1-based mode number in
    1..n. Returns l + 1 ``Fraction``s (c_0 = 0: the fixed support), independent of m and k.
    """
    _check_nl(n, l)
    table = _difference_operator(n, l)
    if table[l][l] != l * l:  # the triangular structure claimed in the module docstring
        raise AssertionError("difference operator is not triangular with diagonal d^2")
    c = [Fraction(0)] * (l + 1)
    c[l] = Fraction(1)
    for j in range(l - 1, -1, -1):
        rhs = sum((table[j][d] * c[d] for d in range(j + 1, l + 1)), Fraction(0))
        c[j] = rhs / (l * l - j * j)
    return tuple(c)


def _evaluate(coefficients, i: int) -> Fraction:
    value = Fraction(0)
    for c in reversed(coefficients):
        value = value * i + c
    return value


def mode_shape(n: int, l: int, normalize: str | None = "max") -> Vector:
    """Mode shape u_l = (p_l(1), ..., p_l(n)) of Mikota's chain (eq. 2.5): an (n,) array.

    ``l`` is the 1-based mode number in 1..n (eigenfrequency l sqrt(k/m), eq. 2.4); entry i - 1
    belongs to DOF i. Evaluated exactly in rational arithmetic, then rounded once to float64.
    ``normalize="max"`` scales by max_i |p_l(i)| (exactly, before rounding, so high modes do not
    overflow); ``None`` returns the monic polynomial's values as in eq. (2.6). Dimensionless and
    independent of m and k.
    """
    coefficients = mode_shape_coefficients(n, l)
    values = [_evaluate(coefficients, i) for i in range(1, n + 1)]
    if normalize == "max":
        scale = max(abs(v) for v in values)
        values = [v / scale for v in values]
    elif normalize is not None:
        raise ValueError(MARK + f"normalize must be 'max' or None, got {normalize!r}.")
    return jnp.asarray(np.array([float(v) for v in values]))


def paper_mode_shape(n: int, l: int) -> Vector:
    """The paper's closed-form mode polynomials p_1, p_2, p_3 (eq. 2.6) at i = 1..n: an (n,) array.

    ``l`` in 1, 2, 3 (1-based mode number); unnormalised (monic), as printed. For l > 3 use
    ``mode_shape``.
    """
    _check_nl(n, l)
    i = jnp.arange(1, n + 1, dtype=jnp.float64)
    if l == 1:
        return i
    if l == 2:
        return i**2 - (2 * n + 1) / 3 * i
    if l == 3:
        return i**3 - 3 / 5 * (2 * n + 1) * i**2 + (1.5 * n * (n + 1) + 1) / 5 * i
    raise ValueError(MARK + f"eq. (2.6) gives l = 1, 2, 3 only, got l = {l}; use mode_shape.")
