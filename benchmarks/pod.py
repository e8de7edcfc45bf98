"""POD of snapshot matrices: jit SVD, numpy's LAPACK, the method of snapshots, randomized.

Snapshot matrices Q (n x m, one column per time) of Mikota's chain (m_i = 1/i, k_i = n - i + 1)
with a grounded damper d = 1 at DOF 7 and x_3(0) = 1, v(0) = 0:

* n = 300: the Section 5 scene (``load_scene("section5_damped")``), exact (matrix-exponential)
  displacements at t = 0, 0.01, ..., 10: Q is 300 x 1001;
* n in {1000, 3000, 10000, 30000}: the same setup, ``mj.ODE()`` Dopri8 (rtol 1e-8,
  atol 1e-10) on the short horizon [0, 1] with 501 outputs: Q is n x 501 (the exact solver needs
  a dense 2n x 2n matrix exponential, too costly past n ~ 10^3; a short horizon keeps the explicit
  solve of the stiff large chains to a few thousand steps).

Per matrix, all in this process: ``pod(method="svd")`` (jit thin SVD), numpy
``np.linalg.svd(full_matrices=False)`` (LAPACK gesdd; the reference), ``pod(method="snapshots")``
(eigh of the smaller Gram matrix) and ``pod(method="randomized", rank=K)`` (K = 100, oversampling
10, key(0); q = 2 power iterations, the default, and q = 6). The check before timing: sigma_1 of
every method agrees with numpy's (full methods to 1e-10, randomized to 1e-3: a wrong range, not an
inaccurate flat spectrum, is what that catches) and the leading 10 modes are orthonormal. JAX
methods: ``jax.jit(pod).lower(...).compile()`` timed apart; run time is the median of repeated
calls, each ended by ``block_until_ready``. Agreement with numpy,
over the leading L = min(K, numerical rank) values: max |sigma_j / sigma_j^np - 1|, max
|sigma_j - sigma_j^np| / sigma_1, the sine of the largest principal angle between the leading 10
(and L) modes, and max ||u_j - u_j^np|| over the leading 10 modes (numpy's signs fixed by the
package rule). A method whose predicted call time (previous size scaled linearly in n, the cost
at fixed m) exceeds ``--budget`` seconds is skipped and recorded as such.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/pod.py [--quick]`` (quick: n = 300 and 1000).
Writes ``benchmarks/results/pod.json`` and ``pod.png`` (``--quick``: ``pod_quick.*``).
"""

# _common first: it sets OPENBLAS_NUM_THREADS before numpy and jax load.
from _common import (  # noqa: I001
    Compiled, elapsed, figure, fit_exponent, legend, parse_args, print_table, read_json,
    save_figure, subtitle, timed, write_json)

import time

import jax
import numpy as np

import mikota_jax as mj
from mikota_jax.testing import pod, PODDecomposition

SIZES = (300, 1000, 3000, 10000, 30000)
QUICK_SIZES = (300, 1000)
SCENE = "section5_damped"
HORIZON, OUTPUTS = 1.0, 501  # snapshots of the larger chains: t in [0, 1], 501 instants
SNAPSHOT_RTOL, SNAPSHOT_ATOL = 1e-8, 1e-10
RANK, OVERSAMPLING = 100, 10  # randomized range finder: k and p
POWER_ITERATIONS = {"mj randomized": 2, "mj randomized q=6": 6}  # q: the default, and more
MODES_COMPARED = 10
METHODS = ("mj svd (jit)", "numpy svd", "mj snapshots", *POWER_ITERATIONS)
# Checks before timing, sigma_1 vs numpy's (relative): the full methods must agree to rounding; a
# randomized sigma_1 only to 1e-3 (this catches a wrong range, not a flat spectrum's inaccuracy,
# which is the measured result).
CHECK_SIGMA1 = {"mj svd (jit)": 1e-10, "numpy svd": 1e-10, "mj snapshots": 1e-10,
                "mj randomized": 1e-3, "mj randomized q=6": 1e-3}


