"""Scene files: ``load_scene`` reads a scene from TOML (a file, a string, a mapping or a packaged
paper scene name) into the core ``Scene`` data.

``load_scene`` validates every key: an unknown key, a wrong type or a value out of range raises one
``ValueError`` naming the key (``[table] key``) and the allowed values. The tables that build the
system (``[chain]``, ``[[damper]]``, ``[internal_damping]``) are read by ``scene_systems``; the
validation helpers live in ``toml_checks``. DOFs are 1-based.
"""

import tomllib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from .._custom_types import Times, Vector
from .._errors import MARK, available_bytes
from .._metrics import AGGREGATES
from .._model.loads import Pulse, pulse
from .._rom.base import POD
from .._rom.pod import CRITERIA, METHODS
from .._scenes.scene import QUANTITIES, REDUCED_QUANTITIES, Output, Scene
from .._solver.ode import SOLVERS
from .._solver.solve import ODE, Auto, DenseExponential, Spectral
from .._solver.spectral.modes import spectral_applies
from .scene_systems import system_from
from .toml_checks import choice as _choice
from .toml_checks import fail as _fail
from .toml_checks import number as _number
from .toml_checks import table as _table

PAPER_SCENES = ("section4_first_mode", "section4_impulse", "section5_damped")


def _is_count(text: str) -> bool:
    """ASCII digits only (str.isdigit also takes "²", which int() refuses)."""
    return text.isascii() and text.isdecimal()


def _state_from(value, n: int, where: str, mode) -> Vector | None:
    if value is None or value == {} or value == []:
        return None
    if isinstance(value, str):
        words = value.split()
        if len(words) == 2 and words[0] == "mode" and _is_count(words[1]):
            number = int(words[1])
            if not 1 <= number <= n:
                _fail(where, f"mode number must lie in 1..{n}, got {number}.")
            return mode(number)
        _fail(where, f"must be a table {{DOF = value}}, a list of {n} numbers or \"mode l\", "
              f"got {value!r}.")
    if isinstance(value, Mapping):
        x = np.zeros(n)
        for dof, v in value.items():
            if not _is_count(str(dof)) or not 1 <= int(dof) <= n:
                _fail(where, f"DOF keys must be integers in 1..{n}, got {dof!r}.")
            if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
                _fail(where, f"value at DOF {dof} must be a finite number, got {v!r}.")
            x[int(dof) - 1] = v
        return jnp.asarray(x)
    if isinstance(value, list):
        if len(value) != n or not all(isinstance(v, int | float) and not isinstance(v, bool)
                                      and np.isfinite(v) for v in value):
            _fail(where, f"a list must hold {n} finite numbers.")
        return jnp.asarray(np.asarray(value, dtype=np.float64))
    _fail(where, f"unsupported value {value!r}.")


def _load_from(data, n: int) -> Pulse | None:
    table = _table(data, "load", {"type", "dof", "amplitude", "duration", "start"})
    if not table:
        return None
    _choice(table, "[load]", "type", ("pulse",), "pulse")
    dof = _number(table, "[load]", "dof", low=1, high=n, integer=True)
    amplitude = _number(table, "[load]", "amplitude", default=1.0)
    duration = _number(table, "[load]", "duration", low=0, strict_low=True)
    start = _number(table, "[load]", "start", default=0.0)
    return pulse(n, dof, float(amplitude), float(duration), float(start))


MAX_OUTPUTS = 1e8  # output times of a scene (a full solve saves N x n numbers)


def _check_output_memory(ts, n: int, output: Output, reduction) -> None:
    """Refuse, with the numbers, a scene whose saved outputs cannot fit in memory."""
    saved = n if reduction is not None or output.dofs is None else len(output.dofs)
    need = 2 * 8.0 * ts.shape[0] * saved * (2 if reduction is not None else 1)
    available = available_bytes()
    if available is not None and need > available:
        _fail("[time] step", f"{ts.shape[0]} output times x {saved} DOFs need about "
              f"{need / 2**30:.1f} GiB, more than the {available / 2**30:.1f} GiB available: "
              "take a longer step, fewer [output] dofs, or a shorter span.")


def _times_from(data) -> Times:
    table = _table(data, "time", {"start", "end", "step"}, required=True)
    start = float(_number(table, "[time]", "start", default=0.0))
    end = float(_number(table, "[time]", "end"))
    step = float(_number(table, "[time]", "step", low=0, strict_low=True))
    if end <= start:
        _fail("[time] end", f"must be greater than start = {start}, got {end}.")
    count = (end - start) / step
    if not np.isfinite(count) or count > MAX_OUTPUTS:
        _fail("[time] step", f"gives {count:.3g} output times on [{start}, {end}]; at most "
              f"{MAX_OUTPUTS:.0e}: take a longer step or a shorter span.")
    if abs(count - round(count)) > 1e-9 * max(1.0, count):
        _fail("[time] step", f"must divide end - start = {end - start} into whole steps.")
    return jnp.asarray(start + step * np.arange(round(count) + 1, dtype=np.float64))


