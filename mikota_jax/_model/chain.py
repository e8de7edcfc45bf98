"""Fixed-free and branched chains (eqs. 2.1-2.3) as ``SecondOrderSystem``s (eq. 3.1).

Chain conventions: DOF i = 1..n (1-based) carries mass m_i and is tied to DOF i-1 by spring k_i;
DOF 0 is the fixed support, DOF n is free. So K = tridiag(-k_i, k_i + k_{i+1}, -k_{i+1}) with
k_{n+1} = 0 (eq. 2.2). Mikota's chain has m_i = m / i and k_i = (n - i + 1) k (eq. 2.3),
eigenfrequencies l * sqrt(k / m) (eq. 2.4).

Units: any consistent set (the paper's are dimensionless): masses, stiffnesses in force per length,
damping coefficients in force * time per length, times, frequencies in rad per unit time.
"""

from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np

from .._custom_types import ScalarLike, Vector
from .._errors import MARK, array_module, as_float, check, check_chain_size, positive_scalar
from .dampers import DamperArgument
from .internal_damping import ModalDamping, Rayleigh, as_internal
from .operators import Diagonal, SymmetricTridiagonal
from .system import SecondOrderSystem, dampers_operator


def chain_stiffness(springs: Vector) -> SymmetricTridiagonal:
    """K = tridiag(-k_i, k_i + k_{i+1}, -k_{i+1}) with k_{n+1} = 0 (eq. 2.2), from springs (n,),
    unchecked: ``chain`` checks first, the parameter map (``_parameters``) checks at its entry."""
    xp = array_module(springs)  # concrete springs: numpy (exact elementwise; nothing compiled)
    if xp is np:
        springs = np.asarray(springs)
    next_springs = xp.concatenate([springs[1:], xp.zeros(1)])
    return SymmetricTridiagonal(jnp.asarray(springs + next_springs), jnp.asarray(-springs[1:]),
                                jnp.asarray(springs))


def chain(masses: Sequence[float] | Vector, springs: Sequence[float] | Vector,
          dampers: DamperArgument = (), *,
          internal_damping: Rayleigh | ModalDamping | tuple | None = None) -> SecondOrderSystem:
    """A fixed-free chain (eq. 2.2) from masses m_1..m_n and springs k_1..k_n, each (n,).

    Spring k_i ties DOF i to DOF i - 1 (1-based; k_1 ties DOF 1 to the fixed support), DOF n is
    free; all values finite and > 0 (masses, stiffnesses in force per length; consistent units).
    ``dampers``: ``GroundedDamper``/``RelativeDamper`` instances (a list, or one alone), or none
    (then ``damping=None``).
    ``internal_damping``: ``Rayleigh(alpha, beta)``, ``ModalDamping(zeta)``, both, or None.
    """
    masses = as_float(masses, "masses")
    springs = as_float(springs, "springs")
    if masses.ndim != 1 or masses.shape[0] < 1:
        raise ValueError(MARK + f"masses must be a 1-d array of length n >= 1, got {masses.shape}.")
    if springs.shape != masses.shape:
        raise ValueError(MARK + f"springs must have the shape of masses {masses.shape}, "
                         f"got {springs.shape}.")
    xp = array_module(masses, springs)
    if xp is np:  # concrete: checks and stiffness bands in numpy (see chain_stiffness)
        masses, springs = np.asarray(masses), np.asarray(springs)
    masses = check(masses, ~(xp.isfinite(masses) & (masses > 0)), "masses must be finite and > 0.")
    springs = check(springs, ~(xp.isfinite(springs) & (springs > 0)),
                    "springs must be finite and > 0.")
    masses = jnp.asarray(masses)
    n = masses.shape[0]
    return SecondOrderSystem(Diagonal(masses), chain_stiffness(springs),
                             dampers_operator(n, dampers),
                             as_internal(internal_damping, n))


def mikota_chain(n: int, m: ScalarLike = 1.0, k: ScalarLike = 1.0,
                 dampers: DamperArgument = (), *,
                 internal_damping: Rayleigh | ModalDamping | tuple | None = None
                 ) -> SecondOrderSystem:
    """Mikota's chain (eqs. 2.2-2.3): m_i = m / i, k_i = (n - i + 1) k for DOFs i = 1..n.

    ``m`` is the first mass and ``k`` the last spring's stiffness (force per length), in consistent
    units (the paper: m = k = 1, dimensionless); the undamped chain's eigenfrequencies are
    l sqrt(k/m), l = 1..n (eq. 2.4). ``dampers`` and ``internal_damping`` as in ``chain``.
    """
    if isinstance(n, bool) or not isinstance(n, int | jnp.integer) or n < 1:
        raise ValueError(MARK + f"n must be an integer >= 1, got {n!r}.")
    n = int(n)
    check_chain_size(n)
    m, k = positive_scalar(m, "m"), positive_scalar(k, "k")
    xp = array_module(m, k)  # concrete m, k: numpy (the same IEEE quotients; nothing compiled)
    if xp is np:
        m, k = np.asarray(m), np.asarray(k)
    i = xp.arange(1, n + 1, dtype=np.float64)
    return chain(m / i, (n - i + 1) * k, dampers, internal_damping=internal_damping)


