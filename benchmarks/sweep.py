"""A 10^4-point parameter sweep of the paper's Section 5 scene: full model and ROM, by mj.sweep.

The energy objective int_0^20 (x^T K x + x'^T M x') / 2 dt of the Section 5 scene (n = 300,
x_3(0) = 1) on a grid of 100 damper positions (1 ... 300) x 100 coefficients (0.1 ... 10, log);
``--quick``: 10 x 10. Evaluated three ways, each a ``SceneFunction`` swept by ``mj.sweep``:

* ROM, exact: the Galerkin model of the scene's 99.99 % POD basis (r = 98, held fixed), energy by
  matrix exponentials, ``batch="map"`` (under vmap every Pade branch of expm would be computed);
* full model, Dopri8: n = 300, the energy as one more state (rtol 1e-8), ``batch="map"``;
* ``--quick`` only: both Dopri8 variants vmapped, to show why "map" is the CPU default (a vmapped
  adaptive solve steps every lane until the stiffest point of the chunk is done).

Coefficients stop at 10: beyond, a damper near the free end makes the full chain stiff for Dopri8
(rate c i / m up to 3e3 at c = 10) and a vmapped chunk runs as long as its stiffest point.
Compile time is reported apart (a first call on one chunk, then the whole sweep from the cache);
before timing, 8 random points are checked against unbatched evaluations.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/sweep.py [--quick]``. Writes
``benchmarks/results/sweep.json`` and ``.png`` (``--quick``: ``sweep_quick.*``).
"""

import time

import _common  # noqa: F401  (sets OPENBLAS_NUM_THREADS before jax)
import jax
import jax.numpy as jnp
import numpy as np
from _common import figure, parse_args, print_table, read_json, save_figure, subtitle, write_json

import mikota_jax as mj


def scene(solver: str):
    text = f"""
name = "section5_{solver}"
[chain]
n = 300
[[damper]]
position = 7
coefficient = 1.0
[initial]
displacement = {{ 3 = 1.0 }}
[time]
end = 20.0
step = 0.01
[solver]
method = "{solver}"
rtol = 1e-8
atol = 1e-10
max_steps = 200000
[reduction]
snapshots = [0.0, 10.0]
energy = 0.9999
criterion = "paper"
"""
    return mj.app.load_scene(text)


def unbatched(function, points, index):
    return np.array([float(function({k: jnp.asarray(v[i]) for k, v in points.items()}))
                     for i in index])


