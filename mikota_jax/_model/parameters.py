"""One parameter map: named physical parameters onto the leaves of an assembled system.

==========================  =======  ==========================================================
name                        shape    leaf it sets
==========================  =======  ==========================================================
``"m"``, ``"k"``            ()       Mikota's chain: m_i = m / i, k_i = (n - i + 1) k (eq. 2.3)
``"masses"``, ``"springs"`` (n,)     a fixed-free chain's diagonal M and the springs of K (eq. 2.2)
``"positions"``             (g,)     grounded dampers' positions in [1, n] (1-based)
``"coefficients"``          (g,)     grounded dampers' coefficients (force x time / length)
``"relative_coefficients"`` (p,)     relative dampers' coefficients
``"alpha"``, ``"beta"``     ()       Rayleigh damping alpha M + beta K
``"zeta"``                  () / (n,) modal damping ratios, as the system has them
==========================  =======  ==========================================================

``with_parameters`` replaces the leaves with ``eqx.tree_at``: the structure (operator types,
damper pairs, which damping exists) is the system's own, so a traced design costs the arithmetic
of its leaves and nothing else -- no validation inside. Values are checked once at the entry of
a computation by ``check_parameters`` (eagerly, or ``eqx.error_if`` on traced values), with the
messages the constructors (``chain``, ``Dampers``, ``Rayleigh``, ``ModalDamping``) give.
"""

import equinox as eqx
import jax.numpy as jnp

from .._errors import MARK, check
from .chain import chain_stiffness
from .dampers import Dampers
from .operators import Diagonal, SymmetricTridiagonal
from .system import SecondOrderSystem

PARAMETERS = ("m", "k", "masses", "springs", "positions", "coefficients", "relative_coefficients",
              "alpha", "beta", "zeta")
_CHAIN = ("m", "k", "masses", "springs")
_DAMPERS = {"positions": "positions", "coefficients": "coefficients",
            "relative_coefficients": "pair_coefficients"}


def is_chain(system: SecondOrderSystem) -> bool:
    """Whether ``system`` is a fixed-free chain: a diagonal M and K built from its springs."""
    stiffness = system.stiffness
    return (isinstance(system.mass, Diagonal) and isinstance(stiffness, SymmetricTridiagonal)
            and stiffness.springs is not None and not stiffness.links)


def _refuse(names, system: SecondOrderSystem) -> None:
    """Structural (static) refusals: unknown names and names the system has no leaf for."""
    unknown = sorted(set(names) - set(PARAMETERS))
    if unknown:
        raise ValueError(MARK + f"parameters: unknown {unknown}; allowed: {list(PARAMETERS)}.")
    if set(names) & set(_CHAIN) and not is_chain(system):
        raise ValueError(MARK + "parameters: masses, springs, m and k need a fixed-free chain "
                         "(a diagonal mass and the springs of its stiffness).")
    if set(names) & set(_DAMPERS) and not isinstance(system.damping, Dampers):
        raise ValueError(MARK + "parameters: the system has no dampers to move.")
    internal = system.internal
    if {"alpha", "beta"} & set(names) and (internal is None or internal.rayleigh is None):
        raise ValueError(MARK + "parameters: alpha and beta need Rayleigh damping.")
    if "zeta" in names and (internal is None or internal.modal is None):
        raise ValueError(MARK + "parameters: zeta needs modal damping.")


def with_parameters(system: SecondOrderSystem, parameters: dict) -> SecondOrderSystem:
    """``system`` with the named ``parameters`` (see the module docstring) on its leaves.

    Missing names keep the system's values. No value is checked here (see ``check_parameters``):
    this is the map a traced design goes through. ``m``/``k`` win over ``masses``/``springs``.
    """
    _refuse(parameters, system)
    names = set(parameters)
    if names & set(_CHAIN):
        n = system.size
        i = jnp.arange(1, n + 1, dtype=jnp.float64)
        if "m" in names or "masses" in names:
            masses = parameters["m"] / i if "m" in names else parameters["masses"]
            system = eqx.tree_at(lambda s: s.mass.diagonal, system, masses)
        if "k" in names or "springs" in names:
            springs = (n - i + 1) * parameters["k"] if "k" in names else parameters["springs"]
            system = eqx.tree_at(lambda s: s.stiffness, system, chain_stiffness(springs))
    for name, leaf in _DAMPERS.items():
        if name in names:
            system = eqx.tree_at(lambda s, leaf=leaf: getattr(s.damping, leaf), system,
                                 parameters[name])
    for name in ("alpha", "beta"):
        if name in names:
            system = eqx.tree_at(lambda s, name=name: getattr(s.internal.rayleigh, name), system,
                                 parameters[name])
    if "zeta" in names:
        system = eqx.tree_at(lambda s: s.internal.modal.zeta, system, parameters["zeta"])
    return system


def check_parameters(system: SecondOrderSystem, parameters: dict) -> dict:
    """``parameters`` with their values checked once (eagerly, or ``eqx.error_if`` when traced).

    Shapes must be the system's (a static ``ValueError``); the ranges are the constructors'.
    """
    _refuse(parameters, system)
    n = system.size
    nonnegative = "must be finite and >= 0."
    rules = {
        "m": lambda x: (~((x > 0) & jnp.isfinite(x)), "m must be finite and > 0."),
        "k": lambda x: (~((x > 0) & jnp.isfinite(x)), "k must be finite and > 0."),
        "masses": lambda x: (~(jnp.isfinite(x) & (x > 0)), "masses must be finite and > 0."),
        "springs": lambda x: (~(jnp.isfinite(x) & (x > 0)), "springs must be finite and > 0."),
        "positions": lambda x: (~((x >= 1) & (x <= n)), f"damper position must lie in [1, {n}] "
                                f"(1-based DOFs of a chain with n = {n})."),
        "coefficients": lambda x: (~(jnp.isfinite(x) & (x >= 0)), "damper coefficient "
                                   + nonnegative),
        "relative_coefficients": lambda x: (~(jnp.isfinite(x) & (x >= 0)), "damper coefficient "
                                            + nonnegative),
        "alpha": lambda x: (~(jnp.isfinite(x) & (x >= 0)), "Rayleigh alpha " + nonnegative),
        "beta": lambda x: (~(jnp.isfinite(x) & (x >= 0)), "Rayleigh beta " + nonnegative),
        "zeta": lambda x: (~jnp.all(jnp.isfinite(x) & (x >= 0)), "zeta " + nonnegative),
    }
    nominal = {"m": (), "k": (), "masses": (n,), "springs": (n,), "alpha": (), "beta": ()}
    if isinstance(system.damping, Dampers):
        nominal.update(positions=system.damping.positions.shape,
                       coefficients=system.damping.coefficients.shape,
                       relative_coefficients=system.damping.pair_coefficients.shape)
    if "zeta" in parameters:
        nominal["zeta"] = system.internal.modal.zeta.shape
    checked = {}
    for name, value in parameters.items():
        value = jnp.asarray(value)
        if value.shape != nominal[name]:
            raise ValueError(MARK + f"parameters[{name!r}] must have shape {nominal[name]}, got "
                             f"{value.shape}.")
        bad, message = rules[name](value)
        checked[name] = check(value, bad, message)
    return checked
