"""Batched parameter sweeps: one pure function over many parameter points, chunked and sharded.

``sweep(function, points)`` evaluates ``function(point)`` at every point of ``points`` (a pytree,
e.g. the parameter dict of ``SceneFunction``, whose leaves carry the points along their leading
axis). The points go through in chunks of a fixed size (the last one padded, so one shape compiles
once), each chunk split over every device by ``jax.shard_map`` and batched on each device by
``jax.vmap`` (or ``jax.lax.map``). The same code runs on one CPU, on several devices of one
machine, and across processes under ``jax.distributed`` (every process calls ``sweep`` with the same
points and receives all results). Memory stays bounded: the chunk size is halved until the compiled
chunk fits ``memory_limit``, and results larger than memory go to ``.npy`` files on disk.
"""

import itertools
import os
from pathlib import Path

import equinox as eqx
import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from ._errors import MARK, check_x64

_AXIS = "points"


def grid(**axes) -> dict[str, np.ndarray]:
    """The Cartesian product of parameter axes, flattened into one leading axis of points.

    Each axis is an array whose leading axis lists its values (``positions=np.linspace(1, 300,
    100)[:, None]`` for one damper); the result holds, for each name, the values at every point
    of the product in row-major order (the last axis fastest), so ``values.reshape(lengths)``
    restores the grid.
    """
    if not axes:
        raise ValueError(MARK + "grid needs at least one axis, e.g. grid(coefficients=...).")
    arrays = {name: np.asarray(values, dtype=np.float64) for name, values in axes.items()}
    for name, values in arrays.items():
        if values.ndim < 1 or values.shape[0] < 1:
            raise ValueError(MARK + f"grid axis {name!r} must list at least one value along its "
                             f"leading axis, got shape {values.shape}.")
    index = np.array(list(itertools.product(*(range(v.shape[0]) for v in arrays.values()))))
    return {name: values[index[:, k]] for k, (name, values) in enumerate(arrays.items())}


def _count_points(points) -> int:
    leaves = jax.tree.leaves(points)
    if not leaves:
        raise ValueError(MARK + "points must hold at least one array.")
    sizes = {np.shape(leaf)[0] if np.ndim(leaf) else None for leaf in leaves}
    if None in sizes or len(sizes) != 1:
        raise ValueError(MARK + "every leaf of points must list the points along its leading axis "
                         f"(the same number for all), got leading sizes {sorted(map(str, sizes))}.")
    return sizes.pop()


