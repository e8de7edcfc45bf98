"""Work-precision on the paper's Section 5 scene: every solver against the exact solution.

``mj.app.load_scene("section5_damped")``: Mikota's chain with n = 300, a grounded damper d = 1 at
DOF 7, x_3(0) = 1, v(0) = 0, outputs at the 2001 times 0, 0.01, ..., 20. One reference, the exact
(matrix-exponential) solution of the full model; error = max |x_i(t_k) - x_i^exact(t_k)| over all
300 DOFs and all 2001 times. Full-model rows return what the error needs, the displacement at all
DOFs and outputs (solve_ivp returns the whole state regardless); the reference and the reduced rows
also return the velocity, which eq. (5.4) reads. Measured in this one process:

* the exact solves of the full model (rows "exact_solve ..."): ``mj.DenseExponential()``
  (modal coordinates, one 2n x 2n matrix exponential; a horizontal line: the reference, no
  error) and ``mj.Spectral()`` (the default: damped modes from the secular equation; a point at
  its distance from the dense one);
* ``mj.ODE`` (rows "simulate ...") with diffrax Dopri8, Tsit5, Dopri5 and Kvaerno5 at rtol
  1e-3 ... 1e-10, atol = 1e-2 rtol (one executable per solver: tolerances are traced);
* scipy ``solve_ivp`` RK45, DOP853, Radau and LSODA at the same tolerances, as a user calls it:
  first-order form y = (x, v), an O(n) numpy right-hand side, ``t_eval`` = the 2001 outputs, no
  user Jacobian for Radau/LSODA;
* the reduced model (POD of the exact displacement snapshots on [0, 10], Galerkin) at
  r in {10, 20, 40, 76, 98, 140}, solved with ``mj.DenseExponential()`` and with ``mj.ODE``
  Dopri8 at rtol 1e-8, lifted to all DOFs and compared with the *full* exact solution, so
  truncation and integration error show together; plus the phase error of eq. (5.4) and the
  offline cost.

Time budget: one call over CALL_BUDGET_S seconds ends a solver's sweep (the tighter rtols are
recorded as skipped, with the reason). A scipy call is abandoned at the budget (its right-hand side
raises), a compiled JAX call cannot be, so it finishes first. Repeats: the median of up to
``repeats`` calls, fewer when they would take more than REPEAT_BUDGET_S together.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/work_precision.py [--quick]``; writes
``benchmarks/results/work_precision[_quick].json`` and ``.png``. ``--quick``: the same scene at
n = 60, Dopri8 and scipy DOP853 at rtol 1e-6 and 1e-8, one reduced model (r = 20), fewer
repeats.
"""

from _common import (  # noqa: I001  (first: it sets OPENBLAS_NUM_THREADS before numpy/jax)
    Compiled,
    elapsed,
    figure,
    legend,
    max_error,
    ode,
    parse_args,
    print_table,
    read_json,
    save_figure,
    section5_scene,
    subtitle,
    timed,
    write_json,
)

import statistics
import time

import numpy as np
from scipy.integrate import solve_ivp

import mikota_jax as mj
from mikota_jax.testing import energy_fraction, pod

NAME = "work_precision"
RTOLS = tuple(10.0**-k for k in range(3, 11))  # 1e-3 ... 1e-10
QUICK_RTOLS = (1e-6, 1e-8)
DIFFRAX = ("dopri8", "tsit5", "dopri5", "kvaerno5")
SCIPY = ("RK45", "DOP853", "Radau", "LSODA")
RANKS = (10, 20, 40, 76, 98, 140)  # below the numerical rank 148 of these snapshots
QUICK_RANKS = (20,)  # --quick: the scene at n = 60
ROM_RTOL = 1e-8
TARGET_RTOL = 1e-8  # the target: full model vs scipy DOP853 at this rtol
CHECK_RTOL = 1e-10
CHECK_TOLERANCE = 1e-6  # max abs displacement difference allowed in the correctness checks
CALL_BUDGET_S = 20.0  # one call longer than this ends the solver's sweep
REPEAT_BUDGET_S = 10.0  # no more repeats once they would take longer than this together


