"""The full model's J and gradient by the spectral path at large n, in O(n) memory.

The crossover's n = 30000 row lacked the full model's J + gradient on this machine: the spectral
path formed (2n, n) and (2n, 2n) complex arrays (29 GB each there) and U (7.2 GB), and Dopri8 at
rtol 1e-10 did not finish in 25 min on 2 cores. The spectral engine now forms every per-root
row a block of roots at a time (above n = 512), and a chain above n = 4096 takes its modes' rows
and projections without U (``chain_mode_data``).

Problem (crossover's nominal design, the Section 5 setting at size n): Mikota's chain (m = k =
1), a grounded damper at p = 7 with c = 1, x_3(0) = 1, v(0) = 0, J = the energy on [0, 20];
J and dJ/d(p, c) by ``jax.jacfwd`` of ``Energy(method=Spectral())`` (what
``crossover.py`` times as the full spectral query).

* Part A (one process, n = 1000 and 3000): the library's choice (blocks) against the same
  engine all at once from U (``mikota_jax.testing.spectral_energy_with_result(..., block=0)``,
  the layout before the blocks); compile apart, median of 3 runs; J and gradient compared.
* Part B (each n in its own process, for its peak memory: n = 10^4 and 3 x 10^4): the library's
  choice; compile apart (ahead of time), then 2 runs at 10^4 and 1 at 3 x 10^4; the process's
  peak resident memory (VmHWM) after them; Dopri8's J alone at rtol 1e-6 (atol 1e-8,
  max_steps 10^6, as ``crossover.py``) timed after it in the same process at 10^4 (at 3 x 10^4
  with ``--dopri``: ~7 min).
  At 3 x 10^4 J and gradient are compared with the Dopri8 reference at rtol 1e-10 (J + two
  forward-mode tangents, run on an H100 GPU: ``results/crossover_reference_gpu.json``), an
  independent path.
* Part C (in the n = 3 x 10^4 process, after the spectral query): one query through the best
  reduced model of ``crossover.py`` there, Craig-Bampton + x0 at its rank r = 840 (J within 1e-4
  at this design the day before): basis build (warm) + J + gradient, compile apart, its J and
  gradient against the spectral ones; so the ROM's speed-up over the full path is measured in
  one process.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/spectral_energy_large.py [--quick] [--dopri]``
(``--quick``: n = 600 and 1000 in Part A, 5000 in Part B). Writes
``results/spectral_energy_large.json`` and ``.png``; ``--replot`` redraws the figure.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (RESULTS, Compiled, figure, legend, parse_args,  # noqa: I001
                     print_table, read_json, save_figure, subtitle, timed, write_json)

import json
import resource
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import crossover
import mikota_jax as mj
from mikota_jax.testing import spectral_energy_with_result

HORIZON = 20.0
DESIGN = (7.0, 1.0)  # crossover's nominal design: p, c
REFERENCE = RESULTS / "crossover_reference_gpu.json"
ROM_RANKS = {30_000: 840, 5000: 360}  # Part C: crossover_30000's Craig-Bampton + x0 rank (J
# within 1e-4 there); 5000 for --quick (r ~ n^0.5 between crossover's ranks)


def start(n):
    return jnp.zeros(n).at[2].set(1.0)


def query(n, block):
    """design (p, c) -> (J, dJ/d(p, c), ok) by the spectral path at size n, ``block`` as
    ``spectral_energy_with_result`` (None: the library's choice; 0: all at once from U)."""
    def energy(design):
        system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(design[0], design[1])])
        return spectral_energy_with_result(system, HORIZON, start(n), jnp.zeros(n),
                                           block=block)

    def with_aux(design):
        value, ok = energy(design)
        return value, (value, ok)

    def value_and_gradient(design):  # one forward pass: J and ok ride along as aux
        jacobian, (value, ok) = jax.jacfwd(with_aux, has_aux=True)(design)
        return value, jacobian, ok

    return value_and_gradient


def compiled_query(n, block):
    return Compiled(query(n, block), jnp.array(DESIGN))


