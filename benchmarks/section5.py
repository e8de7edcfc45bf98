"""Work-precision benchmark on the paper's Section 5 scene (``load_scene("section5_damped")``).

Mikota's chain with n = 300, a grounded damper d = 1 at DOF 7, x_3(0) = 1, outputs at the 2001
times 0, 0.01, ..., 20. Every row is measured in this one process against one reference, the exact
(matrix-exponential) solution of the full model, all DOFs:

* ``exact_solve`` of the full model;
* ``simulate`` with diffrax Dopri8 and Tsit5 at rtol in {1e-6, 1e-8, 1e-10}, atol = 1e-2 rtol;
* scipy ``solve_ivp`` DOP853 and RK45 at the same tolerances, on the first-order form with an
  O(n) numpy right-hand side (tridiagonal K, diagonal M and D), ``t_eval`` = the 2001 outputs;
* the reduced model (POD of the exact snapshots on [0, 10], Galerkin) at r in {76, 98}, solved
  with ``exact_solve`` and with ``simulate`` Dopri8 at rtol 1e-8, lifted to all DOFs so the
  truncation error shows; plus the offline cost (POD + Galerkin) of each.

JAX rows: the public function is wrapped in ``jax.jit`` and compiled ahead of time
(``.lower(...).compile()``, timed: trace + lower + XLA compile); tolerances are traced arguments,
so one executable serves every rtol of a solver. Run time is the median of repeated calls of that
executable, each ended by ``jax.block_until_ready``. scipy rows: the median of repeated calls.
Error: max |x_i(t_k) - x_i^exact(t_k)| over all DOFs i and all 2001 times.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/section5.py [--quick]``. Writes
``benchmarks/results/section5.json`` and ``benchmarks/results/section5.png`` (``--quick``:
``section5_quick.json`` and ``section5_quick.png``, so a smoke run never replaces the full results).
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import datetime
import json
import platform
import statistics
import time
from pathlib import Path

import jax
import numpy as np
import scipy
from scipy.integrate import solve_ivp

import mikota_jax as mj

RESULTS = Path(__file__).resolve().parent / "results"
SCENE = "section5_damped"
RANKS = (76, 98)  # the paper's n_red for 99 % and 99.99 % pseudo-energy (Section 5)
REDUCED_RTOL = 1e-8
CHECK_RTOL = 1e-10
CHECK_TOLERANCE = 1e-6  # max abs displacement difference allowed in the correctness checks


def atol_for(rtol: float) -> float:
    return rtol * 1e-2


def max_error(displacement, reference) -> float:
    return float(np.max(np.abs(np.asarray(displacement) - reference)))


# --------------------------------------------------------------------------- JAX: compile, run


class Compiled:
    """A public mikota_jax call wrapped in jax.jit and compiled ahead of time."""

    def __init__(self, fn, *example_args):
        jitted = jax.jit(fn)
        start = time.perf_counter()
        lowered = jitted.lower(*example_args)
        middle = time.perf_counter()
        self.executable = lowered.compile()
        end = time.perf_counter()
        self.trace_s, self.xla_s = middle - start, end - middle
        self.compile_s = end - start

    def __call__(self, *args):
        return jax.block_until_ready(self.executable(*args))


def timed(fn, *args, repeats: int):
    """(result of the last call, median seconds, all seconds) over ``repeats`` calls."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn(*args)
        times.append(time.perf_counter() - start)
    return result, statistics.median(times), times


# --------------------------------------------------------------------------- scipy baseline


def scipy_problem(scene):
    """(rhs, y0) for y = (x, v), y' = (v, M^-1 (-K x - D v)) in O(n) numpy, as a user writes it."""
    mass, damping, stiffness = (np.asarray(a) for a in scene.system.dense())
    m = np.diag(mass).copy()
    k_diag, k_off = np.diag(stiffness).copy(), np.diag(stiffness, 1).copy()
    if np.any(mass != np.diag(m)) or np.any(np.triu(stiffness, 2) != 0):
        raise ValueError("the scipy baseline assumes a diagonal M and a tridiagonal K (a chain).")
    d_diag = np.diag(damping).copy()
    if np.any(damping != np.diag(d_diag)):
        raise ValueError("the scipy baseline assumes grounded dampers (a diagonal D).")
    n = m.shape[0]

    def rhs(t, y):
        x, v = y[:n], y[n:]
        force = -k_diag * x - d_diag * v
        force[:-1] -= k_off * x[1:]
        force[1:] -= k_off * x[:-1]
        return np.concatenate([v, force / m])

    x0 = np.asarray(scene.x0)
    v0 = np.zeros(n) if scene.v0 is None else np.asarray(scene.v0)
    return rhs, np.concatenate([x0, v0])