def atol_for(rtol: float) -> float:
    return 1e-2 * rtol


def repeated(fn, *args, repeats: int):
    """(result, median s, all s): ``repeats`` calls, fewer if they would pass REPEAT_BUDGET_S."""
    result, _, times = timed(fn, *args, repeats=1)
    first = max(times[0], 1e-9)
    more = min(repeats - 1, int(REPEAT_BUDGET_S / first) - 1)
    if more > 0:
        result, _, rest = timed(fn, *args, repeats=more)
        times += rest
    return result, statistics.median(times), times


# --------------------------------------------------------------------------- scipy baseline


class OverBudget(Exception):
    """Raised from the scipy right-hand side when a call passes its time budget."""


def scipy_problem(scene):
    """(rhs, y0) for y = (x, v), y' = (v, M^-1 (-K x - D v)) in O(n) numpy, as a user writes it."""
    mass, damping, stiffness = (np.asarray(a) for a in scene.system.dense())
    m = np.diag(mass).copy()
    k_diag, k_off = np.diag(stiffness).copy(), np.diag(stiffness, 1).copy()
    if np.any(mass != np.diag(m)) or np.any(np.triu(stiffness, 2) != 0):
        raise SystemExit("the scipy baseline assumes a diagonal M and a tridiagonal K (a chain).")
    d_diag = np.diag(damping).copy()
    if np.any(damping != np.diag(d_diag)):
        raise SystemExit("the scipy baseline assumes grounded dampers (a diagonal D).")
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


def scipy_solve(rhs, y0, ts, method: str, rtol: float, budget_s: float | None = None):
    """``solve_ivp`` on the outputs ``ts``; past ``budget_s`` the rhs raises OverBudget."""
    fun = rhs
    if budget_s is not None:
        deadline = time.perf_counter() + budget_s

        def fun(t, y):
            if time.perf_counter() > deadline:
                raise OverBudget(float(t))
            return rhs(t, y)

    sol = solve_ivp(fun, (ts[0], ts[-1]), y0, method=method, t_eval=ts, rtol=rtol,
                    atol=atol_for(rtol))
    if not sol.success:
        raise RuntimeError(f"solve_ivp {method} at rtol {rtol:g} failed: {sol.message}")
    return sol