def _reduction_from(data, ts, n: int) -> POD | None:
    table = _table(data, "reduction", {"snapshots", "energy", "rank", "criterion", "quantity",
                                       "method"})
    if not table:
        return None
    window = table.get("snapshots", [float(ts[0]), float(ts[-1])])
    if (not isinstance(window, list) or len(window) != 2
            or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in window)
            or not window[0] <= window[1]):
        _fail("[reduction] snapshots", f"must be a time window [start, end] with start <= end, "
              f"got {window!r}.")
    first, last = float(ts[0]), float(ts[-1])
    if not first - 1e-12 <= window[0] <= last + 1e-12 or window[1] > last + 1e-9:
        _fail("[reduction] snapshots", f"must lie within the time grid [{float(ts[0])}, "
              f"{float(ts[-1])}], got {window!r}.")
    if ("energy" in table) == ("rank" in table):
        _fail("[reduction]", "give exactly one of energy (a fraction in (0, 1]) or rank.")
    energy = rank = None
    if "energy" in table:
        energy = float(_number(table, "[reduction]", "energy", low=0, high=1, strict_low=True))
    else:
        rank = _number(table, "[reduction]", "rank", low=1, high=n, integer=True)
    return POD(
        window=(float(window[0]), float(window[1])),
        quantity=_choice(table, "[reduction]", "quantity", ("displacement", "velocity"),
                         "displacement"),
        energy=energy, rank=rank,
        criterion=_choice(table, "[reduction]", "criterion", CRITERIA, "squared"),
        method=_choice(table, "[reduction]", "method", METHODS, "svd"))


def _output_from(data, n: int, reduced: bool) -> Output:
    table = _table(data, "output", {"dofs", "quantities", "phase_error", "figures"})
    dofs = table.get("dofs")
    if dofs is not None:
        if (not isinstance(dofs, list) or not dofs
                or not all(isinstance(d, int) and not isinstance(d, bool) and 1 <= d <= n
                           for d in dofs)):
            _fail("[output] dofs", f"must be a non-empty list of integer DOFs in 1..{n}, "
                  f"got {dofs!r}.")
        dofs = tuple(dofs)
    quantities = table.get("quantities", ["displacement"])
    if not isinstance(quantities, list) or not all(q in QUANTITIES for q in quantities):
        _fail("[output] quantities", f"must be a list drawn from {list(QUANTITIES)}, "
              f"got {quantities!r}.")
    needs_rom = set(REDUCED_QUANTITIES)
    if not reduced and needs_rom & set(quantities):
        _fail("[output] quantities", f"{sorted(needs_rom & set(quantities))} need a [reduction] "
              "table.")
    aggregate = _choice(table, "[output]", "phase_error", AGGREGATES[:3], "sum")
    figures = table.get("figures", False)
    if not isinstance(figures, bool):
        _fail("[output] figures", f"must be true or false, got {figures!r}.")
    return Output(dofs, tuple(dict.fromkeys(quantities)), aggregate, figures)


def _method_from(data, system, ts, load):
    """[solver] as the scene's ``method``: "exact" is ``Spectral()`` where the damped modes apply
    (``spectral_applies``), else ``DenseExponential()``; "auto" is what ``Auto().select`` names;
    an ODE solver's name is ``ODE`` with it at rtol, atol and max_steps."""
    table = _table(data, "solver", {"method", "rtol", "atol", "max_steps"})
    name = _choice(table, "[solver]", "method", ("exact", "auto", *SOLVERS), "exact")
    rtol = float(_number(table, "[solver]", "rtol", default=1e-10, low=0, strict_low=True,
                         high=1, strict_high=True))
    atol = float(_number(table, "[solver]", "atol", default=1e-12, low=0, strict_low=True))
    max_steps = _number(table, "[solver]", "max_steps", default=100_000, low=1, integer=True)
    if name == "exact":
        return Spectral() if spectral_applies(system) is None else DenseExponential()
    method = Auto().select(system, ts, load) if name == "auto" else ODE(SOLVERS[name]())
    if isinstance(method, ODE):
        method = ODE(method.solver, rtol=rtol, atol=atol, max_steps=max_steps)
    return method


