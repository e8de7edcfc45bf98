"""Internals that benchmarks and tests need by name, documented here but outside the stable API
(they may change with the operators and solvers they come from). Import them from here, never from
the private modules:

* ``stiffness_rate(system)``: rho = max(highest eigenfrequency, fastest damper decay rate), the
  host-side bound ``choose_solver`` compares with the horizon (Gershgorin bounds for a diagonal
  mass, exact values otherwise); ``choose_solver(model, ts, load)``: the rule of ``Auto().select``
  as a name ("exact", "kvaerno5", "dopri8");
* ``Diagonal(diagonal)``, ``Dense(matrix)``, ``Sparse(rows, cols, values, n)``: the matrix
  operators a system holds (0-based coordinate indices for ``Sparse``, both triangles stored),
  to hand ``system`` an explicit form (e.g. a dense mass operator) instead of letting it choose
  the structure of an array;
* ``criterion_function(system, objective)``: d -> (f, df/dd), the compiled objective (one of
  ``Energy``, ``AverageEnergy``, ``OutputEnergy``, ``H2Norm``, ``Peak``) that ``Coefficients``
  minimises over the coefficient vector d;
* ``DamperProblem(system, ts, x0, v0, load, objective=..., ...)`` and ``placement_objective(
  problem, basis=None)``: the design problem ``ScreenAndCertify`` and ``Grid`` build from a
  ``DamperDesign``, and its objective as a function (positions (g,), coefficients (g,)) -> J,
  reduced on a fixed (n, r) basis or full; ``LBFGS``: the optax L-BFGS (backtracking line
  search) of the polish, for ``ScreenAndCertify(optimizer=LBFGS)``;
* ``spectral_energy_with_result(system, horizon, x0, v0, block=None)``: (J, ok) of
  ``integrated_energy(method="spectral")``; ``block=0`` forms the O(n^2) work all at once from
  U (the layout before the blocks, for the benchmarks' comparison), None is the library's choice;
* ``pod(snapshots, method=..., rank=...)``: the POD of an (n, m) snapshot matrix as it is (the
  decomposition a ``POD`` reduction keeps in ``stats.decomposition``), ``PODDecomposition`` its
  class and ``energy_fraction(singular_values, criterion)`` eq. (3.7), for benchmarks that time
  or probe the decomposition itself (a reduced model: ``reduce(scene, POD(...))``).
"""

from ._model.chain_modes import chain_mode_data as chain_mode_data
from ._model.chain_modes import chain_modes as chain_modes
from ._model.modal import generalized_modes as generalized_modes
from ._model.operators import Dense as Dense
from ._model.operators import Diagonal as Diagonal
from ._model.operators import Sparse as Sparse
from ._placement.certify import LBFGS as LBFGS
from ._placement.objective import placement_objective as placement_objective
from ._placement.problem import DamperProblem as DamperProblem
from ._placement.viscosity import criterion_function as criterion_function
from ._rom.pod import _Decomposition as PODDecomposition
from ._rom.pod import energy_fraction as energy_fraction
from ._rom.pod import pod as pod
from ._solver.exact import dense_solve_with_result as dense_solve_with_result
from ._solver.select import choose_solver as choose_solver
from ._solver.select import stiffness_rate as stiffness_rate
from ._solver.spectral.energy import spectral_energy_with_result as spectral_energy_with_result
from ._solver.spectral.modes import damped_modes as damped_modes
from ._solver.spectral.response import spectral_solve_with_result as spectral_solve_with_result

__all__ = ["Dense", "Diagonal", "Sparse", "chain_mode_data", "chain_modes", "damped_modes",
           "dense_solve_with_result", "generalized_modes", "spectral_solve_with_result",
           "spectral_energy_with_result", "stiffness_rate", "choose_solver", "criterion_function",
           "DamperProblem", "placement_objective", "LBFGS", "pod", "PODDecomposition",
           "energy_fraction"]
