"""Validation of parsed TOML tables for scenes: a bad key is one ``ValueError`` that starts with
``MARK``, names the place (``[table] key``) and says which values are allowed."""

from collections.abc import Mapping

import numpy as np

from .._errors import MARK


def fail(where: str, message: str):
    """Raise the ``ValueError`` ``"mikota_jax: {where}: {message}"``."""
    raise ValueError(MARK + f"{where}: {message}")


def is_number(value) -> bool:
    """Whether ``value`` is a finite int or float (``True``/``False`` are not numbers here)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and np.isfinite(value)


def table(data: Mapping, key: str, allowed: set[str], required: bool = False) -> dict:
    """The table ``data[key]`` as a dict ({} when absent and not ``required``), keys checked."""
    value = data.get(key)
    if value is None:
        if required:
            fail(f"[{key}]", "this table is required.")
        return {}
    if not isinstance(value, Mapping):
        fail(f"[{key}]", f"must be a table, got {type(value).__name__}.")
    unknown = set(value) - allowed
    if unknown:
        fail(f"[{key}]", f"unknown key(s) {sorted(unknown)}; allowed: {sorted(allowed)}.")
    return dict(value)


def number(values: dict, where: str, key: str, *, default=None, low=None, high=None,
           strict_low: bool = False, strict_high: bool = False, integer: bool = False):
    """``values[key]``, a finite number (an int with ``integer``) in the given range; required
    unless a ``default`` is given."""
    if key not in values:
        if default is None:
            fail(f"{where} {key}", "is required.")
        return default
    value = values[key]
    kinds = (int,) if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kinds) or not np.isfinite(value):
        fail(f"{where} {key}", f"must be a finite {'integer' if integer else 'number'}, "
             f"got {value!r}.")
    if low is not None and (value <= low if strict_low else value < low):
        fail(f"{where} {key}", f"must be {'>' if strict_low else '>='} {low}, got {value!r}.")
    if high is not None and (value >= high if strict_high else value > high):
        fail(f"{where} {key}", f"must be {'<' if strict_high else '<='} {high}, got {value!r}.")
    return value


def choice(values: dict, where: str, key: str, choices, default):
    """``values[key]`` (or ``default``), one of ``choices``."""
    value = values.get(key, default)
    if value not in choices:
        fail(f"{where} {key}", f"must be one of {list(choices)}, got {value!r}.")
    return value


def positive_list(values: dict, where: str, key: str) -> list[float]:
    """``values[key]``, a non-empty list of finite numbers > 0, as floats."""
    value = values.get(key)
    if (not isinstance(value, list) or not value or not all(is_number(v) for v in value)
            or not all(v > 0 for v in value)):
        fail(f"{where} {key}", f"must be a non-empty list of finite numbers > 0, got {value!r}.")
    return [float(v) for v in value]