def part_a(sizes):
    """Blocks against all at once, one process."""
    rows = []
    for n in sizes:
        out = {}
        for label, block in (("blocks", None), ("all at once", 0)):
            fn = compiled_query(n, block)
            (value, jacobian, ok), run_s, times = timed(fn, jnp.array(DESIGN), repeats=3)
            assert bool(ok), f"n = {n}, {label}: the spectral path did not hold"
            out[label] = (float(value), np.asarray(jacobian), fn.compile_s, run_s, times)
            print(f"  n = {n}, {label}: compile {fn.compile_s:.1f} s, run {run_s:.2f} s "
                  f"(median of 3), J = {float(value):.12g}", flush=True)
        (j_b, g_b, c_b, r_b, t_b), (j_w, g_w, c_w, r_w, t_w) = out["blocks"], out["all at once"]
        rows.append(dict(n=n, blocks_s=r_b, blocks_times_s=t_b, blocks_compile_s=c_b,
                         whole_s=r_w, whole_times_s=t_w, whole_compile_s=c_w,
                         speedup=r_w / r_b, J=j_b, gradient=g_b.tolist(),
                         J_difference=abs(j_b / j_w - 1),
                         gradient_difference=float(np.max(np.abs(g_b / g_w - 1)))))
    return rows


def peak_gib():
    """This process's peak resident memory so far, GiB: VmHWM of /proc/self/status (Linux; it
    belongs to the address space that exec made), else ``ru_maxrss``, which Linux carries over
    from the parent through fork and exec (the parent's Part A at n = 3000 all at once made
    every child report 11.4 GiB)."""
    try:
        for line in open("/proc/self/status"):
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 2**20  # kB
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def rom_query_at(n, rank, j_full, gradient_full):
    """Part C in the same process: one query through crossover's best reduced model at n,
    Craig-Bampton + x0 at ``rank`` (crossover's ``craig_bampton_basis(system, r - 7,
    states=x0)``): the basis build, then J + gradient (``SceneFunction(model="reduced",
    forward=True)`` under ``jacfwd``), compile apart; errors against the spectral J, gradient."""
    scene = crossover.scene_for(n)
    nominal = crossover.design(*DESIGN)
    build = lambda: jax.block_until_ready(  # noqa: E731
        crossover.craig_bampton(scene.system, scene.x0, rank))
    build()  # warm-up, as crossover.py (compiles the shapes of r)
    start = time.perf_counter()
    basis = build()
    build_s = time.perf_counter() - start
    rom = mj.SceneFunction(scene, "energy", model="reduced", basis=basis, forward=True)
    query = Compiled(crossover.rom_query, rom, nominal)
    (value, jacobian), online_s, _ = timed(query, rom, nominal, repeats=1)
    rom_gradient = np.array([float(jacobian["positions"][0]), float(jacobian["coefficients"][0])])
    out = dict(method="Craig-Bampton + x0", r=int(basis.shape[1]), build_s=build_s,
               compile_s=query.compile_s, online_s=online_s, query_s=build_s + online_s,
               J_error=abs(float(value) / j_full - 1),
               gradient_error=float(np.max(np.abs(rom_gradient / gradient_full - 1))))
    print(f"  n = {n}: ROM (Craig-Bampton + x0, r = {out['r']}): build {build_s:.1f} s, "
          f"J + gradient {online_s:.1f} s (compile {query.compile_s:.1f} s); J "
          f"{out['J_error']:.1e}, gradient {out['gradient_error']:.1e} off the spectral ones",
          flush=True)
    return out


