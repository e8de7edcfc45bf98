"""One basis certified over the Section 5 design box by the hierarchical estimator, and its
effectivity at 1000 random designs against the full model.

The scene: Mikota n = 300, x_3(0) = 1, J = the energy integrated over [0, 20]; the design box:
one grounded damper at p in [1, 300] (a real position: split over two DOFs between them) with
c in [0.1, 1000]. The estimator (``Hierarchical``): |J - J_r| ~ 2 |J_f - J_r|, J_f the
Galerkin model on span(basis, the m_f lowest undamped modes, 3 static moments of the damper
directions); no full solve.

1. **Candidates**: fixed bases first, the paper's POD basis (r = 98 of the nominal design's
   snapshots) united with the m lowest undamped modes, m in FIXED; then the same united with
   m in CANDIDATES modes and MOMENTS static moments of the design's damper directions
   (``basis_moments``: 4 columns rebuilt per design, O(n)). Fine space: m_f = min(n, m +
   FINE_EXTRA) modes and 3 moments. Each is screened on a coarse grid (every SCREEN_STEP-th DOF x
   the 5 decades of c); the first of CANDIDATES whose largest relative estimate is <= TOL goes on.
2. **Certification**: the estimate at every design of the training grid (every TRAIN_STEP-th
   DOF from 1 to 300 x the 5 decades): certified where the largest is <= TOL.
3. **Spot check**: 1000 random designs (p uniform, c log-uniform): the true relative error of
   J_r against the full model (spectral path), the estimate, the effectivity estimate / true
   error (reported where the true error is above 1e-9, the two exact J's rounding level; below
   it the estimate is the 1e-9 rounding floor), the under-estimates counted everywhere. The same
   for the paper's POD basis alone (r = 98): the estimator on a basis that is far off.

Times per design (estimate, full spectral J), medians, compile apart. Run:
``OPENBLAS_NUM_THREADS=1 python benchmarks/hierarchical.py [--quick] [--replot]``
(``--quick``: 100 random designs, a coarser training grid). Writes
``results/hierarchical[_quick].json`` and ``.png``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (Compiled, elapsed, figure, legend, parse_args, read_json,  # noqa: I001
                     save_figure, subtitle, write_json)

import statistics
import time

import jax.numpy as jnp
import numpy as np

import mikota_jax as mj

NAME = "hierarchical"
SCENE = "section5_damped"
HORIZON = 20.0
RANK = 98
TOL = 1e-4
FIXED = (150, 200)  # fixed bases (250: the fine space, 290 of 300 modes, is nearly the full model)
CANDIDATES = (40, 60, 80, 100, 120)  # + MOMENTS static moments of the design's damper
MOMENTS = 2
FINE_EXTRA = 40
COEFFICIENTS = (0.1, 1.0, 10.0, 100.0, 1000.0)
SCREEN_STEP, TRAIN_STEP = 15, 2
RANDOM = 1000
FLOOR = 1e-9
SEED = 2026


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return print(plot(read_json(NAME, args.quick), args.quick))
    start = time.perf_counter()
    scene = mj.app.load_scene(SCENE)
    n = scene.size
    function = mj.SceneFunction(scene, "energy")
    x0 = scene.x0

    def design(p, c):
        return function.system({"positions": jnp.reshape(p, (1,)),
                                "coefficients": jnp.reshape(c, (1,))})

    def estimate(estimator, p, c):
        e = mj.estimate(design(p, c), estimator, HORIZON, x0)
        return jnp.stack([e.value, e.fine, e.error, e.relative])

    full = Compiled(lambda p, c: mj.Energy(HORIZON, x0, method=mj.Spectral())(design(p, c)),
                    7.0, 1.0)
    pod = mj.reduce(scene, scene.reduction).stats.decomposition.basis(RANK)
    modes = np.asarray(mj.reduce(scene.system, mj.Modal(n)).basis)
    say = lambda text: print(f"[{elapsed(start):7.1f} s] {text}", flush=True)  # noqa: E731

    def estimator_for(basis, fine_modes, basis_moments=0):
        est = mj.Hierarchical(scene.system, jnp.asarray(basis), modes=fine_modes,
                                       basis_moments=basis_moments)
        return est, Compiled(estimate, est, 7.0, 1.0)

    def grid(step):
        positions = np.unique(np.concatenate([np.arange(1.0, n + 1, step), [float(n)]]))
        return [(p, c) for p in positions for c in COEFFICIENTS]

    def screened(m, basis_moments):
        basis = np.asarray(mj.reduce(scene, mj.Union(mj.Projection(pod),
                                                     mj.Projection(modes[:, :m]))).basis)
        est, run = estimator_for(basis, min(n, m + FINE_EXTRA), basis_moments)
        worst = max(float(run(est, p, c)[3]) for p, c in grid(SCREEN_STEP))
        rank = int(basis.shape[1]) + 2 * basis_moments
        kind = "fixed" if basis_moments == 0 else f"+ {basis_moments} moments at the design"
        say(f"candidate POD + {m} modes {kind} (r <= {rank}): largest estimate {worst:.2e} on "
            f"{len(grid(SCREEN_STEP))} designs")
        return dict(modes=m, basis_moments=basis_moments, rank=rank, worst_relative=worst), (
            m, basis, est, run)

    screen = [screened(m, 0)[0] for m in FIXED]
    chosen = None
    for m in CANDIDATES:
        record, candidate = screened(m, MOMENTS)
        screen.append(record)
        if record["worst_relative"] <= TOL:
            chosen = candidate
            break
    if chosen is None:
        chosen = candidate
    m, basis, est, run = chosen
    training = grid(4 * TRAIN_STEP if args.quick else TRAIN_STEP)
    estimates = np.array([float(run(est, p, c)[3]) for p, c in training])
    certified = bool(np.max(estimates) <= TOL)
    say(f"training grid: {len(training)} designs, largest relative estimate "
        f"{np.max(estimates):.2e}: {'certified' if certified else 'NOT certified'} to {TOL:g}")

    paper_est, paper_run = estimator_for(pod, min(n, RANK + 2 * FINE_EXTRA))
    rng = np.random.default_rng(SEED)
    count = 100 if args.quick else RANDOM
    designs = [(float(rng.uniform(1.0, n)), float(10 ** rng.uniform(-1.0, 3.0)))
               for _ in range(count)]
    rows, times = [], {"full": [], "estimate": []}
    for i, (p, c) in enumerate(designs):
        t = time.perf_counter()
        j = float(full(p, c))
        times["full"].append(time.perf_counter() - t)
        row = dict(position=p, coefficient=c, J=j)
        for label, e, r in (("certified", est, run), ("paper", paper_est, paper_run)):
            t = time.perf_counter()
            value, fine, energy, relative = (float(a) for a in r(e, p, c))
            if label == "certified":
                times["estimate"].append(time.perf_counter() - t)
            true = abs(value - j)
            row |= {f"{label}_error": true / j, f"{label}_estimate": energy / j,
                    f"{label}_relative_estimate": relative if np.isfinite(relative) else None,
                    f"{label}_fine_error": abs(fine - j) / j,
                    f"{label}_effectivity": energy / true if true > 0 else None}
        rows.append(row)
        if (i + 1) % 100 == 0:
            say(f"{i + 1} of {count} random designs")

    def stats(label):
        errors = np.array([r[f"{label}_error"] for r in rows])
        estimate = np.array([r[f"{label}_estimate"] for r in rows])
        above = errors > FLOOR
        eff = estimate[above] / errors[above]
        return dict(worst_error=float(errors.max()), worst_estimate=float(estimate.max()),
                    under_estimates=int(np.sum(estimate < errors)),
                    effectivity_min=float(eff.min()) if eff.size else None,
                    effectivity_max=float(eff.max()) if eff.size else None,
                    designs_above_floor=int(above.sum()),
                    worst_fine_error=float(max(r[f"{label}_fine_error"] for r in rows)),
                    within_tol=int(np.sum(errors <= TOL)))

    summary = dict(tol=TOL, modes=m, rank=int(basis.shape[1]) + 2 * MOMENTS,
                   basis_moments=MOMENTS, fine_modes=min(n, m + FINE_EXTRA),
                   training_designs=len(training), training_worst=float(np.max(estimates)),
                   certified=certified, random_designs=count,
                   certified_basis=stats("certified"), paper_basis=stats("paper"),
                   median_estimate_s=statistics.median(times["estimate"]),
                   median_full_s=statistics.median(times["full"]),
                   compile_estimate_s=run.compile_s, compile_full_s=full.compile_s)
    for label in ("certified", "paper"):
        s = summary[f"{label}_basis"]
        print(f"{label} basis: worst true error {s['worst_error']:.2e}, worst estimate "
              f"{s['worst_estimate']:.2e}, under-estimates {s['under_estimates']} of {count}, "
              f"effectivity {s['effectivity_min']:.3g} .. {s['effectivity_max']:.3g} on "
              f"{s['designs_above_floor']} designs above {FLOOR:g}, fine model's worst error "
              f"{s['worst_fine_error']:.1e}")
    print(f"per design (median): estimate {summary['median_estimate_s']:.3f} s, full spectral J "
          f"{summary['median_full_s']:.3f} s")
    data = dict(problem=dict(scene=SCENE, horizon=HORIZON, box="p in [1, 300], c in [0.1, 1000]",
                             estimator="2 |J_f - J_r| + 1e-9 J_r", candidates=list(CANDIDATES)),
                screen=screen, summary=summary, rows=rows, total_wall_s=elapsed(start))
    path = write_json(NAME, args.quick, data)
    png = plot(read_json(NAME, args.quick), args.quick)
    print(f"wrote {path} and {png}")
    return data


def plot(data: dict, quick: bool):
    rows, s = data["rows"], data["summary"]
    fig, ax = figure(figsize=(8.0, 7.0), readable=True)
    for label, colour, text in (("paper", "C1", f"the paper's POD, r = {RANK}"),
                                ("certified", "C0", f"POD + {s['modes']} modes + the damper's "
                                              f"{s['basis_moments']} moments, r <= {s['rank']}")):
        errors = np.maximum([r[f"{label}_error"] for r in rows], 1e-13)
        ax.loglog(errors, [r[f"{label}_estimate"] for r in rows], ".", color=colour, ms=4,
                  label=text)
    line = np.array([1e-13, 10.0])
    ax.loglog(line, line, "k-", lw=0.8, label="estimate = true error")
    ax.loglog(line, 20 * line, "k--", lw=0.8, label="20 x true error")
    ax.axhline(TOL, color="0.5", lw=0.8, ls=":")
    ax.axvline(FLOOR, color="0.5", lw=0.8, ls=":")
    ax.set(xlabel="true relative error of J_r (full model, spectral path)",
           ylabel="estimate 2 |J_f - J_r| / J", xlim=(1e-13, 10), ylim=(1e-13, 10))
    legend(ax, "below", ncols=2)
    ax.set_title(f"Hierarchical estimate vs true error, {s['random_designs']} random designs of "
                 f"the Section 5 box\n" + subtitle(data["metadata"]))
    return save_figure(fig, NAME, quick)


if __name__ == "__main__":
    main()
