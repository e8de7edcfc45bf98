"""Cost against the chain size n: the full model vs the POD reduced model at a fixed accuracy.

Scene for every n in {100, 300, 1000, 3000, 10000, 30000}: Mikota's chain (m_i = 1/i,
k_i = n - i + 1, eigenfrequencies l * 1 for l = 1..n) with a grounded damper d = 1 at DOF 7,
x_3(0) = 1, v(0) = 0, no load, horizon T = 1 with outputs every 0.01 (101 times) at the three DOFs
1, n/10 and n/2 only. The spectrum is linear, so a disturbance travels from DOF i to DOF j in
2 |arcsin sqrt(j/n) - arcsin sqrt(i/n)|, independent of n: by t = 1 the pulse from DOF 3 has
reached DOF n/10 (at t ~ 0.64) but not DOF n/2, which stays at rest (x ~ 1e-14 or less) and checks
that the reduced model stays quiet there. T = 1 keeps n = 30000 affordable: the explicit step count
grows like n (the highest eigenfrequency is n) and each step costs O(n).

Each n runs in its own Python process (so its peak memory can be read) and measures, compile time
apart from run time (``Compiled``: ``jax.jit(f).lower(...).compile()``), run time as the median of
repeats ended by ``block_until_ready``:

* reference: ``mj.DenseExponential()`` for n <= 1000 (n x n eigh, 2n x 2n expm), else
  Dopri8 at rtol 1e-12; both exist for n <= 1000, where they must agree before anything is timed;
* full model, spectral: ``mj.Spectral()`` (the default path: damped modes from
  the secular equation, O(n^2)) for n <= 3000, its error against the
  reference recorded; n = 10^4 is ``spectral_large.py``'s;
* full model, best explicit: ``mj.ODE()`` Dopri8 (tridiagonal O(n) operator) at rtol 1e-8 and
  1e-4 (atol = 1e-2 rtol, one executable: tolerances are traced), num_steps recorded; "full at equal
  accuracy" is the loosest of the two that meets the accuracy target below;
* full model, implicit: diffrax's own ``Kvaerno5()`` instance (it factors the dense 2n x 2n
  Jacobian every step; ``mj.StructuredKvaerno5()`` is the structured one, see stability.py). Its
  cost per step is measured on the short window [0, 0.02] for n <= 1000 and the whole horizon for
  n <= 300; beyond, the total is an EXTRAPOLATION, flagged as such: the per-step cost
  (measured, or its power-law fit beyond n = 1000) times the step count measured at the largest
  whole-horizon n (a lower bound: the step count grows with n);
* ROM offline: the snapshot run (Dopri8 rtol 1e-8 on [0, T], all DOFs saved every 0.002: 501
  snapshots), ``pod`` (thin SVD) and ``mj.reduce(system, mj.Projection(basis))`` at the chosen rank;
* ROM rank at a fixed accuracy: the smallest r whose lifted error at the three DOFs over all 101
  outputs is below TARGET = 1e-3 max|x_ref|, found by bisection on 1..numerical rank (the error is
  assumed to fall with r; r - 1 is checked to miss the target) with a numpy modal propagator (the
  same algorithm as ``mj.DenseExponential()``); not counted in the offline cost (a user would pick
  r by energy); the timed ``DenseExponential()`` solve of the ROM must then meet the target;
* ROM online: ``mj.DenseExponential()`` and ``mj.ODE()`` Dopri8 (rtol 1e-8) of the reduced model at
  that r, outputs lifted to the three DOFs;
* memory: the process's peak resident set (``ru_maxrss``: Python, JAX runtime, compiled code, all
  stages of that n including the reference and the snapshot matrix) and XLA's static footprint of
  each executable (``memory_analysis``: arguments + outputs + temporaries).

The snapshots cover the whole horizon: the ROM reproduces the run it was built from (the best case
for a ROM; a basis from [0, T/2] misses the pulse reaching DOF n/2 and has O(1) error). So its
offline cost always contains one full solve, and one query never pays off; the fitted exponents,
the online speed-up and the number of queries that repay the offline cost are what this measures.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/scaling.py [--quick] [--sizes N ...]``.
``--quick``: n = 100 alone, in this one process (no fitted exponents), 2 repeats, no Kvaerno5
and no Dopri8 of the ROM (two compiles fewer). Writes
``benchmarks/results/scaling[_quick].json`` and ``.png``.
"""

from _common import (  # noqa: I001  (first: it sets OPENBLAS_NUM_THREADS before numpy/jax)
    Compiled,
    elapsed,
    figure,
    fit_exponent,
    legend,
    max_error,
    parse_args,
    print_table,
    read_json,
    save_figure,
    subtitle,
    timed,
    write_json,
)

import argparse
import json
import resource
import textwrap
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import diffrax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

import mikota_jax as mj
from mikota_jax.testing import pod

