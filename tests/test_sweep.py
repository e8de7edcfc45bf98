"""Sweeps: results equal the unbatched runs (batched, chunked, on two host devices, and across two
processes under jax.distributed), the grid's order, bounded memory, results on disk, refusals."""

import os
import socket
import subprocess
import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest
from _sweep_scene import function, points

import mikota_jax as mj

HERE = Path(__file__).parent


@pytest.fixture(scope="module")
def unbatched():
    f = function("energy")
    grid = points()
    return np.array([float(f({k: jnp.asarray(v[i]) for k, v in grid.items()}))
                     for i in range(12)])


def test_grid_is_the_row_major_product():
    grid = mj.grid(a=np.array([1.0, 2.0]), b=np.array([[10.0, 0.0], [20.0, 0.0], [30.0, 0.0]]))
    assert grid["a"].shape == (6,) and grid["b"].shape == (6, 2)
    assert grid["a"].tolist() == [1, 1, 1, 2, 2, 2]
    assert grid["b"][:, 0].tolist() == [10, 20, 30, 10, 20, 30]


@pytest.mark.parametrize("chunk_size", [None, 5, pytest.param(12, marks=pytest.mark.slow)])
def test_mapped_sweep_equals_unbatched_bit_for_bit(unbatched, chunk_size):
    """Chunks of 5 leave a padded last chunk of 2 points."""
    result = mj.sweep(function(), points(), chunk_size=chunk_size, batch="map", progress=False)
    assert result.shape == (12,) and result.dtype == np.float64
    np.testing.assert_array_equal(result, unbatched)


def test_vmapped_sweep_equals_unbatched(unbatched, close):
    """Histories bit for bit; the Dopri8 energy to rounding amplified by the adaptive steps."""
    result = mj.sweep(function(), points(), chunk_size=6, batch="vmap", progress=False)
    close(result, unbatched, rtol=1e-8)
    f, grid = function("displacement"), points()
    histories = mj.sweep(f, grid, chunk_size=4, batch="vmap", progress=False)
    assert histories.shape == (12, 61, 1)
    for i in (0, 7, 11):
        np.testing.assert_array_equal(histories[i], f({k: jnp.asarray(v[i])
                                                       for k, v in grid.items()}))


def test_a_second_sweep_of_other_values_does_not_recompile(monkeypatch):
    from mikota_jax import _sweep

    mj.sweep(function(), points(), chunk_size=4, batch="map", progress=False)
    calls = []
    monkeypatch.setattr(_sweep, "_compile_fitting",
                        lambda *a, **k: calls.append(1) or pytest.fail("recompiled"))
    moved = {**points(), "coefficients": points()["coefficients"] * 0.9}
    mj.sweep(function(), moved, chunk_size=4, batch="map", progress=False)
    assert calls == []


def test_results_larger_than_memory_go_to_disk(unbatched, tmp_path):
    result = mj.sweep(function(), points(), chunk_size=4, batch="map", progress=False,
                      out=tmp_path / "sweep")
    assert isinstance(result, np.memmap)
    np.testing.assert_array_equal(np.load(tmp_path / "sweep" / "result_0.npy"), unbatched)


@pytest.mark.slow  # 18 s: one compile per halving
def test_memory_limit_shrinks_the_chunk(unbatched):
    result = mj.sweep(function(), points(), batch="vmap", progress=False,
                      memory_limit=2 * 2**20)
    np.testing.assert_allclose(result, unbatched, rtol=1e-8)
    with pytest.raises(ValueError, match="one point per device"):
        mj.sweep(function(), points(), batch="vmap", progress=False, memory_limit=1000)


def test_a_chunk_above_the_memory_limit_is_refused_before_it_runs():
    with pytest.raises(ValueError, match="chunk_size=4 needs .* memory_limit"):
        mj.sweep(function(), points(), chunk_size=4, batch="map", progress=False,
                 memory_limit=1000)


def test_a_point_out_of_range_fails_loudly_by_name():
    grid = points()
    grid["positions"][5, 0] = 13.0
    with pytest.raises(ValueError, match=r"position must lie in \[1, 12\].*points 4\.\.7"):
        mj.sweep(function(), grid, chunk_size=4, batch="map", progress=False)


@pytest.mark.parametrize("kwargs,match", [
    (dict(batch="loop"), "batch must be"),
    (dict(chunk_size=0), "chunk_size must be"),
    (dict(memory_limit=-1), "memory_limit must be"),
])
def test_bad_arguments_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        mj.sweep(function(), points(), progress=False, **kwargs)


def test_points_must_agree_and_be_float64():
    with pytest.raises(ValueError, match="leading"):
        mj.sweep(function(), {"positions": np.ones((3, 1)), "coefficients": np.ones((4, 1))})
    with pytest.raises(ValueError, match="float64"):
        mj.sweep(function(), {"coefficients": np.ones((3, 1), np.float32)})


def _own_xla_flags() -> str:
    """This process's XLA_FLAGS without a host device count: a child compiling with the same
    flags gives bitwise the same numbers."""
    return " ".join(flag for flag in os.environ.get("XLA_FLAGS", "").split()
                    if not flag.startswith("--xla_force_host_platform_device_count"))


def _python(code_or_args, env_extra, timeout=300):
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": str(HERE), **env_extra}
    return subprocess.run([sys.executable, *code_or_args], env=env, capture_output=True,
                          text=True, timeout=timeout, cwd=HERE)


def test_sharded_over_two_host_devices_equals_unbatched(unbatched, tmp_path):
    out = tmp_path / "sharded.npy"
    code = ("import jax, numpy as np, mikota_jax as mj\n"
            "from _sweep_scene import function, points\n"
            "assert len(jax.devices()) == 2\n"
            f"np.save({str(out)!r}, mj.sweep(function(), points(), chunk_size=4, "
            "progress=False))\n")
    # the child compiles as this process does (conftest's XLA_FLAGS), on two host devices
    done = _python(["-c", code], {"XLA_FLAGS": f"{_own_xla_flags()} "
                                                "--xla_force_host_platform_device_count=2"})
    assert done.returncode == 0, done.stderr[-2000:]
    np.testing.assert_array_equal(np.load(out), unbatched)


@pytest.mark.slow  # 11 s in CI; sharding is checked by the two-device test
def test_jax_distributed_with_two_local_processes_equals_unbatched(unbatched, tmp_path):
    with socket.socket() as probe:
        probe.bind(("localhost", 0))
        port = str(probe.getsockname()[1])
    outs = [tmp_path / f"process_{k}.npy" for k in range(2)]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": str(HERE),
           "XLA_FLAGS": _own_xla_flags()}  # compiled as this process compiles, one device each
    workers = [subprocess.Popen([sys.executable, str(HERE / "_sweep_worker.py"), str(k), port,
                                 str(outs[k])], env=env, cwd=HERE, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True) for k in range(2)]
    errors = [w.communicate(timeout=300)[1] for w in workers]
    assert [w.returncode for w in workers] == [0, 0], errors[0][-1500:] + errors[1][-1500:]
    for out in outs:  # every process receives every result
        np.testing.assert_array_equal(np.load(out), unbatched)
