"""Where several dampers go: a coordinate-wise search over candidate DOFs at full order.

``place_dampers`` moves the grounded dampers of a system among candidate DOFs, the coefficients
of all dampers (grounded and relative) re-optimised at each accepted placement by
``optimise_viscosities``. It is a coordinate-wise (block Gauss-Seidel) descent on the positions,
not an enumeration of the C(c, g) placements of g dampers on c candidates:

1. the start: the system's own positions, coefficients optimised there;
2. a sweep: for each grounded damper in turn, the criterion at every free candidate DOF, its
   coefficient at 0.1, 1 and 10 times its current value, the other dampers held (*screening*:
   one compiled ``lax.map``, exact, spectral); the ``keep`` best DOFs get all coefficients
   optimised (*polish*) and the best design so far is kept;
3. sweeps repeat until one moves no damper (a placement no single move improves: a
   coordinate-wise minimum), or ``max_sweeps``.

Each evaluation is exact (the spectral path: O(k n^2) after the undamped modes, which are shared
by every design); the cost is g c screening values and g ``keep`` polishes per sweep instead of
the C(c, g) polishes of an enumeration. A coordinate-wise minimum need not be the global one: the
tests compare it with the enumeration on small chains, and ``starts`` other than the system's own
are the user's to try. This is the alternating strategy of damper-position searches in the
damping-optimisation literature (Nakic, Tomljanovic & Truhar: discrete position sets screened
with the viscosities re-optimised; Truhar & Veselic 2009 for the criterion).
"""

import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._errors import MARK
from ._parameters import with_parameters
from ._viscosity import checked_criterion, criterion_value, optimise_viscosities

# the moved damper's coefficient is screened at these multiples of its current value: the best
# DOF at one coefficient is often not the best once the coefficient is re-optimised
_SCALES = (0.1, 1.0, 10.0)


@dataclasses.dataclass(frozen=True)
class DamperPlacement:
    """The result of ``place_dampers``.

    ``positions``: (g,) 1-based DOFs of the grounded dampers; ``coefficients``: (g + p,) all
    damper coefficients (grounded, then relative) optimised there; ``value``: the criterion;
    ``sweeps``; ``evaluations``: screening values; ``polishes``: coefficient optimisations
    (``optimise_viscosities`` calls); ``seconds`` (wall, compile included); ``history``: one
    (sweep, damper index, position, value) per accepted move; ``status``: one line.
    """

    positions: np.ndarray
    coefficients: np.ndarray
    value: float
    sweeps: int
    evaluations: int
    polishes: int
    seconds: float
    history: list
    status: str


@eqx.filter_jit
def _screen(system, index, candidates, scales, criterion):
    """The criterion with grounded damper ``index`` at each candidate DOF, its coefficient
    times each of ``scales`` (others held): (c, len(scales)), +inf where the spectral path does
    not hold (a mode no damper reaches, say)."""
    coefficient = system.damping.coefficients[index]

    def one(design):
        position, scale = design
        moved = with_parameters(system, dict(
            positions=system.damping.positions.at[index].set(position),
            coefficients=system.damping.coefficients.at[index].set(coefficient * scale)))
        return criterion_value(moved, criterion)

    grid = (jnp.repeat(candidates, scales.shape[0]), jnp.tile(scales, candidates.shape[0]))
    return jax.lax.map(one, grid).reshape(candidates.shape[0], scales.shape[0])


def _candidates(candidates, n: int) -> np.ndarray:
    if candidates is None:
        return np.arange(1, n + 1, dtype=float)
    array = np.asarray(candidates)
    if (array.ndim != 1 or array.size == 0 or not np.issubdtype(array.dtype, np.number)
            or np.any(array != np.round(array)) or np.any((array < 1) | (array > n))
            or np.unique(array).size != array.size):
        raise ValueError(MARK + f"candidates must be distinct integer DOFs in 1..{n}, got "
                         f"{candidates!r:.80}.")
    return array.astype(float)