def scipy_solve(rhs, y0, ts, method: str, rtol: float):
    sol = solve_ivp(rhs, (ts[0], ts[-1]), y0, method=method, t_eval=ts, rtol=rtol,
                    atol=atol_for(rtol))
    if not sol.success:
        raise RuntimeError(f"solve_ivp {method} at rtol {rtol} failed: {sol.message}")
    return sol


# --------------------------------------------------------------------------- the benchmark


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="rtol 1e-8, rank 76, fewer repeats, no RK45 (under a minute)")
    args = parser.parse_args(argv)
    quick = args.quick
    rtols = (1e-8,) if quick else (1e-6, 1e-8, 1e-10)
    ranks = RANKS[:1] if quick else RANKS
    jax_repeats, scipy_repeats = (3, 1) if quick else (7, 3)
    scipy_methods = ("DOP853",) if quick else ("DOP853", "RK45")
    wall_start = time.perf_counter()

    scene = mj.load_scene(SCENE)
    system, ts, x0 = scene.system, scene.ts, scene.x0
    if scene.v0 is not None or scene.load is not None:
        raise ValueError("this benchmark expects the Section 5 scene: x(0), v(0) = 0, no load.")
    n, ts_np = system.size, np.asarray(ts)
    rows: list[dict] = []

    # ---- compile every JAX executable (compile time measured apart from run time)
    exact_full = Compiled(lambda sys, x: mj.exact_solve(sys, ts, x, velocity=True), system, x0)
    solvers = {}
    for solver in ("dopri8", "tsit5"):
        solvers[solver] = Compiled(
            lambda sys, x, rtol, solver=solver: mj.simulate(
                sys, ts, x, solver=solver, rtol=rtol, atol=rtol * 1e-2),
            system, x0, 1e-8)

    # ---- reference, then correctness checks before any timing
    reference = exact_full(system, x0)
    ref_x = np.asarray(reference.displacement)
    if ref_x.shape != (ts_np.shape[0], n) or np.asarray(reference.velocity).shape != ref_x.shape:
        raise RuntimeError(f"reference has shape {ref_x.shape}, expected {(ts_np.shape[0], n)}.")
    rhs, y0 = scipy_problem(scene)
    checks = {
        "dopri8": max_error(solvers["dopri8"](system, x0, CHECK_RTOL).displacement, ref_x),
        "scipy_DOP853": max_error(scipy_solve(rhs, y0, ts_np, "DOP853", CHECK_RTOL).y[:n].T, ref_x),
    }
    for name, error in checks.items():
        status = "ok" if error < CHECK_TOLERANCE else "FAILED"
        print(f"check: {name} at rtol {CHECK_RTOL:g} vs exact_solve: max |dx| = {error:.2e} "
              f"(< {CHECK_TOLERANCE:g}) {status}")
    if not all(error < CHECK_TOLERANCE for error in checks.values()):
        raise SystemExit("correctness check failed; no timings taken.")

    def row(name, method, library, *, rtol=None, rank=None, compile_s=None, run_s, run_times,
            error, steps=None, nfev=None, **extra):
        rows.append(dict(name=name, method=method, library=library, rtol=rtol,
                         atol=None if rtol is None else atol_for(rtol), rank=rank,
                         compile_s=compile_s, run_s=run_s, run_times_s=run_times, error=error,
                         steps=steps, nfev=nfev, **extra))

    # ---- exact_solve, full model
    _, run_s, times = timed(exact_full, system, x0, repeats=jax_repeats)
    row("exact_solve (full)", "exact", "mikota_jax", compile_s=exact_full.compile_s, run_s=run_s,
        run_times=times, error=0.0, reference=True)

    # ---- diffrax through simulate
    for solver, compiled in solvers.items():
        for rtol in rtols:
            result, run_s, times = timed(compiled, system, x0, rtol, repeats=jax_repeats)
            row(f"simulate {solver}", solver, "mikota_jax", rtol=rtol,
                compile_s=compiled.compile_s, run_s=run_s, run_times=times,
                error=max_error(result.displacement, ref_x), steps=int(result.num_steps))

    # ---- scipy solve_ivp
    for method in scipy_methods:
        for rtol in rtols:
            sol, run_s, times = timed(scipy_solve, rhs, y0, ts_np, method, rtol,
                                      repeats=scipy_repeats)
            row(f"scipy {method}", method, "scipy", rtol=rtol, run_s=run_s, run_times=times,
                error=max_error(sol.y[:n].T, ref_x), nfev=int(sol.nfev))

    # ---- reduced models: POD of the exact snapshots on [0, 10], Galerkin, lifted errors
    window = scene.reduction.window
    mask = (ts_np >= window[0] - 1e-9) & (ts_np <= window[1] + 1e-9)
    snapshots = ref_x[mask].T  # (n, m), eq. (3.5)

    def offline(rank):
        return jax.block_until_ready(mj.galerkin(system, mj.pod(snapshots).basis(rank)))

    offline_costs = {}
    for rank in ranks:
        start = time.perf_counter()
        model = offline(rank)  # the first call compiles the SVD and the projection
        first = time.perf_counter() - start
        model, run_s, times = timed(offline, rank, repeats=jax_repeats)
        offline_costs[str(rank)] = dict(first_call_s=first, run_s=run_s, run_times_s=times,
                                        snapshots=int(mask.sum()))
        exact_reduced = Compiled(lambda mdl, x: mj.exact_solve(mdl, ts, x), model, x0)
        result, run_s, times = timed(exact_reduced, model, x0, repeats=jax_repeats)
        row(f"reduced r={rank} exact_solve", "exact", "mikota_jax", rank=rank,
            compile_s=exact_reduced.compile_s, run_s=run_s, run_times=times,
            error=max_error(result.displacement, ref_x))
        sim_reduced = Compiled(
            lambda mdl, x, rtol: mj.simulate(mdl, ts, x, solver="dopri8", rtol=rtol,
                                             atol=rtol * 1e-2), model, x0, REDUCED_RTOL)
        result, run_s, times = timed(sim_reduced, model, x0, REDUCED_RTOL, repeats=jax_repeats)
        row(f"reduced r={rank} dopri8", "dopri8", "mikota_jax", rtol=REDUCED_RTOL, rank=rank,
            compile_s=sim_reduced.compile_s, run_s=run_s, run_times=times,
            error=max_error(result.displacement, ref_x), steps=int(result.num_steps))

    # ---- report
    def find(name, rtol):
        return next(r for r in rows if r["name"] == name and r["rtol"] == rtol)

    ratio = find("scipy DOP853", 1e-8)["run_s"] / find("simulate dopri8", 1e-8)["run_s"]
    print_table(rows, offline_costs)
    print(f"\nscipy DOP853 / mikota_jax dopri8 run time at rtol 1e-8: {ratio:.2f}x")

    data = {
        "benchmark": "section5", "scene": SCENE, "quick": quick,
        "metadata": metadata(),
        "problem": {
            "n": n, "times": {"start": float(ts_np[0]), "end": float(ts_np[-1]),
                              "count": int(ts_np.shape[0])},
            "damper": "grounded, d = 1 at DOF 7", "initial": "x_3(0) = 1, v(0) = 0",
            "snapshot_window": list(window), "atol": "rtol * 1e-2",
            "error": "max abs displacement error over all DOFs and times vs exact_solve (full)",
            "compile": "jax.jit(public function).lower(...).compile(), trace + lower + compile; "
                       "tolerances are traced, so one executable serves every rtol of a solver",
            "repeats": {"jax": jax_repeats, "scipy": scipy_repeats},
        },
        "checks": {"rtol": CHECK_RTOL, "tolerance": CHECK_TOLERANCE,
                   "max_abs_displacement_difference": checks},
        "offline_pod_galerkin": offline_costs,
        "rows": rows,
        "ratio_scipy_dop853_over_dopri8_rtol_1e-8": ratio,
        "total_wall_s": time.perf_counter() - wall_start,
    }
    # --quick writes beside the full results, never over them.
    stem = RESULTS / ("section5_quick" if quick else "section5")
    RESULTS.mkdir(parents=True, exist_ok=True)
    stem.with_suffix(".json").write_text(json.dumps(data, indent=1, allow_nan=False) + "\n")
    plot(rows, stem.with_suffix(".png"), data["metadata"])
    print(f"wrote {stem.with_suffix('.json')} and {stem.with_suffix('.png')} "
          f"({data['total_wall_s']:.0f} s)")
    return data


