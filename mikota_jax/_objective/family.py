"""The scalars a damper design minimises, as one family: ``objective(model)``.

Each objective holds what it needs besides the model (a horizon, initial states, output
matrices) and is called on a full ``SecondOrderSystem`` or a ``ReducedModel``; each is a pure
function of the model's values, so ``jax.grad``, ``jax.vmap`` and ``mj.sweep`` pass through:

    >>> import jax, mikota_jax as mj
    >>> energy = mj.Energy(20.0, x0=mj.unit_vector(300, 3))
    >>> jax.grad(lambda c: energy(mj.mikota_chain(300, dampers=[mj.GroundedDamper(7.0, c)])))(1.0)

* ``Energy(horizon, x0, v0, load)``: int_0^T (x^T K x + x'^T M x') / 2 dt;
* ``AverageEnergy(lowest, method)``: Veselic's total average energy, the trace of the Lyapunov
  solution;
* ``OutputEnergy(cx, cv, x0, v0, lowest, horizon)``: the energy of weighted outputs;
* ``H2Norm(inputs, cx, cv)``: ||G||_H2 of the input-output map;
* ``Peak(dof, ts, x0, v0, load, order, method)``: a smooth peak of one DOF's displacement from a
  ``solve``.

They replace the functions of the same names (``integrated_energy``, ``total_average_energy``,
``output_energy``, ``h2_norm``, ``smooth_peak``), which are private (``_objectives``,
``_output_criteria``).

``AbstractObjective`` is the base a user subclasses (implement ``__call__``).
"""

import abc

import diffrax
import equinox as eqx

from .._custom_types import Array
from .._errors import MARK
from .._solver.solve import ODE, AbstractMethod, Auto, DenseExponential, Spectral


class AbstractObjective(eqx.Module):
    """A scalar of a model: ``objective(model)`` for a ``SecondOrderSystem`` or a
    ``ReducedModel``. Subclass it and implement ``__call__``."""

    @abc.abstractmethod
    def __call__(self, model) -> Array:
        """The objective's value at ``model``: a float64 scalar."""


class Energy(AbstractObjective):
    """J = int_0^T (x^T K x + x'^T M x') / 2 dt of the response of eq. 3.1 from (``x0``, ``v0``),
    each (n,) in full coordinates, under ``load`` (default: free vibration from rest, which is
    zero), T = ``horizon``.

    ``method``, ``solve``'s method objects: ``Auto()`` (default: the damped modes where they
    apply, else the Van Loan integral, chosen from the structure; free vibration only),
    ``Spectral()`` (the damped modes in closed form), ``DenseExponential()`` (the Van Loan
    matrix-exponential integral, O(n^3): the choice for a reduced model) or ``ODE(rtol=...,
    atol=..., max_steps=..., adjoint=...)`` (Dopri8 with the energy as one more state, any load;
    ``atol=None`` means 1e-11; its ``solver`` must be ``diffrax.Dopri8()``). Units energy x time.
    """

    horizon: float
    x0: Array | None = None
    v0: Array | None = None
    load: object = None
    method: AbstractMethod = Auto()

    def __call__(self, model) -> Array:
        """J of ``model``."""
        from .functions import integrated_energy

        return integrated_energy(model, self.horizon, self.x0, self.v0, self.load,
                                 **energy_options(self.method))


def energy_options(method) -> dict:
    """``integrated_energy``'s method and options for a method object of ``Energy``."""
    if isinstance(method, ODE):
        if not isinstance(method.solver, diffrax.Dopri8):
            raise ValueError(MARK + "Energy(method=ODE(...)) integrates with Dopri8 (the energy "
                             f"as one more state): leave ODE's solver out, got {method.solver!r}.")
        atol = 1e-11 if method.atol is None else method.atol
        return dict(method="ode", rtol=method.rtol, atol=atol, max_steps=method.max_steps,
                    adjoint=method.adjoint)
    return dict(method=exact_method(method, "Energy", " or ODE(...)"))


