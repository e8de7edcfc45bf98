"""``python -m mikota_jax optimise SCENE.toml``: damper placement for a scene, as JSON and a plot.

The scene's grounded dampers are the design (their positions and coefficients the start), its
initial state or load the excitation, its time grid the horizon, and its ``[reduction]`` table
(if any) the snapshot window and rank rule of the first POD basis.
"""

from pathlib import Path

import numpy as np

from .. import (
    AverageEnergy,
    DamperDesign,
    Energy,
    Grid,
    Peak,
    Scene,
    ScreenAndCertify,
    optimise,
)
from .._errors import MARK
from .figures import placement_landscape
from .results import write_json
from .scene_file import load_scene

_MIN_ENERGY = 0.9999
_OBJECTIVES = ("energy", "average_energy", "peak")


def problem_from_scene(scene: Scene, *, objective: str = "energy", dof: int | None = None,
                       lowest: int | None = None, energy: float | None = None,
                       **strategy) -> tuple[DamperDesign, ScreenAndCertify]:
    """The design problem of a scene and the ``ScreenAndCertify`` strategy with its POD settings
    (see the module docstring for what is taken from where): ``(design, strategy)`` for
    ``optimise``.

    ``objective``: "energy" (``Energy`` over the scene's horizon ts[-1] - ts[0]),
    "average_energy" (``AverageEnergy`` of the ``lowest`` s modes) or "peak" (``Peak`` of the
    1-based ``dof`` over the scene's grid); the design is the scene's grounded dampers, placed
    anywhere on the chain. The first basis keeps at least 99.99 % of the snapshots'
    pseudo-energy (the scene's fraction if higher, its rank if it gives one); ``energy``
    overrides both. ``strategy``: further ``ScreenAndCertify`` settings (starts, iterations...).
    """
    if not isinstance(scene, Scene):
        raise ValueError(MARK + f"scene must be a Scene, got {type(scene).__name__}.")
    if objective not in _OBJECTIVES:
        raise ValueError(MARK + f"objective must be one of {list(_OBJECTIVES)}, got "
                         f"{objective!r}.")
    reduction = scene.reduction
    kwargs = {}
    if reduction is not None:
        kwargs = dict(snapshots=reduction.window, criterion=reduction.criterion)
        if reduction.rank is not None:
            kwargs["rank"] = reduction.rank
        else:
            # at least 99.99 %: a coarser basis (the paper's 99 %, r = 76 in Section 5) is off by
            # several % at strong dampers, so certification would only enrich it (one more round
            # of full solves, measured)
            kwargs["energy"] = max(reduction.energy, _MIN_ENERGY)
    if energy is not None:
        kwargs.pop("rank", None)
        kwargs["energy"] = energy
    ts = scene.ts
    if objective == "energy":
        goal = Energy(float(ts[-1] - ts[0]), scene.x0, scene.v0, scene.load)
        kwargs.update(ts=ts)
    elif objective == "peak":
        if dof is None:
            raise ValueError(MARK + "objective 'peak' needs dof (a 1-based DOF in 1..n).")
        goal = Peak(dof, ts, scene.x0, scene.v0, scene.load)
    else:
        goal = AverageEnergy(lowest)
        kwargs.update(ts=ts, x0=scene.x0, v0=scene.v0, load=scene.load)
    n = scene.system.size
    design = DamperDesign(scene.system, goal, positions=range(1, n + 1))
    return design, ScreenAndCertify(**kwargs, **strategy)


