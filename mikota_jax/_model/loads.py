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

from .._custom_types import Array, Basis, Float, ScalarLike, Vector
from .._errors import MARK, as_float, check


def unit_vector(n: int, dof: int, value: ScalarLike = 1.0) -> Vector:
    """An (n,) vector of zeros with ``value`` at the 1-based ``dof`` (the paper's x_3(0) = 1).

    For initial states (displacement or velocity, in their own units) and load directions.
    """
    _check_dof(n, dof, "dof")
    return jnp.zeros(n).at[dof - 1].set(as_float(value, "value"))


def _check_dof(n: int, dof, name: str) -> None:
    if isinstance(dof, bool) or not isinstance(dof, int | jnp.integer) or not 1 <= dof <= n:
        raise ValueError(MARK + f"{name} must be an integer DOF in 1..{n} (1-based), got {dof!r}.")


class Pulse(eqx.Module):
    """Rectangular pulse f(t) = direction on [start, start + duration], else zero (eq. 4.3).

    ``direction``: the (n,) force vector while the pulse is on (force units); ``start``,
    ``duration``: scalars in time units. Build the paper's with ``pulse``. ``solve``'s ``ODE``
    stops its steps at the two jumps; the exact methods treat the load as piecewise constant.
    """

    direction: Vector
    start: Float[Array, ""]
    duration: Float[Array, ""]

    @property
    def size(self) -> int:
        """n, the length of ``direction``."""
        return self.direction.shape[0]

    @property
    def jump_times(self) -> Float[Array, " 2"]:
        """(2,): the times start and start + duration at which f jumps."""
        return jnp.stack([self.start, self.start + self.duration])

    def is_on(self, t) -> Array:
        """Whether start <= t <= start + duration (a boolean array of t's shape)."""
        return (t >= self.start) & (t <= self.start + self.duration)

    def __call__(self, t) -> Vector:
        """f(t): (n,) for a scalar time t."""
        return jnp.where(self.is_on(t), 1.0, 0.0) * self.direction

    def project(self, basis: Basis) -> "Pulse":
        """The reduced pulse with direction basis^T f, (r,) for an (n, r) basis (eq. 3.4)."""
        return Pulse(basis.T @ self.direction, self.start, self.duration)


def pulse(n: int, dof: int, amplitude: ScalarLike = 1.0, duration: ScalarLike = 0.05,
          start: ScalarLike = 0.0) -> Pulse:
    """The paper's impulse load (eq. 4.3): force ``amplitude`` on the 1-based ``dof``, n DOFs.

    On for start <= t <= start + ``duration`` (the paper: amplitude 1 on DOF 1 for 0.05, starting
    at 0); forces and times in consistent units. Returns a ``Pulse`` with an (n,) direction.
    Short pulses approach the Dirac limit v0 = M^-1 (amplitude duration) e_dof (Section 4).
    """
    _check_dof(n, dof, "dof")
    amplitude, duration, start = (as_float(x, name) for x, name in (
        (amplitude, "amplitude"), (duration, "duration"), (start, "start")))
    for x, name in ((amplitude, "amplitude"), (duration, "duration"), (start, "start")):
        if x.shape != ():
            raise ValueError(MARK + f"pulse {name} must be a scalar, got shape {x.shape}.")
    # checked here, or a NaN force would surface later blamed on the system
    amplitude = check(amplitude, ~jnp.isfinite(amplitude), "pulse amplitude must be finite.")
    duration = check(duration, ~(jnp.isfinite(duration) & (duration > 0)),
                     "pulse duration must be finite and > 0.")
    start = check(start, ~jnp.isfinite(start), "pulse start must be finite.")
    return Pulse(unit_vector(n, dof, amplitude), start, duration)


class LoadFunction(eqx.Module):
    """Any load f(t) given by the user (eq. 3.1): ``function`` maps a scalar t to an (n,) force.

    ``basis``: None, or the (n, r) basis of a reduced model, which then applies basis^T f(t)
    (eq. 3.4). ``solve``'s ``ODE`` wraps a plain callable ``load`` in one; the exact methods
    refuse it.
    """

    function: Callable
    basis: Basis | None = None

    def __call__(self, t) -> Vector:
        """f(t): (n,), or basis^T f(t), (r,), once projected."""
        f = self.function(t)
        return f if self.basis is None else self.basis.T @ f

    def project(self, basis: Basis) -> "LoadFunction":
        """The same load seen by a reduced model with an (n, r) ``basis`` (eq. 3.4)."""
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