def place_dampers(system, criterion: str = "average_energy", *, candidates=None,
                  lowest: int | None = None, horizon: float | None = None, x0=None, v0=None,
                  cx=None, cv=None, inputs=None, dof: int | None = None, ts=None,
                  order: int = 16, keep: int = 2, max_sweeps: int = 10,
                  lower=0.0, upper=None, tolerance: float = 1e-6,
                  progress: bool = False) -> DamperPlacement:
    """Place the grounded dampers of ``system`` on ``candidates`` (1-based DOFs, default all)
    and optimise every damper's coefficient, at full order (see the module docstring).

    ``system``: a ``SecondOrderSystem`` with at least one ``GroundedDamper`` (its positions and
    coefficients are the start; relative dampers stay where they are, their coefficients are
    optimised too). ``criterion`` and its arguments (``lowest``, ``horizon``, ``x0``, ``v0``,
    ``cx``, ``cv``, ``inputs``, ``dof``, ``ts``, ``order``), ``lower``, ``upper``,
    ``tolerance``: as in ``optimise_viscosities``. ``keep``: DOFs polished per damper and
    sweep (>= 1); ``max_sweeps`` (>= 1). Returns a ``DamperPlacement``.
    """
    start = time.perf_counter()
    args = checked_criterion(system, criterion, lowest, horizon, x0, v0, cx, cv, inputs, dof,
                             ts, order)
    g = int(system.damping.positions.shape[0])
    if g == 0:
        raise ValueError(MARK + "system has no GroundedDamper to place.")
    for name, value in (("keep", keep), ("max_sweeps", max_sweeps)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(MARK + f"{name} must be an integer >= 1, got {value!r}.")
    cand = _candidates(candidates, system.size)
    options = dict(lowest=lowest, horizon=horizon, x0=x0, v0=v0, cx=cx, cv=cv, inputs=inputs,
                   dof=dof, ts=ts, order=order, lower=lower, upper=upper, tolerance=tolerance)

    def at(positions, coefficients):  # the system at a design: (g,) positions, (g + p,) d
        return with_parameters(system, dict(positions=jnp.asarray(positions, jnp.float64),
                                            coefficients=jnp.asarray(coefficients[:g]),
                                            relative_coefficients=jnp.asarray(coefficients[g:])))

    def polish(positions, coefficients):
        return optimise_viscosities(at(positions, coefficients), criterion, **options)

    positions = np.asarray(system.damping.positions, dtype=float).copy()
    best = polish(positions, np.concatenate([np.asarray(system.damping.coefficients),
                                             np.asarray(system.damping.pair_coefficients)]))
    polishes, evaluations, history = 1, 0, []
    status, sweeps = f"max_sweeps = {max_sweeps} reached", 0
    for sweeps in range(1, max_sweeps + 1):
        moved_any = False
        for i in range(g):
            screened = _screen(at(positions, best.coefficients), jnp.asarray(i),
                               jnp.asarray(cand), jnp.asarray(_SCALES), args)
            values = np.min(np.asarray(screened), axis=1)
            evaluations += cand.shape[0] * len(_SCALES)
            occupied = np.isin(cand, np.delete(positions, i))
            order = [j for j in np.argsort(values) if not occupied[j] and np.isfinite(values[j])
                     and cand[j] != positions[i]][:keep]
            for j in order:
                trial_positions = positions.copy()
                trial_positions[i] = cand[j]
                trial = polish(trial_positions, best.coefficients)
                polishes += 1
                if trial.value < best.value * (1 - 1e-12):
                    best, positions, moved_any = trial, trial_positions, True
                    history.append((sweeps, i, float(cand[j]), trial.value))
            if progress:
                print(f"  sweep {sweeps}, damper {i + 1}: positions {positions.tolist()}, "
                      f"value {best.value:.12g}", flush=True)
        if not moved_any:
            status = "converged (no single move improves)"
            break
    return DamperPlacement(positions, best.coefficients, best.value, sweeps, evaluations,
                           polishes, time.perf_counter() - start, history, status)