NAME = "scaling"
SIZES = (100, 300, 1000, 3000, 10000, 30000)
QUICK_SIZES = (100,)  # compiling is most of a smoke run: one size
HORIZON = 1.0
OUTPUT_STEP = 0.01  # 101 outputs at the three saved DOFs
SNAPSHOT_EVERY = 5  # snapshots every 0.002: 501 columns (101 are too few for r(n) beyond n ~ 3000)
INITIAL_DOF = 3
DAMPER = (7.0, 1.0)  # grounded: position, coefficient
RTOL, REFERENCE_RTOL = 1e-8, 1e-12
FULL_RTOLS = (RTOL, 1e-6, 1e-4)  # "equal accuracy": the loosest of these that meets TARGET
TARGET = 1e-3  # ROM (and "equal accuracy" full) error at the saved DOFs / max |x_ref| there
EXACT_MAX_N = 1000  # exact_solve of the full model (dense eigh + 2n x 2n expm) up to here
SPECTRAL_MAX_N = 3000  # exact_solve's spectral path (12 n^2 floats; n = 10^4: spectral_large.py)
IMPLICIT_STEP_MAX_N = 1000  # kvaerno5 cost per step measured up to here (short window)
IMPLICIT_RUN_MAX_N = 300  # kvaerno5 on the whole horizon up to here
QUICK_IMPLICIT_MAX_N = 0  # --quick: no kvaerno5 (its compile alone takes ~5 s)
IMPLICIT_WINDOW = 0.02
REFERENCE_CHECK = 1e-8  # exact vs Dopri8 rtol 1e-12 (max abs displacement), n <= EXACT_MAX_N
FULL_CHECK = 1e-5  # Dopri8 rtol 1e-8 and the snapshot run vs the reference


def atol_for(rtol: float) -> float:
    return 1e-2 * rtol


