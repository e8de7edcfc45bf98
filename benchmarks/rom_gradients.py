"""ROM gradients across the design space: plain POD against sensitivity-enriched POD.

The Section 5 scene (Mikota n = 300, x_3(0) = 1, exact solves on [0, 20], snapshots on [0, 10]);
J = the scene's time-integrated energy; the design is the grounded damper's (position p,
coefficient c) on a grid spanning the chain (p = 7 .. 290) and the coefficient range (0.1 ..
1000). At every design: the full model's dJ/dp, dJ/dc (``sensitivities``, spectral path) and the
ROM's on a basis built *at that design*, (a) plain POD of the states (``reduce``) and (b) the
sensitivity-enriched POD (``EnrichedPOD``: states and their forward-mode derivatives in p and
c, each block weighted to the states' norm), both at the paper's r = 98 and at each basis' own
99.99 % rank (the paper's criterion), and (c) no snapshots: the 94 lowest undamped modes and two
static moments of the damper directions (``modal_static_basis(system, 94, moments=2)``, r <= 98),
(d) no snapshots, Craig-Bampton: the 92 lowest modes of the chain held at the damper's DOF
and three static moments of its two DOFs (``craig_bampton_basis(system, 92)``, r <= 98), and
(c') and (d') the same with the start kept: one mode fewer (93 and 91) and the initial
displacement and velocity added as they are (``states=``), so the ROM starts where the full
model does.
Error = max over (p, c) of |ROM / full - 1|.

Target: within 1e-3 relative at r <= 98 on every design. Cost: offline (basis) time
per design, warm (compiled once: the first design is the compile), median over the grid.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/rom_gradients.py [--quick] [--replot]``
(``--quick``: a 2 x 2 grid). Writes ``results/rom_gradients[_quick].json`` and ``.png``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (elapsed, figure, parse_args, print_table, read_json,  # noqa: I001
                     save_figure, subtitle, write_json)

import statistics
import time

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import mikota_jax as mj

NAME = "rom_gradients"
SCENE = "section5_damped"
RANK = 98  # the paper's 99.99 % rank
ENERGY = 0.9999
TARGET = 1e-3
WRT = ("positions", "coefficients")
POSITIONS = (7.0, 75.0, 150.0, 225.0, 290.0)
COEFFICIENTS = (0.1, 1.0, 10.0, 100.0, 1000.0)


def errors(scene, design, basis, full) -> dict:
    rom = mj.sensitivities(scene, "energy", wrt=WRT, parameters=design, model="reduced",
                           basis=basis)
    return {name: abs(float(rom.jacobian[name][0]) / float(full.jacobian[name][0]) - 1)
            for name in WRT} | {"J": abs(float(rom.value) / float(full.value) - 1)}


def one_design(scene, p: float, c: float) -> dict:
    design = {"positions": jnp.array([p]), "coefficients": jnp.array([c])}
    full = mj.sensitivities(scene, "energy", wrt=WRT, parameters=design)
    row = dict(position=p, coefficient=c, J=float(full.value),
               dJdp=float(full.jacobian["positions"][0]),
               dJdc=float(full.jacobian["coefficients"][0]))
    start = time.perf_counter()
    system = mj.SceneFunction(scene, "energy").system(design)
    at_design = eqx.tree_at(lambda s: s.system, scene, system)
    plain = mj.reduce(at_design, mj.POD(scene.reduction.window, energy=ENERGY,
                                        criterion="paper"))
    row["plain_offline_s"] = elapsed(start)
    start = time.perf_counter()
    enriched = mj.reduce(scene, mj.EnrichedPOD(WRT, parameters=design, energy=ENERGY))
    row["enriched_offline_s"] = elapsed(start)
    row["plain_rank"], row["enriched_rank"] = plain.rank, enriched.rank
    # no snapshots, RANK columns each: modes + 2 moments of the damper's two DOFs; held modes +
    # 3 moments; the same with the start (x0, and v0 where the scene sets one) kept
    start_states = jnp.stack([v for v in (scene.x0, scene.v0) if v is not None], axis=1)
    for label, build in (
            ("moments", lambda: mj.reduce(system, mj.ModalStatic(RANK, moments=2)).basis),
            ("held", lambda: mj.reduce(system, mj.CraigBampton(RANK)).basis),
            ("moments_start", lambda: mj.reduce(system, mj.ModalStatic(
                RANK, moments=2, states=start_states)).basis),
            ("held_start", lambda: mj.reduce(system, mj.CraigBampton(
                RANK, states=start_states)).basis)):
        start = time.perf_counter()
        basis = build()
        row[f"{label}_offline_s"] = elapsed(start)
        e = errors(scene, design, basis, full)
        row[f"{label}_r98"] = max(e["positions"], e["coefficients"])
        row[f"{label}_r98_J"], row[f"{label}_r98_p"], row[f"{label}_r98_c"] = (
            e["J"], e["positions"], e["coefficients"])
        row[f"{label}_rank"] = int(basis.shape[1])
    for label, pod, own in (("plain", plain.stats.decomposition, plain.rank),
                            ("enriched", enriched.stats.decomposition, enriched.rank)):
        for tag, r in (("r98", RANK), ("own", own)):
            e = errors(scene, design, pod.basis(r), full)
            row[f"{label}_{tag}"] = max(e["positions"], e["coefficients"])
            row[f"{label}_{tag}_J"] = e["J"]
    return row


def plot(data: dict, quick: bool):
    rows = data["rows"]
    positions = sorted({r["position"] for r in rows})
    coefficients = sorted({r["coefficient"] for r in rows})
    fig, axes = figure(nrows=6, figsize=(9, 24.5), readable=True)
    for ax, label, title in ((axes[0], "plain", "(a) POD of the states"),
                             (axes[1], "enriched", "(b) sensitivity-enriched POD"),
                             (axes[2], "moments", "(c) modes + 2 damper moments"),
                             (axes[3], "held", "(d) Craig-Bampton: held modes + 3 moments"),
                             (axes[4], "moments_start", "(c') (c) with the start kept"),
                             (axes[5], "held_start", "(d') (d) with the start kept")):
        grid = np.full((len(coefficients), len(positions)), np.nan)
        for r in rows:
            grid[coefficients.index(r["coefficient"]), positions.index(r["position"])] = max(
                r[f"{label}_r98"], 1e-12)
        ax.imshow(np.log10(grid), origin="lower", cmap="viridis", vmin=-8, vmax=0,
                          aspect="auto")
        for i in range(len(coefficients)):
            for j in range(len(positions)):
                value = grid[i, j]
                ax.text(j, i, f"{value:.1e}", ha="center", va="center",
                        color="w" if value < 10 ** -4 else "k")
        ax.set_xticks(range(len(positions)), [f"{p:g}" for p in positions])
        ax.set_yticks(range(len(coefficients)), [f"{c:g}" for c in coefficients])
        ax.set_xlabel("damper position p (DOF, dimensionless chain)")
        ax.set_ylabel("damper coefficient c (dimensionless)")
        worst = max(r[f"{label}_r98"] for r in rows)
        ax.set_title(f"{title}: worst {worst:.1e}")
    # the header as the first panel's title: tight_layout leaves room for it (not a suptitle's)
    axes[0].set_title(f"Section 5 scene: max relative error of the ROM's dJ/dp, dJ/dc at r <= "
                      f"{RANK},\nbasis built at each design (colour: log10 of the error, 1e-8 "
                      f"to 1; target {TARGET:g})\n" + subtitle(data["metadata"]) + "\n\n"
                      + axes[0].get_title())
    return save_figure(fig, NAME, quick)


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return print(plot(read_json(NAME, args.quick), args.quick))
    positions = (7.0, 290.0) if args.quick else POSITIONS
    coefficients = (1.0, 100.0) if args.quick else COEFFICIENTS
    scene = mj.app.load_scene(SCENE)
    start = time.perf_counter()
    rows = []
    for c in coefficients:
        for p in positions:
            rows.append(one_design(scene, p, c))
            r = rows[-1]
            print(f"p = {p:g}, c = {c:g}: plain r98 {r['plain_r98']:.1e} (own r = "
                  f"{r['plain_rank']}: {r['plain_own']:.1e}), enriched r98 "
                  f"{r['enriched_r98']:.1e} (own r = {r['enriched_rank']}: "
                  f"{r['enriched_own']:.1e})", flush=True)
    print_table(rows, [("position", "p", "g"), ("coefficient", "c", "g"), ("dJdp", "dJ/dp", ".5g"),
                       ("dJdc", "dJ/dc", ".5g"), ("plain_r98", "plain r98", ".1e"),
                       ("enriched_r98", "enriched r98", ".1e"),
                       ("moments_r98_p", "mom. dJ/dp", ".1e"),
                       ("moments_r98_c", "mom. dJ/dc", ".1e"),
                       ("held_r98_p", "CB dJ/dp", ".1e"), ("held_r98_c", "CB dJ/dc", ".1e"),
                       ("moments_start_r98", "mom.+x0", ".1e"),
                       ("held_start_r98", "CB+x0", ".1e"),
                       ("plain_rank", "plain r", "d"),
                       ("plain_own", "plain own r", ".1e"), ("enriched_rank", "enr. r", "d"),
                       ("enriched_own", "enr. own r", ".1e"),
                       ("plain_offline_s", "plain s", ".2f"),
                       ("enriched_offline_s", "enr. s", ".2f")])
    warm = rows[1:] or rows
    summary = dict(
        worst_plain_r98=max(r["plain_r98"] for r in rows),
        worst_enriched_r98=max(r["enriched_r98"] for r in rows),
        worst_plain_own=max(r["plain_own"] for r in rows),
        worst_enriched_own=max(r["enriched_own"] for r in rows),
        worst_moments_r98=max(r["moments_r98"] for r in rows),
        worst_moments_r98_c=max(r["moments_r98_c"] for r in rows),
        worst_held_r98=max(r["held_r98"] for r in rows),
        designs_within_target_held_r98=sum(r["held_r98"] <= TARGET for r in rows),
        median_offline_held_s=statistics.median(r["held_offline_s"] for r in warm),
        designs_within_target_moments_r98=sum(r["moments_r98"] <= TARGET for r in rows),
        worst_moments_start_r98=max(r["moments_start_r98"] for r in rows),
        worst_held_start_r98=max(r["held_start_r98"] for r in rows),
        designs_within_target_moments_start_r98=sum(r["moments_start_r98"] <= TARGET
                                                    for r in rows),
        designs_within_target_held_start_r98=sum(r["held_start_r98"] <= TARGET for r in rows),
        max_rank_held_start=max(r["held_start_rank"] for r in rows),
        median_offline_held_start_s=statistics.median(r["held_start_offline_s"] for r in warm),
        designs_within_target_moments_r98_c=sum(r["moments_r98_c"] <= TARGET for r in rows),
        designs_within_target_plain_r98=sum(r["plain_r98"] <= TARGET for r in rows),
        designs_within_target_enriched_r98=sum(r["enriched_r98"] <= TARGET for r in rows),
        median_offline_plain_s=statistics.median(r["plain_offline_s"] for r in warm),
        median_offline_enriched_s=statistics.median(r["enriched_offline_s"] for r in warm),
        target=TARGET, target_met=min(max(r[f"{b}_r98"] for r in rows) for b in (
            "plain", "enriched", "moments", "held", "moments_start", "held_start")) <= TARGET)
    print(f"\nworst at r = {RANK}: plain {summary['worst_plain_r98']:.1e}, enriched "
          f"{summary['worst_enriched_r98']:.1e} (target {TARGET:g}: "
          f"{'met' if summary['target_met'] else 'missed'}); within target: plain "
          f"{summary['designs_within_target_plain_r98']}/{len(rows)}, enriched "
          f"{summary['designs_within_target_enriched_r98']}/{len(rows)}; offline per design "
          f"(warm median): plain {summary['median_offline_plain_s']:.2f} s, enriched "
          f"{summary['median_offline_enriched_s']:.2f} s; modal + 2 moments (r <= {RANK}): "
          f"worst {summary['worst_moments_r98']:.1e}, within target "
          f"{summary['designs_within_target_moments_r98']}/{len(rows)} (dJ/dc alone "
          f"{summary['designs_within_target_moments_r98_c']}/{len(rows)}, worst "
          f"{summary['worst_moments_r98_c']:.1e}); Craig-Bampton (r <= {RANK}): worst "
          f"{summary['worst_held_r98']:.1e}, within target "
          f"{summary['designs_within_target_held_r98']}/{len(rows)}, offline "
          f"{summary['median_offline_held_s']:.3f} s; with the start kept: modes + 2 moments "
          f"worst {summary['worst_moments_start_r98']:.1e} "
          f"({summary['designs_within_target_moments_start_r98']}/{len(rows)}), Craig-Bampton "
          f"worst {summary['worst_held_start_r98']:.1e} "
          f"({summary['designs_within_target_held_start_r98']}/{len(rows)}, r <= "
          f"{summary['max_rank_held_start']}, offline "
          f"{summary['median_offline_held_start_s']:.3f} s)")
    data = dict(problem=dict(scene=SCENE, objective="energy on the scene's grid", wrt=list(WRT),
                             rank=RANK, energy=ENERGY, criterion="paper",
                             error="max over p, c of |ROM derivative / full derivative - 1|"),
                rows=rows, summary=summary, total_wall_s=elapsed(start))
    path = write_json(NAME, args.quick, data)
    png = plot(read_json(NAME, args.quick), args.quick)
    print(f"wrote {path} and {png}")
    return data


if __name__ == "__main__":
    main()
