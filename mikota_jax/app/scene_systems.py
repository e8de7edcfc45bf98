"""The scene tables that build the system: ``[chain]`` (Mikota's chain, a custom fixed-free chain,
custom matrices from files or inline, a branched chain), ``[[damper]]`` and ``[internal_damping]``;
and the "mode l" initial states of any such system.

DOFs are 1-based; matrix file names are relative to the scene file's directory (``base``). Every bad
key is one ``ValueError`` naming ``[table] key`` and the allowed values.
"""

from collections.abc import Callable, Mapping
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from .. import (
    GroundedDamper,
    ModalDamping,
    Rayleigh,
    RelativeDamper,
    SecondOrderSystem,
    branched_chain,
    chain,
    mikota_chain,
    modal_decomposition,
    system,
)
from .._custom_types import Vector
from .._errors import BYTES_PER_DOF, MARK, available_bytes
from ..analytic import mode_shape
from ..io import load_matrix
from .toml_checks import choice as _choice
from .toml_checks import fail as _fail
from .toml_checks import is_number as _is_number
from .toml_checks import number as _number
from .toml_checks import positive_list as _positive_list
from .toml_checks import table as _table

_CHAIN_KEYS = {
    "mikota": ("n", "m", "k"),
    "custom": ("masses", "springs", "mass", "stiffness", "damping"),
    "branched": ("branch", "lengths", "mass", "spring", "hub_mass", "hub_spring"),
}
_MATRIX_FORMS = ('a file name ("M.mtx", "system.npz:K"; relative to the scene file), a list of n '
                 "numbers (a diagonal), n rows of n numbers (dense) or bands of lengths n, n - 1, "
                 "... (symmetric banded, main diagonal first)")


def _matrix_from(value, where: str, base: Path | None):
    """One matrix of ``[chain] type = "custom"``: a file (``load_matrix``) or an inline value."""
    if isinstance(value, str):
        name, key = value, None
        head, colon, tail = value.rpartition(":")
        if colon and head.lower().endswith(".npz"):
            name, key = head, tail
        path = Path(name).expanduser()
        path = path if base is None or path.is_absolute() else base / path
        try:
            return load_matrix(path, key)
        except ValueError as error:
            _fail(where, str(error).removeprefix(MARK))
    rows = value if isinstance(value, list) else []
    if rows and all(_is_number(v) for v in rows):
        return np.asarray(rows, dtype=np.float64)  # a diagonal
    if rows and all(isinstance(r, list) and r and all(_is_number(v) for v in r) for r in rows):
        lengths = [len(r) for r in rows]
        if all(length == len(rows) for length in lengths):
            return np.asarray(rows, dtype=np.float64)
        if lengths == list(range(lengths[0], lengths[0] - len(rows), -1)):
            return tuple(np.asarray(r, dtype=np.float64) for r in rows)
        _fail(where, f"rows of lengths {lengths} are neither n rows of n numbers nor bands of "
              "lengths n, n - 1, ...")
    _fail(where, f"must be {_MATRIX_FORMS}; finite numbers only. Got {value!r}.")


def _size(matrix) -> int:
    """n of a parsed matrix: an (n, n) array or sparse matrix, an (n,) diagonal, or bands."""
    return len(matrix[0]) if isinstance(matrix, tuple) else matrix.shape[0]


def _custom_from(table: dict, base: Path | None):
    """``type = "custom"``: masses and springs (a fixed-free chain), or mass, stiffness, damping."""
    matrices = [key for key in ("mass", "stiffness", "damping") if key in table]
    if not matrices:
        masses = _positive_list(table, "[chain]", "masses")
        springs = _positive_list(table, "[chain]", "springs")
        if len(springs) != len(masses):
            _fail("[chain] springs", f"must have as many entries as masses ({len(masses)}), "
                  f"got {len(springs)}.")
        return "chain", dict(masses=masses, springs=springs), len(masses)
    if set(table) & {"masses", "springs"}:
        _fail("[chain]", "give either masses and springs (a fixed-free chain) or the matrices "
              f"mass, stiffness (and damping), not both; got {sorted(set(table) - {'type'})}.")
    for key in ("mass", "stiffness"):
        if key not in table:
            _fail(f"[chain] {key}", "is required with matrices (mass, stiffness, damping).")
    values = {key: _matrix_from(table[key], f"[chain] {key}", base) for key in matrices}
    n = _size(values["mass"])
    for key, value in values.items():
        if _size(value) != n:
            _fail(f"[chain] {key}", f"is {_size(value)} x {_size(value)}, but mass is {n} x {n}.")
    return "matrices", values, n


