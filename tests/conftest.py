"""Test configuration: float64, strict dtype promotion and no implicit rank promotion, so that a
silent float32 downgrade or an accidental broadcast fails loudly in the tests."""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# The CLI turns on JAX's persistent compilation cache; in-process CLI tests must not change the
# global config or write to ~/.cache (test_paper checks the cache in a child process instead).
os.environ.setdefault("MIKOTA_JAX_CACHE", "0")
# The suite is compile-bound (most tests build a few small systems once). XLA's CPU backend
# without its LLVM optimisation passes compiles faster (tests/test_spectral.py: 88 s -> 72 s),
# and its classic fusion emitters instead of the MLIR ones halve the rest (the critical-damping
# gradients: backend compile 48 s -> 24 s); the compiled code runs slower but computes the same
# IEEE operations. The command line's flags for small scenes (no JAX import: set before JAX).
from mikota_jax.app.cli import fast_compile_flags  # noqa: E402

os.environ["XLA_FLAGS"] = fast_compile_flags(os.environ.get("XLA_FLAGS", ""))

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_numpy_rank_promotion", "raise")


def assert_close(actual, expected, rtol=1e-10, atol=0.0, what=""):
    """The one tolerance helper: |actual - expected| <= atol + rtol |expected|, elementwise."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    np.testing.assert_allclose(actual, expected, rtol=rtol, atol=atol, err_msg=what)


@pytest.fixture(scope="session")
def close():
    return assert_close


@pytest.fixture(scope="module", autouse=True)
def _fresh_compilation_caches():
    """Drop JAX's in-memory compilation caches after each test module.

    One long process otherwise keeps every executable of the run (peak RSS 3 GiB by the end of the
    default run), and XLA's CPU compiler crashed late in such runs (issue 23). Executables are
    not shared between modules in any way a test relies on."""
    yield
    jax.clear_caches()
