"""The optimiser certified by the error estimate instead of the full model.

Part A: ``ScreenAndCertify`` on the paper's Section 5 scene (one grounded damper, the energy on
[0, 20] of the free vibration from x_3(0) = 1), ``certify="full"`` (the full model's J and dJ/dc
at the optimum, one solve per round) against ``certify="estimate"`` (the hierarchical estimates
of |J - J_r| and of the log-sensitivity's error c |dJ/dc - dJ_r/dc| / J, no full solve). Each is
run twice in this process, cold then warm; the design, J, the estimates against the true errors
(the full run's J and dJ/dc), the full solves and the warm seconds.

Part B: the certification step alone at n = 300 / 1000 / 3000 (Mikota chains, the same scene
scaled: x_3(0) = 1, horizon 20, a damper at DOF 4 with c = 70; the basis: Craig-Bampton + x0
of the crossover's ranks): the full model's J and dJ/dc (``testing.placement_objective`` under
``jax.value_and_grad``, what ``certify="full"`` runs) against building the estimator and
estimating J and its gradient (``estimate(..., gradient=True)`` with ``Hierarchical``, what
``certify="estimate"`` runs). Compile apart (first call), then the median of repeats.

    OPENBLAS_NUM_THREADS=1 python benchmarks/certify_estimate.py [--quick] [--replot]
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (figure, legend, parse_args, read_json, save_figure,  # noqa: I001
                     subtitle, write_json)

import time

import jax
import jax.numpy as jnp
import matplotlib.ticker
import numpy as np

import mikota_jax as mj
from mikota_jax.testing import LBFGS, DamperProblem, placement_objective

NAME = "certify_estimate"
SIZES = ((300, 100), (1000, 160), (3000, 280))  # (n, Craig-Bampton rank before x0)
HORIZON = 20.0
DESIGN = (4.0, 70.0)


def optimiser_runs(quick: bool) -> dict:
    scene = mj.app.load_scene("section5_damped")
    runs = {}
    for label in ("cold", "warm"):
        for certify in ("full", "estimate"):
            design, strategy = mj.app.problem_from_scene(scene, optimizer=LBFGS, certify=certify,
                                                     iterations=10 if quick else 80)
            start = time.perf_counter()
            result = mj.optimise(design, strategy)
            seconds = time.perf_counter() - start
            s = result.stats
            runs[f"{certify}_{label}"] = dict(
                seconds=seconds, position=float(result.positions[0]),
                coefficient=float(result.coefficients[0]), objective=result.value,
                objective_reduced=s["objective_reduced"], rom_error=s["rom_error"],
                gradient_error=None if np.isnan(s["gradient_error"])
                else s["gradient_error"], full_solves=s["full_solves"],
                seconds_full=s["seconds_full"], rank=s["rank"], status=s["status"],
                gradient=float(s["gradient"][0]),
                ranking=s["ranking"], certified=s["certified"])
            print(f"{certify:8s} {label}: {seconds:6.1f} s, DOF {result.positions[0]:g}, "
                  f"c = {result.coefficients[0]:.6g}, J = {result.value:.10g}, "
                  f"{s['full_solves']} full solves; {s['status']}", flush=True)
    full, est = runs["full_warm"], runs["estimate_warm"]
    true = abs(est["objective"] - full["objective"]) / full["objective"]
    true_gradient = (est["coefficient"] * abs(est["gradient"] - full["gradient"])
                     / full["objective"])
    return dict(runs=runs, true_error=true, estimate=est["rom_error"],
                effectivity=est["rom_error"] / true if true > 0 else None,
                true_gradient_error=true_gradient, gradient_estimate=est["gradient_error"],
                same_design=full["position"] == est["position"]
                and abs(full["coefficient"] - est["coefficient"]) <= 1e-9 * full["coefficient"])


def median_seconds(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        out = jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return float(np.median(times)), out


def certification_step(n: int, r: int, repeats: int) -> dict:
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(*DESIGN)])
    x0 = jnp.zeros(n).at[2].set(1.0)
    problem = DamperProblem(system, jnp.linspace(0.0, HORIZON, 2001), x0)
    positions, coefficients = problem.positions, problem.coefficients
    basis = mj.reduce(system, mj.CraigBampton(r, states=x0)).basis
    full = jax.jit(jax.value_and_grad(placement_objective(problem), argnums=(0, 1)))

    def estimate():
        return mj.estimate(system, mj.Hierarchical(system, basis), HORIZON, x0, gradient=True)

    full_cold, (value, (_, slope)) = median_seconds(lambda: full(positions, coefficients), 1)
    full_warm, _ = median_seconds(lambda: full(positions, coefficients), repeats)
    estimate_cold, _ = median_seconds(estimate, 1)
    estimate_warm, e = median_seconds(estimate, repeats)
    true = abs(float(e.value) - float(value)) / float(value)
    c = float(coefficients[0])
    true_gradient = c * abs(float(e.gradient["coefficients"][0]) - float(slope[0])) / float(value)
    row = dict(n=n, rank=int(basis.shape[1]), objective=float(value), true_error=true,
               estimate=float(e.relative), true_gradient_error=true_gradient,
               gradient_estimate=float(e.log_sensitivity_error),
               full_cold_s=full_cold, full_warm_s=full_warm,
               estimate_cold_s=estimate_cold, estimate_warm_s=estimate_warm,
               speedup=full_warm / estimate_warm)
    print(f"n = {n:5d}, r = {row['rank']}: full J + dJ {full_warm:.3f} s (cold {full_cold:.1f}), "
          f"estimate {estimate_warm:.3f} s (cold {estimate_cold:.1f}): {row['speedup']:.1f}x; "
          f"true error {true:.1e}, estimate {row['estimate']:.1e}; log-sensitivity true "
          f"{true_gradient:.1e}, estimate {row['gradient_estimate']:.1e}", flush=True)
    return row


def plot(data: dict, quick: bool):
    fig, (left, right) = figure(readable=True, ncols=2, figsize=(11, 4.6))
    rows = data["steps"]
    n = [r["n"] for r in rows]
    left.loglog(n, [r["full_warm_s"] for r in rows], "o-", color="black",
                label="full model: J + dJ/dc (certify='full')")
    left.loglog(n, [r["estimate_warm_s"] for r in rows], "s-", color="tab:blue",
                label="estimate of J and dJ: build + one call (certify='estimate')")
    for r in rows:
        left.annotate(f"{r['speedup']:.1f}x", (r["n"], r["estimate_warm_s"]),
                      textcoords="offset points", xytext=(8, -4))
    left.set(xlabel="n (DOFs)", ylabel="seconds (warm, median)",
             title="(a) one certification of the optimum")
    legend(left, "below")
    right.loglog(n, [r["true_error"] for r in rows], "o-", color="black",
                 label="true |J - J_r| / J")
    right.loglog(n, [r["estimate"] for r in rows], "s--", color="tab:blue", label="its estimate")
    if all("true_gradient_error" in r for r in rows):
        right.loglog(n, np.maximum([r["true_gradient_error"] for r in rows], 1e-16), "o-",
                     color="tab:gray", label="true c |dJ/dc - dJ_r/dc| / J")
        right.loglog(n, [r["gradient_estimate"] for r in rows], "s--", color="tab:orange",
                     label="its estimate")
    right.set(xlabel="n (DOFs)", ylabel="relative error",
              title="(b) the estimate against the true error\n(below 1e-9: the rounding floor)")
    legend(right, "below")
    for ax in (left, right):
        ax.xaxis.set_major_locator(matplotlib.ticker.FixedLocator(n))
        ax.xaxis.set_major_formatter(matplotlib.ticker.FixedFormatter([str(v) for v in n]))
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    opt = data["optimiser"]
    fig.suptitle("Certifying the optimum by the estimate (Section 5 optimiser: "
                 f"{opt['runs']['full_warm']['seconds']:.0f} s full vs "
                 f"{opt['runs']['estimate_warm']['seconds']:.0f} s estimate, warm)\n"
                 + subtitle(data.get("metadata")))
    return save_figure(fig, NAME, quick)


def main(argv=None):
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return print(plot(read_json(NAME, args.quick), args.quick))
    start = time.perf_counter()
    optimiser = optimiser_runs(args.quick)
    print(f"Section 5: estimate {optimiser['estimate']:.2e} against the true error "
          f"{optimiser['true_error']:.2e}; log-sensitivity estimate "
          f"{optimiser['gradient_estimate']:.2e} against {optimiser['true_gradient_error']:.2e}; "
          f"same design: {optimiser['same_design']}", flush=True)
    sizes = SIZES[:1] if args.quick else SIZES
    steps = [certification_step(n, r, 1 if n >= 3000 else 3) for n, r in sizes]
    data = dict(benchmark=NAME, quick=args.quick, optimiser=optimiser, steps=steps,
                seconds=time.perf_counter() - start)
    write_json(NAME, args.quick, data)
    print(plot(read_json(NAME, args.quick), args.quick))
    return data


if __name__ == "__main__":
    main()