def metadata() -> dict:
    import diffrax
    import equinox
    import jaxlib

    device = jax.devices()[0]
    return {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "mikota_jax": mj.__version__, "jax": jax.__version__, "jaxlib": jaxlib.__version__,
        "diffrax": diffrax.__version__, "equinox": equinox.__version__,
        "numpy": np.__version__, "scipy": scipy.__version__,
        "python": platform.python_version(), "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "backend": jax.default_backend(),
        "device": getattr(device, "device_kind", None) or str(device),
        "cpu_count": os.cpu_count(), "x64": bool(jax.config.read("jax_enable_x64")),
        "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS"),
    }


def print_table(rows, offline_costs) -> None:
    def fmt(value, spec):
        width = int("".join(c for c in spec.split(".")[0] if c.isdigit()) or 0)
        return f"{'-':>{width}}" if value is None else format(value, spec)

    header = (f"{'row':<28}{'rtol':>8}{'compile s':>11}{'run s':>10}{'error':>11}"
              f"{'steps':>8}{'nfev':>9}")
    print("\n" + header + "\n" + "-" * len(header))
    for r in rows:
        error = "(ref)" if r.get("reference") else fmt(r["error"], ".2e")
        print(f"{r['name']:<28}{fmt(r['rtol'], '8.0e')}{fmt(r['compile_s'], '11.2f')}"
              f"{r['run_s']:>10.4f}{error:>11}{fmt(r['steps'], '8d')}{fmt(r['nfev'], '9d')}")
    for rank, cost in offline_costs.items():
        print(f"{'offline POD+Galerkin r=' + rank:<28}{'-':>8}{'-':>11}{cost['run_s']:>10.4f}"
              f"{'-':>11}{'-':>8}{'-':>9}   (first call {cost['first_call_s']:.2f} s)")


