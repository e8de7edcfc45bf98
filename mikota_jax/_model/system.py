"""``SecondOrderSystem``: M x'' + D x' + K x = f (eq. 3.1), the type of every system.

Full or reduced; the builders live elsewhere: chains in ``_chain`` (eqs. 2.1-2.3), a user's
matrices in ``_user_matrices``, a reduced model's projected system in ``_galerkin``. Units: any
consistent set (masses, stiffnesses in force per length, damping coefficients in force * time per
length).
"""

import equinox as eqx

from .._errors import MARK
from .dampers import Dampers, GroundedDamper, RelativeDamper
from .internal_damping import InternalDamping
from .modal import generalized_modes
from .operators import Operator, add


class SecondOrderSystem(eqx.Module):
    """A linear second-order system M x'' + D x' + K x = f (eq. 3.1), with structured operators.

    ``mass`` M and ``stiffness`` K (force per length) are n x n operators: diagonal and symmetric
    tridiagonal for a chain (eq. 2.2), dense for a reduced model, banded or sparse for a user's
    matrices; ``damping`` is the discrete dampers' operator (low rank once projected), ``internal``
    the rest of D (a user's matrix, Rayleigh, modal damping), each ``None`` when absent; D (force *
    time per length) is their sum. Build with ``mikota_chain``, ``chain``, ``branched_chain`` or
    ``system``; ``solve`` solves it.
    """

    mass: Operator
    stiffness: Operator
    damping: Dampers | Operator | None = None
    internal: InternalDamping | None = None

    @property
    def size(self) -> int:
        """n, the number of DOFs."""
        return self.mass.size

    @property
    def damped(self) -> bool:
        """Whether D is present (dampers or internal damping)."""
        return self.damping is not None or self.internal is not None

    def modes(self):
        """(omega^2, U): K U = M U diag(omega^2), U^T M U = I, ascending (unchecked)."""
        return generalized_modes(self)

    def damping_operator(self):
        """D as one operator (dampers plus internal damping), or None when undamped."""
        internal = None if self.internal is None else self.internal.operator(
            self.mass, self.stiffness, self.modes)
        return add(self.damping, internal)

    def dense(self):
        """(M, D, K) as dense (n, n) arrays (D is None when undamped): for small systems, checks."""
        damping = self.damping_operator()
        damping = None if damping is None else damping.as_matrix()
        return self.mass.as_matrix(), damping, self.stiffness.as_matrix()

    def project(self, basis) -> "SecondOrderSystem":
        """The r-DOF system (basis^T M basis, basis^T D basis, basis^T K basis) of eq. (3.4).

        ``basis`` is (n, r); the result has dense r x r mass and stiffness and low-rank dampers;
        Rayleigh damping stays Rayleigh damping of the projected M and K (exact), modal or a
        user's damping becomes a dense r x r matrix. ``reduce`` checks the basis and keeps it
        for the lift (eq. 3.2); prefer it.
        """
        damping = None if self.damping is None else self.damping.project(basis)
        internal = None if self.internal is None else self.internal.project(
            basis, self.mass, self.stiffness, self.modes)
        return SecondOrderSystem(self.mass.project(basis), self.stiffness.project(basis), damping,
                                 internal)


def dampers_operator(n: int, dampers) -> Dampers | None:
    """The ``Dampers`` of a sequence of dampers (one damper alone is a sequence of one), or None
    when there are none."""
    if isinstance(dampers, GroundedDamper | RelativeDamper):
        dampers = (dampers,)
    try:
        dampers = tuple(dampers)
    except TypeError:
        raise ValueError(MARK + "dampers must be a list of GroundedDamper or RelativeDamper, "
                         f"got {dampers!r:.60}.") from None
    for d in dampers:
        if not isinstance(d, GroundedDamper | RelativeDamper):
            raise ValueError(MARK + f"dampers must be GroundedDamper or RelativeDamper, got {d!r}.")
    return Dampers(n, dampers) if dampers else None
