"""Several dampers on the paper's Section 5 chain: the coordinate-wise search
(``CoordinateDescent``) against a brute-force enumeration on a coarse grid (the target: same or
better objective, >= 100x faster).

The scene: Mikota's chain, n = 300, x_3(0) = 1, the integrated energy on [0, 20] (the paper's
Section 5 objective), g grounded dampers placed on the candidate DOFs 1..10 (where the one-damper
optimum, DOF 4, lies). Every value is exact and at full order (the spectral path).

* ours: ``CoordinateDescent`` from dampers at DOFs 8, 9 (10) with coefficient 10, cold (compiling,
  timed whole) and, for g = 2, warm (the same call again; for g = 3 the cold run is the only
  one: a second would double the benchmark's ~25 min);
* the enumeration: every placement of g dampers on the candidates times every coefficient on a
  log grid of 5 values per damper, one compiled ``lax.map`` over the designs (compiled before
  the clock starts). For g = 2 it runs whole (45 x 25 designs); for g = 3 (120 x 125 designs)
  its time is the measured time per design (a run over 200 of them) times the count, an
  estimate stated as such.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/damper_search.py [--quick]`` (``--quick``:
n = 60, g = 2 only). Writes ``results/damper_search[_quick].json`` and ``.png``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (figure, legend, parse_args, print_table, read_json,  # noqa: I001
                     save_figure, subtitle, write_json)

import itertools
import time

import jax
import jax.numpy as jnp
import numpy as np

import mikota_jax as mj

NAME = "damper_search"
CANDIDATES = tuple(range(1, 11))
GRID = (3.0, 10.0, 30.0, 100.0, 300.0)
HORIZON = 20.0


def system(n, positions, coefficients):
    return mj.mikota_chain(n, dampers=[mj.GroundedDamper(p, c)
                                       for p, c in zip(positions, coefficients)])


def enumeration_function(n, g, x0):
    """designs (D, g) positions and (D, g) coefficients -> (D,) energies, compiled."""
    def one(design):
        positions, coefficients = design
        return mj.Energy(HORIZON, x0)(system(n, [positions[i] for i in range(g)],
                                           [coefficients[i] for i in range(g)]))

    return jax.jit(lambda p, c: jax.lax.map(one, (p, c)))


def designs(g):
    rows = [(p, c) for p in itertools.combinations(CANDIDATES, g)
            for c in itertools.product(GRID, repeat=g)]
    return (jnp.asarray([r[0] for r in rows], dtype=jnp.float64),
            jnp.asarray([r[1] for r in rows], dtype=jnp.float64))


def plot(data: dict) -> None:
    """Wall time of ours (warm) and of the enumeration per damper count, the ratio on top."""
    runs = data["runs"]
    fig, ax = figure(figsize=(6.5, 4.6), readable=True)
    x = np.arange(len(runs))
    ours = [r["ours_warm_s"] for r in runs]
    enumeration = [r["enumeration_s"] for r in runs]
    bars = ax.bar(x - 0.2, ours, 0.4, label="CoordinateDescent (warm)")
    ax.bar_label(bars, [f"{t:.1f} s" for t in ours], padding=2)
    bars = ax.bar(x + 0.2, enumeration, 0.4, label="enumeration on the 5-value grid")
    ax.bar_label(bars, [f"{t:.0f} s" + ("" if r["enumeration_run_whole"] else "\n(estimated)")
                        for t, r in zip(enumeration, runs)], padding=2)
    for i, r in enumerate(runs):
        ax.text(i, 4 * enumeration[i], f"ours {r['speedup_warm']:.1f}x faster", ha="center",
                weight="bold")
    ax.set_yscale("log")
    ax.set_ylim(10, 20 * max(enumeration))
    ax.set_xticks(x, [f"{r['g']} dampers" for r in runs])
    ax.set_xlabel("dampers placed (candidates DOF 1..10)")
    ax.set_ylabel("wall time [s]")
    legend(ax, "below", ncol=2)
    fig.suptitle(f"Damper placement, Mikota n = {data['n']}, x_3(0) = 1, energy on "
                 f"[0, {data['horizon']:g}]\n" + subtitle(data["metadata"]))
    save_figure(fig, NAME, data["quick"])


def main(argv=None) -> None:
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return plot(read_json(NAME, args.quick))
    n = 60 if args.quick else 300
    x0 = np.zeros(n)
    x0[2] = 1.0
    rows, runs = [], []
    for g in (2,) if args.quick else (2, 3):
        start = system(n, list(range(8, 8 + g)), [10.0] * g)
        t = time.perf_counter()
        design = mj.DamperDesign(start, mj.Energy(HORIZON, x0), positions=CANDIDATES)
        warm = mj.optimise(design, mj.CoordinateDescent(progress=True))
        cold_s = time.perf_counter() - t
        if g == 2:
            warm = mj.optimise(design, mj.CoordinateDescent())
        stats = warm.stats
        print(f"g = {g}: CoordinateDescent {warm.positions.tolist()} "
              f"{np.round(warm.coefficients, 4).tolist()} J = {warm.value:.10g} "
              f"({stats['sweeps']} sweeps, {stats['evaluations']} screening values, "
              f"{stats['polishes']} polishes): cold {cold_s:.1f} s, warm {stats['seconds']:.1f} s "
              "(g = 3: the cold run)", flush=True)
        positions, coefficients = designs(g)
        count = positions.shape[0]
        evaluate = enumeration_function(n, g, jnp.asarray(x0))
        jax.block_until_ready(evaluate(positions[:2], coefficients[:2]))  # compile
        whole = g == 2
        sample = count if whole else 200
        t = time.perf_counter()
        values = np.asarray(jax.block_until_ready(evaluate(positions[:sample],
                                                           coefficients[:sample])))
        sample_s = time.perf_counter() - t
        enumeration_s = sample_s * count / sample
        best = int(np.argmin(values))
        row = dict(g=g, ours_positions=warm.positions.tolist(),
                   ours_coefficients=warm.coefficients.tolist(), ours_value=warm.value,
                   ours_cold_s=cold_s, ours_warm_s=stats["seconds"], sweeps=stats["sweeps"],
                   screening_values=stats["evaluations"], polishes=stats["polishes"],
                   designs=count, enumeration_s=enumeration_s, enumeration_run_whole=whole,
                   enumeration_seconds_per_design=sample_s / sample,
                   enumeration_best_value=float(values[best]) if whole else None,
                   enumeration_best_positions=np.asarray(positions[best]).tolist()
                   if whole else None,
                   enumeration_best_coefficients=np.asarray(coefficients[best]).tolist()
                   if whole else None,
                   speedup_warm=enumeration_s / stats["seconds"],
                   speedup_cold=enumeration_s / cold_s)
        runs.append(row)
        rows.append(dict(g=g, ours=f"{warm.value:.8g} at {warm.positions.astype(int).tolist()}",
                         enum=(f"{values[best]:.8g} at "
                               f"{np.asarray(positions[best]).astype(int).tolist()}"
                               if whole else "not run whole"),
                         warm=stats["seconds"], cold=cold_s, enum_s=enumeration_s,
                         speedup=row["speedup_warm"]))
        if whole:
            print(f"  enumeration: {count} designs in {enumeration_s:.1f} s, best "
                  f"J = {values[best]:.10g} at {np.asarray(positions[best]).tolist()} "
                  f"{np.asarray(coefficients[best]).tolist()}; ours is "
                  f"{'lower or equal' if warm.value <= values[best] else 'HIGHER'}", flush=True)
        else:
            print(f"  enumeration (estimate): {count} designs x {sample_s / sample:.3f} s = "
                  f"{enumeration_s:.0f} s", flush=True)
        print(f"  speed-up: {row['speedup_warm']:.1f}x warm, {row['speedup_cold']:.1f}x cold "
              f"(target >= 100x)", flush=True)
        write_json(NAME, args.quick, dict(n=n, candidates=list(CANDIDATES), grid=list(GRID),
                                          horizon=HORIZON, runs=runs))  # so far
    print_table(rows, [("g", "dampers", "d"), ("ours", "CoordinateDescent: J at DOFs", "s"),
                       ("enum", "enumeration: J at DOFs", "s"), ("warm", "ours warm s", ".1f"),
                       ("cold", "ours cold s", ".1f"), ("enum_s", "enumeration s", ".0f"),
                       ("speedup", "speed-up (warm)", ".1f")])
    write_json(NAME, args.quick, dict(n=n, candidates=list(CANDIDATES), grid=list(GRID),
                                      horizon=HORIZON, runs=runs))
    plot(read_json(NAME, args.quick))


if __name__ == "__main__":
    main()