def _branch(masses, springs, j: int):
    masses = as_float(masses, f"masses[{j}]")
    springs = as_float(springs, f"springs[{j}]")
    if masses.ndim != 1 or masses.shape[0] < 1:
        raise ValueError(MARK + f"masses[{j}] must be a 1-d array of length >= 1, got shape "
                         f"{masses.shape}.")
    if springs.shape != (masses.shape[0] + 1,):
        raise ValueError(MARK + f"springs[{j}] must have len(masses[{j}]) + 1 = "
                         f"{masses.shape[0] + 1} entries (ground, between masses, to the hub), "
                         f"got shape {springs.shape}.")
    masses = check(masses, ~(jnp.isfinite(masses) & (masses > 0)),
                   f"masses[{j}] must be finite and > 0.")
    springs = check(springs, ~(jnp.isfinite(springs) & (springs > 0)),
                    f"springs[{j}] must be finite and > 0.")
    return masses, springs


def branched_chain(masses: Sequence[Vector], springs: Sequence[Vector], hub_mass: ScalarLike,
                   hub_spring: ScalarLike, dampers: DamperArgument = (),
                   *, internal_damping: Rayleigh | ModalDamping | tuple | None = None
                   ) -> SecondOrderSystem:
    """Several fixed-free chains joined to a common mass (the hub), grounded by its own spring.

    Branch j has ``masses[j]`` of shape ``(L_j,)``, from its grounded end to the hub, and
    ``springs[j]`` of shape ``(L_j + 1,)``: ``springs[j][0]`` ties its first mass to the ground,
    ``springs[j][i]`` masses i - 1 and i (0-based), ``springs[j][L_j]`` its last mass to the hub.
    ``hub_mass`` and ``hub_spring`` (to the ground) are scalars. All values finite and > 0. DOFs
    (1-based): branch 1 is 1..L_1, then branch 2, ..., the hub is DOF n = sum L_j + 1. The
    multi-chain oscillators of the damping-optimisation literature (e.g. three rows of d masses)
    are this system.

    Structure: a diagonal mass and a tridiagonal stiffness plus one off-band spring ("link") per
    branch but the last, so applying K costs O(n) and the stiff solver's stage solve stays O(n)
    (tridiagonal plus a low-rank correction). ``dampers`` and ``internal_damping`` as in ``chain``.
    """
    if len(masses) != len(springs) or len(masses) < 1:
        raise ValueError(MARK + f"masses and springs must list the same number (>= 1) of "
                         f"branches, got {len(masses)} and {len(springs)}.")
    branches = [_branch(m, k, j) for j, (m, k) in enumerate(zip(masses, springs))]
    hub_mass = positive_scalar(hub_mass, "hub_mass")
    hub_spring = positive_scalar(hub_spring, "hub_spring")
    diagonal, off, links, link_springs, offset = [], [], [], [], 0
    n = sum(m.shape[0] for m, _ in branches) + 1
    for j, (m, k) in enumerate(branches):
        length = m.shape[0]
        diagonal.append(k[:-1] + k[1:])
        off.append(-k[1:-1])
        last = offset + length - 1
        if j == len(branches) - 1:
            off.append(-k[-1:])  # the last branch's last mass is the hub's neighbour
        else:
            off.append(jnp.zeros(1))  # no spring between branches j and j + 1
            links.append((last, n - 1))
            link_springs.append(k[-1])
        offset += length
    hub_stiffness = hub_spring + sum(k[-1] for _, k in branches)
    diagonal.append(hub_stiffness[None])
    stiffness = SymmetricTridiagonal(
        jnp.concatenate(diagonal), jnp.concatenate(off), None, tuple(links),
        jnp.stack(link_springs) if links else None)
    mass = Diagonal(jnp.concatenate([m for m, _ in branches] + [hub_mass[None]]))
    return SecondOrderSystem(mass, stiffness, dampers_operator(n, dampers),
                             as_internal(internal_damping, n))
