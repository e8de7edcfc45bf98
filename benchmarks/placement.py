"""Damper placement on the paper's Section 5 scene: gradient optimiser vs brute-force full sweep.

The objective is the integrated energy on [0, 20] of the free vibration from x_3(0) = 1, one
grounded damper. The optimiser (``ScreenAndCertify``: reduced-model screening of every DOF,
L-BFGS on the coefficient of the best few, full-model certification with basis enrichment) is run
twice: cold (compiling) and warm; its reduced model is evaluated by the damped modes of the
Galerkin model's own modal coordinates. The sweep evaluates the full model at every DOF x a log
grid of coefficients (``Grid``'s ``Auto()`` evaluator: here the closed form from the damped
modes, the evaluator the certification uses), after compiling calls, then refines the
coefficient of its 3 best DOFs by golden-section search. Also timed: one
reduced objective and one gradient step (value and gradient), whose ratio the target bounds by 4.

    OPENBLAS_NUM_THREADS=1 python benchmarks/placement.py [--quick] [--coefficients C]

``--quick``: the same scene at n = 60, the optimiser once (cold) with one start and few
iterations, the sweep at every 6th DOF x 4 coefficients, its best DOF refined.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (figure, legend, parse_args, read_json, save_figure,  # noqa: I001
                     section5_scene, subtitle, write_json)

import json
import time

import jax
import jax.numpy as jnp
import numpy as np

import mikota_jax as mj
from mikota_jax.testing import DamperProblem, placement_objective

QUICK_STRATEGY = dict(starts=1, iterations=5, keep=1, polish_iterations=3, max_rounds=1)


def snapshot_basis(problem) -> np.ndarray:
    """The optimiser's first POD basis, by public names: a Dopri8 solve of the problem's design
    up to the end of its snapshot window (``simulate``), reduced by its window and rank rule
    (``reduce``, the rank capped at the numerical rank as the optimiser caps it)."""
    ts = np.asarray(problem.ts)
    ts = jnp.asarray(ts[ts <= problem.snapshots[1] + 1e-12])
    model = problem.system(problem.positions, problem.coefficients)
    request = mj.POD(problem.snapshots, energy=problem.energy, rank=problem.rank,
                     criterion=problem.criterion)
    scene = mj.Scene(model, ts, problem.x0, problem.v0, problem.load, reduction=request,
                     method=mj.ODE(rtol=problem.rtol, atol=problem.rtol * 1e-2,
                                   max_steps=problem.max_steps))
    return mj.reduce(scene, request).basis


def plot(data: dict) -> None:
    """The swept landscape, the optimiser's coefficient searches, both optima and their times."""
    sweep, summary, result = data["sweep"], data["summary"], data["runs"][-1]["result"]
    grid = sweep["stats"]  # the swept (P, C) values (None where a solve failed)
    fig, ax = figure(figsize=(8, 6.2), readable=True)
    mesh = ax.pcolormesh(grid["positions"], grid["coefficients"],
                         np.log10(np.asarray(grid["grid"], dtype=float)).T, shading="nearest")
    fig.colorbar(mesh, ax=ax, label=r"$\log_{10} J$, full model (J dimensionless)")
    searched = "optimiser's coefficient searches (polish)"
    for record in result["history"]:
        if record.get("phase") == "polish":
            positions, coefficients = np.asarray(record["positions"]), \
                np.asarray(record["coefficients"])
            for s in range(positions.shape[1]):
                ax.plot(positions[:, s, 0], coefficients[:, s, 0], "w.-", lw=0.8, ms=2,
                        alpha=0.8, label=searched)
                searched = None
    best, seconds = summary["sweep_best"], summary["optimiser_seconds"]
    ax.plot(result["positions"], result["coefficients"], "r*", ms=14,
            label=f"certified optimum: DOF {result['positions'][0]:g}, c = "
                  f"{result['coefficients'][0]:.2f} (optimiser, {seconds['warm']:.0f} s warm)")
    ax.plot([best["position"]], [best["coefficient"]], "c+", ms=14, mew=2,
            label=f"sweep best: DOF {best['position']:g}, c = {best['coefficient']:.2f} "
                  f"({best['points']} points, {best['seconds']:.0f} s)")
    ax.set(yscale="log", xlabel="damper position (DOF index)",
           ylabel="damper coefficient c (dimensionless)",
           title=f"Section 5: integrated energy on [0, 20]; the optimiser is "
                 f"{summary['speedup_warm']:.0f}x faster than the sweep\n"
                 + subtitle(data["metadata"]))
    box = legend(ax, "below")
    box.get_frame().set_facecolor("0.85")
    save_figure(fig, "placement", data["quick"])