# --------------------------------------------------------------------------- the benchmark


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return plot(read_json(NAME, args.quick))
    quick = args.quick
    rtols = QUICK_RTOLS if quick else RTOLS
    diffrax_solvers = DIFFRAX[:1] if quick else DIFFRAX
    scipy_methods = ("DOP853",) if quick else SCIPY
    ranks = QUICK_RANKS if quick else RANKS
    jax_repeats, scipy_repeats = (2, 1) if quick else (5, 3)
    wall_start = time.perf_counter()

    scene = section5_scene(quick)
    system, ts, x0 = scene.system, scene.ts, scene.x0
    if scene.v0 is not None or scene.load is not None:
        raise SystemExit("this benchmark expects the Section 5 scene: v(0) = 0, no load.")
    n, ts_np = system.size, np.asarray(ts)
    rows: list[dict] = []
    skipped: list[dict] = []

    # ---- compile every full-model executable (compile time apart from run time); the
    # reference keeps the velocity (the phase error of eq. 5.4 reads it), the solver rows do not
    exact_full = Compiled(lambda sys, x: mj.solve(sys, ts, x, velocity=True,
                                                  method=mj.DenseExponential()), system, x0)
    spectral_full = Compiled(lambda sys, x: mj.solve(sys, ts, x, method=mj.Spectral()),
                             system, x0)
    compiled = {
        solver: Compiled(lambda sys, x, rtol, solver=solver: mj.solve(
            sys, ts, x, method=ode(solver, rtol=rtol, atol=atol_for(rtol))),
            system, x0, TARGET_RTOL)
        for solver in diffrax_solvers}
    compile_s = {"exact_solve": exact_full.compile_s,
                 "exact_solve spectral": spectral_full.compile_s,
                 **{solver: c.compile_s for solver, c in compiled.items()}}

    # ---- the reference: the exact full solution
    reference = exact_full(system, x0)
    ref_x, ref_v = np.asarray(reference.displacement), np.asarray(reference.velocity)
    if ref_x.shape != (ts_np.shape[0], n) or not np.all(np.isfinite(ref_x)):
        raise SystemExit(f"reference has shape {ref_x.shape}, expected {(ts_np.shape[0], n)}.")

    # ---- correctness before any timing: the reference against tight Dopri8 and scipy DOP853
    rhs, y0 = scipy_problem(scene)
    checks = {
        "dopri8": max_error(compiled["dopri8"](system, x0, CHECK_RTOL).displacement, ref_x),
        "scipy_DOP853": max_error(scipy_solve(rhs, y0, ts_np, "DOP853", CHECK_RTOL).y[:n].T,
                                  ref_x),
    }
    for name, error in checks.items():
        status = "ok" if error < CHECK_TOLERANCE else "FAILED"
        print(f"check: {name} at rtol {CHECK_RTOL:g} vs exact_solve: max |dx| = {error:.2e} "
              f"(< {CHECK_TOLERANCE:g}) {status}")
    if not all(error < CHECK_TOLERANCE for error in checks.values()):
        raise SystemExit("correctness check failed; no timings taken.")

    def row(name, method, library, *, run_s, run_times, error, rtol=None, rank=None,
            compile_s=None, steps=None, nfev=None, **extra):
        rows.append(dict(name=name, method=method, library=library, rtol=rtol,
                         atol=None if rtol is None else atol_for(rtol), rank=rank,
                         compile_s=compile_s, run_s=run_s, repeats=len(run_times),
                         run_times_s=run_times, error=error, steps=steps, nfev=nfev, **extra))

    def skip(name, method, rtols_left, reason):
        skipped.extend(dict(name=name, method=method, rtol=r, reason=reason) for r in rtols_left)

    # ---- exact_solve, full model: the dense path is the reference (no error by construction);
    # the spectral path (the default) against it
    _, run_s, times = repeated(exact_full, system, x0, repeats=jax_repeats)
    row("exact_solve dense (full)", "exact", "mikota_jax", compile_s=exact_full.compile_s,
        run_s=run_s, run_times=times, error=0.0, reference=True)
    spectral, run_s, times = repeated(spectral_full, system, x0, repeats=jax_repeats)
    row("exact_solve spectral (full)", "spectral", "mikota_jax",
        compile_s=spectral_full.compile_s, run_s=run_s, run_times=times,
        error=max_error(spectral.displacement, ref_x))

    # ---- diffrax through simulate, loosest rtol first
    for solver, executable in compiled.items():
        for i, rtol in enumerate(rtols):
            name = f"simulate {solver}"
            try:
                result, run_s, times = repeated(executable, system, x0, rtol, repeats=jax_repeats)
            except Exception as error:  # e.g. max_steps reached: record, go on
                skip(name, solver, rtols[i:], f"failed at rtol {rtol:g}: {str(error)[:200]}")
                break
            row(name, solver, "mikota_jax", rtol=rtol, compile_s=executable.compile_s,
                run_s=run_s, run_times=times, error=max_error(result.displacement, ref_x),
                steps=int(result.num_steps))
            print(f"  {name:<22} rtol {rtol:.0e}: {run_s:.4f} s", flush=True)
            if times[0] > CALL_BUDGET_S:
                skip(name, solver, rtols[i + 1:], f"the call at rtol {rtol:g} took "
                     f"{times[0]:.1f} s > {CALL_BUDGET_S:g} s budget; tighter rtols cost more")
                break

    # ---- scipy solve_ivp, loosest rtol first; a call past the budget is abandoned
    for method in scipy_methods:
        name = f"scipy {method}"
        for i, rtol in enumerate(rtols):
            try:
                start = time.perf_counter()
                sol = scipy_solve(rhs, y0, ts_np, method, rtol, budget_s=CALL_BUDGET_S)
                first = elapsed(start)
            except OverBudget as stop:
                skip(name, method, rtols[i:], f"abandoned at rtol {rtol:g}: over the "
                     f"{CALL_BUDGET_S:g} s budget at t = {stop.args[0]:.3g} of {ts_np[-1]:g}")
                break
            except RuntimeError as error:
                skip(name, method, rtols[i:], str(error)[:200])
                break
            times = [first]
            more = min(scipy_repeats - 1, int(REPEAT_BUDGET_S / first) - 1)
            if more > 0:
                sol, _, rest = timed(scipy_solve, rhs, y0, ts_np, method, rtol, repeats=more)
                times += rest
            row(name, method, "scipy", rtol=rtol, run_s=statistics.median(times),
                run_times=times, error=max_error(sol.y[:n].T, ref_x), nfev=int(sol.nfev))
            print(f"  {name:<22} rtol {rtol:.0e}: {statistics.median(times):.4f} s", flush=True)

    # ---- reduced models: POD of the exact snapshots on the scene's window, Galerkin, lifted
    window = scene.reduction.window
    mask = (ts_np >= window[0] - 1e-9) & (ts_np <= window[1] + 1e-9)
    snapshots = ref_x[mask].T  # (n, m), eq. (3.5)
    pod_exe = Compiled(lambda q: pod(q), snapshots)
    decomposition, pod_s, pod_times = repeated(pod_exe, snapshots, repeats=jax_repeats)
    numerical_rank = decomposition.numerical_rank()
    fraction = np.asarray(energy_fraction(decomposition.singular_values,
                                             scene.reduction.criterion))
    modes = decomposition.modes
    reduced: list[dict] = []
    for rank in ranks:
        if rank > numerical_rank:
            raise SystemExit(f"rank {rank} exceeds the numerical rank {numerical_rank} of the "
                             "snapshots.")
        project = Compiled(lambda sys, phi, rank=rank: mj.reduce(sys, mj.Projection(phi[:, :rank])),
                           system, modes)
        model, project_s, project_times = repeated(project, system, modes, repeats=jax_repeats)
        exact_rom = Compiled(lambda mdl, x: mj.solve(mdl, ts, x, velocity=True,
                                                     method=mj.DenseExponential()), model, x0)
        exact_result, run_s, times = repeated(exact_rom, model, x0, repeats=jax_repeats)
        rom_x = np.asarray(exact_result.displacement)
        rom_error = max_error(rom_x, ref_x)
        row(f"ROM r={rank} exact_solve", "exact", "mikota_jax", rank=rank,
            compile_s=exact_rom.compile_s, run_s=run_s, run_times=times, error=rom_error)
        sim_rom = Compiled(lambda mdl, x, rtol: mj.solve(
            mdl, ts, x, velocity=True, method=mj.ODE(rtol=rtol, atol=atol_for(rtol))),
            model, x0, ROM_RTOL)
        sim_result, run_s, times = repeated(sim_rom, model, x0, ROM_RTOL, repeats=jax_repeats)
        row(f"ROM r={rank} dopri8", "dopri8", "mikota_jax", rtol=ROM_RTOL, rank=rank,
            compile_s=sim_rom.compile_s, run_s=run_s, run_times=times,
            error=max_error(sim_result.displacement, ref_x), steps=int(sim_result.num_steps))
        phase = {f"{label}_{aggregate}": float(mj.metrics.phase_error(
            ref_x, ref_v, result.displacement, result.velocity, aggregate=aggregate))
            for label, result in (("exact", exact_result), ("dopri8", sim_result))
            for aggregate in ("sum", "max")}
        reduced.append(dict(
            rank=rank, energy_fraction=float(fraction[rank - 1]),
            error_exact=rom_error, error_dopri8=rows[-1]["error"],
            integration_error_dopri8=max_error(sim_result.displacement, rom_x),
            phase_error_sum=phase["exact_sum"], phase_error_max=phase["exact_max"],
            phase_error_dopri8_sum=phase["dopri8_sum"], phase_error_dopri8_max=phase["dopri8_max"],
            offline_s=pod_s + project_s, pod_s=pod_s, galerkin_s=project_s,
            galerkin_times_s=project_times, galerkin_compile_s=project.compile_s))
        print(f"  ROM r={rank:<4} max error {rom_error:.2e}, phase error (sum) "
              f"{phase['exact_sum']:.3g}", flush=True)

    # ---- the target: scipy DOP853 at rtol 1e-8 vs the fastest full-model diffrax configuration
    # whose error is no worse; and the plain same-rtol Dopri8 ratio
    def find(name, rtol):
        return next((r for r in rows if r["name"] == name and r["rtol"] == rtol), None)

    target = {"rtol": TARGET_RTOL}
    dop853, dopri8 = find("scipy DOP853", TARGET_RTOL), find("simulate dopri8", TARGET_RTOL)
    if dop853 is not None:
        candidates = [r for r in rows if r["library"] == "mikota_jax" and r["rank"] is None
                      and r["rtol"] is not None and r["error"] <= dop853["error"]]
        best = min(candidates, key=lambda r: r["run_s"], default=None)
        target.update(
            scipy_dop853_run_s=dop853["run_s"], scipy_dop853_error=dop853["error"],
            fastest_as_accurate=None if best is None else dict(
                name=best["name"], rtol=best["rtol"], run_s=best["run_s"], error=best["error"]),
            ratio_vs_fastest_as_accurate=None if best is None else dop853["run_s"] / best["run_s"],
            ratio_vs_dopri8_same_rtol=None if dopri8 is None else dop853["run_s"] / dopri8["run_s"],
            dopri8_error=None if dopri8 is None else dopri8["error"],
            goal="at least 20x faster than scipy DOP853 at the same or better error")

    # ---- report
    columns = [("name", "row", "s"), ("rtol", "rtol", ".0e"), ("compile_s", "compile s", ".2f"),
               ("run_s", "run s", ".4f"), ("repeats", "reps", "d"), ("error", "max error", ".2e"),
               ("steps", "steps", "d"), ("nfev", "nfev", "d")]
    print_table(rows, columns)
    for s in skipped:
        print(f"skipped: {s['name']} rtol {s['rtol']:.0e}: {s['reason']}")
    print_table(reduced, [("rank", "ROM r", "d"), ("energy_fraction", "energy", ".5f"),
                          ("error_exact", "err exact", ".2e"),
                          ("error_dopri8", "err dopri8", ".2e"),
                          ("phase_error_sum", "phase sum", ".3e"),
                          ("phase_error_max", "phase max", ".3e"),
                          ("offline_s", "offline s", ".4f"),
                          ("galerkin_compile_s", "galerkin compile s", ".2f")])
    print(f"(offline = pod {pod_s:.4f} s, compiled in {pod_exe.compile_s:.2f} s, + basis and "
          f"galerkin; numerical rank {numerical_rank})")
    if "ratio_vs_dopri8_same_rtol" in target:
        best = target["fastest_as_accurate"]
        print(f"\nscipy DOP853 at rtol {TARGET_RTOL:g}: {target['scipy_dop853_run_s']:.3f} s, "
              f"error {target['scipy_dop853_error']:.2e}")
        if best is not None:
            print(f"fastest mikota_jax diffrax config with error <= that: {best['name']} at rtol "
                  f"{best['rtol']:.0e} ({best['run_s']:.4f} s, error {best['error']:.2e}): "
                  f"ratio {target['ratio_vs_fastest_as_accurate']:.1f}x (goal >= 20x)")
        if target["ratio_vs_dopri8_same_rtol"] is not None:
            print(f"same-rtol ratio, scipy DOP853 / simulate dopri8: "
                  f"{target['ratio_vs_dopri8_same_rtol']:.1f}x (dopri8 error "
                  f"{target['dopri8_error']:.2e})")

    data = {
        "scene": scene.name,
        "problem": {
            "n": n, "times": {"start": float(ts_np[0]), "end": float(ts_np[-1]),
                              "count": int(ts_np.shape[0])},
            "damper": "grounded, d = 1 at DOF 7", "initial": "x_3(0) = 1, v(0) = 0",
            "rtols": list(rtols), "atol": "1e-2 * rtol",
            "error": "max abs displacement error over all DOFs and all times vs exact_solve "
                     "of the full model (the reference)",
            "compile": "jax.jit(public function).lower(...).compile(): trace + lower + XLA "
                       "compile; tolerances are traced, so one executable per solver",
            "scipy": "solve_ivp(method, t_eval = the outputs), first-order y = (x, v), O(n) "
                     "numpy rhs, no Jacobian; Radau/LSODA estimate it by finite differences",
            "repeats": {"jax": jax_repeats, "scipy": scipy_repeats,
                        "budget_s": REPEAT_BUDGET_S},
            "call_budget_s": CALL_BUDGET_S,
            "snapshot_window": list(window), "snapshots": int(mask.sum()),
            "outputs": "displacement at all DOFs and times; velocity too for the reference and "
                       "the reduced rows (eq. 5.4); scipy returns the whole state",
            "rom_rtol": ROM_RTOL, "phase_error": "eq. (5.4), mj.metrics.phase_error aggregate "
                                                 "'sum' (default) and 'max'",
        },
        "checks": {"rtol": CHECK_RTOL, "tolerance": CHECK_TOLERANCE,
                   "max_abs_displacement_difference": checks},
        "compile_s": compile_s,
        "pod": {"run_s": pod_s, "run_times_s": pod_times, "compile_s": pod_exe.compile_s,
                "numerical_rank": numerical_rank, "criterion": scene.reduction.criterion},
        "rows": rows,
        "skipped": skipped,
        "reduced": reduced,
        "target": target,
        "total_wall_s": elapsed(wall_start),
    }
    path = write_json(NAME, quick, data)
    png = plot(read_json(NAME, quick))
    print(f"wrote {path} and {png} ({data['total_wall_s']:.0f} s)")
    return data


