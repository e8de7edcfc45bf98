"""The hierarchical estimate of the gradient's error over the Section 5 design box
(``estimate(..., gradient=True)`` with ``Hierarchical``): its effectivity at 1000
random designs against the full model's gradient, no full solve.

The scene, box and bases are ``hierarchical.py``'s: Mikota n = 300, x_3(0) = 1, J = the energy
integrated over [0, 20]; one grounded damper at p in [1, 300] (split over two DOFs between
them) with c in [0.1, 1000]. Two bases:

- *certified*: the paper's POD basis (r = 98) united with the 40 lowest undamped modes and the
  design's 2 static damper moments (rebuilt per design, r <= 117; ``hierarchical.py``'s choice,
  certified there to 1e-4 in J); fine space: 80 modes and 3 moments;
- *paper*: the paper's POD basis alone (r = 98; fine space: 178 modes and 3 moments), far off.

The estimate of |dJ - dJ_r| is 2 |dJ_f - dJ_r| + 1e-9 (|dJ_r| + J_r / h) (h = c for a
coefficient, n - 1 for a position) with both reduced models' bases held fixed, per derivative
(reverse mode through the spectral J on the reduced models' own modes). The errors compared are
the ones the optimiser certifies, relative to J: the log-sensitivity c |dJ/dc - dJ_r/dc| / J
and the position's (n - 1) |dJ/dp - dJ_r/dp| / J; also |dJ - dJ_r| / |dJ| (target 1's
measure). The truth: the full model's J and gradient by the spectral path (reverse mode,
implicit differentiation of the secular equation). Effectivity (estimate / true error) is
reported where the true error is above FLOOR, and again where it is also above 10x its
rounding floor 1e-9 (1 + c |dJ/dc| / J), resp. 1e-9 (1 + (n - 1) |dJ/dp| / J) (two exact
gradients differ by ~1e-9 of the derivative); the under-estimates are counted everywhere and
listed.

Also the training grid of ``hierarchical.py`` (every 2nd DOF x 5 decades of c): the largest
estimated log-sensitivity error of the certified basis there (is the basis certified for the
gradient as well as for J?). Times per design (gradient estimate, estimate of J alone, full
spectral J + gradient), medians, compile apart. Run:
``OPENBLAS_NUM_THREADS=1 python benchmarks/hierarchical_gradient.py [--quick] [--replot]``
(``--quick``: 100 random designs, a coarser training grid; ``--replot``: the statistics
recomputed from the stored rows, and the figure). Writes
``results/hierarchical_gradient[_quick].json`` and ``.png``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (Compiled, elapsed, figure, legend, parse_args, read_json,  # noqa: I001
                     save_figure, subtitle, write_json)

import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import mikota_jax as mj

NAME = "hierarchical_gradient"
SCENE = "section5_damped"
HORIZON = 20.0
RANK = 98
MODES, MOMENTS, FINE_EXTRA = 40, 2, 40  # hierarchical.py's certified candidate
COEFFICIENTS = (0.1, 1.0, 10.0, 100.0, 1000.0)
TRAIN_STEP = 2
RANDOM = 1000
FLOOR = 1e-8
FLOOR_MARGIN = 10  # effectivity also reported where the true error is 10x its rounding floor
SEED = 2026  # hierarchical.py's: the same random designs
KINDS = ("coefficient", "position")


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:  # the statistics recomputed from the stored rows, then the figure
        data = read_json(NAME, args.quick)
        data["summary"] |= summarise(data["rows"])
        data.pop("benchmark"), data.pop("quick")
        write_json(NAME, args.quick, data, meta=data.pop("metadata"))
        return print(plot(read_json(NAME, args.quick), args.quick))
    start = time.perf_counter()
    scene = mj.app.load_scene(SCENE)
    n = scene.size
    function = mj.SceneFunction(scene, "energy")
    x0 = scene.x0
    say = lambda text: print(f"[{elapsed(start):7.1f} s] {text}", flush=True)  # noqa: E731

    def design(p, c):
        return function.system({"positions": jnp.reshape(p, (1,)),
                                "coefficients": jnp.reshape(c, (1,))})

    def full_energy(pc):
        return mj.Energy(HORIZON, x0, method=mj.Spectral())(design(pc[0], pc[1]))

    def full_gradient(p, c):
        value, gradient = jax.value_and_grad(full_energy)(jnp.stack([p, c]))
        return jnp.concatenate([value[None], gradient])

    def estimate(estimator, p, c):
        e = mj.estimate(design(p, c), estimator, HORIZON, x0, gradient=True)
        return jnp.stack([e.value, e.error, e.gradient["coefficients"][0],
                          e.gradient["positions"][0], e.gradient_error["coefficients"][0],
                          e.gradient_error["positions"][0]])

    def estimate_value(estimator, p, c):
        return mj.estimate(design(p, c), estimator, HORIZON, x0).error

    full = Compiled(full_gradient, 7.0, 1.0)
    pod = mj.reduce(scene, scene.reduction).stats.decomposition.basis(RANK)
    modes = np.asarray(mj.reduce(scene.system, mj.Modal(n)).basis)
    certified = mj.Hierarchical(
        scene.system, mj.reduce(scene, mj.Union(mj.Projection(pod),
                                                mj.Projection(modes[:, :MODES]))).basis,
        modes=min(n, MODES + FINE_EXTRA), basis_moments=MOMENTS)
    paper = mj.Hierarchical(scene.system, jnp.asarray(pod), modes=min(n, RANK + 2 * FINE_EXTRA))
    runs = {label: (est, Compiled(estimate, est, 7.0, 1.0))
            for label, est in (("certified", certified), ("paper", paper))}
    value_only = Compiled(estimate_value, certified, 7.0, 1.0)
    say(f"compiled: full J + gradient {full.compile_s:.1f} s, gradient estimate "
        f"{runs['certified'][1].compile_s:.1f} s")

    def relative(row, c, value):
        """(log-sensitivity error, position error) relative to J = ``value``."""
        return abs(c) * row[0] / value, (n - 1) * row[1] / value

    est, run = runs["certified"]
    positions = np.unique(np.concatenate([np.arange(1.0, n + 1, 4 * TRAIN_STEP if args.quick
                                                    else TRAIN_STEP), [float(n)]]))
    training = [(p, c) for p in positions for c in COEFFICIENTS]
    worst = {kind: 0.0 for kind in KINDS}
    for p, c in training:
        out = np.asarray(run(est, p, c))
        floor = out[0] - out[1]
        for kind, v in zip(KINDS, relative(out[4:6], c, floor), strict=True):
            worst[kind] = max(worst[kind], float(v) if floor > 0 else float("inf"))
    say(f"training grid: {len(training)} designs, largest estimated log-sensitivity error "
        f"{worst['coefficient']:.2e}, position error {worst['position']:.2e}")

    rng = np.random.default_rng(SEED)
    count = 100 if args.quick else RANDOM
    designs = [(float(rng.uniform(1.0, n)), float(10 ** rng.uniform(-1.0, 3.0)))
               for _ in range(count)]
    rows, times = [], {"full": [], "estimate": [], "estimate_value": []}
    for i, (p, c) in enumerate(designs):
        t = time.perf_counter()
        j, dj_dp, dj_dc = (float(a) for a in full(p, c))
        times["full"].append(time.perf_counter() - t)
        t = time.perf_counter()
        value_only(certified, p, c)
        times["estimate_value"].append(time.perf_counter() - t)
        row = dict(position=p, coefficient=c, J=j)
        for label, (e, r) in runs.items():
            t = time.perf_counter()
            out = np.asarray(r(e, p, c))
            if label == "certified":
                times["estimate"].append(time.perf_counter() - t)
            absolute = (abs(out[2] - dj_dc), abs(out[3] - dj_dp))
            true = relative(absolute, c, j)
            est_rel = relative(out[4:6], c, j)
            for kind, a, b, d, own in zip(KINDS, true, est_rel, absolute, (dj_dc, dj_dp),
                                          strict=True):
                row |= {f"{label}_{kind}_error": float(a), f"{label}_{kind}_estimate": float(b),
                        f"{label}_{kind}_own": float(d / abs(own)) if own else None}
            row[f"{label}_J_error"] = abs(out[0] - j) / j
        rows.append(row)
        if (i + 1) % 100 == 0:
            say(f"{i + 1} of {count} random designs")

    summary = dict(random_designs=count, training_designs=len(training),
                   training_worst_log_sensitivity=worst["coefficient"],
                   training_worst_position=worst["position"],
                   median_estimate_s=statistics.median(times["estimate"]),
                   median_estimate_value_s=statistics.median(times["estimate_value"]),
                   median_full_s=statistics.median(times["full"]),
                   compile_estimate_s=runs["certified"][1].compile_s,
                   compile_full_s=full.compile_s)
    summary |= summarise(rows)
    print(f"per design (median): gradient estimate {summary['median_estimate_s']:.3f} s, "
          f"estimate of J alone {summary['median_estimate_value_s']:.3f} s, full spectral J + "
          f"gradient {summary['median_full_s']:.3f} s")
    data = dict(problem=dict(scene=SCENE, horizon=HORIZON, box="p in [1, 300], c in [0.1, 1000]",
                             estimator="2 |dJ_f - dJ_r| + 1e-9 (|dJ_r| + J_r / h), bases fixed",
                             certified_basis=f"POD r = {RANK} + {MODES} modes + {MOMENTS} "
                             "moments of the design", floor=FLOOR),
                summary=summary, rows=rows, total_wall_s=elapsed(start))
    path = write_json(NAME, args.quick, data)
    png = plot(read_json(NAME, args.quick), args.quick)
    print(f"wrote {path} and {png}")
    return data


def stats(rows, label, kind):
    """One basis' and derivative's figures over the random designs. The rounding floor of a
    true error, in the measure reported: 1e-9 (1 + c |dJ/dc| / J) for a coefficient, 1e-9
    (1 + (n - 1) |dJ/dp| / J) for a position (two exact gradients differ by ~1e-9 of the
    derivative; the estimate's own floor). Effectivity is given where the true error is above
    FLOOR and above ``FLOOR_MARGIN`` x that floor, the under-estimates everywhere."""
    errors = np.array([r[f"{label}_{kind}_error"] for r in rows])
    estimate = np.array([r[f"{label}_{kind}_estimate"] for r in rows])
    own = np.array([np.nan if r[f"{label}_{kind}_own"] is None else r[f"{label}_{kind}_own"]
                    for r in rows])
    # err / own = c |dJ/dc| / J (or (n - 1) |dJ/dp| / J); a zero derivative: floor 1e-9
    rounding = 1e-9 * (1 + np.where(own > 0, errors / np.where(own > 0, own, 1.0), 0.0))
    above = errors > FLOOR
    clear = above & (errors > FLOOR_MARGIN * rounding)
    eff, eff_clear = estimate[above] / errors[above], estimate[clear] / errors[clear]
    under = np.flatnonzero(estimate < errors)
    return dict(worst_error=float(errors.max()), worst_estimate=float(estimate.max()),
                # |dJ - dJ_r| / |dJ| (target 1's measure; large where dJ ~ 0)
                median_relative_to_own=float(np.nanmedian(own)),
                within_1e_3_of_own=int(np.sum(own <= 1e-3)),
                under_estimates=int(under.size),
                under_estimates_above_floor=int(np.sum(estimate[above] < errors[above])),
                under_estimated=[dict(position=rows[i]["position"],
                                      coefficient=rows[i]["coefficient"],
                                      error=float(errors[i]), estimate=float(estimate[i]),
                                      relative_to_own=float(own[i]),
                                      rounding_floor=float(rounding[i])) for i in under],
                effectivity_min=float(eff.min()) if eff.size else None,
                effectivity_max=float(eff.max()) if eff.size else None,
                effectivity_median=float(np.median(eff)) if eff.size else None,
                designs_above_floor=int(above.sum()),
                effectivity_clear_min=float(eff_clear.min()) if eff_clear.size else None,
                effectivity_clear_max=float(eff_clear.max()) if eff_clear.size else None,
                designs_clear=int(clear.sum()),
                within_1e_3=int(np.sum(errors <= 1e-3)),
                estimated_within_1e_3=int(np.sum(estimate <= 1e-3)))


def summarise(rows) -> dict:
    """The per-basis statistics, printed (also by ``--replot``, from the stored rows)."""
    summary, count = {}, len(rows)
    for label in ("certified", "paper"):
        summary[f"{label}_basis"] = {kind: stats(rows, label, kind) for kind in KINDS}
        for kind in KINDS:
            s = summary[f"{label}_basis"][kind]
            print(f"{label} basis, {kind}: worst true error {s['worst_error']:.2e}, worst "
                  f"estimate {s['worst_estimate']:.2e}, under-estimates {s['under_estimates']} "
                  f"of {count} ({s['under_estimates_above_floor']} above {FLOOR:g}), "
                  f"effectivity {s['effectivity_min']:.3g} .. {s['effectivity_max']:.3g} "
                  f"(median {s['effectivity_median']:.3g}) on {s['designs_above_floor']} "
                  f"designs above {FLOOR:g}, {s['effectivity_clear_min']:.3g} .. "
                  f"{s['effectivity_clear_max']:.3g} on the {s['designs_clear']} above "
                  f"{FLOOR_MARGIN:g}x their rounding floor; within 1e-3: {s['within_1e_3']} "
                  f"true, {s['estimated_within_1e_3']} estimated; |dJ - dJ_r| / |dJ| <= 1e-3 "
                  f"at {s['within_1e_3_of_own']} (median {s['median_relative_to_own']:.1e})")
            for u in s["under_estimated"]:
                print(f"  under-estimated at p = {u['position']:.3f}, c = {u['coefficient']:.4g}:"
                      f" true {u['error']:.2e} ({u['relative_to_own']:.1e} of the derivative),"
                      f" estimate {u['estimate']:.2e}, rounding floor {u['rounding_floor']:.1e}")
    return summary


def plot(data: dict, quick: bool):
    rows, s = data["rows"], data["summary"]
    fig, axes = figure(ncols=2, figsize=(11.0, 7.5), readable=True)
    for ax, kind, xlabel in ((axes[0], "coefficient", "c |dJ/dc - dJ_r/dc| / J"),
                             (axes[1], "position", "(n - 1) |dJ/dp - dJ_r/dp| / J")):
        for label, colour, text in (("paper", "C1", f"the paper's POD, r = {RANK}"),
                                    ("certified", "C0", f"POD + {MODES} modes + the damper's "
                                                        f"{MOMENTS} moments, r <= 117")):
            errors = np.maximum([r[f"{label}_{kind}_error"] for r in rows], 1e-13)
            ax.loglog(errors, np.maximum([r[f"{label}_{kind}_estimate"] for r in rows], 1e-13),
                      ".", color=colour, ms=4, label=text)
        line = np.array([1e-13, 1e3])
        ax.loglog(line, line, "k-", lw=0.8, label="estimate = true error")
        ax.loglog(line, 20 * line, "k--", lw=0.8, label="20 x true error")
        ax.axvline(FLOOR, color="0.5", lw=0.8, ls=":")
        ax.set(xlabel=f"true error\n{xlabel}", ylabel="estimate (2 |dJ_f - dJ_r|, same scale)",
               xlim=(1e-13, 1e3), ylim=(1e-13, 1e3))
        ax.set_title(f"{kind} derivative")
    legend(axes[0], "below")
    fig.suptitle(f"Hierarchical estimate of the gradient's error vs true error, "
                 f"{s['random_designs']} random designs of the Section 5 box\n"
                 + subtitle(data["metadata"]))
    return save_figure(fig, NAME, quick)


if __name__ == "__main__":
    main()