def main(argv=None) -> None:
    args = parse_args(__doc__, argv, replot=True, coefficients=dict(type=int, default=17))
    if args.replot:
        return plot(read_json("placement", args.quick))
    scene = section5_scene(args.quick)
    design, strategy = mj.app.problem_from_scene(scene, **(QUICK_STRATEGY if args.quick else {}))
    # the problem the strategy builds, for the reduced objective's timings
    problem = DamperProblem(design.system, strategy.ts, scene.x0, scene.v0, scene.load,
                            snapshots=strategy.snapshots, energy=strategy.energy,
                            criterion=strategy.criterion, rank=strategy.rank)
    n = problem.size

    # one reduced evaluation vs one gradient step (same basis, compiled apart)
    basis = snapshot_basis(problem)
    objective = placement_objective(problem, basis)
    rom = jax.jit(lambda p, c: objective(p, c))
    step = jax.jit(jax.value_and_grad(objective, argnums=(0, 1)))
    p, c = problem.positions, problem.coefficients
    times = {}
    for name, fn in (("rom_value", rom), ("rom_value_and_gradient", step)):
        jax.block_until_ready(fn(p, c))
        samples = []
        for _ in range(3 if args.quick else 7):
            t = time.perf_counter()
            jax.block_until_ready(fn(p, c))
            samples.append(time.perf_counter() - t)
        times[name] = float(np.median(samples))

    runs = []
    for label in ("cold",) if args.quick else ("cold", "warm"):
        t = time.perf_counter()
        result = mj.optimise(design, strategy)
        runs.append(dict(label=label, seconds=time.perf_counter() - t, result=result.to_json()))
    result_json = runs[-1]["result"]
    stats = result_json["stats"]

    positions = np.arange(1.0, n + 1) if not args.quick else np.arange(1.0, n + 1, 6.0)
    coefficients = np.geomspace(0.1, 1000.0, 4 if args.quick else args.coefficients)
    grid = dict(ts=strategy.ts)
    last = mj.DamperDesign(design.system, design.objective, positions=positions[-1:])
    for c in (coefficients[0], coefficients[-1]):  # compile the ODE and the exact evaluator
        mj.optimise(last, mj.Grid([c], **grid))
    sweep = mj.optimise(mj.DamperDesign(design.system, design.objective, positions=positions),
                        mj.Grid(coefficients, refine=1 if args.quick else 3,
                                progress=not args.quick, **grid))
    sweep_seconds = sweep.stats["seconds"] + sweep.stats["seconds_refine"]

    warm = runs[-1]["seconds"]
    summary = dict(
        optimum=dict(position=result_json["positions"], coefficient=result_json["coefficients"],
                     objective_full=result_json["value"], rom_error=stats["rom_error"],
                     certified=stats["certified"], rounds=stats["rounds"],
                     full_solves=stats["full_solves"], rank=stats["rank"]),
        sweep_best=dict(position=float(sweep.positions[0]),
                        coefficient=float(sweep.coefficients[0]), objective=sweep.value,
                        points=int(sweep.stats["grid"].size), exact_points=sweep.stats["exact"],
                        seconds_grid=sweep.stats["seconds"],
                        seconds_refine=sweep.stats["seconds_refine"], seconds=sweep_seconds,
                        refined=sweep.stats["refined"]),
        relative_difference=(result_json["value"] - sweep.value) / sweep.value,
        optimiser_seconds=dict(cold=runs[0]["seconds"], warm=warm),
        speedup_warm=sweep_seconds / warm, speedup_cold=sweep_seconds / runs[0]["seconds"],
        gradient_step_over_forward=times["rom_value_and_gradient"] / times["rom_value"],
        rom_times=times)
    print(json.dumps(summary, indent=1))
    write_json("placement", args.quick, dict(summary=summary, runs=runs, sweep=sweep.to_json()))

    plot(read_json("placement", args.quick))


if __name__ == "__main__":
    main()