def exact_method(method, owner: str, more: str = "") -> str:
    """The exact functions' method name of ``Auto()``, ``Spectral()`` or ``DenseExponential()``;
    anything else refused in one line naming ``owner`` (``more``: the other methods it takes)."""
    for kind, name in ((Auto, "exact"), (Spectral, "spectral"), (DenseExponential, "dense")):
        if type(method) is kind:
            return name
    raise ValueError(MARK + f"{owner}'s method must be Auto(), Spectral(), DenseExponential()"
                     f"{more}, got {method!r}.")


class AverageEnergy(AbstractObjective):
    """Veselic's total average energy: trace X, A^T X + X A = -Z (A the state matrix of eq. 3.1
    in scaled modal coordinates), over the ``lowest`` modes (all when None); needs no excitation,
    is infinite (refused) where a mode is undamped. Its unit is time. It is Veselic's and
    FastOptimalDamping.jl's trace: ``OutputEnergy`` with C_x = Omega U^T M, C_v = U^T M (the
    energy norm) and the same ``lowest``; a trace of the physical (x, x') Gramian is another
    number (the module docstring of ``_output_criteria`` compares the published definitions).

    ``method``: ``Auto()`` (default: the damped modes where they apply, chosen from the
    structure), ``Spectral()`` or ``DenseExponential()`` (Smith doubling of Van Loan's integral,
    O(n^3): where the damped modes refuse, e.g. where more pairs of roots meet at once than they
    sum exactly)."""

    lowest: int | None = eqx.field(static=True, default=None)
    method: AbstractMethod = Auto()

    def __call__(self, model) -> Array:
        """trace X of ``model``."""
        from .functions import total_average_energy

        return total_average_energy(model, self.lowest,
                                    method=exact_method(self.method, "AverageEnergy"))


class OutputEnergy(AbstractObjective):
    """sum_i int_0^T |C_x x_i + C_v x_i'|^2 dt over the free vibrations from the columns of
    ``x0``, ``v0`` (or the 2s unit modal states of the ``lowest`` s modes; neither: all 2n),
    T = ``horizon`` (None: infinite). ``cx``, ``cv``: (q, n) or (n,) output matrices; units
    output^2 x time."""

    cx: Array | None = None
    cv: Array | None = None
    x0: Array | None = None
    v0: Array | None = None
    lowest: int | None = eqx.field(static=True, default=None)
    horizon: float | None = None

    def __call__(self, model) -> Array:
        """The output energy of ``model``."""
        from .outputs import output_energy

        return output_energy(model, self.cx, self.cv, x0=self.x0, v0=self.v0,
                             lowest=self.lowest, horizon=self.horizon)


class H2Norm(AbstractObjective):
    """||G||_H2 of G(s) = (C_x + s C_v)(s^2 M + s D + K)^-1 B, B = ``inputs`` ((n, m) or (n,)
    force directions); undamped modes the inputs do not excite or the outputs do not see are
    dropped, a seen one is refused."""

    inputs: Array
    cx: Array | None = None
    cv: Array | None = None

    def __call__(self, model) -> Array:
        """||G||_H2 of ``model``."""
        from .outputs import h2_norm

        return h2_norm(model, self.inputs, self.cx, self.cv)


class Peak(AbstractObjective):
    """A smooth peak (the order-p mean of |x_dof(t)| over the (N,) times ``ts``) of the
    displacement of the 1-based ``dof``, from ``solve(model, ts, x0, v0, load, method=...)``;
    in [N^(-1/p), 1] x the maximum, in displacement units (p = ``order``, even)."""

    dof: int = eqx.field(static=True)
    ts: Array
    x0: Array | None = None
    v0: Array | None = None
    load: object = None
    order: int = eqx.field(static=True, default=16)
    method: AbstractMethod = Auto()

    def __call__(self, model) -> Array:
        """The smooth peak of ``model``'s response at ``dof``."""
        from .._solver.solve import solve
        from .functions import smooth_peak

        trajectory = solve(model, self.ts, self.x0, self.v0, self.load, method=self.method,
                           dofs=[self.dof])
        return smooth_peak(trajectory.displacement[:, 0], self.order)