# --------------------------------------------------------------------------- the figure


def plot(data: dict):
    """(a) run time against error for every setup, (b) the reduced models' errors against r."""
    rows, reduced, problem = data["rows"], data["reduced"], data["problem"]
    rom_rtol = problem["rom_rtol"]
    fig, (ax, ax_rom) = figure(nrows=2, figsize=(10, 14.5),
                               gridspec_kw={"height_ratios": [1.7, 1.0]}, readable=True)
    styles = {"simulate dopri8": ("C0", "o", "-"), "simulate tsit5": ("C1", "s", "-"),
              "simulate dopri5": ("C2", "D", "-"), "simulate kvaerno5": ("C3", "X", "-"),
              "scipy DOP853": ("C4", "^", "--"), "scipy RK45": ("C5", "v", "--"),
              "scipy Radau": ("C6", "<", "--"), "scipy LSODA": ("C7", ">", "--")}
    for name, (color, marker, line) in styles.items():
        group = sorted((r for r in rows if r["name"] == name), key=lambda r: -r["rtol"])
        if not group:
            continue
        ax.loglog([r["error"] for r in group], [r["run_s"] for r in group], color=color,
                  marker=marker, linestyle=line, markersize=5, label=name)
        for r in {id(r): r for r in (group[0], group[-1])}.values():  # the sweep's two ends
            ax.annotate(f"{np.log10(r['rtol']):.0f}", (r["error"], r["run_s"]),
                        textcoords="offset points", xytext=(3, 3), color=color)
    roms = [r for r in rows if r["rank"] is not None]
    for method, marker, color in (("exact", "*", "k"), ("dopri8", "P", "C9")):
        group = [r for r in roms if r["method"] == method]
        if not group:
            continue
        label = ("ROM, exact_solve" if method == "exact"
                 else f"ROM, simulate dopri8 (rtol {rom_rtol:.0e})")
        ax.loglog([r["error"] for r in group], [r["run_s"] for r in group], color=color,
                  marker=marker, linestyle="none", markersize=9, label=label)
        labels: dict[float, list] = {}  # one label for points on top of each other
        for r in group:
            key = next((k for k in labels if abs(np.log10(r["error"] / k)) < 0.05), r["error"])
            labels.setdefault(key, []).append(r)
        for same in labels.values():
            ax.annotate("r=" + ",".join(str(r["rank"]) for r in same),
                        (same[0]["error"], same[0]["run_s"]), textcoords="offset points",
                        xytext=(-8, -13) if method == "exact" else (7, -14), color=color,
                        ha="right" if method == "exact" else "left",
                        bbox=dict(fc="white", ec="none", alpha=0.7, pad=0.2))
    exact = next(r for r in rows if r.get("reference"))
    ax.axhline(exact["run_s"], color="k", linestyle=":", linewidth=1.2,
               label=f"exact_solve dense, full (the reference): {exact['run_s']:.3f} s")
    spectral = next((r for r in rows if r["method"] == "spectral"), None)
    if spectral is not None:
        ax.loglog([max(spectral["error"], 1e-16)], [spectral["run_s"]], color="k", marker="p",
                  linestyle="none", markersize=10,
                  label=f"exact_solve spectral, full (the default): {spectral['run_s']:.3f} s")
    times = problem["times"]
    ax.set_xlabel(f"max abs displacement error vs exact solution, all DOFs and {times['count']} "
                  "times\n(dimensionless: m = k = 1, x_3(0) = 1)")
    ax.set_ylabel("run time [s] (median, compile apart)")
    ax.set_title("(a) work vs precision; labels: log10 rtol at the ends of each sweep\n(a "
                 "marker per decade), atol = 1e-2 rtol; ROM points: their rank r")
    ax.grid(True, which="both", alpha=0.3)
    legend(ax, "below", ncol=2)

    if reduced:
        r_values = [d["rank"] for d in reduced]
        for key, label, marker in (
                ("error_exact", "max abs error, ROM exact_solve", "*"),
                ("error_dopri8", f"max abs error, ROM dopri8 (rtol {rom_rtol:.0e})", "P"),
                ("integration_error_dopri8", "ROM dopri8 vs ROM exact (integration only)", "x"),
                ("phase_error_sum", "phase error eq. (5.4), aggregate 'sum'", "o"),
                ("phase_error_max", "phase error eq. (5.4), aggregate 'max'", "s")):
            ax_rom.semilogy(r_values, [d[key] for d in reduced], marker=marker, label=label)
        ax_rom.set_xlabel(f"ROM rank r (POD of displacements on {problem['snapshot_window']})")
        ax_rom.set_ylabel("error vs the full exact solution\n(dimensionless)")
        ax_rom.set_title("(b) reduced model: truncation error and phase error vs r")
        ax_rom.grid(True, which="both", alpha=0.3)
        legend(ax_rom, "below", ncol=2)
    fig.suptitle(f"Section 5 scene (n = {problem['n']}, [0, {times['end']:g}], "
                 f"{times['count']} outputs)\n{subtitle(data['metadata'])}")
    return save_figure(fig, NAME, data["quick"])


if __name__ == "__main__":
    main()
