"""Undamped chain modes in O(n^2) (``_chain_modes``) against the dense bidiagonal SVD (O(n^3),
what ``generalized_modes`` did for chains before it took ``chain_modes``).

* **chain_modes vs the dense SVD** on Mikota's chain (m_i = m / i, k_i = (n - i + 1) k,
  omega_l^2 = l^2 k / m exactly) at n = 300, 1000, 3000: run time (median of ``repeats``) and
  compile time apart; correctness first: the largest error of omega^2 in ulps of the exact values,
  max |U^T M U - I|. ``chain_modes`` recognises Mikota's chain and takes its eigenvalues exactly;
  its general path (bisection) is timed on the same chain with its middle mass 1e-9 heavier.
* **chain_mode_data** (1 output row, 3 vectors, U never stored) at n = 10^4 and 3 x 10^4 (and
  10^5 with ``--large``): correctness first: omega^2 in ulps, and completeness
  sum_l U[r, l] (U^T M e_r)_l = 1, sum_l U[r, l] (U^T M e_s)_l = 0 (U^T M = U^-1).

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/chain_modes.py [--quick] [--large]``. Writes
``benchmarks/results/chain_modes[_quick].json`` (no figure).
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import Compiled, parse_args, print_table, timed, write_json  # noqa: I001

import jax
import jax.numpy as jnp
import numpy as np

from mikota_jax.testing import chain_mode_data, chain_modes

EPS = float(np.finfo(np.float64).eps)


def mikota(n):
    i = np.arange(1, n + 1, dtype=float)
    return jnp.asarray(1.0 / i), jnp.asarray(n - i + 1.0), i**2


def ulps(omega2, exact):
    return float(np.max(np.abs(np.asarray(omega2) / exact - 1)) / EPS)


def dense_svd(masses, springs):
    """(omega^2, U) by the SVD of C = diag(sqrt k) L M^-1/2, O(n^3)."""
    scale = 1 / jnp.sqrt(masses)
    n = scale.shape[0]
    factor = jnp.sqrt(springs)[:, None] * (jnp.eye(n) - jnp.eye(n, k=-1)) * scale[None, :]
    _, sigma, vectors_t = jnp.linalg.svd(factor)
    return sigma[::-1] ** 2, scale[:, None] * vectors_t[::-1].T


def bisection(masses, springs):
    """chain_modes' general path (bisection): the middle mass 1e-9 heavier, no longer Mikota's
    chain (its eigenvalues move by ~1e-9 relative: ulps are not reported for it)."""
    return chain_modes(masses.at[masses.shape[0] // 2].multiply(1 + 1e-9), springs)


def compare_full(n, repeats):
    masses, springs, exact = mikota(n)
    row = {"n": n}
    for name, fn in [("chain_modes", chain_modes), ("bisection", bisection),
                     ("dense_svd", dense_svd)]:
        compiled = Compiled(fn, masses, springs)
        (omega2, modes), run_s, _ = timed(compiled, masses, springs, repeats=repeats)
        gram = np.asarray(modes).T @ (np.asarray(masses)[:, None] * np.asarray(modes))
        row |= {f"{name}_ulps": None if name == "bisection" else ulps(omega2, exact),
                f"{name}_orthonormality": (None if name == "bisection" else
                                           float(np.max(np.abs(gram - np.eye(n))))),
                f"{name}_compile_s": compiled.compile_s, f"{name}_run_s": run_s}
    if row["chain_modes_ulps"] > 64 or row["chain_modes_orthonormality"] > 1e-11:
        raise RuntimeError(f"chain_modes is wrong at n = {n}: {row}")
    return row


def data(n, repeats):
    masses, springs, exact = mikota(n)
    r, s = n // 3, n - 1
    vectors = jnp.zeros((n, 3)).at[r, 0].set(masses[r]).at[s, 1].set(masses[s])
    vectors = vectors.at[:, 2].set(jnp.asarray(np.random.default_rng(0).standard_normal(n)))
    rows = jnp.asarray([r])
    compiled = Compiled(lambda m, k, v: chain_mode_data(m, k, rows, v), masses, springs, vectors)
    (omega2, picked, projected), run_s, _ = timed(compiled, masses, springs, vectors,
                                                  repeats=repeats)
    completeness = np.asarray(picked[0] @ projected)
    row = {"n": n, "ulps": ulps(omega2, exact),
           "completeness_error": float(max(abs(completeness[0] - 1), abs(completeness[1]))),
           "compile_s": compiled.compile_s, "run_s": run_s}
    if row["ulps"] > 64 or row["completeness_error"] > 1e-10:
        raise RuntimeError(f"chain_mode_data is wrong at n = {n}: {row}")
    return row


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, large=dict(action="store_true", help="also n = 10^5"))
    jax.config.update("jax_enable_x64", True)
    repeats = 3
    full_sizes = [300, 1000] if args.quick else [300, 1000, 3000]
    data_sizes = [3000] if args.quick else [10_000, 30_000] + ([100_000] if args.large else [])
    full = [compare_full(n, repeats) for n in full_sizes]
    print_table(full, [("n", "n", "d"), ("chain_modes_run_s", "O(n^2) run s", ".3g"),
                       ("bisection_run_s", "bisection run s", ".3g"),
                       ("dense_svd_run_s", "SVD run s", ".3g"),
                       ("chain_modes_compile_s", "O(n^2) compile s", ".3g"),
                       ("chain_modes_ulps", "O(n^2) ulps", ".3g"),
                       ("bisection_ulps", "bisection ulps", ".3g"),
                       ("dense_svd_ulps", "SVD ulps", ".3g"),
                       ("chain_modes_orthonormality", "O(n^2) |U'MU-I|", ".2e"),
                       ("dense_svd_orthonormality", "SVD |U'MU-I|", ".2e")])
    chunked = []
    for n in data_sizes:
        chunked.append(data(n, repeats))
        print_table(chunked[-1:], [("n", "n", "d"), ("run_s", "run s", ".3g"),
                                   ("compile_s", "compile s", ".3g"), ("ulps", "ulps", ".3g"),
                                   ("completeness_error", "completeness", ".2e")])
    result = {"repeats": repeats, "full": full, "mode_data": chunked}
    print(write_json("chain_modes", args.quick, result))
    return result


if __name__ == "__main__":
    main()
