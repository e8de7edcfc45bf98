"""``results.json``: a ``SceneResult`` in the layout the command line writes, and ``write_json``,
the one JSON writer of the package, its notebooks and the benchmarks.

Layout: ``name``, ``times`` (N), ``full`` and (with a ``[reduction]``) ``reduced``:
{quantity: {"DOF": N values}} for the 1-based output DOFs, then the requested outputs of
``OUTPUTS`` in its order (``singular_values`` (k), ``rank``, ``modes`` (r lists of n),
``phase_error`` (eq. 5.4) with its ``phase_error_aggregate``, ``relative_error``), then ``meta``.
"""

import json
import os
import platform
import tempfile
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

from .._errors import MARK
from .._plain import to_plain
from .._scenes.run import SceneResult
from .._scenes.scene import Scene

# quantities reported as histories: {"DOF": values} under "full" and "reduced"
HISTORIES = ("displacement", "velocity")

# [output] quantity -> the JSON entries it adds (after "full"/"reduced", in this order). Adding an
# output is one entry here (and its name in ``mikota_jax._scenes.scene.QUANTITIES``).
OUTPUTS: dict[str, Callable[[SceneResult], dict]] = {
    "singular_values": lambda r: {"singular_values": r.model.stats.singular_values},
    "rank": lambda r: {"rank": r.model.rank},
    "modes": lambda r: {"modes": r.model.basis.T},
    "phase_error": lambda r: {"phase_error": float(r.metrics["phase_error"]),
                              "phase_error_aggregate": r.scene.output.phase_error},
    "relative_error": lambda r: {"relative_error": float(r.metrics["relative_error"])},
}


def _histories(trajectory, quantities, dofs) -> dict[str, dict[str, np.ndarray]]:
    index = {d: k for k, d in enumerate(trajectory.dofs)}
    columns = {}
    for quantity in HISTORIES:
        if quantity in quantities:
            values = np.asarray(getattr(trajectory, quantity))
            columns[quantity] = {str(d): values[:, index[d]] for d in dofs}
    return columns


def result_dict(result: SceneResult) -> dict:
    """``result`` as the dict of ``results.json`` (arrays as numpy; ``write_json`` writes it)."""
    if not isinstance(result, SceneResult):
        raise ValueError(MARK + f"result must be a SceneResult (see run_scene), got "
                         f"{type(result).__name__}.")
    scene, quantities = result.scene, result.scene.output.quantities
    data: dict = {"name": scene.name, "times": np.asarray(result.times),
                  "full": _histories(result.full, quantities, result.dofs)}
    if result.reduced is not None:
        data["reduced"] = _histories(result.reduced, quantities, result.dofs)
        for quantity, entries in OUTPUTS.items():
            if quantity in quantities:
                data.update(entries(result))
    data["meta"] = meta(scene, result.timings)
    return data


def run_summary(result: SceneResult, out: Path, figures=()) -> str:
    """A few lines for a person: what ``run`` computed, its key numbers, where the files are."""
    scene, times = result.scene, np.asarray(result.times)
    solver = method_record(scene.method)
    solver = ", ".join([solver["method"]] + (
        [f"rtol {solver['rtol']:g}"] if "rtol" in solver else []))
    lines = [f"{scene.name}: n = {scene.size} DOFs, full model ({solver}) on "
             f"[{times[0]:g}, {times[-1]:g}] at {times.shape[0]} times, "
             f"{len(result.dofs)} output DOF(s); outputs: {', '.join(scene.output.quantities)}"]
    timings = result.timings
    stages = [f"full solve {timings['full_solve_s']:.2f} s"] if "full_solve_s" in timings else []
    if result.model is not None:
        reduction = scene.reduction
        rule = (f"rank {reduction.rank}" if reduction.rank is not None
                else f"{100 * reduction.energy:g} % pseudo-energy")
        lines.append(f"  POD of {result.model.stats.snapshots} snapshots on "
                     f"[{reduction.window[0]:g}, {reduction.window[1]:g}]: r = "
                     f"{result.model.rank} ({rule})")
        stages += [f"{name.removesuffix('_s').replace('_', ' ')} {timings[name]:.2f} s"
                   for name in ("reduction_s", "reduced_solve_s") if name in timings]
    for name, value in result.metrics.items():
        lines.append(f"  {name.replace('_', ' ')}: {float(value):.6g}")
    if stages:
        lines.append("  " + ", ".join(stages))
    lines.append(f"wrote {out / 'results.json'}"
                 + (f" and {len(figures)} figure(s): {', '.join(figures)}" if figures else
                    " (for figures: figures = true in the scene's [output] table)"))
    return "\n".join(lines)


def method_record(method) -> dict:
    """The scene's method as JSON: {"method": "spectral" | "dense" | a [solver] name (with
    rtol, atol, max_steps) | the method's class name}."""
    from .._solver.ode import SOLVERS
    from .._solver.solve import ODE, DenseExponential, Spectral

    if isinstance(method, Spectral | DenseExponential):
        return {"method": "spectral" if isinstance(method, Spectral) else "dense"}
    if isinstance(method, ODE):
        names = {cls: name for name, cls in SOLVERS.items()}
        return {"method": names.get(type(method.solver), type(method.solver).__name__),
                "rtol": float(method.rtol), "atol": None if method.atol is None
                else float(method.atol), "max_steps": method.max_steps}
    return {"method": type(method).__name__}


def meta(scene: Scene, timings: dict) -> dict:
    """The versions, backend, x64 flag, solver, reduction request and wall times of a run."""
    import diffrax
    import equinox

    from .. import __version__

    solver = method_record(scene.method)
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


def _default(value):
    """``json``'s hook for what it cannot write itself: arrays and numpy/JAX scalars (``to_plain``),
    refusing non-finite numbers as ``json`` refuses a non-finite float."""
    if isinstance(value, np.ndarray | np.generic | jax.Array):
        array = np.asarray(value)
        if array.dtype.kind in "fc" and not np.all(np.isfinite(array)):
            raise ValueError(MARK + "a non-finite number (NaN or inf) cannot be written to JSON.")
        return to_plain(array)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def _umask() -> int:
    """The process's umask (read by setting it, then restoring it)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_json(data: dict, path: str | Path, *, newline: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically (a failed run leaves no partial file), without its
    top-level ``_`` keys; arrays become lists (``to_plain``); NaN or inf is a ``ValueError``.

    ``newline``: end the file with a line break. Returns the path.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    clean = {k: v for k, v in data.items() if not str(k).startswith("_")}
    text = json.dumps(clean, indent=1, allow_nan=False, default=_default)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as handle:
            handle.write(text + ("\n" if newline else ""))
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; a plain open() respects the umask
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