def _memory_limit(devices) -> int:
    local = [d for d in devices if d.process_index == jax.process_index()] or devices
    try:
        stats = local[0].memory_stats()
    except (AttributeError, jax.errors.JaxRuntimeError):
        stats = None
    if stats and stats.get("bytes_limit"):
        return int(0.5 * stats["bytes_limit"])
    return int(0.25 * os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def _compiled_bytes(compiled) -> int | None:
    analysis = compiled.memory_analysis()
    if analysis is None:
        return None
    return int(analysis.temp_size_in_bytes + analysis.argument_size_in_bytes
               + analysis.output_size_in_bytes)


class Sweep(eqx.Module):
    """The chunked, sharded evaluator of one function (built by ``sweep``)."""

    function: object
    mesh: Mesh = eqx.field(static=True)
    batch: str = eqx.field(static=True)

    def local(self, chunk):
        one = lambda point: self.function(point)  # noqa: E731
        if self.batch == "map":
            return jax.lax.map(one, chunk)
        return jax.vmap(one)(chunk)

    def __call__(self, chunk):
        spec = P(_AXIS)
        return jax.shard_map(self.local, mesh=self.mesh, in_specs=spec, out_specs=spec,
                             check_vma=False)(chunk)


def sweep(function, points, *, chunk_size: int | None = None, devices=None,
          batch: str = "auto", progress: bool = False, memory_limit: int | None = None,
          out: str | Path | None = None):
    """``function(point)`` at every point: a pytree like ``function``'s output, with a leading
    axis of points (numpy arrays on the host, or ``.npy`` memory maps in ``out``).

    ``function``: pure, of one point (a pytree like ``points`` without the leading axis), e.g. a
    ``SceneFunction``. ``points``: pytree of float64 arrays, points along the leading axis (see
    ``grid``). ``devices``: default every device of every process (``jax.devices()``).
    ``progress``: a progress bar over the chunks on stderr (off unless asked, as in every
    library call).
    ``chunk_size``: points per compiled call (a multiple of the device count; default the largest
    power of two up to 256 per device whose compiled memory fits ``memory_limit`` bytes per
    device, default a quarter of the host RAM or half a GPU's). ``batch``: "vmap" (vectorised on
    each device) or "map" (one point after another per device: less memory, and no wasted work on
    branches, e.g. matrix exponentials). ``out``: a directory for results larger than memory.
    Results equal ``function`` applied point by point, unbatched, to rounding: bit for bit with
    "map" in the tests (a Dopri8 energy), sharded or not, 4.5e-13 for an exact energy that XLA
    fuses differently inside one program; "vmap" may reorder the sums of a batched dot product
    (measured: 1e-9 relative on the Dopri8 energy, whose adaptive steps amplify rounding; bit for
    bit on histories).
    """
    check_x64()
    if batch not in ("auto", "vmap", "map"):
        raise ValueError(MARK + f"batch must be 'auto', 'vmap' or 'map', got {batch!r}.")
    total = _count_points(points)
    points = jax.tree.map(lambda leaf: np.asarray(leaf), points)
    for leaf in jax.tree.leaves(points):
        if leaf.dtype != np.float64 and np.issubdtype(leaf.dtype, np.floating):
            raise ValueError(MARK + f"points must be float64, got {leaf.dtype}.")
    devices = list(jax.devices() if devices is None else devices)
    if batch == "auto":
        batch = "map" if devices[0].platform == "cpu" else "vmap"
    count = len(devices)
    mesh = Mesh(np.asarray(devices), (_AXIS,))
    evaluator = Sweep(function, mesh, batch)
    limit = _memory_limit(devices) if memory_limit is None else int(memory_limit)
    if limit <= 0:
        raise ValueError(MARK + f"memory_limit must be > 0 bytes, got {memory_limit!r}.")
    if chunk_size is not None and (isinstance(chunk_size, bool) or not isinstance(chunk_size, int)
                                   or chunk_size < 1 or chunk_size % count):
        raise ValueError(MARK + f"chunk_size must be a positive multiple of the device count "
                         f"{count}, got {chunk_size!r}.")
    per_device = -(-total // count)
    size = chunk_size or count * min(256, 1 << (per_device - 1).bit_length())
    run, size = _compile(evaluator, points, size, count, limit, fixed=chunk_size is not None)
    shapes = jax.eval_shape(evaluator.local, jax.tree.map(lambda x: x[:1], points))
    results = _allocate(shapes, total, out)
    bar = _progress_bar(progress and total > size, total)
    sharding = NamedSharding(mesh, P(_AXIS))
    for start in range(0, total, size):
        index = np.minimum(np.arange(start, start + size), total - 1)  # pad with the last point
        chunk = jax.tree.map(lambda leaf, index=index: leaf[index], points)
        chunk = jax.tree.map(lambda leaf: jax.make_array_from_callback(
            leaf.shape, sharding, lambda where, leaf=leaf: leaf[where]), chunk)
        try:
            values = run(chunk)
        except (jax.errors.JaxRuntimeError, eqx.EquinoxRuntimeError) as error:
            text = str(error)
            if MARK not in text:
                raise
            line = text[text.index(MARK):].splitlines()[0]
            last = min(start + size, total) - 1
            raise ValueError(f"{line} (at one of the points {start}..{last})") from None
        stop = min(start + size, total)
        for target, value in zip(jax.tree.leaves(results), jax.tree.leaves(values)):
            target[start:stop] = _gather(value)[: stop - start]
        if bar is not None:
            bar.update(stop - start)
    if bar is not None:
        bar.close()
    for leaf in jax.tree.leaves(results):
        if isinstance(leaf, np.memmap):
            leaf.flush()
        bad = ~np.isfinite(leaf[...]) if np.issubdtype(leaf.dtype, np.floating) else None
        if bad is not None and bad.any():
            raise ValueError(MARK + f"{int(bad.sum())} non-finite values in the sweep's results "
                             "(first at point "
                             f"{int(np.argwhere(bad)[0][0])}); check those parameters.")
    return results


_COMPILED: dict = {}  # (evaluator structure, shapes, chunk request, limit) -> (executable, size)
_CACHE_SIZE = 16


def _compile(evaluator: Sweep, points, size: int, count: int, limit: int, fixed: bool):
    """The compiled chunk evaluator and its chunk size, halved until it fits ``limit``; cached,
    so a second sweep of the same function and shapes (other values) does not recompile."""
    arrays, rest = eqx.partition(evaluator, eqx.is_array)
    leaves = jax.tree.leaves(arrays) + jax.tree.leaves(points)
    try:
        key = (jax.tree.structure(evaluator), jax.tree.structure(points),
               tuple((np.shape(x)[1:] if k >= len(jax.tree.leaves(arrays)) else np.shape(x),
                      str(x.dtype)) for k, x in enumerate(leaves)), size, limit, fixed)
        hash(key)
    except TypeError:  # an unhashable static field: compile without caching
        key = None
    if key is not None and key in _COMPILED:
        compiled, size = _COMPILED[key]
        return (lambda chunk: compiled(arrays, chunk)), size
    compiled, size = _compile_fitting(arrays, rest, evaluator.mesh, points, size, count, limit,
                                      fixed)
    if key is not None:
        if len(_COMPILED) >= _CACHE_SIZE:
            _COMPILED.pop(next(iter(_COMPILED)))
        _COMPILED[key] = (compiled, size)
    return (lambda chunk: compiled(arrays, chunk)), size


def _compile_fitting(arrays, rest, mesh, points, size, count, limit, fixed):
    sharding = NamedSharding(mesh, P(_AXIS))
    while True:
        shapes = jax.tree.map(lambda leaf, size=size: jax.ShapeDtypeStruct((size, *leaf.shape[1:]),
                                                                leaf.dtype, sharding=sharding),
                              points)
        compiled = jax.jit(lambda arrays, chunk: eqx.combine(arrays, rest)(chunk)).lower(
            arrays, shapes).compile()
        needed = _compiled_bytes(compiled)
        if needed is None or needed <= limit or fixed:
            if needed is not None and needed > limit:
                raise ValueError(MARK + f"chunk_size={size} needs {needed / 2**20:.0f} MiB per "
                                 f"device, above memory_limit = {limit / 2**20:.0f} MiB; lower "
                                 "chunk_size or leave it to sweep.")
            return compiled, size
        if size == count:
            raise ValueError(MARK + f"one point per device needs {needed / 2**20:.0f} MiB, above "
                             f"memory_limit = {limit / 2**20:.0f} MiB; raise memory_limit or "
                             "use batch='map'.")
        size = max(count, size // 2 // count * count)


def _allocate(shapes, total: int, out):
    if out is None:
        return jax.tree.map(lambda s: np.empty((total, *s.shape[1:]), s.dtype), shapes)
    directory = Path(out)
    directory.mkdir(parents=True, exist_ok=True)
    leaves, tree = jax.tree.flatten(shapes)
    maps = [np.lib.format.open_memmap(directory / f"result_{k}.npy", mode="w+", dtype=s.dtype,
                                      shape=(total, *s.shape[1:])) for k, s in enumerate(leaves)]
    return jax.tree.unflatten(tree, maps)


def _gather(value) -> np.ndarray:
    """All of a sharded result on this host (across processes under ``jax.distributed``)."""
    if jax.process_count() > 1:
        return np.asarray(multihost_utils.process_allgather(value, tiled=True))
    return np.asarray(value)


def _progress_bar(show: bool, total: int):
    if not show or jax.process_index() != 0:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc="sweep", unit="point")