def scene_from_dict(data: Mapping, name: str = "scene", base: str | Path | None = None) -> Scene:
    """Build a ``Scene`` from the parsed TOML mapping (see ``load_scene`` for the keys).

    ``base``: the directory that relative matrix file names are read from (None: the current one).
    """
    allowed = {"name", "description", "chain", "damper", "internal_damping", "initial", "load",
               "time", "solver", "reduction", "output"}
    unknown = set(data) - allowed
    if unknown:
        _fail("scene", f"unknown top-level key(s) {sorted(unknown)}; allowed: {sorted(allowed)}.")
    name = data.get("name", name)
    if not isinstance(name, str):
        _fail("scene name", f"must be a string, got {name!r}.")
    system, mode = system_from(data, None if base is None else Path(base))
    n = system.size
    initial = _table(data, "initial", {"displacement", "velocity"})
    x0 = _state_from(initial.get("displacement"), n, "[initial] displacement", mode)
    v0 = _state_from(initial.get("velocity"), n, "[initial] velocity", mode)
    load = _load_from(data, n)
    ts = _times_from(data)
    reduction = _reduction_from(data, ts, n)
    output = _output_from(data, n, reduction is not None)
    _check_output_memory(ts, n, output, reduction)
    return Scene(system, ts, x0, v0, load, reduction, output, name=name,
                 method=_method_from(data, system, ts, load))


def _is_file(path: Path) -> bool:
    try:
        return path.is_file()
    except (OSError, ValueError):  # a name too long, or with a NUL: TOML text after all
        return False


def load_scene(source: str | Path | Mapping) -> Scene:
    """Read a scene from a TOML file, a TOML string, a mapping, or a packaged paper scene name
    (``section4_first_mode``, ``section4_impulse``, ``section5_damped``).

    Tables: ``[chain]`` (type = "mikota" with n, m, k | "custom" with masses, springs (a
    fixed-free chain) or with matrices mass, stiffness, damping (each a file name "M.mtx",
    "M.npz", "system.npz:K" read by ``load_matrix`` relative to the scene file's directory, or
    inline: a list = diagonal, n rows of n = dense, lists of lengths n, n - 1, ... = symmetric
    bands) | "branched" with [[chain.branch]] tables (masses, springs: one more spring than masses)
    or lengths = [L1, ...] with mass, spring; hub_mass, hub_spring), ``[[damper]]`` (type =
    "grounded" with position in [1, n] | "relative" with dofs = [i, j]; coefficient >= 0),
    ``[internal_damping]`` (rayleigh = [alpha, beta], modal = zeta or n ratios), ``[initial]``
    (displacement, velocity: {DOF = value}, a list, or "mode l": Mikota's eq. 2.5, or column l of
    ``modal_decomposition``, scaled to max |u_i| = 1 with the last DOF positive),
    ``[load]`` (type = "pulse", dof, amplitude, duration, start), ``[time]`` (start, end, step),
    ``[solver]`` (method = "exact" | "auto" | "dopri8" | "tsit5" | "dopri5" | "kvaerno5", rtol,
    atol, max_steps), ``[reduction]`` (snapshots = [t0, t1], energy or rank, criterion = "squared" |
    "paper", quantity, method = "svd" | "snapshots"), ``[output]`` (dofs, quantities, phase_error =
    "sum" | "max" | "mean", figures).
    """
    if isinstance(source, Mapping):
        return scene_from_dict(source)
    if isinstance(source, str) and source in PAPER_SCENES:
        text = resources.files("mikota_jax").joinpath("scenes", f"{source}.toml").read_text()
        return scene_from_dict(tomllib.loads(text), name=source)
    path = Path(source)
    base = None  # TOML text: matrix files relative to the current directory
    # TOML text, not a path: a line break or "=" and no such file (a path that exists is a path,
    # "=" in its name or not)
    is_text = (isinstance(source, str) and ("\n" in source or "=" in source)
               and not ("\n" not in source and _is_file(path)))
    if is_text:
        text, name, where = source.removeprefix("\ufeff"), "scene", "scene text"
    else:
        if path.is_dir():
            raise ValueError(MARK + f"scene file {str(path)!r} is a directory, not a TOML file.")
        if not path.is_file():
            raise ValueError(MARK + f"scene file {str(path)!r} does not exist (or name one of "
                             f"{list(PAPER_SCENES)}).")
        try:  # "utf-8-sig": a byte-order mark (Windows editors write one) is not TOML
            text = path.read_text(encoding="utf-8-sig")
        except UnicodeDecodeError as error:
            raise ValueError(MARK + f"scene file {str(path)!r} is not UTF-8 text ({error.reason} "
                             f"at byte {error.start}).") from None
        name, base, where = path.stem, path.parent, f"scene file {str(path)!r}"
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ValueError(MARK + f"{where} is not valid TOML: {error}") from None
    return scene_from_dict(data, name=name, base=base)
