"""Sensitivities: Jacobians of a scene's outputs with respect to its physical parameters.

A scene's physical values become a dict of named float64 arrays (a pytree), the *parameters*:

==========================  =======  ==========================================================
name                        shape    meaning
==========================  =======  ==========================================================
``"m"``, ``"k"``            ()       Mikota's chain only: m_i = m / i, k_i = (n - i + 1) k (eq. 2.3)
``"masses"``, ``"springs"`` (n,)     any chain: m_1..m_n and k_1..k_n (eq. 2.2)
``"positions"``             (g,)     grounded dampers' positions in [1, n] (1-based)
``"coefficients"``          (g,)     grounded dampers' coefficients (force x time / length)
``"relative_coefficients"`` (p,)     relative dampers' coefficients
``"alpha"``, ``"beta"``     ()       Rayleigh damping alpha M + beta K (``Rayleigh``)
``"zeta"``                  () / (n,) modal damping ratios (``ModalDamping``), as the scene has it
``"amplitude"``             ()       a factor on the excitation: the load if the scene has one,
                                     else the initial state (x0, v0); nominal value 1
==========================  =======  ==========================================================

and ``SceneFunction(scene, output, ...)`` maps them to one output:

* ``"displacement"`` / ``"velocity"``: the history at the scene's output DOFs, (N, d);
* ``"energy"``: int_t0^T (x^T K x + x'^T M x') / 2 dt, () (exact for free vibration, else Dopri8);
* ``"phase_error"``: Delta E_phase of eq. (5.4) between the full and the reduced model, aggregated
  as the scene says, () -- it needs a ``[reduction]`` and compares both models at the parameters;
* ``"singular_values"``: the leading ``count`` singular values of the snapshot matrix (eq. 3.5) of
  the chosen model over the reduction window, (count,) -- differentiable only where they are
  distinct, which ``sensitivities`` checks.

``model="reduced"`` solves the Galerkin model (eq. 3.4) of the system at the parameters on a basis
held fixed: the scene's own POD basis at the nominal parameters (or the ``basis`` given). So a
reduced sensitivity is the derivative of the ROM, not of a ROM re-fitted at every parameter.
A damper's position derivative at an integer position is the right-sided one (the split damper
has a kink there, see ``GroundedDamper``).
"""

from dataclasses import dataclass

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import MARK, as_float
from .._limits import FEW_PARAMETERS
from .._metrics import phase_error
from .._model.loads import Pulse
from .._model.parameters import check_parameters, with_parameters
from .._model.reduced import galerkin
from .._model.system import SecondOrderSystem
from .._objective.functions import integrated_energy
from .._rom.base import pod_basis, snapshot_window
from .._solver.solve import ODE
from .scene import Scene, scene_parameters
from .scene import solve_scene as _solve

OUTPUTS = ("displacement", "velocity", "energy", "phase_error", "singular_values")
MODES = ("auto", "forward", "reverse")
def parameters_at(scene: Scene, wrt=None, parameters: dict | None = None) -> dict:
    """``scene_parameters(scene, wrt)`` with the entries of ``parameters`` (checked: names among
    ``wrt``, float64 of the nominal shapes) in place of the scene's values."""
    if not isinstance(scene, Scene):
        raise ValueError(MARK + f"scene must be a Scene (see mj.app.load_scene), got "
                         f"{type(scene).__name__}.")
    nominal = scene_parameters(scene, wrt)
    if parameters is not None:
        unknown = set(parameters) - set(nominal)
        if unknown:
            raise ValueError(MARK + f"parameters: {sorted(unknown)} are not among wrt = "
                             f"{sorted(nominal)}.")
        for name, value in parameters.items():
            value = as_float(value, name)
            if value.shape != nominal[name].shape:
                raise ValueError(MARK + f"parameters[{name!r}] must have shape "
                                 f"{nominal[name].shape}, got {value.shape}.")
            nominal[name] = value
    return nominal