def _branched_from(table: dict):
    """``type = "branched"``: [[chain.branch]] tables or lengths = [...], and the hub."""
    where = "[chain]"
    if ("branch" in table) == ("lengths" in table):
        _fail(where, "give exactly one of [[chain.branch]] tables (masses, springs) or "
              "lengths = [L1, L2, ...] (with mass, spring).")
    if "lengths" in table:
        lengths = table["lengths"]
        if (not isinstance(lengths, list) or not lengths or not all(
                isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in lengths)):
            _fail(f"{where} lengths", f"must be a non-empty list of integers >= 1, got "
                  f"{lengths!r}.")
        mass = float(_number(table, where, "mass", default=1.0, low=0, strict_low=True))
        spring = float(_number(table, where, "spring", default=1.0, low=0, strict_low=True))
        masses = [[mass] * length for length in lengths]
        springs = [[spring] * (length + 1) for length in lengths]
    else:
        extra = set(table) & {"mass", "spring"}
        if extra:
            _fail(where, f"{sorted(extra)} belong to the shorthand lengths = [...]; each "
                  "[[chain.branch]] gives its own masses and springs.")
        branches = table["branch"]
        branches = [branches] if isinstance(branches, Mapping) else branches
        if not isinstance(branches, list) or not branches:
            _fail("[[chain.branch]]", "must be a non-empty array of tables.")
        masses, springs = [], []
        for number, entry in enumerate(branches, start=1):
            at = f"[[chain.branch]] #{number}"
            if not isinstance(entry, Mapping):
                _fail(at, "must be a table with masses and springs.")
            unknown = set(entry) - {"masses", "springs"}
            if unknown:
                _fail(at, f"unknown key(s) {sorted(unknown)}; allowed: ['masses', 'springs'].")
            masses.append(_positive_list(entry, at, "masses"))
            springs.append(_positive_list(entry, at, "springs"))
            if len(springs[-1]) != len(masses[-1]) + 1:
                _fail(f"{at} springs", f"must have len(masses) + 1 = {len(masses[-1]) + 1} "
                      f"entries (ground, between masses, to the hub), got {len(springs[-1])}.")
    hub_mass = float(_number(table, where, "hub_mass", default=1.0, low=0, strict_low=True))
    hub_spring = float(_number(table, where, "hub_spring", default=1.0, low=0, strict_low=True))
    spec = dict(masses=masses, springs=springs, hub_mass=hub_mass, hub_spring=hub_spring)
    return "branched", spec, sum(len(m) for m in masses) + 1


def _chain_from(data, base: Path | None) -> tuple[str, dict, int]:
    """The ``[chain]`` table as (kind, constructor arguments, n); kind is "mikota", "chain"
    (custom masses and springs), "matrices" (custom mass, stiffness, damping) or "branched"."""
    keys = {"type"}.union(*_CHAIN_KEYS.values())
    table = _table(data, "chain", keys, required=True)
    kind = _choice(table, "[chain]", "type", tuple(_CHAIN_KEYS), "mikota")
    extra = set(table) - {"type", *_CHAIN_KEYS[kind]}
    if extra:
        _fail("[chain]", f"unknown key(s) {sorted(extra)} for type = \"{kind}\"; allowed: "
              f"{sorted(_CHAIN_KEYS[kind])}.")
    if kind == "custom":
        return _custom_from(table, base)
    if kind == "branched":
        return _branched_from(table)
    n = _number(table, "[chain]", "n", low=1, integer=True)
    available = available_bytes()
    if available is not None and BYTES_PER_DOF * n > available:
        _fail("[chain] n", f"= {n} needs about {BYTES_PER_DOF * n / 2**30:.0f} GiB for the O(n) "
              f"solvers' vectors, more than the {available / 2**30:.1f} GiB available.")
    m = _number(table, "[chain]", "m", default=1.0, low=0, strict_low=True)
    k = _number(table, "[chain]", "k", default=1.0, low=0, strict_low=True)
    return "mikota", dict(n=n, m=float(m), k=float(k)), n


def _internal_from(data, n: int):
    """``[internal_damping]``: ``Rayleigh``, ``ModalDamping``, a tuple of both, or None."""
    if "internal_damping" not in data:
        return None
    table = _table(data, "internal_damping", {"rayleigh", "modal"})
    if not table:
        _fail("[internal_damping]", "give rayleigh = [alpha, beta] and/or modal = zeta.")
    parts = []
    if "rayleigh" in table:
        pair = table["rayleigh"]
        if (not isinstance(pair, list) or len(pair) != 2
                or not all(_is_number(v) and v >= 0 for v in pair)):
            _fail("[internal_damping] rayleigh", f"must be [alpha, beta], two finite numbers "
                  f">= 0 (D = alpha M + beta K), got {pair!r}.")
        parts.append(Rayleigh(float(pair[0]), float(pair[1])))
    if "modal" in table:
        zeta = table["modal"]
        if isinstance(zeta, list):
            if len(zeta) != n or not all(_is_number(v) and v >= 0 for v in zeta):
                _fail("[internal_damping] modal", f"a list must hold n = {n} finite numbers >= 0 "
                      f"(one ratio per mode, ascending frequency), got {zeta!r}.")
            parts.append(ModalDamping(jnp.asarray(np.asarray(zeta, dtype=np.float64))))
        elif _is_number(zeta) and zeta >= 0:
            parts.append(ModalDamping(float(zeta)))
        else:
            _fail("[internal_damping] modal", f"must be a ratio >= 0 (every mode) or a list of "
                  f"n = {n} ratios >= 0, got {zeta!r}.")
    return parts[0] if len(parts) == 1 else tuple(parts)


