"""Error measures between a full and a reduced (lifted) solution, and the pseudo-energy (eq. 3.7).

Arrays are (N, n): rows are time instants, columns DOFs, as in ``Trajectory``.
"""

import functools

import jax
import jax.numpy as jnp

from ._custom_types import Array, Float
from ._errors import MARK

AGGREGATES = ("max", "sum", "mean", "none")


def _check_pair(a, b, name_a: str, name_b: str):
    a, b = jnp.asarray(a), jnp.asarray(b)
    if a.shape != b.shape:
        raise ValueError(MARK + f"{name_a} and {name_b} must have the same shape, got "
                         f"{a.shape} and {b.shape}.")
    return a, b


def phase_error(displacement, velocity, reduced_displacement, reduced_velocity,
                aggregate: str = "sum") -> Float[Array, "..."]:
    """Delta E_phase of eq. (5.4) between a full and a reduced solution, four (N, n) arrays.

    Rows are times, columns DOFs (``Trajectory.displacement`` / ``.velocity``, the reduced ones
    lifted; eq. 5.4 sums over all n DOFs, a subset of d columns gives that subset's error).
    Dimensionless; x and x' are summed as they are, so it depends on the unit of time (as the
    paper's does). At every instant:
    sqrt( sum_i [(x_i - x_red,i)^2 + (v_i - v_red,i)^2] / sum_i (x_i^2 + v_i^2) ).
    The paper does not say how instants are combined; ``aggregate`` chooses: ``"sum"`` (default:
    one ratio of sums over all instants, i.e. the relative L2 error of the state over the run),
    ``"max"`` or ``"mean"`` of the instantaneous ratio over time, or ``"none"`` (the (N,) history).
    The instantaneous ratio has isolated spikes (on the paper's Section 5 scene with r = 76: max
    2.38 against 0.071 for the ratio of sums), so ``"max"`` says little about the whole run.
    """
    if aggregate not in AGGREGATES:
        raise ValueError(MARK + f"aggregate must be one of {AGGREGATES}, got {aggregate!r}.")
    x, xr = _check_pair(displacement, reduced_displacement, "displacement", "reduced_displacement")
    v, vr = _check_pair(velocity, reduced_velocity, "velocity", "reduced_velocity")
    x, v = _check_pair(x, v, "displacement", "velocity")
    return _phase_error(x, v, xr, vr, aggregate)


@functools.partial(jax.jit, static_argnames="aggregate")
def _phase_error(x, v, xr, vr, aggregate):
    """One compiled function (eagerly, its seven small reductions would each compile)."""
    error = jnp.sum((x - xr) ** 2 + (v - vr) ** 2, axis=-1)
    norm = jnp.sum(x**2 + v**2, axis=-1)
    if aggregate == "sum":
        return jnp.sqrt(jnp.sum(error) / jnp.sum(norm))
    history = jnp.sqrt(error / norm)
    if aggregate == "none":
        return history
    return jnp.max(history) if aggregate == "max" else jnp.mean(history)


def relative_error(reference, approximation) -> Float[Array, ""]:
    """Relative L2 (Frobenius) error ||approx - reference|| / ||reference|| over times and DOFs.

    ``reference``, ``approximation``: arrays of one shape, e.g. (N, d) trajectories; a scalar.
    """
    a, b = _check_pair(reference, approximation, "reference", "approximation")
    return jnp.linalg.norm(b - a) / jnp.linalg.norm(a)


def pseudo_energy(singular_values) -> Float[Array, ""]:
    """The pseudo-energy E_pseudo = ||Q||_F^2 = sum_k sigma_k^2 (eq. 3.7) of (k,) singular values.

    A scalar in squared snapshot units. The paper's printed value (eq. 5.2, "977.5528^2") is
    (sum_k sigma_k)^2 instead; ``energy_fraction(..., criterion="paper")`` follows that reading.
    """
    s = jnp.asarray(singular_values)
    return jnp.sum(s**2)