def _scene_basis(scene: Scene) -> jax.Array:
    """The scene's POD basis at its nominal parameters (as ``run_scene`` computes it)."""
    reduction = scene.reduction
    if reduction is None:
        raise ValueError(MARK + "model='reduced' and output='phase_error' need a reduced basis: "
                         "give basis=... or a scene with a [reduction] table.")
    velocity = reduction.quantity == "velocity"
    full = _solve(scene.system, scene, None, not velocity, velocity, None)
    return pod_basis(full.velocity if velocity else full.displacement, scene.ts, reduction)[0]


class SceneFunction(eqx.Module):
    """parameters (dict, see the module docstring) -> one output of ``scene``: a pure function.

    ``jax.jacfwd``, ``jax.jacrev``, ``jax.vmap`` and ``jax.jit`` pass through it; changing the
    parameters' values never recompiles. ``forward=True`` integrates with
    ``diffrax.ForwardMode()`` (the adjoint for ``jax.jvp``/``jax.jacfwd``), else diffrax's
    reverse-mode checkpointing (for ``jax.grad``/``jax.jacrev``); exact solves ignore it.
    """

    scene: Scene
    basis: jax.Array | None
    output: str = eqx.field(static=True)
    model: str = eqx.field(static=True)
    count: int | None = eqx.field(static=True)
    forward: bool = eqx.field(static=True)
    snapshots: tuple[int, ...] = eqx.field(static=True)  # time indices of the snapshot window

    def __init__(self, scene: Scene, output: str = "energy", *, model: str = "full",
                 basis=None, count: int | None = None, forward: bool = False):
        if not isinstance(scene, Scene):
            raise ValueError(MARK + f"scene must be a Scene (see mj.app.load_scene), got "
                             f"{type(scene).__name__}.")
        if output not in OUTPUTS:
            raise ValueError(MARK + f"output must be one of {list(OUTPUTS)}, got {output!r}.")
        if model not in ("full", "reduced"):
            raise ValueError(MARK + f"model must be 'full' or 'reduced', got {model!r}.")
        if output == "energy" and scene.load is not None and float(scene.ts[0]) != 0.0:
            raise ValueError(MARK + "output='energy' with a load needs a time grid starting at "
                             "t = 0 (the load's times are absolute).")
        if basis is None and (model == "reduced" or output == "phase_error"):
            basis = _scene_basis(scene)
        elif basis is not None:
            basis = as_float(basis, "basis")
            if basis.ndim != 2 or basis.shape[0] != scene.size:
                raise ValueError(MARK + f"basis must be (n, r) with n = {scene.size}, got "
                                 f"{basis.shape}.")
        window = _snapshot_mask(scene)
        self.snapshots = tuple(int(k) for k in np.flatnonzero(window))
        if output == "singular_values":
            limit = min(scene.size, int(window.sum()))
            if count is None:
                count = basis.shape[1] if basis is not None else min(10, limit)
            if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= limit:
                raise ValueError(MARK + f"count must be an integer in 1..{limit} (the snapshot "
                                 f"matrix is {scene.size} x {int(window.sum())}), got {count!r}.")
        elif count is not None:
            raise ValueError(MARK + "count applies to output='singular_values' only.")
        self.scene, self.basis, self.output, self.model = scene, basis, output, model
        self.count, self.forward = count, bool(forward)

    def system(self, parameters: dict) -> SecondOrderSystem:
        """The system and dampers at ``parameters`` (missing names keep the scene's values).

        The values are checked here, once per evaluation, then mapped onto the scene's system by
        ``with_parameters`` (no rebuild, no re-validation)."""
        physical = {name: value for name, value in parameters.items() if name != "amplitude"}
        base = self.scene.system
        return with_parameters(base, check_parameters(base, physical))

    def excitation(self, parameters: dict):
        """(x0, v0, load) scaled by the amplitude: the load if there is one, else x0 and v0."""
        scene = self.scene
        a = parameters.get("amplitude")
        if a is None:
            return scene.x0, scene.v0, scene.load
        if scene.load is not None:
            load = scene.load
            if not isinstance(load, Pulse):
                raise ValueError(MARK + "amplitude scales a Pulse load only.")
            return scene.x0, scene.v0, Pulse(a * load.direction, load.start, load.duration)
        scale = lambda x: None if x is None else a * x  # noqa: E731
        return scale(scene.x0), scale(scene.v0), None

    def __call__(self, parameters: dict) -> jax.Array:
        scene = self.scene
        system = self.system(parameters)
        x0, v0, load = self.excitation(parameters)
        scene = eqx.tree_at(lambda s: (s.x0, s.v0, s.load), scene, (x0, v0, load),
                            is_leaf=lambda x: x is None)
        adjoint = diffrax.ForwardMode() if self.forward else None
        rom = None if self.basis is None else galerkin(system, self.basis)
        model = rom if self.model == "reduced" else system
        out = self.output
        if out in ("displacement", "velocity"):
            dofs = scene.output.dofs
            solution = _solve(model, scene, dofs, out == "displacement", out == "velocity",
                              adjoint)
            return getattr(solution, out)
        if out == "energy":
            method = scene.method
            horizon = scene.ts[-1] - scene.ts[0]
            if not isinstance(method, ODE) and load is None:
                return integrated_energy(model, horizon, x0, v0)
            # a pulse's energy is integrated: at the scene's ODE, else at rtol 1e-10
            method = method if isinstance(method, ODE) else ODE(rtol=1e-10, atol=1e-12)
            atol = 1e-12 if method.atol is None else method.atol
            return integrated_energy(model, horizon, x0, v0, load, method="ode",
                                     rtol=method.rtol, atol=atol,
                                     max_steps=method.max_steps, adjoint=adjoint)
        if out == "phase_error":
            full = _solve(system, scene, None, True, True, adjoint)
            reduced = _solve(rom, scene, None, True, True, adjoint)
            return phase_error(full.displacement, full.velocity, reduced.displacement,
                               reduced.velocity, aggregate=scene.output.phase_error)
        # singular values of the snapshot matrix Q (n x m, eq. 3.5)
        velocity = scene.reduction is not None and scene.reduction.quantity == "velocity"
        solution = _solve(model, scene, None, not velocity, velocity, adjoint)
        states = solution.velocity if velocity else solution.displacement
        snapshots = states[np.asarray(self.snapshots)].T
        return jnp.linalg.svd(snapshots, compute_uv=False)[: self.count]


