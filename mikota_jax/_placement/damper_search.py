"""Where several dampers go: a coordinate-wise search over candidate DOFs at full order.

The algorithm of the ``CoordinateDescent`` strategy (``optimise``): ``search_places`` moves the
grounded dampers of a system among candidate DOFs (when given) and its relative dampers among
candidate pairs of DOFs (when given), the coefficients of all dampers (grounded and relative)
re-optimised at each accepted placement by ``search_coefficients`` (``Coefficients``). It is a
coordinate-wise (block Gauss-Seidel) descent on the positions, not an enumeration of the C(c, g)
placements of g dampers on c candidates:

1. the start: the system's own positions, coefficients optimised there;
2. a sweep: for each movable damper in turn, the criterion at every free candidate place, its
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

from .._errors import MARK
from .._model.parameters import with_parameters
from .viscosity import criterion_value, search_coefficients

# the moved damper's coefficient is screened at these multiples of its current value: the best
# DOF at one coefficient is often not the best once the coefficient is re-optimised
_SCALES = (0.1, 1.0, 10.0)


@dataclasses.dataclass(frozen=True)
class PlacementRun:
    """What ``search_places`` found.

    ``positions``: (g,) 1-based DOFs of the grounded dampers; ``pairs``: (p, 2) 1-based DOFs
    of the relative dampers; ``coefficients``: (g + p,) all damper coefficients (grounded, then
    relative) optimised there; ``value``: the criterion; ``sweeps``; ``evaluations``: screening
    values; ``polishes``: coefficient optimisations (``search_coefficients`` calls);
    ``seconds`` (wall, compile included); ``history``: one (sweep, damper index in
    ``coefficients``, position or pair, value) per accepted move of the best start; ``status``:
    one line; ``start_values``: the value each start descended to (the first is the system's
    own placement).
    """

    positions: np.ndarray
    pairs: np.ndarray
    coefficients: np.ndarray
    value: float
    sweeps: int
    evaluations: int
    polishes: int
    seconds: float
    history: list
    status: str
    start_values: list


def _moved(system, kind: str, index, design, coefficient):
    """``system`` with damper ``index`` of ``kind`` ("grounded": ``design`` a position;
    "relative": a 0-based pair) there, with ``coefficient``; all traced (one compile)."""
    damping = system.damping
    if kind == "grounded":
        return with_parameters(system, dict(
            positions=damping.positions.at[index].set(design),
            coefficients=damping.coefficients.at[index].set(coefficient)))
    return eqx.tree_at(lambda s: (s.damping.pairs, s.damping.pair_coefficients), system,
                       (damping.pairs.at[index].set(design),
                        damping.pair_coefficients.at[index].set(coefficient)))


@eqx.filter_jit
def _screen(system, kind: str, index, candidates, scales, criterion):
    """The criterion with damper ``index`` of ``kind`` at each candidate (a DOF, or a pair of
    0-based DOFs), its coefficient times each of ``scales`` (others held): (c, len(scales)),
    +inf where the spectral path does not hold (a mode no damper reaches, say)."""
    held = system.damping.coefficients if kind == "grounded" else system.damping.pair_coefficients
    coefficient = held[index]

    def one(design):
        place, scale = design
        return criterion_value(_moved(system, kind, index, place, coefficient * scale),
                               criterion)

    count = candidates.shape[0]
    grid = (jnp.repeat(candidates, scales.shape[0], axis=0), jnp.tile(scales, count))
    return jax.lax.map(one, grid).reshape(count, scales.shape[0])


def checked_positions(candidates, n: int) -> np.ndarray:
    """(c,) candidate DOFs, 1-based, checked; as floats."""
    array = np.asarray(candidates)
    if (array.ndim != 1 or array.size == 0 or not np.issubdtype(array.dtype, np.number)
            or np.any(array != np.round(array)) or np.any((array < 1) | (array > n))
            or np.unique(array).size != array.size):
        raise ValueError(MARK + f"positions must be distinct integer DOFs in 1..{n}, got "
                         f"{candidates!r:.80}.")
    return array.astype(float)


def checked_pairs(pairs, n: int) -> np.ndarray:
    """(c, 2) 0-based pairs from 1-based candidate ``pairs``, checked."""
    message = (MARK + f"pairs must be distinct pairs (i, j) of different integer DOFs "
               f"in 1..{n}, got {pairs!r:.80}.")
    try:
        array = np.asarray(pairs)
    except ValueError:
        raise ValueError(message) from None
    if (array.ndim != 2 or array.shape[0] == 0 or array.shape[1] != 2
            or not np.issubdtype(array.dtype, np.number) or np.any(array != np.round(array))
            or np.any((array < 1) | (array > n)) or np.any(array[:, 0] == array[:, 1])
            or np.unique(np.sort(array, axis=1), axis=0).shape[0] != array.shape[0]):
        raise ValueError(message)
    return array.astype(int) - 1


def _onto(kind: str, design: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """``design`` (grounded: (g,) positions; relative: (p, 2) 0-based pairs) with every place
    that is not a candidate moved to the nearest candidate not yet taken (the first of equals)."""
    if kind == "grounded":
        distance = np.abs(design[:, None] - candidates[None, :])
    else:  # pairs in either order are the same place
        distance = np.minimum(np.abs(design[:, None, :] - candidates[None, :, :]).sum(-1),
                              np.abs(design[:, None, ::-1] - candidates[None, :, :]).sum(-1))
    exact = distance == 0
    taken = exact.any(axis=0)
    placed = design.copy()
    for i in np.flatnonzero(~exact.any(axis=1)):
        j = int(np.argmin(np.where(taken, np.inf, distance[i])))
        placed[i], taken[j] = candidates[j], True
    return placed


def search_places(system, objective, *, candidates=None, pair_candidates=None,
                  keep: int = 2, max_sweeps: int = 10, starts: int = 1, seed: int = 0,
                  free=None, lower=0.0, upper=None, tolerance: float = 1e-6,
                  minimiser=None, progress: bool = False) -> PlacementRun:
    """Place the dampers of ``system`` on candidate DOFs and optimise every damper's
    coefficient, at full order (see the module docstring).

    ``system``: a ``SecondOrderSystem`` with dampers; their places and coefficients are the
    start. Grounded dampers move among ``candidates`` ((c,) 1-based DOFs, checked, at least one
    per damper) when given and stay where they are otherwise; relative dampers among
    ``pair_candidates`` ((c, 2) 0-based pairs, checked) likewise; their coefficients are
    optimised either way. A damper that does not start on a candidate starts on the nearest
    free one, so every place returned is a candidate. ``objective``: a ``checked_objective``;
    ``free``, ``lower``, ``upper``, ``tolerance``, ``minimiser``: as in ``search_coefficients``.
    ``keep``: places polished per damper and sweep (>= 1); ``max_sweeps`` (>= 1). ``starts``
    (>= 1): the system's own placement, then ``starts - 1`` random placements on the candidates
    (``seed``), each descended to a coordinate-wise minimum; the best is returned.
    """
    start = time.perf_counter()
    args = objective
    g = int(system.damping.positions.shape[0])
    p = system.damping.pair_count
    if (g == 0 or candidates is None) and (p == 0 or pair_candidates is None):
        raise ValueError(MARK + "positions/pairs: nothing to place; give the candidate DOFs of "
                         "the grounded dampers (positions) or the candidate pairs of the "
                         "relative ones (pairs).")
    for name, value in (("keep", keep), ("max_sweeps", max_sweeps), ("starts", starts)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(MARK + f"{name} must be an integer >= 1, got {value!r}.")
    places = {}
    if candidates is not None and g:
        places["grounded"] = np.asarray(candidates, dtype=float)
        if places["grounded"].shape[0] < g:
            raise ValueError(MARK + f"positions must hold at least one DOF per grounded damper "
                             f"({g}), got {places['grounded'].shape[0]}.")
    if pair_candidates is not None:
        if p == 0:
            raise ValueError(MARK + "pairs: the system has no RelativeDamper to move.")
        places["relative"] = np.asarray(pair_candidates, dtype=int)
        if places["relative"].shape[0] < p:
            raise ValueError(MARK + f"pairs must hold at least one pair per relative "
                             f"damper ({p}), got {places['relative'].shape[0]}.")
    options = dict(free=free, lower=lower, upper=upper, tolerance=tolerance,
                   minimiser=minimiser)

    def at(design, coefficients):  # the system at a design: positions (g,), pairs (p, 2)
        moved = with_parameters(system, dict(positions=jnp.asarray(design["grounded"],
                                                                   jnp.float64),
                                             coefficients=jnp.asarray(coefficients[:g]),
                                             relative_coefficients=jnp.asarray(coefficients[g:])))
        return eqx.tree_at(lambda s: s.damping.pairs, moved, jnp.asarray(design["relative"]))

    def polish(design, coefficients):
        return search_coefficients(at(design, coefficients), args, **options)

    def same(kind, a, b):  # one place: a DOF, or a pair in either order
        return a == b if kind == "grounded" else set(a.tolist()) == set(b.tolist())

    coefficients = np.concatenate([np.asarray(system.damping.coefficients),
                                   np.asarray(system.damping.pair_coefficients)])
    movable = [(kind, i) for kind in places for i in range(g if kind == "grounded" else p)]
    counts = dict(evaluations=0, polishes=0)

    def descend(design, label):
        """Sweeps from ``design`` to a placement no single move improves (or max_sweeps)."""
        best = polish(design, coefficients)
        counts["polishes"] += 1
        history, status = [], f"max_sweeps = {max_sweeps} reached"
        for sweep in range(1, max_sweeps + 1):
            moved_any = False
            for kind, i in movable:
                cand = places[kind]
                screened = _screen(at(design, best.coefficients), kind, jnp.asarray(i),
                                   jnp.asarray(cand), jnp.asarray(_SCALES), args)
                values = np.min(np.asarray(screened), axis=1)
                counts["evaluations"] += cand.shape[0] * len(_SCALES)
                others = np.delete(design[kind], i, axis=0)
                free = [not any(same(kind, c, o) for o in others)
                        and not same(kind, c, design[kind][i]) for c in cand]
                ranked = [j for j in np.argsort(values) if free[j] and np.isfinite(values[j])]
                for j in ranked[:keep]:
                    trial_design = {k: v.copy() for k, v in design.items()}
                    trial_design[kind][i] = cand[j]
                    trial = polish(trial_design, best.coefficients)
                    counts["polishes"] += 1
                    if trial.value < best.value * (1 - 1e-12):
                        best, design, moved_any = trial, trial_design, True
                        place = (float(cand[j]) if kind == "grounded"
                                 else tuple(int(x) + 1 for x in cand[j]))
                        history.append((sweep, i if kind == "grounded" else g + i, place,
                                        trial.value))
                if progress:
                    print(f"  {label}, sweep {sweep}, {kind} damper {i + 1}: positions "
                          f"{design['grounded'].tolist()}, pairs "
                          f"{(design['relative'] + 1).tolist()}, value {best.value:.12g}",
                          flush=True)
            if not moved_any:
                status = "converged (no single move improves)"
                break
        return best, design, sweep, history, status

    rng = np.random.default_rng(seed)
    own = {"grounded": np.asarray(system.damping.positions, dtype=float),
           "relative": np.asarray(system.damping.pairs)}
    # the first start: the system's own places, a damper off the candidates moved to the nearest
    # free one (a damper a sweep cannot move, its place taken, would otherwise stay off them)
    designs = [{kind: _onto(kind, own[kind], places[kind]) if kind in places else own[kind].copy()
                for kind in own}]
    for _ in range(starts - 1):  # distinct random places among the candidates
        designs.append({
            "grounded": (rng.choice(places["grounded"], g, replace=False)
                         if "grounded" in places else own["grounded"].copy()),
            "relative": (places["relative"][rng.choice(places["relative"].shape[0], p,
                                                       replace=False)]
                         if "relative" in places else own["relative"].copy())})
    runs = [descend(design, f"start {k + 1} of {starts}") for k, design in enumerate(designs)]
    best, design, sweeps, history, status = min(runs, key=lambda run: run[0].value)
    return PlacementRun(design["grounded"], design["relative"] + 1, best.coefficients,
                           best.value, sweeps, counts["evaluations"], counts["polishes"],
                           time.perf_counter() - start, history, status,
                           [run[0].value for run in runs])