def saved_dofs(n: int) -> tuple[int, ...]:
    return (1, max(n // 10, 2), n // 2)


def repeats_for(n: int, quick: bool) -> int:
    if quick:
        return 2 if n < 1000 else 1
    return 5 if n <= 3000 else 3 if n <= 10000 else 1


def xla_memory(compiled: Compiled) -> dict:
    """XLA's static plan for one executable (bytes): arguments, outputs, temporaries, their sum."""
    stats = compiled.executable.memory_analysis()
    if stats is None:
        return {}
    out = {"argument": int(stats.argument_size_in_bytes), "output": int(stats.output_size_in_bytes),
           "temp": int(stats.temp_size_in_bytes)}
    out["total"] = sum(out.values())
    return out


def first_call(fn, *args):
    """(result, [seconds]) of one call of a compiled function: checked, then kept as a sample."""
    result, _, times = timed(fn, *args, repeats=1)
    return result, times


def more(times, fn, *args, repeats: int):
    """(median, all) of ``times`` plus enough further calls to make ``repeats`` samples."""
    times = list(times)
    if repeats > len(times):
        times += timed(fn, *args, repeats=repeats - len(times))[2]
    return statistics.median(times), times


def peak_rss_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux: KiB


# --------------------------------------------------------------------------- ROM rank search


class ModalRom:
    """The rank-r leading block of one Galerkin projection, solved exactly in numpy.

    Same algorithm as ``exact_solve``: M-orthonormal modes of (K_r, M_r), scaled modal state
    z = (Omega eta, eta'), z_{k+1} = expm(A h) z_k with A = [[0, Omega], [-Omega, -U^T D_r U]].
    """

    def __init__(self, system, decomposition, rank_max: int, x0, dofs):
        rom = mj.reduce(system, mj.Projection(decomposition.basis(rank_max)))
        mass, damping, stiffness = (np.asarray(a) for a in rom.system.dense())
        self.mass, self.damping, self.stiffness = mass, damping, stiffness
        self.basis = np.asarray(decomposition.basis(rank_max))
        self.q0 = self.basis.T @ np.asarray(x0)
        self.rows = self.basis[np.asarray(dofs) - 1]

    def displacement(self, rank: int, step: float, count: int) -> np.ndarray:
        r = rank
        m, d, k = self.mass[:r, :r], self.damping[:r, :r], self.stiffness[:r, :r]
        omega2, modes = scipy.linalg.eigh(k, m)
        omega = np.sqrt(omega2)
        a = np.block([[np.zeros((r, r)), np.diag(omega)], [-np.diag(omega), -modes.T @ d @ modes]])
        propagator = scipy.linalg.expm(a * step)
        z = np.concatenate([omega * (modes.T @ (m @ self.q0[:r])), np.zeros(r)])
        lift = (self.rows[:, :r] @ modes) / omega[None, :]
        out = [lift @ z[:r]]
        for _ in range(count - 1):
            z = propagator @ z
            out.append(lift @ z[:r])
        return np.array(out)


def rank_at_target(rom: ModalRom, rank_max: int, reference, scale):
    """(smallest r with error < TARGET or None, {r: relative error} evaluated), by bisection."""
    count = reference.shape[0]
    errors = {}

    def error(r):
        if r not in errors:
            errors[r] = max_error(rom.displacement(r, OUTPUT_STEP, count), reference) / scale
        return errors[r]

    if error(rank_max) >= TARGET:
        return None, errors
    low, high = 0, rank_max  # error(low) misses (r = 0: no model), error(high) meets the target
    while high - low > 1:
        middle = (low + high) // 2
        if error(middle) < TARGET:
            high = middle
        else:
            low = middle
    if high > 1:
        error(high - 1)
    return high, errors


# --------------------------------------------------------------------------- one n, one process


def measure(n: int, quick: bool) -> dict:
    """Everything for one chain size, in this process; returns a JSON-ready dict."""
    start = time.perf_counter()
    repeats = repeats_for(n, quick)
    dofs = saved_dofs(n)
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(*DAMPER)])
    x0 = mj.unit_vector(n, INITIAL_DOF)
    count = int(round(HORIZON / OUTPUT_STEP)) + 1
    ts = jnp.linspace(0.0, HORIZON, count)
    ts_snap = jnp.linspace(0.0, HORIZON, (count - 1) * SNAPSHOT_EVERY + 1)
    out = {"n": n, "dofs": list(dofs), "repeats": repeats,
           "rss_after_setup_bytes": peak_rss_bytes()}
    say = lambda text: print(f"  n={n}: {text} ({elapsed(start):.0f} s)", flush=True)  # noqa: E731

    # ---- compile the full-model executables
    full = Compiled(lambda s, x, rtol: mj.solve(s, ts, x, dofs=dofs,
                                                method=mj.ODE(rtol=rtol, atol=rtol * 1e-2)),
                    system, x0, RTOL)
    snap = Compiled(lambda s, x, rtol: mj.solve(s, ts_snap, x,
                                                method=mj.ODE(rtol=rtol, atol=rtol * 1e-2)),
                    system, x0, RTOL)
    exact = None
    if n <= EXACT_MAX_N:
        exact = Compiled(lambda s, x: mj.solve(s, ts, x, dofs=dofs, method=mj.DenseExponential()),
                         system, x0)
    spectral = None
    if n <= SPECTRAL_MAX_N:
        spectral = Compiled(lambda s, x: mj.solve(s, ts, x, dofs=dofs, method=mj.Spectral()),
                            system, x0)
    say("compiled full-model executables")

    # ---- reference and correctness checks, before any timing
    # The calls that the checks read are timed too: each is the first sample of its row.
    checks = {}
    dopri_ref, dopri_ref_times = first_call(full, system, x0, REFERENCE_RTOL)
    if exact is not None:
        exact_ref, exact_times = first_call(exact, system, x0)
        reference = np.asarray(exact_ref.displacement)
        checks["dopri8_rtol_1e-12_vs_exact"] = max_error(dopri_ref.displacement, reference)
        if checks["dopri8_rtol_1e-12_vs_exact"] > REFERENCE_CHECK:
            raise SystemExit(f"n={n}: Dopri8 at rtol {REFERENCE_RTOL:g} differs from exact_solve "
                             f"by {checks['dopri8_rtol_1e-12_vs_exact']:.2e} > "
                             f"{REFERENCE_CHECK:g}.")
    else:
        reference = np.asarray(dopri_ref.displacement)
    scale = float(np.max(np.abs(reference)))
    out["reference"] = {"method": "exact_solve" if exact is not None else
                        f"simulate dopri8 rtol {REFERENCE_RTOL:g}", "max_abs_x": scale,
                        "max_abs_x_per_dof": np.max(np.abs(reference), axis=0).tolist(),
                        "dopri8_reference_steps": int(dopri_ref.num_steps),
                        "dopri8_reference_run_s": dopri_ref_times[0]}
    first, first_times = first_call(full, system, x0, RTOL)
    snapshots_run, snap_times = first_call(snap, system, x0, RTOL)
    snapshots = np.asarray(snapshots_run.displacement)  # (times, n)
    checks["dopri8_rtol_1e-8_vs_reference"] = max_error(first.displacement, reference)
    checks["snapshot_run_vs_reference"] = max_error(
        snapshots[::SNAPSHOT_EVERY][:, np.asarray(dofs) - 1], reference)
    for key in ("dopri8_rtol_1e-8_vs_reference", "snapshot_run_vs_reference"):
        if checks[key] > FULL_CHECK:
            raise SystemExit(f"n={n}: check {key} failed: {checks[key]:.2e} > {FULL_CHECK:g}.")
    out["checks"] = checks
    say("checks passed")

    # ---- full model: explicit
    out["full"] = {"compile_s": full.compile_s, "memory": xla_memory(full), "rtols": {}}
    for rtol in FULL_RTOLS:
        if rtol == RTOL:
            result, (run_s, times) = first, more(first_times, full, system, x0, rtol,
                                                 repeats=repeats)
        else:
            result, run_s, times = timed(full, system, x0, rtol, repeats=repeats)
        error = max_error(result.displacement, reference)
        out["full"]["rtols"][f"{rtol:g}"] = {
            "rtol": rtol, "atol": atol_for(rtol), "run_s": run_s, "run_times_s": times,
            "steps": int(result.num_steps), "error": error, "relative_error": error / scale}
    meets = [v for v in out["full"]["rtols"].values() if v["relative_error"] < TARGET]
    out["full"]["equal_accuracy"] = max(meets, key=lambda v: v["rtol"]) if meets else None
    if exact is not None:
        run_s, times = more(exact_times, exact, system, x0, repeats=repeats)
        out["full_exact"] = {"compile_s": exact.compile_s, "run_s": run_s, "run_times_s": times,
                             "memory": xla_memory(exact)}
    if spectral is not None:
        result, run_s, times = timed(spectral, system, x0, repeats=repeats)
        error = max_error(result.displacement, reference)
        out["full_spectral"] = {"compile_s": spectral.compile_s, "run_s": run_s,
                                "run_times_s": times, "memory": xla_memory(spectral),
                                "error": error, "relative_error": error / scale}
    say("full model timed")

    # ---- full model: implicit (kvaerno5), dense Jacobian per step
    out["implicit"] = measure_implicit(n, quick, system, x0, dofs, reference, scale, repeats, say)

    # ---- ROM offline: snapshot run, POD, Galerkin
    snap_s, snap_times = more(snap_times, snap, system, x0, RTOL, repeats=repeats)
    q = jnp.asarray(snapshots.T)  # (n, m), eq. (3.5)
    pod_exe = Compiled(lambda a: pod(a), q)
    decomposition, pod_s, pod_times = timed(pod_exe, q, repeats=repeats)
    rank_max = decomposition.numerical_rank()
    search_start = time.perf_counter()
    modal = ModalRom(system, decomposition, rank_max, x0, dofs)
    rank, search = rank_at_target(modal, rank_max, reference, scale)
    search_s = elapsed(search_start)
    out["rom"] = {
        "snapshots": {"count": int(snapshots.shape[0]), "step": OUTPUT_STEP / SNAPSHOT_EVERY,
                      "compile_s": snap.compile_s, "run_s": snap_s, "run_times_s": snap_times,
                      "steps": int(snapshots_run.num_steps), "memory": xla_memory(snap)},
        "pod": {"method": "svd", "compile_s": pod_exe.compile_s, "run_s": pod_s,
                "run_times_s": pod_times, "numerical_rank": rank_max,
                "memory": xla_memory(pod_exe)},
        "rank": rank,
        "rank_search": {"s": search_s, "relative_errors": {str(k): v for k, v in
                                                          sorted(search.items())}},
        "rank_for_energy_0.99_squared": decomposition.rank_for_energy(0.99),
        "rank_for_energy_0.999999_squared": decomposition.rank_for_energy(0.999999),
    }
    del snapshots, snapshots_run, q
    say(f"snapshots + POD timed, rank at target = {rank}")
    if rank is None:
        out["rom"]["note"] = (f"no rank up to the numerical rank {rank_max} meets the target "
                              f"{TARGET:g}: the ROM does not reach this accuracy")
        return finish(out, start)
    basis = decomposition.basis(rank)
    project = Compiled(lambda s, b: mj.reduce(s, mj.Projection(b)), system, basis)
    model, galerkin_s, galerkin_times = timed(project, system, basis, repeats=repeats)
    out["rom"]["galerkin"] = {"compile_s": project.compile_s, "run_s": galerkin_s,
                              "run_times_s": galerkin_times, "memory": xla_memory(project)}
    out["rom"]["offline_s"] = snap_s + pod_s + galerkin_s

    # ---- ROM online
    rom_exact = Compiled(lambda mdl, x: mj.solve(mdl, ts, x, dofs=dofs,
                                                 method=mj.DenseExponential()), model, x0)
    check_error = max_error(rom_exact(model, x0).displacement, reference) / scale
    if not check_error < TARGET:
        raise SystemExit(f"n={n}: exact_solve of the rank-{rank} ROM has relative error "
                         f"{check_error:.3e}, not below {TARGET:g} as the numpy search found.")
    result, run_s, times = timed(rom_exact, model, x0, repeats=repeats)
    out["rom"]["exact"] = {"compile_s": rom_exact.compile_s, "run_s": run_s, "run_times_s": times,
                           "relative_error": max_error(result.displacement, reference) / scale,
                           "memory": xla_memory(rom_exact)}
    if quick:  # one compile fewer per n; the online cost is exact_solve's
        out["rom"]["dopri8"] = None
        return finish(out, start)
    rom_dopri = Compiled(lambda mdl, x, rtol: mj.solve(mdl, ts, x, dofs=dofs,
                                                       method=mj.ODE(rtol=rtol, atol=rtol * 1e-2)),
                         model, x0, RTOL)
    result, run_s, times = timed(rom_dopri, model, x0, RTOL, repeats=repeats)
    out["rom"]["dopri8"] = {"rtol": RTOL, "compile_s": rom_dopri.compile_s, "run_s": run_s,
                            "run_times_s": times, "steps": int(result.num_steps),
                            "relative_error": max_error(result.displacement, reference) / scale,
                            "memory": xla_memory(rom_dopri)}
    say("ROM online timed")
    return finish(out, start)