def _snapshot_mask(scene: Scene) -> np.ndarray:
    if scene.reduction is None:
        return np.ones(np.shape(scene.ts), bool)
    return snapshot_window(scene.ts, scene.reduction.window)


@eqx.filter_jit
def _jacobian(function: SceneFunction, parameters: dict):
    """(value, jacobian) in one pass: the value rides along as the jacobian's aux (computed
    beside it, the solve ran twice: 1.7x the time of the full spectral J + gradient at
    n = 5000)."""
    jac = jax.jacfwd if function.forward else jax.jacrev

    def with_value(p):
        value = function(p)
        return value, value

    jacobian, value = jac(with_value, has_aux=True)(parameters)
    return value, jacobian


@dataclass(frozen=True)
class Sensitivities:
    """What ``sensitivities`` returns.

    ``jacobian[name]`` has shape ``value.shape + parameters[name].shape``: d output / d parameter.
    ``normalised[name]`` is the logarithmic sensitivity p dy/dp / y for outputs that are positive
    by nature (energy, phase error, singular values), and p dy/dp / max|y| for histories (which
    pass through zero): in both cases dimensionless, so parameters of different units compare.
    """

    output: str
    model: str
    mode: str
    value: jax.Array
    parameters: dict
    jacobian: dict
    normalised: dict
    normalisation: str

    def ranking(self) -> list[tuple[str, float]]:
        """(parameter entry, max |normalised sensitivity| over the output), largest first.

        Vector parameters are listed per entry, 1-based (``"masses[3]"``, ``"coefficients[1]"``).
        """
        rows = []
        axes = tuple(range(np.ndim(self.value)))
        for name, s in self.normalised.items():
            magnitude = np.max(np.abs(np.asarray(s)), axis=axes) if axes else np.abs(s)
            magnitude = np.atleast_1d(np.asarray(magnitude))
            if np.ndim(self.parameters[name]) == 0:
                rows.append((name, float(magnitude[0])))
            else:
                rows += [(f"{name}[{j + 1}]", float(v)) for j, v in enumerate(magnitude)]
        return sorted(rows, key=lambda row: -row[1])