def one_size(n, dopri, rom_rank=None):
    """Part B at one n (run in a child process): the library's choice, then a ROM query
    (``rom_rank``: Part C) and Dopri8's J alone."""
    begin = time.perf_counter()
    fn = compiled_query(n, None)
    repeats = 2 if n <= 10_000 else 1
    (value, jacobian, ok), run_s, times = timed(fn, jnp.array(DESIGN), repeats=repeats)
    row = dict(n=n, compile_s=fn.compile_s, run_s=run_s, run_times_s=times, ok=bool(ok),
               J=float(value), gradient=np.asarray(jacobian).tolist())
    row["peak_memory_gib"] = peak_gib()  # before Dopri8, whose own peak is recorded apart
    print(f"  n = {n}: J + gradient compile {fn.compile_s:.1f} s, run {run_s:.1f} s, "
          f"J = {float(value):.12g}, dJ/d(p, c) = {np.asarray(jacobian)}, peak memory "
          f"{row['peak_memory_gib']:.2f} GiB", flush=True)
    if rom_rank:
        row["rom"] = rom_query_at(n, rom_rank, float(value), np.asarray(jacobian))
    if dopri:
        system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(*DESIGN)])

        def dopri8(x0):
            method = mj.ODE(rtol=1e-6, atol=1e-8, max_steps=10**6)
            return mj.Energy(HORIZON, x0, method=method)(system)

        exe = Compiled(dopri8, start(n))
        dopri_value, dopri_s, _ = timed(exe, start(n), repeats=1)
        row.update(dopri8_J_alone_s=dopri_s, dopri8_compile_s=exe.compile_s,
                   dopri8_J_difference=abs(float(dopri_value) / float(value) - 1))
        row["peak_memory_with_dopri8_gib"] = peak_gib()
        print(f"  n = {n}: Dopri8 J alone (rtol 1e-6) {dopri_s:.1f} s, differs from the "
              f"spectral J by {row['dopri8_J_difference']:.1e}; the process's peak memory "
              f"then {row['peak_memory_with_dopri8_gib']:.2f} GiB", flush=True)
    row["wall_s"] = time.perf_counter() - begin
    return row


def part_b(sizes, dopri_all):
    rows = []
    for n in sizes:
        dopri = dopri_all or n <= 10_000
        child = subprocess.run([sys.executable, __file__, "--one", str(n)]
                               + (["--dopri"] if dopri else []),
                               capture_output=True, text=True, check=False)
        print(child.stdout, end="", flush=True)
        if child.returncode != 0:
            raise RuntimeError(f"n = {n} failed:\n{child.stderr[-3000:]}")
        row = json.loads(child.stdout.strip().splitlines()[-1])
        reference = json.loads(REFERENCE.read_text())["references"].get(str(n))
        if reference is not None:
            g = reference["gradient"]
            ref_gradient = np.array([g["positions"], g["coefficients"]])
            row.update(reference=f"{reference['method']} ({reference['device']}, "
                                 f"{REFERENCE.name})",
                       reference_J_difference=abs(row["J"] / reference["J"] - 1),
                       reference_gradient_difference=float(np.max(np.abs(
                           np.array(row["gradient"]) / ref_gradient - 1))))
        rows.append(row)
    return rows


def memory_panel(ax, rows, path, array):
    """Peak memory of each Part B process against one (2n, n) complex array (``array``)."""
    ax.loglog([r["n"] for r in rows], [r["peak_memory_gib"] for r in rows], "s-",
              label=f"peak memory of the process ({path})")
    ns = np.array([r["n"] for r in rows], dtype=float)
    ax.loglog(ns, 2 * ns**2 * 16 / 2**30, "--", color="gray", label=array)
    ax.set_xlabel("n (DOFs)")
    ax.set_ylabel("GiB")
    legend(ax, "below")


