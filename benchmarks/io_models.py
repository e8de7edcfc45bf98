"""Input-output models: the frequency response against scipy, and the H2 errors of reductions.

The Section 5 system as an input-output map: Mikota's chain, the damper d = 1 at DOF 7, the
input a force at DOF 3, the output the displacement of DOF 150 (``IOModel``).

* **Frequency response**: G(i omega) at 4000 log-spaced frequencies in [0.01, 400], n = 300, 1000
  and 3000. ``IOModel.frequency_response`` (one pivoted tridiagonal solve per frequency),
  compiled once (first call timed apart), the median of 3 warm calls; against scipy's
  ``solve_banded`` per frequency on the three bands of K - omega^2 M + i omega D (taken once) in
  the same process (one run), and the largest relative difference between the two.
* **H2 errors**: ``(full - reduced).h2_norm() / full.h2_norm()`` at n = 300 for the structural
  reductions that need no snapshots (modal, modal + static, Krylov with the input, rational
  Krylov across the band) at r = 10, 20, 40, 80, each reduced model's offline time (the first r
  compiled beforehand; each later r includes its own compile) and the time of its error norm
  (first call, and the median of 3 warm calls); the full model's H2 norm (exact, the damped
  modes). A reduced model with a mode that does not decay has no H2 norm: its row says so.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/io_models.py [--quick] [--replot]``
(``--quick``: n = 60 and r = 10 only). Writes ``results/io_models[_quick].json`` and ``.png``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (elapsed, figure, parse_args, print_table,  # noqa: I001
                     read_json, save_figure, subtitle, timed, write_json)

import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sl

import mikota_jax as mj

NAME = "io_models"
SIZES, QUICK_SIZES = (300, 1000, 3000), (60,)
RANKS, QUICK_RANKS = (10, 20, 40, 80), (10,)
FREQUENCIES = np.logspace(-2, np.log10(400.0), 4000)
METHODS = ("modal", "modal + static", "Krylov", "rational Krylov")


def io_model(n: int) -> mj.IOModel:
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(7.0, 1.0)])
    return mj.IOModel(system, mj.unit_vector(n, 3), cx=mj.unit_vector(n, n // 2))


def scipy_response(io: mj.IOModel, omegas) -> np.ndarray:
    """G(i omega) by scipy's banded solve of (K - omega^2 M + i omega D) x = b per frequency
    (M, D, K tridiagonal here: their three bands taken once, O(n) per frequency)."""
    def bands(a):
        out = np.zeros((3, a.shape[0]))
        out[0, 1:], out[1], out[2, :-1] = np.diag(a, 1), np.diag(a), np.diag(a, -1)
        return out

    m, d, k = (bands(np.asarray(a)) for a in io.model.dense())
    b, c = np.asarray(io.inputs[:, 0]).astype(complex), np.asarray(io.cx[0])
    out = np.empty(omegas.size, complex)
    for j, omega in enumerate(omegas):
        out[j] = c @ sl.solve_banded((1, 1), k - omega**2 * m + 1j * omega * d, b)
    return out


def reduction(method: str, io: mj.IOModel, r: int):
    b = io.inputs[:, 0]
    strategy = {"modal": lambda: mj.Modal(r), "modal + static": lambda: mj.ModalStatic(r),
                "Krylov": lambda: mj.Krylov(r, b),
                "rational Krylov": lambda: mj.RationalKrylov(-(-r // 2), b)}[method]()
    return mj.reduce(io, strategy)


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return print(plot(read_json(NAME, args.quick), args.quick))
    start = time.perf_counter()
    omegas = jnp.asarray(FREQUENCIES)
    response_rows = []
    for n in QUICK_SIZES if args.quick else SIZES:
        io = io_model(n)
        respond = jax.jit(lambda io: io.frequency_response(omegas))
        t0 = time.perf_counter()
        ours = np.asarray(jax.block_until_ready(respond(io)))[:, 0, 0]
        first = elapsed(t0)
        _, warm, _ = timed(respond, io, repeats=3)
        t0 = time.perf_counter()
        reference = scipy_response(io, FREQUENCIES)
        scipy_s = elapsed(t0)
        difference = float(np.max(np.abs(ours - reference) / np.abs(reference)))
        response_rows.append(dict(n=n, first_s=first, run_s=warm, scipy_s=scipy_s,
                                  speedup=scipy_s / warm, max_relative_difference=difference))
        print(f"n = {n}: ours {warm:.3f} s (first {first:.2f} s), scipy {scipy_s:.2f} s, "
              f"difference {difference:.1e}", flush=True)
    io = io_model(QUICK_SIZES[0] if args.quick else 300)
    t0 = time.perf_counter()
    norm = float(io.h2_norm())
    norm_s = elapsed(t0)
    error_rows = []
    for method in METHODS:
        reduction(method, io, (QUICK_RANKS if args.quick else RANKS)[0])  # compile first
        for r in QUICK_RANKS if args.quick else RANKS:
            t0 = time.perf_counter()
            reduced = jax.block_until_ready(reduction(method, io, r))
            offline = elapsed(t0)
            t0 = time.perf_counter()
            try:
                error = float((io - reduced).h2_norm()) / norm
            except ValueError as refused:  # a reduced mode that does not decay: no H2 norm
                error_rows.append(dict(method=method, r=r, relative_h2_error=None,
                                       offline_s=offline, refused=str(refused)))
                print(f"{method:>15} r = {r:3d}: refused ({refused})", flush=True)
                continue
            first = elapsed(t0)
            _, error_s, _ = timed(lambda m=reduced: (io - m).h2_norm(), repeats=3)
            error_rows.append(dict(method=method, r=r, relative_h2_error=error,
                                   offline_s=offline, error_norm_first_s=first,
                                   error_norm_s=error_s))
            print(f"{method:>15} r = {r:3d}: relative H2 error {error:.3e}, offline "
                  f"{offline:.2f} s, error norm {error_s:.3f} s (first {first:.2f} s)",
                  flush=True)
    print_table(response_rows, [("n", "n", "d"), ("run_s", "ours s", ".3f"),
                                ("scipy_s", "scipy s", ".2f"), ("speedup", "x", ".0f"),
                                ("max_relative_difference", "difference", ".1e")])
    print_table([row for row in error_rows if row["relative_h2_error"] is not None],
                [("method", "method", ""), ("r", "r", "d"),
                 ("relative_h2_error", "H2 error", ".3e"), ("offline_s", "offline s", ".2f"),
                 ("error_norm_s", "norm s", ".3f")])
    data = dict(problem=dict(system="Mikota chain, damper d = 1 at DOF 7", input="force at DOF 3",
                             output="displacement of DOF n // 2 (150 at n = 300)",
                             frequencies="4000 log-spaced in [0.01, 400] rad per unit time"),
                frequency_response=response_rows,
                h2=dict(n=io.size, full_h2_norm=norm, full_h2_norm_s=norm_s, rows=error_rows),
                total_wall_s=elapsed(start))
    path = write_json(NAME, args.quick, data)
    png = plot(read_json(NAME, args.quick), args.quick)
    print(f"wrote {path} and {png}")
    return data


def plot(data: dict, quick: bool):
    fig, (left, right) = figure(ncols=2, figsize=(10, 4.0), readable=True)
    rows = data["frequency_response"]
    sizes = [r["n"] for r in rows]
    left.loglog(sizes, [r["run_s"] for r in rows], "o-", label="IOModel.frequency_response")
    left.loglog(sizes, [r["scipy_s"] for r in rows], "s--", label="scipy solve_banded loop")
    left.set_xticks(sizes, [str(n) for n in sizes])
    left.minorticks_off()
    left.set_xlabel("n")
    left.set_ylabel("seconds for 4000 frequencies")
    left.set_title("(a) frequency response")
    left.grid(True, which="both", alpha=0.3)
    left.legend(loc="lower right")
    for method, style in zip(METHODS, ("o-", "s-", "^--", "x:")):
        mine = [r for r in data["h2"]["rows"]
                if r["method"] == method and r["relative_h2_error"] is not None]
        right.semilogy([r["r"] for r in mine], [max(r["relative_h2_error"], 1e-16) for r in mine],
                       style, label=method)
    right.set_xlabel("reduced order r")
    right.set_ylabel("||G - G_r||_H2 / ||G||_H2")
    right.set_title(f"(b) H2 error, n = {data['h2']['n']}")
    right.grid(True, which="both", alpha=0.3)
    right.legend(loc="lower left")
    fig.suptitle("Section 5 input-output map (force at DOF 3, displacement of DOF n / 2)\n"
                 + subtitle(data["metadata"]))
    return save_figure(fig, NAME, quick)


if __name__ == "__main__":
    main()
