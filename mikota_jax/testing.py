"""Internals that benchmarks and tests need by name, documented here but outside the stable API
(they may change with the operators and solvers they come from). Import them from here, never from
the private modules:

* ``stiffness_rate(system)``: rho = max(highest eigenfrequency, fastest damper decay rate), the
  host-side bound ``choose_solver`` compares with the horizon (Gershgorin bounds for a diagonal
  mass, exact values otherwise);
* ``Diagonal(diagonal)``, ``Dense(matrix)``, ``Sparse(rows, cols, values, n)``: the matrix
  operators a system holds (0-based coordinate indices for ``Sparse``, both triangles stored),
  to hand ``system`` an explicit form (e.g. a dense mass operator) instead of letting it choose
  the structure of an array.
"""

from ._operators import Dense as Dense
from ._operators import Diagonal as Diagonal
from ._operators import Sparse as Sparse
from ._solver_choice import stiffness_rate as stiffness_rate

__all__ = ["Dense", "Diagonal", "Sparse", "stiffness_rate"]
