"""The search over designs: the optax driver, screening of every DOF, and the polish.

* ``_search`` iterates ``_step``: one optax step (Adam or L-BFGS) for every start of a batch, on
  unconstrained variables, position = 1 + (n - 1) sigmoid(u) in [1, n] and coefficient
  = c_ref exp(w) >= 0 (``from_unconstrained``), so every design is valid by construction and the
  compiled step holds no check (no host callback) of ours. With ``positions_fixed`` it is the
  *polish*: L-BFGS in log c at fixed positions.
* ``_screen``: the reduced objective at every DOF with three coefficients around its local
  scale 2 sqrt(K_jj M_jj); a parabola in log c estimates the best (Section 5: the objective over
  the DOFs is rugged, so no relaxation points to the best DOF).
* ``realisable_candidates``: the designs at DOFs that the polish starts from.

Shapes: S starts, g dampers; positions (S, g), 1-based; paths (iterations, S, g).
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._model.operators import diagonal_of
from .objective import objective_function, reduced_form
from .problem import DamperProblem

_W_BOUND = 40.0  # |log(c / c_ref)| <= 40: coefficients stay finite


def from_unconstrained(n: int, c_ref, u, w):
    """Unconstrained (u, w) -> positions in [1, n], coefficients c_ref exp(w) >= 0."""
    positions = 1.0 + (n - 1) * jax.nn.sigmoid(u) if n > 1 else jnp.ones_like(u)
    return positions, c_ref * jnp.exp(jnp.clip(w, -_W_BOUND, _W_BOUND))


def to_unconstrained(n: int, c_ref, positions, coefficients):
    """Positions in [1, n] and coefficients >= 0 -> unconstrained (u, w) (clipped at the ends)."""
    frac = np.clip((np.asarray(positions) - 1.0) / max(n - 1, 1), 1e-6, 1 - 1e-6)
    ratio = np.maximum(np.asarray(coefficients) / np.asarray(c_ref), np.exp(-_W_BOUND))
    return jnp.asarray(np.log(frac) - np.log1p(-frac)), jnp.asarray(np.log(ratio))


# optax's pairs of pure functions (init, update), by their public names
OPTIMIZERS = {
    "adam": optax.adam,
    # backtracking (Armijo) line search: optax's default zoom search did not return on this
    # objective under vmap (measured with optax 0.2.x on CPU)
    "lbfgs": lambda learning_rate: optax.lbfgs(
        linesearch=optax.scale_by_backtracking_linesearch(max_backtracking_steps=20,
                                                          store_grad=True)),
}


def _optimizer(optimizer, learning_rate):
    """An optax ``GradientTransformation``: the object itself, or one of ``OPTIMIZERS`` by name
    (the polish's L-BFGS)."""
    return OPTIMIZERS[optimizer](learning_rate) if isinstance(optimizer, str) else optimizer


def _loss(problem, reduced, c_ref, params, fixed, positions_fixed: bool):
    """(objective, (positions, coefficients, failed)) at unconstrained params; NaN on failure."""
    positions, coefficients = from_unconstrained(problem.size, c_ref, *params)
    if positions_fixed:
        positions = fixed
    value, failed = objective_function(problem, reduced)(positions, coefficients)
    return jnp.where(failed, jnp.nan, value), (positions, coefficients, failed)


@eqx.filter_jit
def _init(params, learning_rate, *, optimizer):
    return jax.vmap(_optimizer(optimizer, learning_rate).init)(params)


@eqx.filter_jit
def _step(problem, basis, c_ref, params, state, fixed, alive, active, learning_rate, *,
          optimizer, positions_fixed: bool):
    """One optax step for every start, one after the other (``lax.map``: on a CPU, batched
    matrix exponentials cost more than the same ones in turn); an inactive start is skipped, a
    start whose objective fails stops where it is (``ok`` false)."""
    opt = _optimizer(optimizer, learning_rate)
    reduced = reduced_form(problem, basis)

    def skip(params, state, fixed, alive):
        positions, coefficients = from_unconstrained(problem.size, c_ref, *params)
        if positions_fixed:
            positions = fixed
        nan = jnp.asarray(jnp.nan, positions.dtype)
        return params, state, (positions, coefficients, nan, nan, alive)

    def one(params, state, fixed, alive):
        loss = lambda q: _loss(problem, reduced, c_ref, q, fixed, positions_fixed)[0]  # noqa: E731
        (value, (positions, coefficients, failed)), grad = jax.value_and_grad(
            lambda q: _loss(problem, reduced, c_ref, q, fixed, positions_fixed), has_aux=True)(
            params)
        if positions_fixed:
            grad = (jnp.zeros_like(grad[0]), grad[1])
        ok = alive & ~failed & jnp.all(jnp.isfinite(jnp.concatenate(grad)))
        grad = jax.tree.map(lambda g: jnp.where(ok, g, 0.0), grad)
        with jax.numpy_dtype_promotion("standard"):  # optax mixes int32 counts and floats
            if isinstance(opt, optax.GradientTransformationExtraArgs):  # L-BFGS's line search
                updates, new_state = opt.update(grad, state, params, value=value, grad=grad,
                                                value_fn=loss)
            else:
                updates, new_state = opt.update(grad, state, params)
            new_params = optax.apply_updates(params, updates)
        keep = lambda a, b: jnp.where(ok, a, b)  # noqa: E731
        new_params = jax.tree.map(keep, new_params, params)
        new_state = jax.tree.map(keep, new_state, state)
        # gradient in physical units: d/dp = d/du / (dp/du), d/dc = d/dw / c
        u = params[0]
        slope = (problem.size - 1) * jax.nn.sigmoid(u) * (1 - jax.nn.sigmoid(u))
        physical = jnp.concatenate([jnp.where(positions_fixed, 0.0, grad[0] / slope),
                                    grad[1] / coefficients])
        return new_params, new_state, (positions, coefficients, value,
                                       jnp.linalg.norm(physical), ok)

    def each(args):
        params, state, fixed, alive, active = args
        return jax.lax.cond(active & alive, one, skip, params, state, fixed, alive)

    return jax.lax.map(each, (params, state, fixed, alive, active))


@dataclasses.dataclass
class _Search:
    """What one batched search did: final params, path, which starts are still alive."""

    params: tuple
    positions: np.ndarray  # (iterations, starts, g)
    coefficients: np.ndarray
    values: np.ndarray  # (iterations, starts)
    gradient_norms: np.ndarray
    alive: np.ndarray  # (starts,)


def run_search(problem, basis, c_ref, params, fixed, *, optimizer, iterations, learning_rate,
            positions_fixed, tol, progress, label, race: bool = False) -> _Search:
    """Iterate ``_step``; with ``race``, the worse half of the running starts stops after a
    quarter and after half of the iterations (successive halving), so that most of the work goes
    to the most promising starts."""
    learning_rate = jnp.asarray(learning_rate, float)
    state = _init(params, learning_rate, optimizer=optimizer)
    starts = params[0].shape[0]
    alive = jnp.ones(starts, bool)
    active = np.ones(starts, bool)
    cuts = {max(iterations // 4, 1), max(iterations // 2, 2)} if race and starts > 2 else set()
    records = []
    bar = _progress(progress, iterations, label)
    for iteration in range(1, iterations + 1):
        new_params, state, record = _step(problem, basis, c_ref, params, state, fixed, alive,
                                          jnp.asarray(active), learning_rate,
                                          optimizer=optimizer, positions_fixed=positions_fixed)
        records.append([np.asarray(a) for a in record])
        values, ok = records[-1][2], records[-1][4]
        alive = alive & jnp.asarray(ok)
        moved = max(float(jnp.max(jnp.abs(a - b))) for a, b in zip(new_params, params))
        params = new_params
        if bar is not None:
            finite = values[np.isfinite(values)]
            bar.update(1)
            bar.set_postfix(best=f"{finite.min():.6g}" if finite.size else "-")
        running = active & np.asarray(alive)
        if iteration in cuts and running.sum() > 1:
            ranked = np.argsort(np.where(running & np.isfinite(values), values, np.inf))
            active = np.zeros(starts, bool)
            active[ranked[: max(running.sum() // 2, 1)]] = True
        if not (active & np.asarray(alive)).any() or moved < tol:
            break
    if bar is not None:
        bar.close()
    positions, coefficients, values, norms, _ = (np.stack(a) for a in zip(*records))
    return _Search(params, positions, coefficients, values, norms, np.asarray(alive))


def _progress(progress: bool, total: int, label: str):
    if not progress:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=label, leave=False)


@eqx.filter_jit
def value_and_gradient(problem, basis, positions, coefficients):
    """(objective, d/dpositions, d/dcoefficients, failed) of the reduced (basis) or full model."""
    (value, failed), (gp, gc) = jax.value_and_grad(
        objective_function(problem, reduced_form(problem, basis)), argnums=(0, 1), has_aux=True)(
        positions, coefficients)
    return value, gp, gc, failed


_SCREEN_RATIO = 3.0  # trial coefficients s_j / 3, s_j, 3 s_j around the local scale s_j


@eqx.filter_jit
def _screen_values(problem, basis, positions, coefficients, index, dofs, trials):
    """The reduced objective with damper ``index`` moved to each of ``dofs`` and given each of
    ``trials`` (J, 3) coefficients, the other dampers as they are; NaN where it fails."""
    objective = objective_function(problem, reduced_form(problem, basis))

    def one(args):
        dof, c = args
        value, failed = objective(positions.at[index].set(dof), coefficients.at[index].set(c))
        return jnp.where(failed, jnp.nan, value)

    grid = jnp.repeat(dofs, trials.shape[1]), trials.ravel()
    return jax.lax.map(one, grid).reshape(trials.shape)


def _local_scale(problem: DamperProblem) -> np.ndarray:
    """s_j = 2 sqrt(K_jj M_jj): the critical damping of DOF j held by its own springs."""
    return 2.0 * np.sqrt(np.asarray(diagonal_of(problem.base.stiffness))
                         * np.asarray(diagonal_of(problem.base.mass)))


def _screen(problem, basis, positions, coefficients, index: int, dofs: np.ndarray):
    """Screen DOFs for damper ``index``: (estimated best objective, its coefficient) per DOF.

    Three reduced evaluations per DOF, at s_j / 3, s_j and 3 s_j; a parabola in log c through
    them estimates the best coefficient when it has its minimum inside, else the best trial
    counts. The estimate only ranks DOFs: the best ones are then polished exactly.
    """
    scale = _local_scale(problem)[dofs.astype(int) - 1]
    factors = _SCREEN_RATIO ** np.array([-1.0, 0.0, 1.0])
    trials = scale[:, None] * factors[None, :]
    values = np.asarray(_screen_values(problem, basis, jnp.asarray(positions),
                                       jnp.asarray(coefficients), jnp.asarray(index),
                                       jnp.asarray(dofs, float), jnp.asarray(trials)))
    low, mid, high = values.T
    curvature = low - 2 * mid + high
    with np.errstate(invalid="ignore", divide="ignore"):
        shift = (low - high) / (2 * curvature)  # vertex, in units of log(ratio)
        vertex = mid - (low - high) ** 2 / (8 * curvature)
    inside = np.isfinite(values).all(axis=1) & (curvature > 0) & (np.abs(shift) <= 1)
    best = np.nanargmin(np.where(np.isfinite(values), values, np.inf), axis=1)
    estimate = np.where(inside, vertex, values[np.arange(len(dofs)), best])
    coefficient = np.where(inside, scale * _SCREEN_RATIO ** np.where(inside, shift, 0.0),
                           trials[np.arange(len(dofs)), best])
    estimate = np.where(np.isfinite(values).any(axis=1), estimate, np.inf)
    return estimate, coefficient


def default_starts(problem: DamperProblem, starts: int, seed: int):
    """(S, g) positions: the problem's own design first, then spread over [1, n]."""
    n, g = problem.size, problem.num_dampers
    own = np.asarray(problem.positions)[None, :]
    if starts == 1:
        return own
    if g == 1:
        spread = 1.0 + (n - 1) * (np.arange(starts - 1) + 0.5)[:, None] / (starts - 1)
    else:
        rng = np.random.default_rng(seed)
        spread = np.sort(rng.uniform(1.0, n, (starts - 1, g)), axis=1)
    return np.concatenate([own, spread])


def phase_record(phase: str, round_: int, search: _Search) -> dict:
    return dict(phase=phase, round=round_, positions=search.positions,
                coefficients=search.coefficients, objective=search.values,
                gradient_norm=search.gradient_norms)


def best_index(values, mask=None) -> int:
    values = np.where(np.isfinite(values), values, np.inf)
    if mask is not None:
        values = np.where(mask, values, np.inf)
    return int(np.argmin(values))


def realisable_candidates(problem, basis, relaxed, shortlist, keep: int, round_: int,
                          history: list):
    """(positions, coefficients) of ``keep`` designs at DOFs to polish, and the new shortlist.

    One damper: the first round screens every DOF (``_screen``), later rounds re-screen the
    ``4 keep`` best of the previous screening with the enriched basis; the ``keep`` best go on.
    Several dampers: from the rounded relaxed optimum, each damper in turn is screened over every
    DOF with the others fixed and moved to its best; the candidates are that design and, for each
    damper, its next best DOFs.
    """
    n, g = problem.size, problem.num_dampers
    if g == 1:
        dofs = np.arange(1.0, n + 1) if shortlist is None else shortlist
        estimate, coefficient = _screen(problem, basis, np.asarray(problem.positions),
                                        np.asarray(problem.coefficients), 0, dofs)
        history.append(dict(phase="screen", round=round_, damper=0, positions=dofs,
                            coefficients=coefficient, objective=estimate))
        order = np.argsort(estimate, kind="stable")
        top = order[:min(keep, len(order))]
        top = np.concatenate([top, np.full(keep - len(top), top[0])])  # one shape: one compile
        return dofs[top][:, None], coefficient[top][:, None], dofs[order[:4 * keep]]
    positions = np.clip(np.round(relaxed[0]), 1, n)
    coefficients = np.asarray(relaxed[1], float).copy()
    dofs = np.arange(1.0, n + 1)
    alternatives = []
    for i in range(g):
        estimate, coefficient = _screen(problem, basis, positions, coefficients, i, dofs)
        history.append(dict(phase="screen", round=round_, damper=i, positions=dofs,
                            coefficients=coefficient, objective=estimate))
        order = np.argsort(estimate, kind="stable")
        positions[i], coefficients[i] = dofs[order[0]], coefficient[order[0]]
        alternatives.append([(dofs[j], coefficient[j]) for j in order[1:keep]])
    cand_p, cand_c = [positions.copy()], [coefficients.copy()]
    for i, options in enumerate(alternatives):
        for dof, c in options:
            p, q = positions.copy(), coefficients.copy()
            p[i], q[i] = dof, c
            cand_p.append(p)
            cand_c.append(q)
    return np.stack(cand_p), np.stack(cand_c), None


def last_finite(search: _Search):
    """Per start, the last design with a finite objective: (positions, coefficients, values)."""
    finite = np.isfinite(search.values)
    if not finite.any():
        return None
    index = np.where(finite, np.arange(len(search.values))[:, None], -1).max(axis=0)
    starts = np.arange(search.values.shape[1])
    ok = index >= 0
    index = np.maximum(index, 0)
    values = np.where(ok, search.values[index, starts], np.nan)
    return search.positions[index, starts], search.coefficients[index, starts], values