def snapshots(n: int) -> tuple[np.ndarray, dict]:
    """(Q as float64 numpy (n, m), how it was built)."""
    start = time.perf_counter()
    if n == 300:
        scene = mj.app.load_scene(SCENE)
        ts = np.asarray(scene.ts)
        window = scene.reduction.window
        ts = ts[(ts >= window[0] - 1e-9) & (ts <= window[1] + 1e-9)]
        q = mj.solve(scene.system, ts, scene.x0, method=mj.Spectral()).displacement.T
        how = f"exact_solve, scene {SCENE}, t in [{ts[0]:g}, {ts[-1]:g}], {len(ts)} instants"
    else:
        system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(7.0, 1.0)])
        x0 = np.zeros(n)
        x0[2] = 1.0
        ts = np.linspace(0.0, HORIZON, OUTPUTS)
        out = mj.solve(system, ts, x0,
                       method=mj.ODE(rtol=SNAPSHOT_RTOL, atol=SNAPSHOT_ATOL, max_steps=10**6))
        q = out.displacement.T
        how = (f"simulate dopri8 rtol {SNAPSHOT_RTOL:g} atol {SNAPSHOT_ATOL:g}, t in [0, "
               f"{HORIZON:g}], {OUTPUTS} instants, {int(out.num_steps)} steps")
    q = np.array(jax.block_until_ready(q), dtype=np.float64)
    return q, {"how": how, "build_s_with_compile": elapsed(start)}


def compile_method(name: str, q, key) -> Compiled:
    if name == "mj svd (jit)":
        return Compiled(lambda x: pod(x, method="svd"), q)
    if name == "mj snapshots":
        return Compiled(lambda x: pod(x, method="snapshots"), q)
    return Compiled(lambda x, k: pod(x, method="randomized", rank=RANK,
                                        oversampling=OVERSAMPLING,
                                        power_iterations=POWER_ITERATIONS[name], key=k), q, key)


def numpy_svd(q):
    return np.linalg.svd(q, full_matrices=False)


def sign_rule(u):
    index = np.argmax(np.abs(u), axis=0)
    signs = np.sign(u[index, np.arange(u.shape[1])])
    return u * np.where(signs == 0, 1.0, signs)[None, :]


def largest_angle_sine(a, b) -> float:
    """sin of the largest principal angle between span(a) and span(b), both orthonormal."""
    return float(np.linalg.norm(b - a @ (a.T @ b), 2))


