"""Which solver a model needs, decided on the host before anything is compiled.

``choose_solver`` (what ``simulate(solver="auto")`` takes) compares rho T with a threshold, where
rho is a Gershgorin bound of the highest eigenfrequency or damper decay rate; the brute-force
sweep uses the same bound (``gershgorin_omega``) for its stiff rule.
"""

import jax
import numpy as np

from .._errors import MARK
from .._limits import STIFF_THRESHOLD
from .._model.loads import Pulse
from .._model.operators import Diagonal, abs_row_sums
from .._model.reduced import ReducedModel
from .spectral.response import spectral_applies


def gershgorin_omega(mass_diagonal, stiffness) -> float:
    """Upper bound of the highest eigenfrequency: sqrt(max_i sum_j |K_ij| / M_ii), on the host."""
    rows = np.asarray(abs_row_sums(stiffness))
    return float(np.sqrt(np.max(rows / np.asarray(mass_diagonal))))


def _internal_rate(internal, mass_diagonal, omega: float) -> float:
    """A bound of the internal damping's fastest decay rate (an eigenvalue of M^-1 D)."""
    rate = 0.0
    if internal.rayleigh is not None:
        rate += float(internal.rayleigh.alpha) + float(internal.rayleigh.beta) * omega**2
    if internal.modal is not None:
        rate += 2 * float(np.max(np.asarray(internal.modal.zeta))) * omega
    if internal.matrix is not None:
        rate += float(np.max(np.asarray(abs_row_sums(internal.matrix)) / mass_diagonal))
    return rate


def stiffness_rate(system) -> float:
    """rho = max(highest eigenfrequency, fastest damper decay rate), Gershgorin bounds on the host.

    For a diagonal mass: omega_max^2 <= max_i sum_j |K_ij| / M_ii and the damper rate
    <= max_i sum_j |D_ij| / M_ii (internal damping: alpha + beta omega_max^2, 2 zeta omega_max);
    for a non-diagonal mass (a reduced model, a user's) the exact values.
    """
    system = system.system if isinstance(system, ReducedModel) else system
    mass, damping = system.mass, system.damping
    if isinstance(mass, Diagonal):
        m = np.asarray(mass.diagonal)
        omega = gershgorin_omega(m, system.stiffness)
        rate = 0.0
        if damping is not None:
            rate = float(np.max(np.asarray(abs_row_sums(damping)) / m))
        if system.internal is not None:
            rate += _internal_rate(system.internal, m, omega)
        return max(omega, rate)
    m = np.asarray(mass.as_matrix())
    k = np.asarray(system.stiffness.as_matrix())
    omega2 = np.max(np.abs(np.linalg.eigvals(np.linalg.solve(m, k))))
    rate = 0.0
    damping = system.damping_operator()
    if damping is not None:
        d = np.linalg.solve(m, np.asarray(damping.as_matrix()))
        rate = float(np.max(np.abs(np.linalg.eigvals(d))))
    return max(float(np.sqrt(omega2)), rate)


def exact_applies(model, load=None) -> bool:
    """Whether ``model`` and ``load`` have the structure of the exact spectral path: a full
    system with discrete dampers (internal damping, if any, diagonal in modal coordinates), and
    no load or a ``Pulse``. Decided from types alone, never from values."""
    return spectral_applies(model) is None and (load is None or isinstance(load, Pulse))


def choose_solver(model, ts, load=None) -> str:
    """What ``simulate(solver="auto")`` takes: "exact", else "kvaerno5" when rho * T > 1e5, else
    "dopri8".

    "exact" (``exact_solve(method="spectral")``: the damped modes, no integration error) wherever
    the structure allows it (``exact_applies``: a full system with discrete dampers, no load or a
    ``Pulse``), decided from types alone, also under ``jit``; it is not exchanged for an
    integrator when its modes fail (that is an error) or memory is short (that is refused).
    Otherwise ``model``: a ``SecondOrderSystem`` or ``ReducedModel``; ``ts``: the (N,) time grid.
    rho is the highest eigenfrequency or damper rate c / m_i in rad per unit time (a Gershgorin
    bound on the host for a chain, >= n sqrt(k/m) for Mikota's, eq. 2.4), T = ts[-1] - ts[0]:
    rho * T / 5 is about the number of steps the explicit Dopri8 needs for stability alone,
    whatever the tolerance. That rule needs concrete (not traced) system values: name the solver
    under ``jit``.
    """
    if exact_applies(model, load):
        return "exact"
    leaves = jax.tree.leaves(model) + [ts]
    if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
        raise ValueError(MARK + "Auto() needs concrete system values and times; under jit/vmap "
                         "name the method (ODE(), or ODE(StructuredKvaerno5()) for stiff cases).")
    span = float(np.asarray(ts)[-1] - np.asarray(ts)[0])
    return "kvaerno5" if stiffness_rate(model) * span > STIFF_THRESHOLD else "dopri8"