def plot(rows, path: Path, meta: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    styles = {"simulate dopri8": ("C0", "o"), "simulate tsit5": ("C1", "s"),
              "scipy DOP853": ("C2", "^"), "scipy RK45": ("C3", "v")}
    fig, ax = plt.subplots(figsize=(7.5, 5.0))
    for name, (color, marker) in styles.items():
        group = sorted((r for r in rows if r["name"] == name), key=lambda r: r["rtol"])
        if not group:
            continue
        errors, runs = [r["error"] for r in group], [r["run_s"] for r in group]
        ax.loglog(errors, runs, color=color, marker=marker, label=name)
        for r in group:
            ax.annotate(f"{r['rtol']:.0e}", (r["error"], r["run_s"]), textcoords="offset points",
                        xytext=(4, 4), fontsize=7, color=color)
    rank_colors = dict(zip(RANKS, ("C4", "C5")))
    for r in (r for r in rows if r["rank"] is not None):
        color, marker = rank_colors[r["rank"]], "D" if r["method"] == "exact" else "P"
        ax.loglog([r["error"]], [r["run_s"]], color=color, marker=marker, linestyle="none",
                  markersize=8, label=r["name"] + (f" (rtol {r['rtol']:.0e})" if r["rtol"] else ""))
    exact = next(r for r in rows if r.get("reference"))
    ax.axhline(exact["run_s"], color="k", linestyle="--", linewidth=1,
               label="exact_solve (full): the reference")
    ax.set_xlabel("max abs displacement error vs exact solution (all DOFs, all times)")
    ax.set_ylabel("run time [s] (median, compile excluded)")
    ax.set_title(f"Section 5 scene (n = 300, 2001 outputs): work vs precision\n"
                 f"{meta['backend']} / {meta['device']}, {meta['cpu_count']} CPUs, "
                 f"jax {meta['jax']}", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)


if __name__ == "__main__":
    main()
