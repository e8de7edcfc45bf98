"""How far a reduced (lifted) solution is from the full one: the paper's phase error (eq. 5.4)
and relative errors of (N, n) histories, and the POD pseudo-energy of singular values (eq. 3.7).
"""

from ._metrics import phase_error as phase_error
from ._metrics import pseudo_energy as pseudo_energy
from ._metrics import relative_error as relative_error

__all__ = ["phase_error", "pseudo_energy", "relative_error"]
