"""``Trajectory``: what ``solve`` returns, whichever method made it.

Conventions: rows are the N output times, columns the d requested 1-based DOFs.
"""

import equinox as eqx

from .._custom_types import Array, Float, Times


class Trajectory(eqx.Module):
    """The saved outputs of ``solve``: rows are times, columns requested DOFs.

    ``ts``: (N,) times; ``displacement`` x, ``velocity`` x': (N, d), column j for the 1-based DOF
    ``dofs[j]`` (d = len(dofs); all n DOFs by default), None when not requested; ``num_steps``:
    the integrator's step count (``ODE``; None for an exact method). A reduced model's
    outputs are lifted to the full DOFs (eq. 3.2).
    """

    ts: Times
    displacement: Float[Array, "N d"] | None
    velocity: Float[Array, "N d"] | None
    dofs: tuple[int, ...] = eqx.field(static=True)  # 1-based
    num_steps: Array | None = None
