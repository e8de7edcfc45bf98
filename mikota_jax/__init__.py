"""mikota_jax: differentiable reduced-order modelling of linear vibration chains in JAX.

Conventions: DOFs and damper positions are 1-based, as in Weber & Zastrau (2018); arrays are
float64 (importing the package turns on ``jax_enable_x64``; turning it off again is an error);
trajectories are (N, d) with rows at times and columns at the requested DOFs.

Every name loads its module on first use (PEP 562), so ``import mikota_jax`` and
``python -m mikota_jax --help`` import neither JAX nor the solvers until something asks for them.
"""

import os as _os
import sys as _sys
from typing import TYPE_CHECKING as _TYPE_CHECKING

from . import _interrupt

if _interrupt.is_command_line():  # Ctrl-C while JAX loads: one line, not a traceback
    _interrupt.exit_on_interrupt()

# float64 always: JAX reads this when it is first imported; if it already is, set it now
_os.environ["JAX_ENABLE_X64"] = "1"
if "jax" in _sys.modules:
    _sys.modules["jax"].config.update("jax_enable_x64", True)

__version__ = "0.2.0"

# Each core module and the public names it defines, loaded on first use.
_MODULES = {
    "_cache": "enable_compilation_cache",
    "_estimation.estimate": ("AbstractEstimator Estimate Hierarchical ResidualBound "
                             "certified_sweep estimate"),
    "_estimation.enrichment": "EnrichedPOD",
    "_estimation.greedy": "Greedy rank_for_bound",
    "_model.chain": "branched_chain chain mikota_chain",
    "_model.dampers": "GroundedDamper RelativeDamper",
    "_model.internal_damping": "ModalDamping Rayleigh",
    "_model.loads": "Pulse pulse unit_vector",
    "_model.modal": "modal_decomposition",
    "_model.reduced": "ReducedModel ReductionStats",
    "_model.system": "SecondOrderSystem",
    "_model.user_matrices": "system",
    "_objective.family": "AbstractObjective AverageEnergy Energy H2Norm OutputEnergy Peak",
    "_placement.optimise": ("AbstractDesignStrategy Coefficients CoordinateDescent DamperDesign "
                            "DesignResult Grid ScreenAndCertify Solution optimise"),
    "_placement.viscosity": "AbstractBoxMinimiser ProjectedBFGS SpectralProjectedGradient",
    "_rom.balanced": "SOBT TwoSided",
    "_rom.base": "POD AbstractIOReduction AbstractReduction",
    "_rom.h2_optimal": "H2Optimal StructuredH2",
    "_rom.io_model": "IOModel ErrorModel",
    "_rom.lti": "LTIModel",
    "_rom.reduce": ("CraigBampton IRKA Krylov Modal ModalStatic Projection RationalKrylov Union "
                    "reduce"),
    "_scenes.run": "SceneResult run_scene",
    "_scenes.scene": "Scene",
    "_scenes.sensitivity": "SceneFunction Sensitivities sensitivities",
    "_solver.implicit": "StructuredKvaerno5",
    "_solver.trajectory": "Trajectory",
    "_solver.solve": "AbstractMethod Auto DenseExponential ODE Spectral solve",
    "_sweep": "grid sweep",
}
_CORE_NAMES = {name: module for module, names in _MODULES.items() for name in names.split()}

# Public submodules: Mikota's closed forms, error measures, matrix files, and the application layer
# (``mj.app``: scene files, the paper's reproduction, damper placement for a scene), which the core
# never imports.
_SUBMODULES = ("analytic", "metrics", "io", "app")


def __getattr__(name: str):
    import importlib

    if name in _SUBMODULES:
        return importlib.import_module(f"mikota_jax.{name}")  # sets the attribute itself
    if name in _CORE_NAMES:
        module = importlib.import_module(f"mikota_jax.{_CORE_NAMES[name]}")
    else:
        raise AttributeError(f"module 'mikota_jax' has no attribute {name!r}")
    import jax

    jax.config.update("jax_enable_x64", True)  # even if JAX was imported with it off
    value = getattr(module, name)
    globals()[name] = value  # later look-ups skip this hook
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_CORE_NAMES) | set(_SUBMODULES))