def plot(data):
    fig, (left, right) = figure(ncols=2, figsize=(11, 5.4), readable=True)
    a, b = data["part_a"], data["part_b"]
    left.loglog([r["n"] for r in a], [r["whole_s"] for r in a], "o-", label="all at once (U)")
    sizes = [r["n"] for r in a] + [r["n"] for r in b]
    left.loglog(sizes, [r["blocks_s"] for r in a] + [r["run_s"] for r in b], "s-",
                label="blocks of roots (the library)")
    dopri = [(r["n"], r["dopri8_J_alone_s"]) for r in b if "dopri8_J_alone_s" in r]
    if dopri:
        left.loglog(*zip(*dopri), "^", ms=9, mfc="none", label="Dopri8, J alone, rtol 1e-6")
    roms = [(r["n"], r["rom"]["query_s"]) for r in b if "rom" in r]
    if roms:
        left.loglog(*zip(*roms), "D", ms=8, mfc="none", color="tab:purple",
                    label="ROM query (Craig-Bampton + x0, build + J + gradient)")
    for r in b:
        text = f"{r['run_s']:.0f} s" + (f"\n(Dopri8 J: {r['dopri8_J_alone_s']:.0f} s)"
                                         if "dopri8_J_alone_s" in r else "")
        left.annotate(text, (r["n"], r["run_s"]), xytext=(-10, 0), textcoords="offset points",
                      ha="right", va="center")
    left.set_ylim(top=3 * max(r["run_s"] for r in b))
    left.set_xlabel("n (DOFs)")
    left.set_ylabel("J + dJ/d(p, c): run time [s]")
    legend(left, "below")
    memory_panel(right, b, "blocks", "one (2n, n) complex array")
    right.set_ylim(1, 100)
    fig.suptitle(f"Spectral J + gradient at large n, O(n) memory\n{subtitle(data['metadata'])}")
    save_figure(fig, "spectral_energy_large", data["quick"])


def main(argv=None):
    args = parse_args(__doc__, argv, replot=True,
                      one=dict(type=int, help="(internal) Part B at one n, JSON to stdout"),
                      dopri=dict(action="store_true",
                                 help="Dopri8's J alone at every Part B size (~14 min at 3e4)"))
    if args.one:
        print(json.dumps(one_size(args.one, args.dopri, ROM_RANKS.get(args.one))))
        return
    if args.replot:
        return plot(read_json("spectral_energy_large", args.quick))
    begin = time.perf_counter()
    print("Part A: blocks against all at once", flush=True)
    a = part_a([600, 1000] if args.quick else [1000, 3000])
    print_table(a, [("n", "n", "d"), ("whole_s", "all at once s", ".2f"),
                    ("blocks_s", "blocks s", ".2f"), ("speedup", "speed-up", ".2f"),
                    ("J_difference", "J diff", ".1e"),
                    ("gradient_difference", "grad diff", ".1e")])
    print("Part B: large n, each in its own process", flush=True)
    b = part_b([5000] if args.quick else [10_000, 30_000], args.dopri)
    print_table(b, [("n", "n", "d"), ("compile_s", "compile s", ".1f"),
                    ("run_s", "run s", ".1f"), ("peak_memory_gib", "peak GiB", ".2f"),
                    ("dopri8_J_alone_s", "Dopri8 J alone s", ".1f"),
                    ("reference_J_difference", "J vs reference", ".1e"),
                    ("reference_gradient_difference", "grad vs reference", ".1e")])
    for r in b:
        if "rom" in r:
            rom = r["rom"]
            rom["speedup"] = r["run_s"] / rom["query_s"]
            print(f"n = {r['n']}: one query through the ROM ({rom['method']}, r = {rom['r']}) "
                  f"{rom['query_s']:.1f} s (build {rom['build_s']:.1f} s + J + gradient "
                  f"{rom['online_s']:.1f} s) against the full spectral {r['run_s']:.1f} s: "
                  f"{rom['speedup']:.1f}x, J {rom['J_error']:.1e} and gradient "
                  f"{rom['gradient_error']:.1e} off the full model's")
    path = write_json("spectral_energy_large", args.quick, dict(
        problem=dict(chain="Mikota, m = k = 1", design=dict(position=DESIGN[0],
                     coefficient=DESIGN[1]), x0="x_3(0) = 1, v0 = 0", J="energy on [0, 20]",
                     derivative="jax.jacfwd in (p, c)"),
        part_a=a, part_b=b, total_wall_s=time.perf_counter() - begin))
    plot(read_json("spectral_energy_large", args.quick))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