def agreement(s, u, s_ref, u_ref, leading: int) -> dict:
    s, u = np.asarray(s), np.asarray(u)
    count = min(leading, len(s))
    rel = np.abs(s[:count] / s_ref[:count] - 1)
    r = min(MODES_COMPARED, count)
    return {
        "compared_values": count,
        "rel_max": float(np.max(rel)),
        "rel_max_first10": float(np.max(rel[:r])),
        "abs_max_over_sigma1": float(np.max(np.abs(s[:count] - s_ref[:count])) / s_ref[0]),
        "rel_per_index": rel,
        "subspace_sine_10": largest_angle_sine(u_ref[:, :r], u[:, :r]),
        "subspace_sine_leading": largest_angle_sine(u_ref[:, :count], u[:, :count]),
        "mode_error_10": float(np.max(np.linalg.norm(u[:, :r] - u_ref[:, :r], axis=0))),
    }


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True, budget=dict(
        type=float, default=60.0, help="skip a method whose predicted call exceeds this (s)"))
    if args.replot:
        return plot(read_json("pod", args.quick))
    quick, budget = args.quick, args.budget
    sizes = QUICK_SIZES if args.quick else SIZES
    wall = time.perf_counter()
    key = jax.random.key(0)
    rows, matrices, last = [], {}, {}  # last: method -> (n, run_s) for the skip prediction

    for n in sizes:
        q, info = snapshots(n)
        m = q.shape[1]
        repeats = 5 if n <= 3000 else 3
        if quick:
            repeats = 3
        start = time.perf_counter()
        u_ref, s_ref, _ = np.linalg.svd(q, full_matrices=False)
        first_numpy = elapsed(start)
        u_ref = sign_rule(u_ref)
        rank = PODDecomposition(s_ref, u_ref).numerical_rank()
        leading = min(RANK, rank)
        matrices[n] = dict(n=n, m=m, numerical_rank=rank, leading_compared=leading,
                           sigma_1=float(s_ref[0]), sigma_leading_over_sigma_1=float(
                               s_ref[leading - 1] / s_ref[0]),
                           sigma_101_over_sigma_1=float(s_ref[min(RANK, len(s_ref) - 1)]
                                                        / s_ref[0]),
                           singular_values_numpy=s_ref[:leading], **info)

        for name in METHODS:
            row = dict(n=n, m=m, method=name, compile_s=None, run_s=None, repeats=0,
                       skipped=None)
            predicted = last[name][1] * n / last[name][0] if name in last else None
            if predicted is not None and predicted > budget:
                row["skipped"] = (f"predicted {predicted:.0f} s per call (linear in n from "
                                  f"n = {last[name][0]}) > budget {budget:g} s")
                rows.append(row)
                print(f"n = {n}: {name} skipped: {row['skipped']}")
                continue
            if name == "numpy svd":
                call, args_ = numpy_svd, (q,)
            else:  # compiled only when the method runs at this size
                call = compile_method(name, q, key)
                args_ = (q, key) if name in POWER_ITERATIONS else (q,)
                row["compile_s"] = call.compile_s
            # correctness before timing
            first = call(*args_)
            s, u = (first[1], first[0]) if name == "numpy svd" else (
                first.singular_values, first.modes)
            if name == "numpy svd":
                u = sign_rule(u)
            sigma1 = abs(float(np.asarray(s)[0]) / s_ref[0] - 1)
            gram = np.asarray(u)[:, :leading].T @ np.asarray(u)[:, :leading] - np.eye(leading)
            ortho_10 = float(np.max(np.abs(gram[:MODES_COMPARED, :MODES_COMPARED])))
            if not sigma1 < CHECK_SIGMA1[name] or not ortho_10 < 1e-8:
                raise SystemExit(f"check failed: n = {n}, {name}: |sigma_1 / sigma_1^np - 1| = "
                                 f"{sigma1:.2e}, max |U^T U - I| over 10 modes = {ortho_10:.2e}")
            if name == "numpy svd" and first_numpy * repeats > 4 * budget:
                repeats_here = 1
            else:
                repeats_here = repeats
            _, run_s, times = timed(call, *args_, repeats=repeats_here)
            row.update(run_s=run_s, run_times_s=times, repeats=repeats_here,
                       orthogonality_error_leading=float(np.max(np.abs(gram))),
                       **agreement(s, u, s_ref, u_ref, leading))
            last[name] = (n, run_s)
            rows.append(row)
        print(f"n = {n} ({m} snapshots, numerical rank {rank}): done, "
              f"{elapsed(wall):.0f} s so far")

    # ---- report
    print_table(rows, [("n", "n", "d"), ("method", "method", "s"),
                       ("compile_s", "compile s", ".2f"), ("run_s", "run s", ".4f"),
                       ("rel_max_first10", "rel d s_1..10", ".1e"),
                       ("rel_max", "rel d s_1..L", ".1e"),
                       ("abs_max_over_sigma1", "|d s|/s_1", ".1e"),
                       ("subspace_sine_10", "sin angle 10", ".1e"),
                       ("subspace_sine_leading", "sin angle L", ".1e")])
    print("L = min(100, numerical rank); rel d s = max |sigma_j / sigma_j^numpy - 1|")
    for r in rows:
        if r["skipped"]:
            print(f"skipped: n = {r['n']} {r['method']}: {r['skipped']}")
    exponents = {name: fit_exponent(
        [r["n"] for r in rows if r["method"] == name and r["n"] >= 1000],
        [r["run_s"] for r in rows if r["method"] == name and r["n"] >= 1000]) for name in METHODS}
    print("run time ~ n^slope at m = 501 (n >= 1000): " + ", ".join(
        f"{k} {v:.2f}" if v is not None else f"{k} -" for k, v in exponents.items()))

    data = {
        "problem": {
            "chain": "Mikota, m = k = 1, grounded damper d = 1 at DOF 7, x_3(0) = 1, v(0) = 0",
            "matrices": list(matrices.values()),
            "randomized": {"rank": RANK, "oversampling": OVERSAMPLING,
                           "power_iterations": POWER_ITERATIONS, "key": "jax.random.key(0)"},
            "checks_sigma_1_rel": CHECK_SIGMA1,
            "reference": "np.linalg.svd(Q, full_matrices=False) (LAPACK gesdd)",
            "agreement": "over the leading L = min(100, numerical rank of numpy's values); "
                         "rel = |sigma_j / sigma_j^np - 1|; subspace_sine = sin of the largest "
                         "principal angle; mode_error_10 = max_j<=10 ||u_j - u_j^np||_2 with "
                         "numpy's signs fixed by the package rule",
            "compile": "jax.jit(lambda Q: pod(Q, ...)).lower(Q).compile()",
            "budget_s": budget,
        },
        "rows": rows,
        "run_time_exponent_n_ge_1000": exponents,
        "total_wall_s": elapsed(wall),
    }
    path = write_json("pod", quick, data)
    plot(read_json("pod", quick))
    print(f"wrote {path} and its .png ({data['total_wall_s']:.0f} s)")
    return data