def plot(data: dict) -> None:
    """(a) the full model's energy over the grid, (b) the ROM's relative error there."""
    if "values" not in data:
        raise SystemExit("this sweep.json holds no grid values (written before they were "
                         "stored): only a full run can draw its figure")
    values = data["values"]
    full, rom = np.asarray(values["J_full"]), np.asarray(values["J_rom"])
    rank = next(r["rank"] for r in data["rows"] if r["variant"] == "ROM exact (map)")
    fig, axes = figure(ncols=2, figsize=(11, 4.8), readable=True)
    for ax, image, label, cmap, title in (
            (axes[0], np.log10(full), "log10 J, full model (dimensionless)", "viridis",
             f"(a) Section 5 energy, {full.size} points"),
            (axes[1], np.log10(np.abs(rom - full) / full),
             "log10 |J_ROM - J_full| / J_full (dimensionless)", "magma",
             f"(b) ROM (r = {rank}) relative error")):
        mesh = ax.pcolormesh(values["coefficients"], values["positions"], image,
                             shading="nearest", cmap=cmap)
        fig.colorbar(mesh, ax=ax, label=label)
        ax.set(xscale="log", xlabel="damper coefficient c (dimensionless)",
               ylabel="damper position (DOF index)", title=title)
    fig.suptitle(f"mj.sweep over the Section 5 scene: {subtitle(data['metadata'])}")
    save_figure(fig, "sweep", data["quick"])


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return plot(read_json("sweep", args.quick))
    size = 10 if args.quick else 100
    points = mj.grid(positions=np.linspace(1.0, 300.0, size)[:, None],
                     coefficients=np.geomspace(0.1, 10.0, size)[:, None])
    total = size * size
    exact_scene, ode_scene = scene("exact"), scene("dopri8")
    start = time.perf_counter()
    basis = mj.SceneFunction(exact_scene, "energy", model="reduced").basis
    offline_s = time.perf_counter() - start
    variants = {
        "ROM exact (map)": (mj.SceneFunction(exact_scene, "energy", model="reduced",
                                             basis=basis), "map"),
        "full Dopri8 (map)": (mj.SceneFunction(ode_scene, "energy"), "map"),
    }
    if args.quick:  # vmapped adaptive solves: every lane steps until the stiffest one is done
        variants["ROM Dopri8 (vmap)"] = (mj.SceneFunction(ode_scene, "energy", model="reduced",
                                                          basis=basis), "vmap")
        variants["full Dopri8 (vmap)"] = (mj.SceneFunction(ode_scene, "energy"), "vmap")
    rng = np.random.default_rng(0)
    check = rng.choice(total, size=min(8, total), replace=False)
    rows, values = [], {}
    for name, (function, batch) in variants.items():
        chunk = 64
        first = {k: v[:chunk] for k, v in points.items()}
        start = time.perf_counter()
        mj.sweep(function, first, chunk_size=chunk, batch=batch, progress=False)
        cold_s = time.perf_counter() - start
        start = time.perf_counter()
        mj.sweep(function, first, chunk_size=chunk, batch=batch, progress=False)
        chunk_s = time.perf_counter() - start
        start = time.perf_counter()
        result = mj.sweep(function, points, chunk_size=chunk, batch=batch, progress=True)
        run_s = time.perf_counter() - start
        reference = unbatched(function, points, check)
        deviation = float(np.max(np.abs(result[check] - reference) / np.abs(reference)))
        values[name] = result
        rows.append(dict(variant=name, points=total, rank=None if "full" in name else
                         basis.shape[1], compile_s=cold_s - chunk_s, run_s=run_s,
                         per_point_ms=1e3 * run_s / total, vs_unbatched=deviation))
        print(f"{name}: {run_s:.1f} s for {total} points ({1e3 * run_s / total:.2f} ms/point), "
              f"compile ~{cold_s - chunk_s:.1f} s, max rel. deviation from unbatched "
              f"{deviation:.1e}")
    full = values["full Dopri8 (map)"]
    for row in rows:
        row["vs_full"] = float(np.max(np.abs(values[row["variant"]] - full) / np.abs(full)))
    print_table(rows, [("variant", "variant", "s"), ("points", "points", "d"),
                       ("rank", "r", "d"), ("compile_s", "compile s", ".1f"),
                       ("run_s", "run s", ".1f"), ("per_point_ms", "ms/point", ".2f"),
                       ("vs_unbatched", "vs unbatched", ".1e"), ("vs_full", "vs full", ".1e")])
    best = int(np.argmin(full))
    summary = dict(grid=[size, size], positions=[1.0, 300.0], coefficients=[0.1, 10.0],
                   offline_s=offline_s, rows=rows, devices=[str(d) for d in jax.devices()],
                   best_full=dict(position=float(points["positions"][best, 0]),
                                  coefficient=float(points["coefficients"][best, 0]),
                                  J=float(full[best])))
    rom = values["ROM exact (map)"]
    summary["values"] = dict(positions=points["positions"][::size, 0],
                             coefficients=points["coefficients"][:size, 0],
                             J_full=full.reshape(size, size), J_rom=rom.reshape(size, size))
    print(f"wrote {write_json('sweep', args.quick, summary)}")
    plot(read_json("sweep", args.quick))
    return summary


if __name__ == "__main__":
    main()