def sensitivities(scene: Scene, output: str = "energy", *, wrt=None, model: str = "full",
                  mode: str = "auto", basis=None, count: int | None = None,
                  parameters: dict | None = None) -> Sensitivities:
    """The Jacobian of one ``output`` of ``scene`` with respect to its physical parameters.

    ``wrt``: parameter names (module docstring; default all that apply), evaluated at the scene's
    values or at ``parameters`` (a dict as from ``scene.parameters()``). ``model``: "full" or
    "reduced" (Galerkin ROM on a fixed basis: the scene's POD basis, or ``basis``). ``mode``:
    "forward" (``jax.jacfwd`` with ``diffrax.ForwardMode``: cheaper when the parameters are fewer
    than the outputs), "reverse" (``jax.jacrev``), or "auto" (forward when the parameters count
    at most 8 entries or no more than the output, reverse otherwise). Raises ``ValueError`` on a
    non-finite Jacobian and, for singular values, where two of them are too close for a
    derivative to exist.
    """
    if mode not in MODES:
        raise ValueError(MARK + f"mode must be one of {list(MODES)}, got {mode!r}.")
    nominal = parameters_at(scene, wrt, parameters)
    function = SceneFunction(scene, output, model=model, basis=basis, count=count)
    shape = jax.eval_shape(function, nominal).shape
    inputs = sum(int(np.prod(v.shape)) for v in nominal.values())
    if mode == "auto":  # forward also for a scalar of a few parameters: it compiles 2-3x faster
        few = inputs <= FEW_PARAMETERS
        mode = "forward" if few or inputs <= int(np.prod(shape)) else "reverse"
    function = SceneFunction(scene, output, model=model, basis=function.basis,
                             count=function.count, forward=mode == "forward")
    value, jacobian = _jacobian(function, nominal)
    if output == "singular_values":
        _check_distinct(value)
    for name, block in jacobian.items():
        if not bool(jnp.all(jnp.isfinite(block))):
            raise ValueError(MARK + f"the derivative with respect to {name!r} is not finite "
                             "(a kink, a repeated eigenvalue, or a failed solve at these values).")
    positive = output in ("energy", "phase_error", "singular_values")
    if positive:
        scale = value
        normalisation = "p dy/dp / y (logarithmic)"
    else:
        scale = jnp.max(jnp.abs(value))
        normalisation = "p dy/dp / max|y|"
    normalised = {}
    out_ndim = jnp.ndim(value)
    for name, block in jacobian.items():
        p = jnp.reshape(nominal[name], (1,) * out_ndim + nominal[name].shape)
        y = jnp.broadcast_to(scale, value.shape)
        y = jnp.reshape(y, value.shape + (1,) * nominal[name].ndim)
        normalised[name] = block * p / y
    return Sensitivities(output, model, mode, value, nominal, jacobian, normalised,
                         normalisation)


def _check_distinct(singular_values) -> None:
    s = np.asarray(singular_values)
    gaps = -np.diff(s)
    if s[-1] <= 1e-12 * s[0] or (gaps.size and np.min(gaps) <= 1e-8 * s[0]):
        raise ValueError(MARK + "count: the requested singular values include a repeated or "
                         "vanishing one, whose derivative does not exist; ask for fewer "
                         "(count=...).")