def finish(out: dict, start: float) -> dict:
    out["peak_rss_bytes"] = peak_rss_bytes()
    out["wall_s"] = elapsed(start)
    return out


def measure_implicit(n, quick, system, x0, dofs, reference, scale, repeats, say) -> dict:
    """kvaerno5: cost per step on [0, IMPLICIT_WINDOW]; the whole horizon where it is affordable.

    One executable serves both: the output grid is an argument of 101 times, spread over the short
    window or over [0, T].
    """
    run_max = QUICK_IMPLICIT_MAX_N if quick else IMPLICIT_RUN_MAX_N
    step_max = QUICK_IMPLICIT_MAX_N if quick else IMPLICIT_STEP_MAX_N
    if n > step_max:
        return {"measured": False,
                "why": f"dense 2n x 2n Jacobian factored every step: not run above n = {step_max}"
                       " within this budget"}
    count = reference.shape[0]
    solve = Compiled(lambda s, x, grid, rtol: mj.solve(
        s, grid, x, dofs=dofs, method=mj.ODE(diffrax.Kvaerno5(), rtol=rtol, atol=rtol * 1e-2)),
        system, x0, jnp.linspace(0.0, HORIZON, count), RTOL)
    window = jnp.linspace(0.0, IMPLICIT_WINDOW, count)
    result, run_s, times = timed(solve, system, x0, window, RTOL, repeats=1 if n > 300 else repeats)
    out = {"measured": True, "rtol": RTOL, "compile_s": solve.compile_s,
           "memory": xla_memory(solve),
           "window": {"end": IMPLICIT_WINDOW, "run_s": run_s, "run_times_s": times,
                      "steps": int(result.num_steps), "per_step_s": run_s / int(result.num_steps)}}
    if n <= run_max:
        grid = jnp.linspace(0.0, HORIZON, count)
        result, run_s, times = timed(solve, system, x0, grid, RTOL, repeats=1)
        error = max_error(result.displacement, reference)
        out["horizon"] = {"run_s": run_s, "run_times_s": times, "steps": int(result.num_steps),
                          "per_step_s": run_s / int(result.num_steps), "error": error,
                          "relative_error": error / scale}
    say("kvaerno5 timed")
    return out


