"""Seven reductions of the Section 5 scene compared on error against size and offline cost
: POD of the states (the paper's), sensitivity-enriched POD, modal truncation,
modal truncation with the static correction of the damper direction, the second-order
Krylov basis (SOAR, moments at s = 0 of the inputs M x0 and the damper directions), the
rational Krylov basis at r / 2 shifts spread over the excited band (``band_shifts``, input
M x0) and the IRKA-type basis (``irka_basis``, input M x0, horizon 20: shifts at the reflected
dominant poles of its own reduced model).

The scene: Mikota n = 300, the damper at DOF 7 with c = 1, x_3(0) = 1, exact solves on [0, 20]
(2001 times), snapshots on [0, 10]. For each method and basis size r: the Galerkin ROM's
relative error in J (the scene's integrated energy), in dJ/dp and dJ/dc (max of the two), and in
the displacement history of all DOFs (relative L2 over the whole run, eq. 5.4's "sum" reading
for x alone), and the offline time to build the basis (warm: every method built once before
timing). The full model is the reference (spectral path).

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/reductions.py [--quick] [--replot]``
(``--quick``: the scene at n = 60, r = 10). Writes ``results/reductions[_quick].json``
and ``.png``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (elapsed, figure, legend, parse_args, print_table,  # noqa: I001
                     read_json, save_figure, section5_scene, subtitle, write_json)

import time

import jax
import numpy as np

import mikota_jax as mj

NAME = "reductions"
WRT = ("positions", "coefficients")
SIZES = (20, 40, 60, 76, 98, 120, 140)  # the POD snapshots have numerical rank 148
QUICK_SIZES = (10,)  # --quick: the scene at n = 60, one size (compiling is most of it)
METHODS = ("POD", "enriched POD", "modal", "modal + static", "Krylov", "rational Krylov",
           "IRKA")
HORIZON = 20.0


def builders(scene):
    """method -> (r -> basis); the POD ones share their decomposition (built in ``warm``)."""
    cache = {}

    def pod(r):
        if "pod" not in cache:
            cache["pod"] = mj.reduce(scene, scene.reduction).stats.decomposition
        return cache["pod"].basis(r)

    def enriched(r):
        if "enriched" not in cache:
            cache["enriched"] = mj.reduce(scene, mj.EnrichedPOD(WRT)).stats.decomposition
        return cache["enriched"].basis(r)

    return {"POD": pod, "enriched POD": enriched,
            "modal": lambda r: mj.reduce(scene.system, mj.Modal(r)).basis,
            "modal + static": lambda r: mj.reduce(scene.system, mj.ModalStatic(r)).basis,
            "Krylov": lambda r: mj.reduce(scene.system, mj.Krylov(r, forcing(scene))).basis,
            "rational Krylov": lambda r: band(scene, r),
            "IRKA": lambda r: irka(scene, r)}, cache


def band(scene, r):
    force = forcing(scene)[:, 0]
    return mj.reduce(scene.system, mj.RationalKrylov(-(-r // 2), force)).basis[:, :r]


IRKA_RUNS = {}  # r -> (iterations, converged), for the JSON


def irka(scene, r):
    result = mj.reduce(scene.system, mj.IRKA(r, forcing(scene)[:, 0], HORIZON))
    IRKA_RUNS[r] = dict(iterations=result.stats.iterations, converged=result.stats.converged)
    return result.basis


def forcing(scene):
    """The Krylov inputs of free vibration from x0: (s M + D) x0 -> M x0, and the damper's
    directions (its force acts there)."""
    mass_x0 = scene.system.mass.mv(scene.x0)
    n, position = scene.size, float(scene.system.damping.positions[0])
    b = np.zeros((n, 2))  # the damper's two DOFs (its coefficient split over them)
    b[int(np.floor(position)) - 1, 0], b[min(int(np.floor(position)), n - 1), 1] = 1.0, 1.0
    return np.column_stack([np.asarray(mass_x0), b])


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return print(plot(read_json(NAME, args.quick), args.quick))
    sizes = QUICK_SIZES if args.quick else SIZES
    scene = section5_scene(args.quick)
    start = time.perf_counter()
    full = mj.sensitivities(scene, "energy", wrt=WRT)
    reference = np.asarray(mj.solve(scene.system, scene.ts, scene.x0,
                                    method=mj.Spectral()).displacement)
    rows = []
    for method in METHODS:
        builds, cache = builders(scene)
        build = builds[method]
        jax.block_until_ready(build(sizes[0]))  # compile (and the POD, once) before timing
        for r in sizes:
            cache.clear()
            t0 = time.perf_counter()
            basis = jax.block_until_ready(build(r))
            offline = elapsed(t0)
            rom = mj.sensitivities(scene, "energy", wrt=WRT, model="reduced", basis=basis)
            rom_model = mj.reduce(scene.system, mj.Projection(basis))
            history = np.asarray(mj.solve(rom_model, scene.ts, scene.x0,
                                          method=mj.DenseExponential()).displacement)
            row = dict(method=method, r=int(basis.shape[1]), offline_s=offline,
                       J=abs(float(rom.value) / float(full.value) - 1),
                       gradient=max(abs(float(rom.jacobian[k][0]) / float(full.jacobian[k][0])
                                        - 1) for k in WRT),
                       history=float(np.linalg.norm(history - reference)
                                     / np.linalg.norm(reference)))
            rows.append(row)
            print(f"{method:>15} r = {row['r']:3d}: J {row['J']:.1e}, gradient "
                  f"{row['gradient']:.1e}, history {row['history']:.1e}, offline "
                  f"{offline:.2f} s", flush=True)
    print_table(rows, [("method", "method", ""), ("r", "r", "d"), ("J", "J err", ".1e"),
                       ("gradient", "dJ err", ".1e"), ("history", "x err", ".1e"),
                       ("offline_s", "offline s", ".2f")])
    data = dict(problem=dict(scene=scene.name, n=scene.size,
                             design=dict(position=7.0, coefficient=1.0),
                             wrt=list(WRT), J="energy on [0, 20]",
                             errors="relative to the full model (spectral exact solve)",
                             modal_static="r - 2 modes + the split damper's two static "
                                          "directions (r columns in all)"),
                full=dict(J=float(full.value), dJdp=float(full.jacobian["positions"][0]),
                          dJdc=float(full.jacobian["coefficients"][0])),
                irka={str(r): v for r, v in IRKA_RUNS.items()},
                rows=rows, total_wall_s=elapsed(start))
    path = write_json(NAME, args.quick, data)
    png = plot(read_json(NAME, args.quick), args.quick)
    print(f"wrote {path} and {png}")
    return data


def plot(data: dict, quick: bool):
    rows = data["rows"]
    fig, axes = figure(ncols=3, figsize=(12, 4.0), readable=True, sharex=True)
    styles = dict(zip(METHODS, ("o-", "s-", "^--", "v--", "d-.", "x:", "P-")))
    for ax, key, title in zip(axes, ("J", "gradient", "history"),
                              ("(a) energy J", "(b) max(dJ/dp, dJ/dc)", "(c) x(t), all DOFs")):
        for method in METHODS:
            mine = [r for r in rows if r["method"] == method]
            ax.semilogy([r["r"] for r in mine], [max(r[key], 1e-16) for r in mine],
                        styles[method], label=method)
        ax.axhline(1e-3, color="k", lw=0.8, ls=":")
        ax.set_title(title)
        ax.set_xlabel("basis size r")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("relative error (dimensionless)")
    legend(axes[2], "right")
    fig.suptitle(f"Section 5 scene (n = {data['problem'].get('n', 300)}, damper at DOF 7, c = 1): "
                 "reductions against the full model; dotted: 1e-3\n" + subtitle(data["metadata"]))
    return save_figure(fig, NAME, quick)


if __name__ == "__main__":
    main()
