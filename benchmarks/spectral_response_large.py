"""``exact_solve``'s spectral response at large n, without U or the (n, 2n) mode vectors.

Above n = 4096 a fixed-free chain with dampers alone takes ``rows_response``: the modal history
eta(t) (N, n) a block of roots at a time, then x = U eta a chunk of modes at a time
(``chain_mode_combination``); before it, the response formed U (7.2 GB at n = 30000) and the
(n, 2n) complex vectors (29 GB) and did not fit on this machine, so ``crossover.py`` took its
n = 30000 histories and POD snapshots from Dopri8 and, from n = 2 x 10^4, left them out.

Problem (``crossover.py``'s history at size n): Mikota's chain (m = k = 1), a grounded damper at
p = 7 with c = 1, x_3(0) = 1, v(0) = 0; the displacement of every DOF at t = 0, 0.05, ..., 20
(N = 401).

* Part A (one process, n = 5000 and 8000): the library's choice (``rows_response``) against the
  same sums all at once from U and the vectors (``mikota_jax.testing.spectral_solve_with_result(
  ..., block=0)``, the path below n = 4097); compile apart (the first call), median of 2 runs;
  the largest difference relative to max |x|.
* Part B (each n in its own process, for its peak memory: n = 10^4 and 3 x 10^4):
  ``exact_solve(method="spectral")`` eagerly, the first call (compile + run) and at 10^4 a
  second (run; at 3 x 10^4 the first call is the time, its compile ~3 s of ~220 s);
  the process's peak resident memory (VmHWM); x(0) against x0; and against Dopri8 at rtol 1e-10
  (atol 1e-12, ``simulate(solver="dopri8")``) at DOFs 1, 3, n / 2 and n on the same grid, an
  independent path (at 10^4; at 3 x 10^4 with ``--dopri``: ~10 min on 2 cores).

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/spectral_response_large.py [--quick] [--dopri]
[--sizes N ...] [--name NAME]`` (``--quick``: n = 4500 in Part A, 5000 in Part B; ``--sizes``:
Part B at these n only, Part A left out). Writes ``results/spectral_response_large.json`` and
``.png``; ``--replot`` redraws the figure.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (figure, legend, parse_args, print_table, read_json,  # noqa: I001
                     save_figure, subtitle, write_json)

import json
import statistics
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import mikota_jax as mj
from mikota_jax.testing import spectral_solve_with_result
from spectral_energy_large import memory_panel, peak_gib, start

NAME = "spectral_response_large"
DESIGN = (7.0, 1.0)  # crossover's nominal design: p, c
TS = np.linspace(0.0, 20.0, 401)  # crossover's history grid


def chain(n):
    return mj.mikota_chain(n, dampers=[mj.GroundedDamper(*DESIGN)])


def part_a(sizes):
    """The library's choice against all at once from U, one process."""
    rows = []
    for n in sizes:
        system, ts, x0, v0 = chain(n), jnp.asarray(TS), start(n), jnp.zeros(n)
        out = {}
        for label, block in (("rows", None), ("all at once", 0)):
            def solve(system=system, ts=ts, x0=x0, v0=v0, block=block):
                trajectory, ok = spectral_solve_with_result(
                    system, ts, x0, v0, None, dofs=tuple(range(1, system.size + 1)),
                    displacement=True, velocity=False, block=block)
                return np.asarray(trajectory.displacement), bool(ok)

            begin = time.perf_counter()
            x, ok = solve()
            first = time.perf_counter() - begin
            times = []
            for _ in range(2):
                begin = time.perf_counter()
                solve()
                times.append(time.perf_counter() - begin)
            assert ok, f"n = {n}, {label}: the spectral path did not hold"
            out[label] = (x, statistics.median(times), times, first - statistics.median(times))
            print(f"  n = {n}, {label}: compile ~{out[label][3]:.1f} s, run "
                  f"{out[label][1]:.2f} s (median of 2)", flush=True)
        (x_r, s_r, t_r, c_r), (x_w, s_w, t_w, c_w) = out["rows"], out["all at once"]
        rows.append(dict(n=n, rows_s=s_r, rows_times_s=t_r, rows_compile_s=c_r, whole_s=s_w,
                         whole_times_s=t_w, whole_compile_s=c_w, speedup=s_w / s_r,
                         difference=float(np.max(np.abs(x_r - x_w)) / np.max(np.abs(x_w)))))
    return rows