def plot(data: dict) -> None:
    """(a) run time vs n, (b) the values' agreement at the largest n, (c) the randomized
    method's at every n."""
    rows, problem = data["rows"], data["problem"]
    matrices = {m["n"]: m for m in problem["matrices"]}
    randomized = problem["randomized"]
    fig, axes = figure(nrows=3, figsize=(7.5, 10.5), readable=True)
    styles = dict(zip(METHODS, (("C0", "o"), ("k", "s"), ("C1", "^"), ("C2", "D"), ("C3", "v"))))
    for name, (color, marker) in styles.items():
        done = [r for r in rows if r["method"] == name and r["run_s"] is not None]
        axes[0].loglog([r["n"] for r in done], [r["run_s"] for r in done], color=color,
                       marker=marker, label=name)
        skipped = [r["n"] for r in rows if r["method"] == name and r["skipped"]]
        for n in skipped:
            axes[0].annotate("skipped", (n, min(r["run_s"] for r in done)), color=color)
    axes[0].set_xlabel("chain size n (DOFs)")
    axes[0].set_ylabel("run time [s] (median, compile apart)")
    sizes = sorted(matrices)
    axes[0].set_title(f"(a) run time; m = {matrices[sizes[0]]['m']} snapshots at n = "
                      f"{sizes[0]}, {matrices[sizes[-1]]['m']} above")
    largest = max(r["n"] for r in rows)
    for name, (color, _) in styles.items():
        row = next((r for r in rows if r["method"] == name and r["n"] == largest
                    and r["run_s"] is not None and name != "numpy svd"), None)
        if row is not None:
            j = np.arange(1, len(row["rel_per_index"]) + 1)
            axes[1].semilogy(j, np.maximum(row["rel_per_index"], 1e-17), color=color,
                             label=name, linewidth=1)
    s_ref = np.asarray(matrices[largest]["singular_values_numpy"])
    axes[1].semilogy(np.arange(1, len(s_ref) + 1), np.finfo(np.float64).eps * s_ref[0] / s_ref,
                     color="0.5", linestyle="--", linewidth=1, label="eps sigma_1 / sigma_j")
    axes[1].set_title(f"(b) n = {largest}: |sigma_j / sigma_j^numpy - 1| (zeros drawn at "
                      "1e-17)")
    for index, n in enumerate(sizes):
        for name, q in randomized["power_iterations"].items():
            row = next((r for r in rows if r["method"] == name and r["n"] == n
                        and r["run_s"] is not None), None)
            if row is not None:
                j = np.arange(1, len(row["rel_per_index"]) + 1)
                axes[2].semilogy(j, np.maximum(row["rel_per_index"], 1e-17), color=f"C{index}",
                                 linestyle="-" if q == 2 else ":", linewidth=1,
                                 label=f"n = {n}, q = {q}")
    axes[2].set_title(f"(c) randomized (k = {randomized['rank']}, p = "
                      f"{randomized['oversampling']}, q power iterations) vs numpy")
    for ax in axes[1:]:
        ax.set_xlabel("index j of sigma_j (1 = largest)")
        ax.set_ylabel("relative difference (dimensionless)")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        legend(ax)
    fig.suptitle("POD of Mikota-chain snapshots: " + subtitle(data["metadata"]))
    save_figure(fig, "pod", data["quick"])


if __name__ == "__main__":
    main()
