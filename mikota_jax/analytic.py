"""Mikota's chain in closed form (Weber & Zastrau 2018, Section 2): the eigenfrequencies
l sqrt(k/m) (eq. 2.4) and the polynomial mode shapes (eqs. 2.5, 2.6), exact, for any n.

    >>> import mikota_jax as mj
    >>> mj.analytic.eigenfrequencies(300)[:3]   # 1, 2, 3 for m = k = 1
"""

from ._analytic import eigenfrequencies as eigenfrequencies
from ._analytic import mode_shape as mode_shape
from ._analytic import mode_shape_coefficients as mode_shape_coefficients
from ._analytic import paper_mode_shape as paper_mode_shape

__all__ = ["eigenfrequencies", "mode_shape", "mode_shape_coefficients", "paper_mode_shape"]