def optimise_scene(source, out, *, objective: str = "energy", dof: int | None = None,
                   lowest: int | None = None, energy: float | None = None, starts: int = 8,
                   optimizer=None, iterations: int = 80, split: bool = False,
                   tolerance: float = 1e-4, certify: str = "full", sweep: int = 0,
                   landscape: tuple[int, int] = (60, 12), progress: bool = True) -> dict:
    """Optimise a scene's dampers (``ScreenAndCertify``); write ``placement.json`` and
    ``placement.png`` into ``out``.

    ``optimizer``: an optax ``GradientTransformation``, "adam" (the default, ``optax.adam(0.1)``)
    or "lbfgs" (optax's L-BFGS with a backtracking line search). ``sweep`` > 0 also runs the
    brute-force full-model sweep (``Grid``: every DOF x ``sweep`` log-spaced coefficients, the 3
    best DOFs refined) and draws it; otherwise the plot shows the reduced model's landscape on a
    ``landscape`` = (positions, coefficients) grid. ``certify``: "full" or "estimate".
    """
    from .._placement.certify import LBFGS
    from .._placement.search import OPTIMIZERS

    if isinstance(optimizer, str):
        if optimizer not in OPTIMIZERS:
            raise ValueError(MARK + f"optimizer must be one of {list(OPTIMIZERS)}, got "
                             f"{optimizer!r}.")
        optimizer = None if optimizer == "adam" else LBFGS
    scene = load_scene(source)
    design, strategy = problem_from_scene(
        scene, objective=objective, dof=dof, lowest=lowest, energy=energy, starts=starts,
        optimizer=optimizer, iterations=iterations, split=split, tolerance=tolerance,
        certify=certify, progress=progress)
    result = optimise(design, strategy)
    report = dict(scene=scene.name, objective=objective, result=result.to_json())
    n = design.system.size
    grounded = int(design.system.damping.positions.shape[0])
    paths_from = [h for h in result.history if h["phase"] in ("search", "polish")]
    c_all = np.concatenate([np.ravel(h["coefficients"]) for h in paths_from]
                           + [result.coefficients[:grounded]])
    c_low = max(float(np.nanmin(c_all)) / 3, 1e-6)
    c_high = float(np.nanmax(c_all)) * 3
    settings = dict(ts=strategy.ts, x0=strategy.x0, v0=strategy.v0, load=strategy.load,
                    rtol=strategy.rtol, max_steps=strategy.max_steps, progress=progress)
    if grounded == 1 and sweep > 0:
        coefficients = np.geomspace(c_low, c_high, sweep)
        grid = optimise(design, Grid(coefficients, refine=3, **settings))
        report["sweep"] = grid.to_json()
        report["sweep_speedup"] = ((grid.stats["seconds"] + grid.stats["seconds_refine"])
                                   / result.stats["seconds"])
        positions, values, kind = grid.stats["positions"], grid.stats["grid"], "full-model sweep"
    elif grounded == 1:
        positions = np.unique(np.round(np.linspace(1, n, min(landscape[0], n))))
        coefficients = np.geomspace(c_low, c_high, landscape[1])
        on = DamperDesign(design.system, design.objective, positions=positions)
        values = optimise(on, Grid(coefficients, basis=result.stats["basis"], batch_size=16,
                                   **settings)).stats["grid"]
        kind = f"reduced model (r = {result.stats['rank']})"
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if grounded == 1:
        last = paths_from[-1]  # the last relaxed search (split) or polish
        paths = [(last["positions"][:, s, 0], last["coefficients"][:, s, 0])
                 for s in range(last["positions"].shape[1])]
        figure = placement_landscape(
            out / "placement.png", positions, coefficients, values, paths,
            (float(result.positions[0]), float(result.coefficients[0])),
            f"{scene.name}: {objective}, {kind}")
        report["figure"] = figure.name
    write_json(report, out / "placement.json")
    return report


# criteria of the full-order searches, and the CLI's objective names for them
FULL_ORDER_CRITERIA = ("energy", "average_energy", "output", "h2", "peak")


def _selection(dofs, n: int, name: str) -> np.ndarray | None:
    """(len(dofs), n) rows e_dof (1-based DOFs), or None."""
    if dofs is None:
        return None
    dofs = [int(d) for d in dofs]
    if not dofs or any(d < 1 or d > n for d in dofs) or len(set(dofs)) != len(dofs):
        raise ValueError(MARK + f"{name} must be distinct DOFs in 1..{n}, got {dofs!r:.80}.")
    return np.eye(n)[np.asarray(dofs) - 1]


