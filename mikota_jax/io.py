"""Matrices from and to files: NumPy ``.npz`` and Matrix Market ``.mtx``/``.mtx.gz``, read into
what ``mikota_jax.system`` takes (a dense array, or a SciPy sparse array where SciPy is
installed), written from a system's operators.
"""

from ._io import load_matrix as load_matrix
from ._io import save_matrix_market as save_matrix_market

__all__ = ["load_matrix", "save_matrix_market"]