if _TYPE_CHECKING:  # the same names for static tools (type checkers, the API reference)
    from . import analytic as analytic
    from . import io as io
    from . import metrics as metrics
    from ._cache import enable_compilation_cache as enable_compilation_cache
    from ._estimation.enrichment import EnrichedPOD as EnrichedPOD
    from ._estimation.estimate import AbstractEstimator as AbstractEstimator
    from ._estimation.estimate import Estimate as Estimate
    from ._estimation.estimate import Hierarchical as Hierarchical
    from ._estimation.estimate import ResidualBound as ResidualBound
    from ._estimation.estimate import certified_sweep as certified_sweep
    from ._estimation.estimate import estimate as estimate
    from ._estimation.greedy import Greedy as Greedy
    from ._estimation.greedy import rank_for_bound as rank_for_bound
    from ._model.chain import branched_chain as branched_chain
    from ._model.chain import chain as chain
    from ._model.chain import mikota_chain as mikota_chain
    from ._model.dampers import GroundedDamper as GroundedDamper
    from ._model.dampers import RelativeDamper as RelativeDamper
    from ._model.internal_damping import ModalDamping as ModalDamping
    from ._model.internal_damping import Rayleigh as Rayleigh
    from ._model.loads import Pulse as Pulse
    from ._model.loads import pulse as pulse
    from ._model.loads import unit_vector as unit_vector
    from ._model.modal import modal_decomposition as modal_decomposition
    from ._model.reduced import ReducedModel as ReducedModel
    from ._model.reduced import ReductionStats as ReductionStats
    from ._model.system import SecondOrderSystem as SecondOrderSystem
    from ._model.user_matrices import system as system
    from ._objective.family import AbstractObjective as AbstractObjective
    from ._objective.family import AverageEnergy as AverageEnergy
    from ._objective.family import Energy as Energy
    from ._objective.family import H2Norm as H2Norm
    from ._objective.family import OutputEnergy as OutputEnergy
    from ._objective.family import Peak as Peak
    from ._placement.optimise import AbstractDesignStrategy as AbstractDesignStrategy
    from ._placement.optimise import Coefficients as Coefficients
    from ._placement.optimise import CoordinateDescent as CoordinateDescent
    from ._placement.optimise import DamperDesign as DamperDesign
    from ._placement.optimise import DesignResult as DesignResult
    from ._placement.optimise import Grid as Grid
    from ._placement.optimise import ScreenAndCertify as ScreenAndCertify
    from ._placement.optimise import Solution as Solution
    from ._placement.optimise import optimise as optimise
    from ._placement.viscosity import AbstractBoxMinimiser as AbstractBoxMinimiser
    from ._placement.viscosity import ProjectedBFGS as ProjectedBFGS
    from ._placement.viscosity import SpectralProjectedGradient as SpectralProjectedGradient
    from ._rom.balanced import SOBT as SOBT
    from ._rom.balanced import TwoSided as TwoSided
    from ._rom.base import POD as POD
    from ._rom.base import AbstractIOReduction as AbstractIOReduction
    from ._rom.base import AbstractReduction as AbstractReduction
    from ._rom.h2_optimal import H2Optimal as H2Optimal
    from ._rom.h2_optimal import StructuredH2 as StructuredH2
    from ._rom.io_model import ErrorModel as ErrorModel
    from ._rom.io_model import IOModel as IOModel
    from ._rom.lti import LTIModel as LTIModel
    from ._rom.reduce import IRKA as IRKA
    from ._rom.reduce import CraigBampton as CraigBampton
    from ._rom.reduce import Krylov as Krylov
    from ._rom.reduce import Modal as Modal
    from ._rom.reduce import ModalStatic as ModalStatic
    from ._rom.reduce import Projection as Projection
    from ._rom.reduce import RationalKrylov as RationalKrylov
    from ._rom.reduce import Union as Union
    from ._rom.reduce import reduce as reduce
    from ._scenes.run import SceneResult as SceneResult
    from ._scenes.run import run_scene as run_scene
    from ._scenes.scene import Scene as Scene
    from ._scenes.sensitivity import SceneFunction as SceneFunction
    from ._scenes.sensitivity import Sensitivities as Sensitivities
    from ._scenes.sensitivity import sensitivities as sensitivities
    from ._solver.implicit import StructuredKvaerno5 as StructuredKvaerno5
    from ._solver.solve import ODE as ODE
    from ._solver.solve import AbstractMethod as AbstractMethod
    from ._solver.solve import Auto as Auto
    from ._solver.solve import DenseExponential as DenseExponential
    from ._solver.solve import Spectral as Spectral
    from ._solver.solve import solve as solve
    from ._solver.trajectory import Trajectory as Trajectory
    from ._sweep import grid as grid
    from ._sweep import sweep as sweep
