"""POD-greedy over the Section 5 design box driven by the hierarchical estimate:
how small a fixed basis (+ the design's two damper moments) the greedy finds, against the
hand-picked POD + 40 modes of ``benchmarks/hierarchical.py``.

The scene: Mikota n = 300, x_3(0) = 1, J = the energy integrated over [0, 20]; training designs:
every TRAIN_STEP-th DOF from 1 to 300 x c in {0.1, 1, 10, 100, 1000}. ``reduce(scene, Greedy(
training, 1e-4, step=STEP, hierarchical={"modes": FINE_MODES, "basis_moments": 2})``, starting
from the scene's own POD (its 99 % rank, r = 76): per iteration the estimate at every training
design (no full solve), one full solve at the worst, STEP modes of its trajectory's part outside
the basis appended. Then the result's estimate and true error at RANDOM random designs (the full
model's exact J: spectral, dense where that path does not hold).

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/greedy_hierarchical.py [--quick] [--replot]``
(``--quick``: every 30th DOF, 50 random designs). Writes ``results/greedy_hierarchical[_quick]
.json`` and ``.png``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (elapsed, figure, legend, parse_args, read_json,  # noqa: I001
                     save_figure, subtitle, write_json)

import time

import jax.numpy as jnp
import numpy as np

import mikota_jax as mj

NAME = "greedy_hierarchical"
SCENE = "section5_damped"
HORIZON = 20.0
TOL = 1e-4
STEP = 5
FINE_MODES = 80
COEFFICIENTS = (0.1, 1.0, 10.0, 100.0, 1000.0)
TRAIN_STEP = 4
RANDOM = 200
SEED = 2027


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True, seed_modes=dict(
        type=int, default=0, metavar="K", help="start from the scene's POD united with the K "
        "lowest undamped modes (writes greedy_hierarchical_seeded)"))
    name = NAME + "_seeded" if args.seed_modes else NAME
    if args.replot:
        return print(plot(read_json(name, args.quick), args.quick, name))
    start = time.perf_counter()
    scene = mj.app.load_scene(SCENE)
    n = scene.size
    step = 30 if args.quick else TRAIN_STEP
    positions = np.unique(np.concatenate([np.arange(1.0, n + 1, step), [float(n)]]))
    designs = [(p, c) for p in positions for c in COEFFICIENTS]
    training = {"positions": np.array([[p] for p, _ in designs]),
                "coefficients": np.array([[c] for _, c in designs])}
    options = {"modes": FINE_MODES, "basis_moments": 2}
    seed = None
    if args.seed_modes:  # the scene's own POD (as the default start) + the lowest modes
        seed = mj.reduce(scene, mj.Union(scene.reduction, mj.Modal(args.seed_modes))).basis
    result = mj.reduce(scene, mj.Greedy(training, TOL, start=seed, step=STEP,
                                        hierarchical=options, progress=True))
    greedy_s = elapsed(start)
    print(f"greedy: r = {result.rank} (+ 4 moment columns per design), certified "
          f"{result.certified}, {result.full_solves} full solves, {greedy_s:.0f} s", flush=True)
    # spot check at random designs against the full model
    function = mj.SceneFunction(scene, "energy")
    estimator = mj.Hierarchical(scene.system, result.basis, **options)
    rng = np.random.default_rng(SEED)
    count = 50 if args.quick else RANDOM
    rows = []
    for p, c in zip(rng.uniform(1.0, n, count), 10 ** rng.uniform(-1, 3, count), strict=True):
        system = function.system({"positions": jnp.array([p]), "coefficients": jnp.array([c])})
        e = mj.estimate(system, estimator, HORIZON, scene.x0)
        j = float(mj.Energy(HORIZON, scene.x0)(system))  # spectral, else dense
        rows.append(dict(position=float(p), coefficient=float(c), J=j,
                         error=abs(float(e.value) / j - 1),
                         estimate=float(e.relative) if np.isfinite(e.relative) else None))
    worst = max(r["error"] for r in rows)
    under = sum(r["estimate"] is not None and r["estimate"] < r["error"] for r in rows)
    finite_max = max((r["estimate"] for r in rows if r["estimate"] is not None), default=np.nan)
    unbounded = sum(r["estimate"] is None for r in rows)
    print(f"{count} random designs: worst true error {worst:.2e}, worst estimate "
          f"{finite_max:.2e}, under-estimates {under}, estimates above 100 %: {unbounded}")
    data = dict(problem=dict(scene=SCENE, horizon=HORIZON, tolerance=TOL, step=STEP,
                             hierarchical=options, training_designs=len(designs),
                             start=f"the scene's POD, r = {result.history[0][0]}" if not
                             args.seed_modes else f"the scene's POD + the {args.seed_modes} "
                             f"lowest modes, r = {result.history[0][0]}"),
                # an estimate above J_r itself is inf (relative error beyond 100 %): None here
                history=[dict(rank=r, worst=w if np.isfinite(w) else None, design=int(d))
                         for r, w, d in result.history],
                summary=dict(rank=result.rank, rank_with_moments=result.rank + 4,
                             certified=result.certified, full_solves=result.full_solves,
                             training_worst=float(result.bounds.max()), greedy_s=greedy_s,
                             random_designs=count, random_worst_error=worst,
                             random_worst_estimate=finite_max, estimates_above_100pc=unbounded,
                             under_estimates=under),
                rows=rows, total_wall_s=elapsed(start))
    path = write_json(name, args.quick, data)
    png = plot(read_json(name, args.quick), args.quick, name)
    print(f"wrote {path} and {png}")
    return data


def plot(data: dict, quick: bool, name: str = NAME):
    fig, ax = figure(figsize=(8, 5), readable=True)
    history = [h for h in data["history"] if h["worst"] is not None]  # None: above 100 %
    ax.semilogy([h["rank"] for h in history], [h["worst"] for h in history], "o-",
                label="largest relative estimate over the training designs (above 100 %: "
                      "not drawn)")
    ax.axhline(data["problem"]["tolerance"], color="k", ls=":", lw=1, label="tolerance")
    ax.set(xlabel="fixed basis size r (+ 4 damper-moment columns per design)",
           ylabel="relative estimate of |J - J_r| / J")
    s = data["summary"]
    ax.set_title(f"POD-greedy by the hierarchical estimate, Section 5 box: r = {s['rank']} "
                 f"({s['full_solves']} full solves)\n" + subtitle(data["metadata"]))
    legend(ax, "below")
    return save_figure(fig, name, quick)


if __name__ == "__main__":
    main()
