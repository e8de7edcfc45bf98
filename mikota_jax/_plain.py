"""JSON-ready values: arrays and numpy scalars as lists and floats, non-finite numbers as None.

The one conversion behind every ``to_json`` of the library, the application layer's
``write_json`` and the benchmarks' result files.
"""

import numpy as np


def to_plain(x):
    """``x`` with arrays as (nested) lists, numpy scalars as Python numbers, NaN/inf as None."""
    if hasattr(x, "__jax_array__") or type(x).__module__.startswith("jax"):
        x = np.asarray(x)
    if isinstance(x, np.ndarray):
        return to_plain(x.tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not np.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: to_plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [to_plain(v) for v in x]
    return x
