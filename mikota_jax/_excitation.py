"""Excitations: initial-state vectors and loads f(t).

Initial states are plain (n,) vectors; ``unit_vector`` and ``mode_shape`` build the usual ones. A
load is a module with ``__call__(t) -> (n,)`` and ``project(basis)`` (f_red = basis^T f, eq. 3.4).
``Pulse`` is the paper's rectangular pulse (eq. 4.3): f(t) = direction for start <= t <= start +
duration, else 0; its two jump times are handed to the step-size controller, and the exact solver
treats it as piecewise constant. ``LoadFunction`` wraps any user function t -> (n,).
"""

from collections.abc import Callable

import equinox as eqx
import jax.numpy as jnp

from ._custom_types import Array, Basis, Float, ScalarLike, Vector
from ._errors import MARK, as_float, check


def unit_vector(n: int, dof: int, value: ScalarLike = 1.0) -> Vector:
    """A vector of zeros with ``value`` at the 1-based ``dof`` (e.g. the paper's x_3(0) = 1)."""
    _check_dof(n, dof, "dof")
    return jnp.zeros(n).at[dof - 1].set(as_float(value, "value"))


def _check_dof(n: int, dof, name: str) -> None:
    if isinstance(dof, bool) or not isinstance(dof, int | jnp.integer) or not 1 <= dof <= n:
        raise ValueError(MARK + f"{name} must be an integer DOF in 1..{n} (1-based), got {dof!r}.")


class Pulse(eqx.Module):
    """Rectangular pulse f(t) = direction on [start, start + duration] (eq. 4.3), else zero."""

    direction: Vector
    start: Float[Array, ""]
    duration: Float[Array, ""]

    @property
    def size(self) -> int:
        return self.direction.shape[0]

    @property
    def jump_times(self) -> Float[Array, " 2"]:
        return jnp.stack([self.start, self.start + self.duration])

    def is_on(self, t) -> Array:
        return (t >= self.start) & (t <= self.start + self.duration)

    def __call__(self, t) -> Vector:
        return jnp.where(self.is_on(t), 1.0, 0.0) * self.direction

    def project(self, basis: Basis) -> "Pulse":
        return Pulse(basis.T @ self.direction, self.start, self.duration)


def pulse(n: int, dof: int, amplitude: ScalarLike = 1.0, duration: ScalarLike = 0.05,
          start: ScalarLike = 0.0) -> Pulse:
    """The paper's impulse load: ``amplitude`` at the 1-based ``dof`` for ``duration`` (eq. 4.3)."""
    _check_dof(n, dof, "dof")
    duration = as_float(duration, "duration")
    duration = check(duration, ~(jnp.isfinite(duration) & (duration > 0)),
                     "pulse duration must be finite and > 0.")
    start = as_float(start, "start")
    return Pulse(unit_vector(n, dof, amplitude), start, duration)


class LoadFunction(eqx.Module):
    """Any load f(t) -> (n,) given by the user; a reduced model applies basis^T f(t)."""

    function: Callable
    basis: Basis | None = None

    def __call__(self, t) -> Vector:
        f = self.function(t)
        return f if self.basis is None else self.basis.T @ f

    def project(self, basis: Basis) -> "LoadFunction":
        if self.basis is not None:
            raise ValueError(MARK + "this load is already projected.")
        return LoadFunction(self.function, basis)


Load = Pulse | LoadFunction


SHORTEST_PULSE = 1e-8  # relative to |start|: start + duration keeps the duration to ~2e-8


def as_load(load, n: int) -> Load | None:
    if load is None or isinstance(load, Pulse | LoadFunction):
        if isinstance(load, Pulse):
            if load.size != n:
                raise ValueError(MARK + f"load has size {load.size}, the system has n = {n}.")
            load = check(load, ~(load.duration > SHORTEST_PULSE * jnp.abs(load.start)),
                         f"pulse duration must exceed {SHORTEST_PULSE:g} |start|: the end time "
                         "start + duration keeps it only to ulp(start). Start the pulse at t = 0 "
                         "(shift the time grid), or use its Dirac limit v0 = M^-1 (amplitude "
                         "duration) e_dof.")
        return load
    if callable(load):
        return LoadFunction(load)
    raise ValueError(MARK + "load must be a Pulse, a LoadFunction or a callable f(t), "
                     f"got {load!r}.")
