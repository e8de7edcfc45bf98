"""The application layer of mikota_jax: files, figures and the command line, built on the core.

The core library (``mikota_jax``: systems, solvers, POD, reduction, objectives, optimisation,
sweeps, and the ``Scene`` data) never imports this package, as pyMOR keeps ``pymor.core`` apart
from ``pymor.scripts``. One module per job:

* ``cli``: ``python -m mikota_jax`` / ``mikota-jax``: ``reproduce``, ``run``, ``optimise``;
* ``scene_file``: ``load_scene``, a scene from TOML (a file, a string, a mapping or a packaged
  paper scene), every key validated;
* ``scene_systems``: the TOML tables that build the system (``[chain]``, ``[[damper]]``,
  ``[internal_damping]``) and "mode l" initial states;
* ``toml_checks``: validation of parsed TOML tables, one ``ValueError`` naming ``[table] key``;
* ``results``: a ``SceneResult`` as the dict of ``results.json`` (``result_dict``, one registry
  entry per output) and ``write_json``, the one JSON writer (also the benchmarks' and notebooks');
* ``figures``: the paper's figures 2-9, a scene's figures and the placement landscape (Agg PNGs);
* ``reproduction``: ``reproduce``, every number of Weber & Zastrau (2018) beside ours;
* ``placement``: ``problem_from_scene`` and ``optimise_scene``, damper placement for a scene.
"""

from typing import TYPE_CHECKING

# Each name and the module that defines it, loaded on first use (``python -m mikota_jax --help``
# imports no more than the command line needs).
_NAMES = {"placement_landscape": "figures", "scene_figures": "figures",
          "optimise_scene": "placement", "problem_from_scene": "placement",
          "reproduce": "reproduction", "result_dict": "results", "write_json": "results",
          "load_scene": "scene_file", "scene_from_dict": "scene_file"}


def __getattr__(name: str):
    if name not in _NAMES:
        raise AttributeError(f"module 'mikota_jax.app' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f"mikota_jax.app.{_NAMES[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_NAMES))


if TYPE_CHECKING:  # the same names for static tools
    from .figures import placement_landscape as placement_landscape
    from .figures import scene_figures as scene_figures
    from .placement import optimise_scene as optimise_scene
    from .placement import problem_from_scene as problem_from_scene
    from .reproduction import reproduce as reproduce
    from .results import result_dict as result_dict
    from .results import write_json as write_json
    from .scene_file import load_scene as load_scene
    from .scene_file import scene_from_dict as scene_from_dict
