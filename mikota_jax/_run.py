"""``run_scene``: compute exactly what a scene asks for, and write it as ``results.json``.

Lazy by construction: velocities are integrated and saved only when an output reads them (the
velocity itself, or the phase error of eq. 5.4); all DOFs are saved only when the reduction or a
whole-chain metric needs them; POD and Galerkin run only with a ``[reduction]`` table. The paper's
reduced initial state is the projection q(0) = Phi^T x(0), q'(0) = Phi^T x'(0).
"""

import json
import os
import platform
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from ._exact import exact_solve
from ._galerkin import galerkin
from ._integrate import simulate
from ._metrics import phase_error, relative_error
from ._reduction import reduce
from ._scene import Scene


def solve_scene(model, scene: Scene, dofs, displacement: bool, velocity: bool, adjoint=None):
    """``model`` solved as ``scene`` says (exactly, or by ``simulate`` with its tolerances)."""
    kwargs = dict(dofs=dofs, displacement=displacement, velocity=velocity)
    if scene.solver == "exact":
        return exact_solve(model, scene.ts, scene.x0, scene.v0, scene.load, **kwargs)
    return simulate(model, scene.ts, scene.x0, scene.v0, scene.load, solver=scene.solver,
                    rtol=scene.rtol, atol=scene.atol, max_steps=scene.max_steps,
                    adjoint=adjoint, **kwargs)


def _columns(trajectory, quantity: str, dofs) -> dict[str, list[float]]:
    values = np.asarray(getattr(trajectory, quantity))
    index = {d: k for k, d in enumerate(trajectory.dofs)}
    return {str(d): values[:, index[d]].tolist() for d in dofs}


def run_scene(scene: Scene) -> dict:
    """Run ``scene``; return a JSON-ready dict: ``times``, ``full``, ``reduced``, metrics, ``meta``.

    ``times``: the N times; ``full``/``reduced``: {quantity: {"DOF": N values}} for the 1-based
    output DOFs; with a ``[reduction]``: POD of the (n, m) snapshots (eqs. 3.5-3.6), ``rank`` by
    eq. (3.7), Galerkin model (eq. 3.4), ``phase_error`` by eq. (5.4), ``singular_values`` (k),
    ``modes`` (r lists of n). Only the requested DOFs (default all) and quantities appear.
    Arrays of the internal solves are kept under the key ``"_arrays"`` (numpy, not written to
    JSON) for figures and further use.
    """
    if not isinstance(scene, Scene):
        raise ValueError(f"mikota_jax: scene must be a Scene (see load_scene), got "
                         f"{type(scene).__name__}.")
    out = scene.output
    quantities = set(out.quantities)
    n = scene.size
    dofs = out.dofs if out.dofs is not None else tuple(range(1, n + 1))
    reduction = scene.reduction
    wants_phase = "phase_error" in quantities or "relative_error" in quantities
    wants_v = "velocity" in quantities or "phase_error" in quantities
    snapshot_v = reduction is not None and reduction.quantity == "velocity"
    need_all = reduction is not None  # snapshots (and whole-chain metrics) need every DOF
    timings = {}
    result: dict = {"name": scene.name, "times": np.asarray(scene.ts).tolist()}
    arrays: dict = {"times": np.asarray(scene.ts), "dofs": dofs}

    start = time.perf_counter()
    full = solve_scene(scene.system, scene, None if need_all else dofs, True,
                  wants_v or snapshot_v)
    jax.block_until_ready(full)
    timings["full_solve_s"] = time.perf_counter() - start
    arrays["full"] = full
    result["full"] = {q: _columns(full, q, dofs) for q in ("displacement", "velocity")
                      if q in quantities}

    if reduction is not None:
        start = time.perf_counter()
        states = full.velocity if snapshot_v else full.displacement
        reduced_basis = reduce(states, scene.ts, reduction)
        decomposition, rank = reduced_basis.pod, reduced_basis.rank
        model = galerkin(scene.system, reduced_basis.basis)
        timings["reduction_s"] = time.perf_counter() - start
        start = time.perf_counter()
        reduced = solve_scene(model, scene, None if wants_phase else dofs, True, wants_v)
        jax.block_until_ready(reduced)
        timings["reduced_solve_s"] = time.perf_counter() - start
        arrays.update(pod=decomposition, rank=rank, reduced=reduced,
                      snapshots=reduced_basis.snapshots)
        result["reduced"] = {q: _columns(reduced, q, dofs) for q in ("displacement", "velocity")
                             if q in quantities}
        if "singular_values" in quantities:
            result["singular_values"] = np.asarray(decomposition.singular_values).tolist()
        if "rank" in quantities:
            result["rank"] = rank
        if "modes" in quantities:
            result["modes"] = np.asarray(decomposition.basis(rank)).T.tolist()
        if "phase_error" in quantities:
            result["phase_error"] = float(phase_error(
                full.displacement, full.velocity, reduced.displacement, reduced.velocity,
                aggregate=out.phase_error))
            result["phase_error_aggregate"] = out.phase_error
        if "relative_error" in quantities:
            result["relative_error"] = float(relative_error(full.displacement,
                                                            reduced.displacement))
    result["meta"] = _meta(scene, timings)
    result["_arrays"] = arrays
    return result


def _meta(scene: Scene, timings: dict) -> dict:
    import diffrax
    import equinox

    from . import __version__

    solver = {"method": scene.solver}
    if scene.solver != "exact":
        solver.update(rtol=scene.rtol, atol=scene.atol, max_steps=scene.max_steps)
    return {
        "mikota_jax": __version__, "jax": jax.__version__, "diffrax": diffrax.__version__,
        "equinox": equinox.__version__, "numpy": np.__version__,
        "python": platform.python_version(),
        "backend": jax.default_backend(), "x64": bool(jax.config.read("jax_enable_x64")),
        "solver": solver, "wall_times_s": timings,
        "reduction": None if scene.reduction is None else {
            "window": list(scene.reduction.window), "quantity": scene.reduction.quantity,
            "energy": scene.reduction.energy, "rank": scene.reduction.rank,
            "criterion": scene.reduction.criterion, "method": scene.reduction.method},
    }


def write_json(data: dict, path: Path) -> None:
    """Write ``data`` atomically (a failed run leaves no partial file), without ``_`` keys."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    clean = {k: v for k, v in data.items() if not k.startswith("_")}
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as handle:
            json.dump(clean, handle, indent=1, allow_nan=False)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