def full_order_scene(source, out, *, search: str, objective: str = "average_energy",
                     lowest: int | None = None, dof: int | None = None, output_dofs=None,
                     input_dofs=None, candidates=None, pair_candidates=None,
                     minimiser=None, progress: bool = True) -> dict:
    """Optimise a scene's dampers at full order; write ``placement.json`` and ``.png``.

    ``search``: ``"viscosities"`` (``Coefficients``: every damper's coefficient, grounded and
    relative, at fixed places) or ``"places"`` (``CoordinateDescent``: the grounded dampers
    moved over ``candidates``, 1-based DOFs, default all, the relative ones over
    ``pair_candidates`` when given, every coefficient re-optimised, each polish by
    ``minimiser``: ``ProjectedBFGS()``, the default, or ``SpectralProjectedGradient()``).
    ``objective``: one of ``FULL_ORDER_CRITERIA``; "energy" and "output" take the scene's
    initial state over its time grid ("output" over the ``lowest`` modes' unit states
    when ``lowest`` is given), "average_energy" the ``lowest`` modes, "output" and "h2" the
    displacements at ``output_dofs``, "h2" unit forces at ``input_dofs``, "peak" the smooth
    peak of the displacement of ``dof`` over the scene's time grid.
    """
    from .. import Coefficients, CoordinateDescent, H2Norm, OutputEnergy, ProjectedBFGS
    from .figures import search_history

    if search not in ("viscosities", "places"):
        raise ValueError(MARK + f"search must be 'viscosities' or 'places', got {search!r}.")
    if objective not in FULL_ORDER_CRITERIA:
        raise ValueError(MARK + f"objective must be one of {FULL_ORDER_CRITERIA} for a "
                         f"full-order search, got {objective!r}.")
    scene = load_scene(source)
    system, n = scene.system, scene.system.size
    cx = _selection(output_dofs, n, "output_dofs")
    inputs = _selection(input_dofs, n, "input_dofs")
    if objective in ("output", "h2") and cx is None:
        raise ValueError(MARK + f"objective {objective!r} needs output_dofs (--output-dofs).")
    if objective == "h2" and inputs is None:
        raise ValueError(MARK + "objective 'h2' needs input_dofs (--input-dofs).")
    free_vibration = objective in ("energy", "peak") or (objective == "output"
                                                          and lowest is None)
    x0 = v0 = None
    if free_vibration:
        if scene.load is not None:
            raise ValueError(MARK + f"objective {objective!r} is the energy of a free vibration; "
                             f"scene {scene.name!r} has a load.")
        x0, v0 = scene.x0, scene.v0
    horizon = float(scene.ts[-1])
    if objective == "peak" and dof is None:
        raise ValueError(MARK + "objective 'peak' needs dof (--dof).")
    goal = {"energy": lambda: Energy(horizon, x0, v0),
            "average_energy": lambda: AverageEnergy(lowest),
            "output": lambda: OutputEnergy(cx, None, x0, v0, lowest,
                                           horizon if free_vibration else None),
            "h2": lambda: H2Norm(None if inputs is None else inputs.T, cx),
            "peak": lambda: Peak(dof, scene.ts, x0, v0)}[objective]()
    minimiser = ProjectedBFGS() if minimiser is None else minimiser
    if search == "viscosities":
        result = optimise(DamperDesign(system, goal),
                          Coefficients(minimiser, progress=progress))
        history = [value for value, _ in result.history]
        extra = dict(relative_gradient=result.stats["relative_gradient"],
                     converged=result.result == "converged",
                     iterations=result.stats["iterations"],
                     evaluations=result.stats["evaluations"])
    else:
        grounded = system.damping.positions.shape[0] > 0
        positions = (range(1, n + 1) if candidates is None else candidates) if grounded else None
        design = DamperDesign(system, goal, positions=positions, pairs=pair_candidates)
        result = optimise(design, CoordinateDescent(minimiser=minimiser, progress=progress))
        history = [value for *_, value in result.history] or [result.value]
        extra = dict(sweeps=result.stats["sweeps"], evaluations=result.stats["evaluations"],
                     polishes=result.stats["polishes"], moves=result.history)
    report = dict(scene=scene.name, search=search, objective=objective,
                  result=dict(status=result.stats["status"], positions=result.positions,
                              pairs=np.asarray(result.pairs).tolist(),
                              coefficients=result.coefficients, value=result.value,
                              seconds=result.stats["seconds"], **extra))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    label = "iteration" if search == "viscosities" else "accepted move"
    report["figure"] = search_history(out / "placement.png", history, label,
                                      f"{scene.name}: {objective}, {search} at full order").name
    write_json(report, out / "placement.json")
    return report