# --------------------------------------------------------------------------- driver


def run_worker(n: int, quick: bool) -> dict:
    """``measure(n)`` in a fresh Python process (its own peak memory); its JSON comes back."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"n{n}.json"
        command = [sys.executable, str(Path(__file__).resolve()), "--worker", str(n),
                   "--worker-out", str(path)] + (["--quick"] if quick else [])
        done = subprocess.run(command, check=False)
        if done.returncode != 0:
            raise SystemExit(f"the measurement for n = {n} failed (exit code {done.returncode}).")
        return json.loads(path.read_text())


def crossover(sizes, ratios):
    """n where a speed-up ratio (full / ROM) crosses 1 for good, log-log interpolated; a note."""
    pairs = [(s, r) for s, r in zip(sizes, ratios) if r is not None]
    if not pairs:
        return None, "not measured"
    if all(r > 1 for _, r in pairs):
        return None, (f"ROM faster at every measured n, already at n = {pairs[0][0]} "
                      "(any crossover lies below)")
    if pairs[-1][1] <= 1:
        return None, f"ROM never faster up to n = {pairs[-1][0]}: no crossover in range"
    last_bad = max(i for i, (_, r) in enumerate(pairs) if r <= 1)
    (n0, r0), (n1, r1) = pairs[last_bad], pairs[last_bad + 1]
    t = -np.log(r0) / (np.log(r1) - np.log(r0))
    n_star = float(np.exp(np.log(n0) + t * (np.log(n1) - np.log(n0))))
    return n_star, f"ROM faster from n ~ {n_star:.0f} on (between {n0} and {n1})"


def summarise(results: list[dict]) -> tuple[list[dict], dict]:
    """Per-n table rows and the fitted exponents / crossovers."""
    rows = []
    for res in results:
        n, rom, full = res["n"], res["rom"], res["full"]
        equal = full["equal_accuracy"]
        implicit = res["implicit"]
        row = {"n": n, "rank": rom["rank"], "steps": full["rtols"][f"{RTOL:g}"]["steps"],
               "full_s": full["rtols"][f"{RTOL:g}"]["run_s"],
               "full_equal_s": equal["run_s"] if equal else None,
               "equal_rtol": equal["rtol"] if equal else None,
               "exact_s": res.get("full_exact", {}).get("run_s"),
               "spectral_s": res.get("full_spectral", {}).get("run_s"),
               "spectral_error": res.get("full_spectral", {}).get("relative_error"),
               "implicit_step_s": (implicit["window"]["per_step_s"] if implicit["measured"]
                                   else None),
               "implicit_s": implicit.get("horizon", {}).get("run_s"),
               "implicit_steps": implicit.get("horizon", {}).get("steps"),
               "snap_s": rom["snapshots"]["run_s"], "pod_s": rom["pod"]["run_s"],
               "offline_s": rom.get("offline_s"),
               "rom_exact_s": rom.get("exact", {}).get("run_s"),
               "rom_dopri_s": (rom.get("dopri8") or {}).get("run_s"),
               "rom_error": rom.get("exact", {}).get("relative_error"),
               "rom_steps": (rom.get("dopri8") or {}).get("steps"),
               "compile_full_s": full["compile_s"], "compile_snap_s": rom["snapshots"]["compile_s"],
               "compile_exact_s": res.get("full_exact", {}).get("compile_s"),
               "compile_spectral_s": res.get("full_spectral", {}).get("compile_s"),
               "compile_kv5_s": implicit.get("compile_s"),
               "compile_rom_exact_s": rom.get("exact", {}).get("compile_s"),
               "compile_rom_dopri_s": (rom.get("dopri8") or {}).get("compile_s"),
               "full_error": full["rtols"][f"{RTOL:g}"]["relative_error"],
               "peak_mb": res["peak_rss_bytes"] / 2**20,
               "peak_delta_mb": (res["peak_rss_bytes"] - res["rss_after_setup_bytes"]) / 2**20,
               "full_xla_mb": full["memory"].get("total", 0) / 2**20,
               "wall_s": res["wall_s"]}
        row["full_step_s"] = row["full_s"] / row["steps"]
        online = [v for v in (row["rom_exact_s"], row["rom_dopri_s"]) if v is not None]
        row["online_s"] = min(online) if online else None
        if row["online_s"] is not None and row["full_equal_s"] is not None:
            row["speedup_online"] = row["full_equal_s"] / row["online_s"]
            row["speedup_one_query"] = row["full_equal_s"] / (row["offline_s"] + row["online_s"])
            gain = row["full_equal_s"] - row["online_s"]
            row["break_even_queries"] = row["offline_s"] / gain if gain > 0 else None
        rows.append(row)
    extrapolate_implicit(rows)
    sizes = [r["n"] for r in rows]

    def fit(key, rows_=rows):
        return fit_exponent([r["n"] for r in rows_], [r.get(key) for r in rows_])

    tail = [r for r in rows if r["n"] >= 1000]
    curves = {"full_s": "full Dopri8 rtol 1e-8", "full_equal_s": "full Dopri8 at equal accuracy",
              "exact_s": "full exact_solve (dense)",
              "spectral_s": "full exact_solve (spectral)",
              "implicit_step_s": "full Kvaerno5 per step",
              "implicit_s": "full Kvaerno5 whole horizon (measured)",
              "implicit_estimate_s": "full Kvaerno5 whole horizon (extrapolated lower bound)",
              "offline_s": "ROM offline", "online_s": "ROM online (best)",
              "rom_exact_s": "ROM exact_solve", "rom_dopri_s": "ROM Dopri8", "rank": "rank r(n)",
              "steps": "Dopri8 steps", "full_step_s": "full Dopri8 per step",
              "rom_steps": "ROM Dopri8 steps",
              "implicit_steps": "Kvaerno5 steps (whole horizon)",
              "speedup_online": "speed-up full (equal accuracy) / ROM online",
              "speedup_one_query": "speed-up full / (ROM offline + online)",
              "break_even_queries": "queries to repay the offline cost",
              "peak_mb": "peak RSS", "peak_delta_mb": "peak RSS - RSS after setup",
              "full_xla_mb": "full Dopri8 XLA footprint"}
    exponents = {key: {"curve": label, "all_n": fit(key),
                       "n_ge_1000": fit(key, tail) if len(tail) >= 2 else None}
                 for key, label in curves.items()}
    online_n, online_note = crossover(sizes, [r.get("speedup_online") for r in rows])
    once_n, once_note = crossover(sizes, [r.get("speedup_one_query") for r in rows])
    summary = {"exponents": exponents,
               "crossover_online": {"n": online_n, "note": online_note},
               "crossover_offline_plus_online_one_query": {"n": once_n, "note": once_note}}
    return rows, summary


def extrapolate_implicit(rows) -> None:
    """Kvaerno5 whole-horizon estimate where not measured: per-step cost x a known step count."""
    whole = [r for r in rows if r["implicit_s"] is not None]
    per_step = [r for r in rows if r["implicit_step_s"] is not None]
    if not whole or len(per_step) < 1:
        return
    anchor = max(whole, key=lambda r: r["n"])
    steps = anchor["implicit_steps"]
    slope = fit_exponent([r["n"] for r in per_step], [r["implicit_step_s"] for r in per_step])
    top = max(per_step, key=lambda r: r["n"])
    for r in rows:
        if r["implicit_s"] is not None:
            continue
        if r["implicit_step_s"] is not None:
            cost = r["implicit_step_s"]
        elif slope is not None:
            cost = top["implicit_step_s"] * (r["n"] / top["n"]) ** slope
        else:
            continue
        r["implicit_estimate_s"] = cost * steps
        r["implicit_estimate_how"] = (
            f"cost per step ({'measured' if r['implicit_step_s'] else 'power-law fit'}) x "
            f"{steps} steps (measured on the whole horizon at n = {anchor['n']}): a lower bound")


# --------------------------------------------------------------------------- plot


def plot(data: dict):
    """(a) cost vs n, (b) per-step cost, steps and rank, (c) pay-off, (d) memory."""
    rows, summary, quick = data["rows"], data["summary"], data["quick"]
    for row, res in zip(rows, data["per_n"]):
        row["raw"] = res
    fig, axes = figure(nrows=2, ncols=2, figsize=(12, 15), readable=True)
    (cost, step), (payoff, memory) = axes
    exps = summary["exponents"]

    def curve(ax, key, label, style, **kw):
        pts = [(r["n"], r[key]) for r in rows if r.get(key) is not None]
        if not pts:
            return
        slope = exps[key]["all_n"] if key in exps else None
        text = f"{label} (~n^{slope:.2f})" if slope is not None else label
        ax.loglog(*zip(*pts), style, label=text, **kw)

    def title(ax, text):
        ax.set_title(textwrap.fill(text, 48))

    curve(cost, "full_s", "full Dopri8, rtol 1e-8", "o-", color="C0")
    curve(cost, "full_equal_s", "full Dopri8, equal accuracy", "o--", color="C0", mfc="none")
    curve(cost, "exact_s", "full exact_solve (dense)", "s-", color="C7")
    curve(cost, "spectral_s", "full exact_solve (spectral, the default)", "p-", color="k")
    curve(cost, "implicit_s", "full Kvaerno5 (measured)", "v-", color="C3")
    curve(cost, "implicit_estimate_s", "full Kvaerno5 (EXTRAPOLATED, lower bound)", "v:",
          color="C3", mfc="none")
    curve(cost, "offline_s", "ROM offline: snapshots + POD + Galerkin", "D-", color="C2")
    curve(cost, "rom_exact_s", "ROM online, exact_solve", "^-", color="C1")
    curve(cost, "rom_dopri_s", "ROM online, Dopri8 rtol 1e-8", "^--", color="C1", mfc="none")
    cost.set_ylabel("run time [s] (median, compile apart)")
    title(cost, f"(a) cost vs n: T = {data['problem']['horizon']:g}, 101 outputs at 3 DOFs; "
                f"ROM at rel. error < {TARGET:g}")

    curve(step, "full_step_s", "full Dopri8 rtol 1e-8: s per step", "o-", color="C0")
    curve(step, "implicit_step_s", "full Kvaerno5: s per step (dense Jacobian)", "v-", color="C3")
    step.set_ylabel("time per step [s] (solid)")
    counts = step.twinx()
    curve(counts, "steps", "full Dopri8 rtol 1e-8: steps", "o:", color="C0", mfc="none")
    curve(counts, "implicit_steps", "full Kvaerno5: steps (whole horizon)", "v:", color="C3",
          mfc="none")
    curve(counts, "rank", "ROM rank r(n) at the target", "x:", color="C4")
    counts.set_ylabel("steps, rank r (dotted; count)")
    title(step, "(b) where the cost comes from: per-step cost, step count, ROM rank")

    for key, label, style in (("speedup_online", "full (equal accuracy) / ROM online", "o-"),
                              ("speedup_one_query", "full / (ROM offline + online), one query",
                               "s--")):
        curve(payoff, key, label, style)
    curve(payoff, "break_even_queries", "queries that repay the offline cost", "d:", color="C2")
    payoff.axhline(1.0, color="k", linewidth=1)
    payoff.set_ylabel("time ratio; queries (dimensionless)")
    title(payoff, "(c) pay-off. online: " + summary["crossover_online"]["note"] + "; one "
                  "query: " + summary["crossover_offline_plus_online_one_query"]["note"])

    curve(memory, "peak_mb", "peak RSS of the process (all stages)", "o-", color="k")
    curve(memory, "peak_delta_mb", "peak RSS minus RSS after setup", "o--", color="k",
          mfc="none")
    mem_rows = {
        "full Dopri8 (XLA)": lambda r: r["full"]["memory"].get("total"),
        "snapshot run (XLA)": lambda r: r["rom"]["snapshots"]["memory"].get("total"),
        "POD SVD (XLA)": lambda r: r["rom"]["pod"]["memory"].get("total"),
        "ROM exact_solve (XLA)": lambda r: (r["rom"].get("exact") or {}).get("memory", {})
        .get("total"),
        "full exact_solve (XLA)": lambda r: (r.get("full_exact") or {}).get("memory", {})
        .get("total"),
        "Kvaerno5 (XLA)": lambda r: r["implicit"].get("memory", {}).get("total"),
    }
    for (label, get), marker in zip(mem_rows.items(), "sDP^v<"):
        pts = [(r["n"], get(r["raw"]) / 2**20) for r in rows if get(r["raw"])]
        if pts:
            slope = fit_exponent(*zip(*pts))
            memory.loglog(*zip(*pts), marker + "--", label=label + (
                "" if slope is None else f" (~n^{slope:.2f})"))
    memory.set_ylabel("memory [MiB]")
    title(memory, "(d) memory: process peak RSS, and XLA's footprint of each executable "
                  "(arguments + outputs + temporaries)")
    for ax in (cost, step, payoff, memory):
        ax.set_xlabel("chain size n (DOFs)")
        ax.grid(True, which="both", alpha=0.3)
        handles = ax.get_legend_handles_labels()[0]
        legend(ax, "below", handles=handles + (
            counts.get_legend_handles_labels()[0] if ax is step else []))
    fig.suptitle(f"Mikota chain scaling, full model vs POD ROM{' (quick)' if quick else ''}: "
                 f"{subtitle(data['metadata'])}")
    return save_figure(fig, NAME, quick)


# --------------------------------------------------------------------------- main


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True,
                      sizes=dict(type=int, nargs="+", help="chain sizes (default: the issue's)"),
                      worker=dict(type=int, help=argparse.SUPPRESS),
                      worker_out=dict(help=argparse.SUPPRESS))
    if args.replot:
        return plot(read_json(NAME, args.quick))
    if args.worker is not None:
        data = measure(args.worker, args.quick)
        Path(args.worker_out).write_text(json.dumps(data, allow_nan=False))
        return data
    quick = args.quick
    sizes = tuple(args.sizes) if args.sizes else QUICK_SIZES if quick else SIZES
    wall = time.perf_counter()
    results = []
    for n in sizes:
        # --quick measures in this process (three fewer Python + JAX start-ups); its peak RSS is
        # then the running high-water mark over the sizes so far, not one size's own.
        print(f"n = {n}: measuring in {'this' if quick else 'a fresh'} process", flush=True)
        results.append(measure(n, quick) if quick else run_worker(n, quick))
    rows, summary = summarise(results)
    for row, res in zip(rows, results):
        row["raw"] = res

    print_table(rows, [
        ("n", "n", "d"), ("steps", "dopri8 steps", "d"), ("full_s", "full 1e-8 s", ".3g"),
        ("full_equal_s", "full eq.acc s", ".3g"), ("equal_rtol", "eq.acc rtol", ".0e"),
        ("exact_s", "full dense s", ".3g"), ("spectral_s", "full spectral s", ".3g"),
        ("implicit_step_s", "kv5 s/step", ".3g"),
        ("implicit_s", "kv5 s", ".3g"), ("implicit_estimate_s", "kv5 est. s", ".3g"),
        ("rank", "r", "d"), ("offline_s", "ROM off s", ".3g"),
        ("rom_exact_s", "ROM exact s", ".3g"),
        ("rom_dopri_s", "ROM dopri8 s", ".3g"), ("speedup_online", "speed-up", ".3g"),
        ("break_even_queries", "queries", ".3g")])
    print_table(rows, [
        ("n", "n", "d"), ("full_error", "full rel.err", ".1e"),
        ("spectral_error", "spectral rel.err", ".1e"), ("rom_error", "ROM rel.err", ".1e"),
        ("snap_s", "snapshots s", ".3g"), ("pod_s", "POD s", ".3g"),
        ("peak_mb", "peak RSS MiB", ".0f"), ("peak_delta_mb", "RSS - setup MiB", ".0f"),
        ("full_xla_mb", "full XLA MiB", ".3g"), ("rom_steps", "ROM dopri8 steps", "d"),
        ("wall_s", "process s", ".0f")])
    print("\ncompile times [s] (trace + lower + XLA compile, once per n):", end="")
    print_table(rows, [
        ("n", "n", "d"), ("compile_full_s", "full dopri8", ".2f"),
        ("compile_snap_s", "snapshot run", ".2f"), ("compile_exact_s", "full dense", ".2f"),
        ("compile_spectral_s", "full spectral", ".2f"),
        ("compile_kv5_s", "kvaerno5", ".2f"), ("compile_rom_exact_s", "ROM exact", ".2f"),
        ("compile_rom_dopri_s", "ROM dopri8", ".2f")])
    print("\nfitted exponents (cost ~ n^p, least squares in log-log; all n / n >= 1000):")
    for item in summary["exponents"].values():
        if item["all_n"] is not None:
            tail = "-" if item["n_ge_1000"] is None else f"{item['n_ge_1000']:.2f}"
            print(f"  {item['curve']:<52} {item['all_n']:6.2f}   {tail:>6}")
    print(f"\nROM online vs full at equal accuracy: {summary['crossover_online']['note']}")
    print(f"ROM offline + online (one query) vs full: "
          f"{summary['crossover_offline_plus_online_one_query']['note']}")

    for row in rows:
        row.pop("raw")
    data = {
        "problem": {
            "chain": "mikota_chain(n), m = k = 1", "sizes": list(sizes),
            "damper": f"grounded, d = {DAMPER[1]:g} at DOF {DAMPER[0]:g}",
            "initial": f"x_{INITIAL_DOF}(0) = 1, v(0) = 0", "horizon": HORIZON,
            "output_step": OUTPUT_STEP, "saved_dofs": "(1, n//10, n//2)",
            "snapshots": f"simulate Dopri8 rtol {RTOL:g} on [0, {HORIZON:g}], all DOFs every "
                         f"{OUTPUT_STEP / SNAPSHOT_EVERY:g}",
            "reference": f"exact_solve for n <= {EXACT_MAX_N}, else Dopri8 rtol {REFERENCE_RTOL:g}",
            "accuracy_target": f"max |x - x_ref| at the saved DOFs and times < {TARGET:g} "
                               "max |x_ref| there",
            "rtols": list(FULL_RTOLS), "atol": "1e-2 rtol",
            "rank_search": "bisection on 1..numerical rank with a numpy modal propagator; not "
                           "part of the offline cost",
            "implicit": f"kvaerno5 rtol {RTOL:g}: per step on [0, {IMPLICIT_WINDOW:g}] for n <= "
                        f"{IMPLICIT_STEP_MAX_N}, whole horizon for n <= "
                        f"{QUICK_IMPLICIT_MAX_N if quick else IMPLICIT_RUN_MAX_N}; beyond: "
                        "extrapolated (per-step cost x step count at the largest measured n)",
            "memory": "peak_rss: ru_maxrss of the per-n process (Python + JAX runtime + compiled "
                      "code + every stage); XLA: memory_analysis of each executable "
                      "(arguments + outputs + temporaries)" + (
                          "; QUICK: all sizes in one process, so peak_rss is cumulative"
                          if quick else ""),
            "timing": "Compiled (jax.jit + AOT compile, timed apart); median of repeats with "
                      "block_until_ready; repeats 5 (n <= 3000), 3 (10000), 1 (30000); quick: 2 "
                      "(n < 1000), 1",
        },
        "rows": rows, "summary": summary, "per_n": results, "total_wall_s": elapsed(wall),
    }
    path = write_json(NAME, quick, data)
    png = plot(read_json(NAME, quick))
    print(f"wrote {path} and {png} ({elapsed(wall):.0f} s)")
    return data


if __name__ == "__main__":
    main()