def _system_from(kind: str, spec: dict, dampers: list, internal) -> SecondOrderSystem:
    """The system of a parsed ``[chain]`` table, with its dampers and internal damping."""
    if kind == "mikota":
        return mikota_chain(spec["n"], spec["m"], spec["k"], dampers, internal_damping=internal)
    if kind == "chain":
        return chain(jnp.asarray(spec["masses"]), jnp.asarray(spec["springs"]), dampers,
                     internal_damping=internal)
    if kind == "branched":
        return branched_chain([jnp.asarray(m) for m in spec["masses"]],
                              [jnp.asarray(k) for k in spec["springs"]], spec["hub_mass"],
                              spec["hub_spring"], dampers, internal_damping=internal)
    try:
        return system(**spec, dampers=dampers, internal_damping=internal)
    except ValueError as error:  # asymmetric, indefinite, ...: name the table
        _fail("[chain]", str(error).removeprefix(MARK))


def _mode(model: SecondOrderSystem, l: int) -> Vector:
    """Mode l of ``model`` (``modal_decomposition``), normalised as ``mode_shape`` normalises
    Mikota's: max_i |u_i| = 1, and the last DOF's entry (the last not negligible) positive."""
    _, modes = modal_decomposition(model)
    u = np.asarray(modes[:, l - 1])
    u = u / np.max(np.abs(u))
    last = np.flatnonzero(np.abs(u) > 1e-8)[-1]
    return jnp.asarray(u * np.sign(u[last]))


def _dampers_from(data, n: int) -> list:
    """``[[damper]]``: ``GroundedDamper``s and ``RelativeDamper``s at 1-based DOFs in 1..n."""
    entries = data.get("damper", [])
    if isinstance(entries, Mapping):
        entries = [entries]
    if not isinstance(entries, list):
        _fail("[[damper]]", "must be an array of tables.")
    dampers = []
    for number, entry in enumerate(entries, start=1):
        where = f"[[damper]] #{number}"
        if not isinstance(entry, Mapping):
            _fail(where, "must be a table.")
        unknown = set(entry) - {"type", "position", "dofs", "coefficient"}
        if unknown:
            _fail(where, f"unknown key(s) {sorted(unknown)}; allowed: "
                  "['coefficient', 'dofs', 'position', 'type'].")
        entry = dict(entry)
        kind = _choice(entry, where, "type", ("grounded", "relative"), "grounded")
        d = float(_number(entry, where, "coefficient", low=0))
        if kind == "grounded":
            if "dofs" in entry:
                _fail(f"{where} dofs", "belongs to type = \"relative\"; use position.")
            p = float(_number(entry, where, "position", low=1, high=n))
            dampers.append(GroundedDamper(p, d))
        else:
            if "position" in entry:
                _fail(f"{where} position", "belongs to type = \"grounded\"; use dofs = [i, j].")
            dofs = entry.get("dofs")
            if (not isinstance(dofs, list) or len(dofs) != 2
                    or not all(isinstance(i, int) and not isinstance(i, bool) for i in dofs)
                    or not all(1 <= i <= n for i in dofs) or dofs[0] == dofs[1]):
                _fail(f"{where} dofs", f"must be two different integer DOFs in 1..{n}, "
                      f"got {dofs!r}.")
            dampers.append(RelativeDamper(tuple(dofs), d))
    return dampers


def system_from(data: Mapping, base: Path | None = None
                ) -> tuple[SecondOrderSystem, Callable[[int], Vector]]:
    """The system of a scene's ``[chain]``, ``[[damper]]`` and ``[internal_damping]`` tables, and
    a function l -> mode l as an (n,) initial state (see ``_mode``; Mikota's: ``mode_shape``).

    ``base``: the directory relative matrix file names are read from (None: the current one).
    """
    kind, spec, n = _chain_from(data, base)
    dampers = _dampers_from(data, n)
    built = _system_from(kind, spec, dampers, _internal_from(data, n))
    if kind == "mikota":  # Mikota's modes are known exactly (eq. 2.5)
        return built, lambda l: mode_shape(n, l)
    return built, lambda l: _mode(built, l)