def one_size(n, dopri):
    """Part B at one n (a child process)."""
    system, ts, x0 = chain(n), jnp.asarray(TS), start(n)
    begin = time.perf_counter()
    x = np.asarray(mj.solve(system, ts, x0, method=mj.Spectral()).displacement)
    first = time.perf_counter() - begin
    run_s = first  # above 10^4 one call (compile included: ~3 s of ~220 s at 3 x 10^4)
    if n <= 10_000:
        begin = time.perf_counter()
        x = np.asarray(mj.solve(system, ts, x0, method=mj.Spectral()).displacement)
        run_s = time.perf_counter() - begin
    row = dict(n=n, run_s=run_s, first_call_s=first,
               compile_s=first - run_s if n <= 10_000 else None,
               peak_memory_gib=peak_gib(), max_abs_x=float(np.max(np.abs(x))),
               x0_error=float(np.max(np.abs(x[0] - np.asarray(x0)))),
               device=str(jax.devices()[0]))
    print(f"  n = {n}: exact_solve (401 times, all DOFs) first call {first:.1f} s, run "
          f"{run_s:.1f} s, peak memory {row['peak_memory_gib']:.2f} GiB", flush=True)
    if dopri:
        dofs = (1, 3, n // 2, n)
        begin = time.perf_counter()
        reference = mj.solve(system, ts, x0, dofs=dofs,
                             method=mj.ODE(rtol=1e-10, atol=1e-12, max_steps=10**7))
        reference = np.asarray(reference.displacement)
        mine = x[:, [d - 1 for d in dofs]]
        row.update(dopri8_s=time.perf_counter() - begin, dopri8_dofs=list(dofs),
                   dopri8_difference=float(np.max(np.abs(mine - reference))
                                           / np.max(np.abs(reference))))
        print(f"  n = {n}: Dopri8 (rtol 1e-10, DOFs {dofs}) {row['dopri8_s']:.1f} s, differs "
              f"by {row['dopri8_difference']:.1e} of max |x|", flush=True)
    return row


def part_b(sizes, dopri_all):
    rows = []
    for n in sizes:
        child = subprocess.run([sys.executable, __file__, "--one", str(n)]
                               + (["--dopri"] if dopri_all or n <= 10_000 else []),
                               capture_output=True, text=True, check=False)
        print(child.stdout, end="", flush=True)
        if child.returncode != 0:
            raise RuntimeError(f"n = {n} failed:\n{child.stderr[-3000:]}")
        rows.append(json.loads(child.stdout.strip().splitlines()[-1]))
    return rows


def plot(data, name):
    fig, (left, right) = figure(ncols=2, figsize=(11, 5.4), readable=True)
    a, b = data["part_a"], data["part_b"]
    if a:
        left.loglog([r["n"] for r in a], [r["whole_s"] for r in a], "o-",
                    label="all at once (U, (n, 2n) vectors)")
    left.loglog([r["n"] for r in a] + [r["n"] for r in b],
                [r["rows_s"] for r in a] + [r["run_s"] for r in b], "s-",
                label="rows (the library above n = 4096)")
    for r in b:
        left.annotate(f"{r['run_s']:.0f} s", (r["n"], r["run_s"]), xytext=(-10, 0),
                      textcoords="offset points", ha="right", va="center")
    left.set_xlabel("n (DOFs)")
    left.set_ylabel("exact_solve, 401 times x all DOFs: run time [s]")
    legend(left, "below")
    memory_panel(right, b, "rows", "the (n, 2n) complex vectors alone")
    fig.suptitle(f"Spectral response at large n, O(n (N + block)) memory\n"
                 f"{subtitle(data['metadata'])}")
    return save_figure(fig, name, data["quick"])


def main(argv=None):
    args = parse_args(__doc__, argv, replot=True,
                      one=dict(type=int, help="(internal) Part B at one n, JSON to stdout"),
                      dopri=dict(action="store_true", help="Dopri8 at every Part B size"),
                      sizes=dict(type=int, nargs="+", help="Part B at these n only"),
                      name=dict(default=NAME, help="the results' name"))
    if args.one:
        print(json.dumps(one_size(args.one, args.dopri)))
        return
    if args.replot:
        return print(plot(read_json(args.name, args.quick), args.name))
    begin = time.perf_counter()
    a = []
    if not args.sizes:
        print("Part A: rows against all at once", flush=True)
        a = part_a([4500] if args.quick else [5000, 8000])
        print_table(a, [("n", "n", "d"), ("whole_s", "all at once s", ".2f"),
                        ("rows_s", "rows s", ".2f"), ("speedup", "speed-up", ".2f"),
                        ("difference", "x diff", ".1e")])
    print("Part B: large n, each in its own process", flush=True)
    b = part_b(args.sizes or ([5000] if args.quick else [10_000, 30_000]), args.dopri)
    print_table(b, [("n", "n", "d"), ("compile_s", "compile s", ".1f"),
                    ("run_s", "run s", ".1f"), ("peak_memory_gib", "peak GiB", ".2f"),
                    ("x0_error", "x(0) err", ".1e"), ("dopri8_s", "Dopri8 s", ".1f"),
                    ("dopri8_difference", "vs Dopri8", ".1e")])
    path = write_json(args.name, args.quick, dict(
        problem=dict(chain="Mikota, m = k = 1", design=dict(position=DESIGN[0],
                     coefficient=DESIGN[1]), x0="x_3(0) = 1, v0 = 0",
                     outputs="displacement, every DOF, t = 0, 0.05, ..., 20 (401 times)"),
        part_a=a, part_b=b, total_wall_s=time.perf_counter() - begin))
    print(f"wrote {path} and {plot(read_json(args.name, args.quick), args.name)}")


if __name__ == "__main__":
    main()
