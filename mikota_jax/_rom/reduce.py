"""``reduce(problem, strategy)``: one verb for every reduction, a strategy per basis.

``problem`` is a ``SecondOrderSystem`` or a ``Scene`` (a system with its excitation, time grid and
snapshot settings); ``strategy`` an ``AbstractReduction``. ``reduce`` asks the strategy for an
(n, r) orthonormal basis Phi, checks it, and returns the Galerkin ``ReducedModel`` (eq. 3.4) with
its ``ReductionStats``. Structural strategies (``Modal``, ``ModalStatic``, ``CraigBampton``,
``Krylov``, ``RationalKrylov``, ``IRKA``, ``Projection``) take either kind of problem (a scene
gives its system); snapshot strategies (``POD``, and ``EnrichedPOD`` and ``Greedy``, which
live with the estimates that drive them in ``_estimation``) need a ``Scene``.

``rank`` is the final column count everywhere. A strategy that cannot reach the rank asked for
(the snapshots' numerical rank, dependent Krylov columns, rank > n) raises a ``ValueError``
naming the reachable maximum; it never returns fewer columns silently.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import MARK
from .._model.reduced import ReducedModel, ReductionStats, _project, check_basis
from .base import AbstractIOReduction, AbstractReduction, problem_system
from .classic import (
    _KRYLOV_DEPENDENT,
    _check,
    _force_columns,
    craig_bampton_basis,
    damper_directions,
    extend_basis,
    krylov_basis,
    modal_basis,
    modal_static_basis,
)
from .io_model import IOModel
from .lti import LTIModel


def reduce(problem, strategy: AbstractReduction | AbstractIOReduction
           ) -> ReducedModel | IOModel | LTIModel:
    """The reduced model of ``problem`` by ``strategy``: Phi^T M Phi q'' + Phi^T D Phi q' +
    Phi^T K Phi q = Phi^T f (eq. 3.4) on the strategy's (n, r) orthonormal basis Phi, x ~ Phi q
    (eq. 3.2).

    ``problem``: a ``SecondOrderSystem`` or a ``Scene``, or an ``IOModel`` of a full system (then
    the result is the ``IOModel`` of the reduced model, with the same inputs and outputs);
    ``strategy``: an ``AbstractReduction`` (``Modal(10)``, ``POD(energy=0.9999)``, ...), or for
    an ``IOModel`` an ``AbstractIOReduction`` (``H2Optimal(10)``), whose result is an
    ``LTIModel`` built from the inputs and outputs. The
    result's ``stats`` says what the reduction did. Structural strategies whose basis is pure
    JAX (``Modal``, ``Projection``) pass ``jax.jit``, ``jax.vmap`` and ``jax.grad`` with respect
    to the system's values.
    """
    if isinstance(strategy, AbstractIOReduction):
        if not isinstance(problem, IOModel) or isinstance(problem.model, ReducedModel):
            raise ValueError(MARK + f"problem: {type(strategy).__name__} reduces an input-output "
                             "map: pass the IOModel of a full system, got "
                             f"{type(problem).__name__}.")
        return strategy.reduce_io(problem)
    if not isinstance(strategy, AbstractReduction):
        raise ValueError(MARK + f"strategy must be an AbstractReduction (Modal, POD, ...) or an "
                         f"AbstractIOReduction (H2Optimal), got {type(strategy).__name__}.")
    if isinstance(problem, IOModel):
        if isinstance(problem.model, ReducedModel):
            raise ValueError(MARK + "problem: this IOModel is reduced already; reduce the "
                             "IOModel of the full system.")
        return IOModel(reduce(problem.model, strategy), problem.inputs, *problem.outputs())
    system = problem_system(problem, type(strategy).__name__)
    result = strategy.basis(problem)
    if not (isinstance(result, tuple) and len(result) == 2):
        raise ValueError(MARK + f"{type(strategy).__name__}.basis must return (basis, stats), "
                         f"got {type(result).__name__}.")
    basis, stats = result
    basis = check_basis(basis, system.size)
    if stats is None:
        stats = ReductionStats(type(strategy).__name__, basis.shape[1])
    return ReducedModel(_project(system, basis), basis, stats)


def _unreachable(strategy: str, rank: int, reachable: int, why: str) -> ValueError:
    return ValueError(MARK + f"{strategy}: rank = {rank} is out of reach: {why} gives at most "
                      f"{reachable} columns; choose rank <= {reachable}.")


def _exact_rank(strategy: str, basis, rank: int, why: str):
    if basis.shape[1] < rank:
        raise _unreachable(strategy, rank, basis.shape[1], why)
    return basis


def _complex_tuple(values):
    """Shifts as a hashable tuple of Python complex numbers (None stays None)."""
    if values is None:
        return None
    return tuple(complex(z) for z in np.atleast_1d(np.asarray(values)))


class Modal(AbstractReduction):
    """Modal truncation: the ``rank`` lowest undamped modes, orthonormalised. Pure JAX (O(n r)
    for a fixed-free chain of n >= 256): ``jit``, ``vmap`` and ``grad`` pass through."""

    rank: int = eqx.field(static=True)

    def basis(self, problem):
        """(n, r) the r lowest undamped modes, orthonormal, and the stats."""
        system = problem_system(problem, "Modal")
        return modal_basis(system, self.rank), ReductionStats("Modal", self.rank,
                                                              modes=self.rank)


def _fill(strategy: str, rank: int, extra: int, build, most: int):
    """(basis, modes): ``build(modes)`` with the fewest modes whose basis has ``rank`` columns
    (modes + the static directions outside their span, at most ``extra`` of them)."""
    if isinstance(rank, bool) or not isinstance(rank, int) or rank < 1:
        raise ValueError(MARK + f"{strategy}: rank must be an integer >= 1, got {rank!r}.")
    modes = max(1, min(rank - extra, most))
    while True:
        basis = build(modes)
        if basis.shape[1] >= rank:
            return basis[:, :rank], modes
        if modes >= most:
            raise _unreachable(strategy, rank, basis.shape[1],
                               f"{most} modes and the static directions")
        modes = min(modes + rank - basis.shape[1], most)


def _columns(value, system, name):
    return 0 if value is None else _force_columns(system, value, name).shape[1]


class ModalStatic(AbstractReduction):
    """Modal truncation with a static correction: the lowest undamped modes and the static
    responses K^-1 b of the damper directions (``dampers``) and of ``loads`` ((n,) or (n, s)),
    ``moments`` of them ((K^-1 M)^j K^-1 b, j < moments), then ``states`` kept as they are;
    ``rank`` columns in all, the modes filling what the static directions leave (stats:
    ``modes``)."""

    rank: int = eqx.field(static=True)
    loads: jax.Array | None = None
    dampers: bool = eqx.field(static=True, default=True)
    moments: int = eqx.field(static=True, default=1)
    states: jax.Array | None = None

    def basis(self, problem):
        """(n, r) modes and static directions, orthonormal, and the stats (``modes``)."""
        system = problem_system(problem, "ModalStatic")
        _check(system, self.rank)
        extra = self.moments * ((damper_directions(system).shape[1] if self.dampers else 0)
                                + _columns(self.loads, system, "loads"))
        extra += _columns(self.states, system, "states")
        basis, modes = _fill("ModalStatic", self.rank, extra, lambda m: modal_static_basis(
            system, m, loads=self.loads, dampers=self.dampers, moments=self.moments,
            states=self.states), system.size)
        return basis, ReductionStats("ModalStatic", self.rank, modes=modes)


class CraigBampton(AbstractReduction):
    """Craig-Bampton with the dampers as the interface: the lowest modes with every acting
    damper held (fixed-interface modes), ``moments`` static moments of the damper directions
    and of ``loads`` (constraint modes), then ``states`` ((n,) or (n, s); pass x0 and v0 so the
    model starts where the full one does); ``rank`` columns in all: held modes + static
    directions (stats: ``modes``, the held ones)."""

    rank: int = eqx.field(static=True)
    loads: jax.Array | None = None
    moments: int = eqx.field(static=True, default=3)
    states: jax.Array | None = None

    def basis(self, problem):
        """(n, r) held modes and static directions, orthonormal, and the stats."""
        from .classic import _damper_weights

        system = problem_system(problem, "CraigBampton")
        _check(system, self.rank)
        held = int(np.sum(_damper_weights(system) > 0))
        extra = self.moments * (damper_directions(system).shape[1]
                                + _columns(self.loads, system, "loads"))
        extra += _columns(self.states, system, "states")
        basis, modes = _fill("CraigBampton", self.rank, extra, lambda m: craig_bampton_basis(
            system, m, loads=self.loads, moments=self.moments, states=self.states),
            system.size - held)
        return basis, ReductionStats("CraigBampton", self.rank, modes=modes)


def _inputs(system, inputs, dampers: bool):
    columns = [] if inputs is None else [_force_columns(system, inputs, "inputs")]
    if dampers:
        columns.append(damper_directions(system))
    if not columns or sum(c.shape[1] for c in columns) == 0:
        raise ValueError(MARK + "inputs: give force directions (n,) or (n, s), or dampers=True "
                         "on a system with dampers.")
    return jnp.concatenate(columns, axis=1)


class Krylov(AbstractReduction):
    """Second-order Krylov (moment matching at s = 0, Bai & Su's SOAR) of ``rank`` columns for
    the force directions ``inputs`` ((n,) or (n, s); free vibration from x0: M x0), with the
    damper directions appended when ``dampers``. Dependent columns that leave fewer than
    ``rank`` are a ``ValueError``."""

    rank: int = eqx.field(static=True)
    inputs: jax.Array | None = None
    dampers: bool = eqx.field(static=True, default=False)

    def basis(self, problem):
        """(n, r) the Krylov basis of the inputs, orthonormal, and the stats."""
        system = problem_system(problem, "Krylov")
        basis = krylov_basis(system, self.rank, _inputs(system, self.inputs, self.dampers))
        basis = _exact_rank("Krylov", basis, self.rank,
                            "the Krylov space of these inputs (its further columns dependent)")
        return basis, ReductionStats("Krylov", self.rank)


class RationalKrylov(AbstractReduction):
    """Rational Krylov: Re and Im of X(sigma) = (sigma^2 M + sigma D + K)^-1 B at ``shifts``
    (complex, real part >= 0; or a count: that many shifts spread over the band the inputs
    excite), orthonormalised; ``inputs`` and ``dampers`` as ``Krylov``'s. The rank is the
    columns that are independent (stats: ``rank``, ``shifts``)."""

    shifts: tuple[complex, ...] | int = eqx.field(static=True)
    inputs: jax.Array | None = None
    dampers: bool = eqx.field(static=True, default=False)

    def __init__(self, shifts, inputs=None, dampers: bool = False):
        if not isinstance(shifts, int) or isinstance(shifts, bool):
            shifts = _complex_tuple(shifts)
        self.shifts, self.inputs, self.dampers = shifts, inputs, dampers

    def basis(self, problem):
        """(n, r) the responses at the shifts, orthonormal, and the stats (``shifts``)."""
        from .interpolatory import band_shifts, rational_krylov_basis

        system = problem_system(problem, "RationalKrylov")
        forces = _inputs(system, self.inputs, self.dampers)
        shifts = (band_shifts(system, self.shifts, forces) if isinstance(self.shifts, int)
                  else np.asarray(self.shifts))
        basis = rational_krylov_basis(system, shifts, forces)
        return basis, ReductionStats("RationalKrylov", basis.shape[1],
                                     shifts=tuple(complex(z) for z in shifts))


class IRKA(AbstractReduction):
    """An interpolatory basis of ``rank`` columns whose shifts a second-order IRKA-type
    iteration chooses (dominant poles over ``horizon``); ``inputs`` and ``dampers`` as
    ``Krylov``'s; ``iterations``, ``tolerance``, start ``shifts`` (default band shifts).
    Stats: ``shifts``, ``iterations``, ``converged``, ``changes``."""

    rank: int = eqx.field(static=True)
    inputs: jax.Array | None = None
    horizon: float = eqx.field(static=True, default=1.0)
    iterations: int = eqx.field(static=True, default=30)
    tolerance: float = eqx.field(static=True, default=1e-6)
    shifts: tuple[complex, ...] | None = eqx.field(static=True, default=None,
                                                   converter=lambda z: _complex_tuple(z))
    dampers: bool = eqx.field(static=True, default=False)

    def basis(self, problem):
        """(n, r) the IRKA-type basis, orthonormal, and the stats (iterations, convergence)."""
        from .interpolatory import irka_basis

        system = problem_system(problem, "IRKA")
        found = irka_basis(system, self.rank, _inputs(system, self.inputs, self.dampers),
                           self.horizon, iterations=self.iterations, tolerance=self.tolerance,
                           shifts=None if self.shifts is None else np.asarray(self.shifts))
        basis = _exact_rank("IRKA", found.basis, self.rank,
                            "the responses at the shifts (their further columns dependent)")
        return basis, ReductionStats("IRKA", self.rank, shifts=found.shifts,
                                     iterations=found.iterations, converged=found.converged,
                                     changes=found.changes)


class Projection(AbstractReduction):
    """A basis of your own: ``basis`` (n, r) float64 with orthonormal columns (max
    |basis^T basis - I| <= 1e-6, else ``reduce`` raises a ``ValueError``; under ``jit`` an
    ``eqx.error_if``), for the problem's n."""

    matrix: jax.Array

    def __init__(self, basis):
        self.matrix = jnp.asarray(basis)

    def basis(self, problem):
        """(n, r) the given basis (checked against the problem's n) and the stats."""
        system = problem_system(problem, "Projection")
        return (check_basis(self.matrix, system.size),
                ReductionStats("Projection", self.matrix.shape[1]))


class Union(AbstractReduction):
    """The union of the strategies' bases, orthonormalised: the first's columns kept first, then
    each next one's directions outside the span so far (above rounding, 1e-14 of their length);
    e.g. ``Union(Modal(40), Projection(load_direction))``. Stats: ``parts``."""

    strategies: tuple[AbstractReduction, ...]

    def __init__(self, *strategies: AbstractReduction):
        if not strategies or not all(isinstance(s, AbstractReduction) for s in strategies):
            raise ValueError(MARK + "Union takes one or more strategies (AbstractReduction), got "
                             f"{[type(s).__name__ for s in strategies]}.")
        self.strategies = tuple(strategies)

    def basis(self, problem):
        """(n, r) the strategies' bases united in order, orthonormal, and the stats (``parts``)."""
        system = problem_system(problem, "Union")
        bases, parts = [], []
        for strategy in self.strategies:
            basis, stats = strategy.basis(problem)
            basis = check_basis(basis, system.size)
            bases.append(basis)
            parts.append(stats if stats is not None
                         else ReductionStats(type(strategy).__name__, basis.shape[1]))
        basis = bases[0]
        for extra in bases[1:]:
            basis = extend_basis(basis, extra, _KRYLOV_DEPENDENT)[:, : system.size]
        return basis, ReductionStats("Union", basis.shape[1], parts=tuple(parts))
