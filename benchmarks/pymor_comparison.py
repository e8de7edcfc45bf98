"""Reductions of the Section 5 input-output map: mikota_jax against pyMOR, one evaluation code.

The map: Mikota's chain n = 300, the damper d = 1 at DOF 7, a force at DOF 3, the displacement of
DOF 150 (``io_models``' system). At r = 10, 20, 40 and 80 reduced DOFs (2r states) every
reduction of both libraries runs in this process: pyMOR 2026.1.1's second-order balanced
truncations (SOBTp, SOBTv, SOBTpv, SOBTvp, SOBTfv, SOBT), SOR-IRKA, SOBHI, and on the first-order
form BT, IRKA, IRKA and TSIA started from BT, and modal truncation (``_pymor_side.py``); ours:
``H2Optimal`` (IRKA in the modal coordinates), ``SOBT`` in its four variants (the modes damped
below what a dense Gramian resolves left out: their share, the models' floor, is 9e-7 here),
``Modal``, ``ModalStatic``, and ``StructuredH2`` (the Galerkin second-order model at r // 4
H2-optimal shifts: at most r DOFs, ``dofs`` in its rows). Each reduced
model, as its dense first-order matrices, becomes an ``mj.LTIModel`` (ours are one or an
``IOModel``) and is scored by the same code: whether every pole has Re < 0, the relative H2
error ``(full - reduced).h2_norm() / full.h2_norm()`` (exact full norm from the damped modes, the
cross term by Bartels-Stewart), and the largest error of G(i omega) on 4000 log-spaced
frequencies in [0.01, 400] relative to the largest |G| there. The H-infinity norm of this full
system is not finite in float64 terms: mode 300's shape at the damper is ~1e-77, so it decays at
~1e-153 while DOF 3 excites it and DOF 150 sees it (a resonance peak ~1e66), and
``IOModel.hinf_norm`` refuses it in one line; the sampled error stands in for it here.

Offline time: wall seconds of each reduction alone (ours after one warm-up reduction at
another order, so the modal data's compile is not counted; pyMOR compiles nothing). The
convergence rows run ``H2Optimal`` from its default start at every r for the displacement and
for the velocity of DOF 150 (8 runs): iterations, whether the shifts settled to 1e-8, and the
largest mismatch of the interpolation (optimality) conditions.

Run: ``pip install -e ".[bench]"`` (pyMOR), then
``OPENBLAS_NUM_THREADS=1 python benchmarks/pymor_comparison.py [--quick] [--replot]``
(``--quick``: n = 60 at r = 5, 10). Writes ``results/pymor_comparison[_quick].json`` and ``.png``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (elapsed, figure, legend, parse_args, print_table,  # noqa: I001
                     read_json, save_figure, subtitle, write_json)

import time
import warnings

import numpy as np

import mikota_jax as mj
from _pymor_side import pymor_reductions

NAME = "pymor_comparison"
FREQUENCIES = np.logspace(-2, np.log10(400.0), 4000)
OURS = {"H2Optimal": mj.H2Optimal, **{f"SOBT{v}": (lambda r, v=v: mj.SOBT(r, v))
                                     for v in ("p", "v", "pv", "vp")},
        "Modal": mj.Modal, "ModalStatic": mj.ModalStatic,
        # up to 4 DOFs per shift: r // 4 shifts stay within r DOFs (``dofs`` says how many)
        "StructuredH2": lambda r: mj.StructuredH2(max(1, r // 4))}


def io_model(n: int, velocity: bool = False) -> mj.IOModel:
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(7.0, 1.0)])
    out = mj.unit_vector(n, n // 2)
    return mj.IOModel(system, mj.unit_vector(n, 3), **({"cv": out} if velocity else {"cx": out}))


def score(io, model, norm: float, response) -> dict:
    """The one evaluation: stability, relative H2 error, sampled relative error of G(i w)."""
    poles = np.asarray(model.poles())
    stable = bool(np.all(poles.real < 0))
    sampled = np.asarray(model.frequency_response(FREQUENCIES))[:, 0, 0]
    row = dict(stable=stable, sampled_error=float(np.max(np.abs(sampled - response))
                                                  / np.max(np.abs(response))))
    row["h2_error"] = float((io - model).h2_norm()) / norm if stable else None
    return row


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return print(plot(read_json(NAME, args.quick), args.quick))
    start = time.perf_counter()
    n, ranks = (60, (5, 10)) if args.quick else (300, (10, 20, 40, 80))
    io = io_model(n)
    norm = float(io.h2_norm())
    response = np.asarray(io.frequency_response(FREQUENCIES))[:, 0, 0]
    rows = []
    for name, strategy in OURS.items():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            mj.reduce(io, strategy(ranks[0] + 1))  # warm-up: the modal data's compile
        for r in ranks:
            with warnings.catch_warnings(record=True) as caught:  # SOBT's floor, in its stats
                warnings.simplefilter("always")
                t0 = time.perf_counter()
                model = mj.reduce(io, strategy(r))
                offline = elapsed(t0)
            dofs = model.model.rank if isinstance(model, mj.IOModel) else model.order // 2
            rows.append(dict(library="mikota_jax", method=name, r=r, dofs=int(dofs),
                             offline_s=offline, warned=bool(caught),
                             **score(io, model, norm, response)))
            print(f"mikota_jax {name:>12} r = {r:3d}: {rows[-1]}", flush=True)
    m, d, k = (np.asarray(x) for x in io.model.dense())
    found = pymor_reductions(m, d, k, np.asarray(io.inputs), np.asarray(io.cx), ranks)
    for found_row in found:
        row = dict(library="pyMOR", method=found_row["method"], r=found_row["r"],
                   offline_s=found_row.get("offline_s"), iterations=found_row.get("iterations"),
                   converged=found_row.get("converged"))
        if "error" in found_row:
            row["failed"] = found_row["error"][:160]
        else:
            try:
                model = mj.LTIModel(found_row["a"], found_row["b"], found_row["c"],
                                    found_row["e"])
                row.update(score(io, model, norm, response))
            except ValueError as refused:  # e.g. a singular E
                row["failed"] = str(refused)[:160]
        rows.append(row)
        print(f"pyMOR {row['method']:>14} r = {row['r']:3d}: "
              f"{ {k: v for k, v in row.items() if k not in ('library', 'method', 'r')} }",
              flush=True)
    convergence = []
    for velocity in (False, True):
        case = io_model(n, velocity)
        for r in ranks:
            model = mj.reduce(case, mj.H2Optimal(r))
            convergence.append(dict(output="velocity" if velocity else "displacement", r=r,
                                    iterations=model.stats.iterations,
                                    converged=model.stats.converged,
                                    last_change=model.stats.changes[-1],
                                    optimality=model.stats.optimality,
                                    stable=model.is_stable()))
    summary = []
    for r in ranks:
        def best(library, r=r):
            scored = [row for row in rows if row["library"] == library and row["r"] == r
                      and row.get("stable") and row.get("h2_error") is not None]
            return min(scored, key=lambda row: row["h2_error"])
        ours, theirs = best("mikota_jax"), best("pyMOR")
        summary.append(dict(r=r, ours=ours["method"], ours_h2_error=ours["h2_error"],
                            ours_offline_s=ours["offline_s"], pymor=theirs["method"],
                            pymor_h2_error=theirs["h2_error"],
                            pymor_offline_s=theirs["offline_s"],
                            error_ratio=ours["h2_error"] / theirs["h2_error"],
                            pymor_stable=sum(bool(row.get("stable")) for row in rows
                                             if row["library"] == "pyMOR" and row["r"] == r),
                            pymor_methods=sum(row["library"] == "pyMOR" and row["r"] == r
                                              for row in rows)))
    print_table(summary, [("r", "r", "d"), ("ours", "ours", ""), ("ours_h2_error", "H2", ".3e"),
                          ("ours_offline_s", "s", ".2f"), ("pymor", "pyMOR", ""),
                          ("pymor_h2_error", "H2", ".3e"), ("pymor_offline_s", "s", ".2f"),
                          ("error_ratio", "ratio", ".3f")])
    print_table(convergence, [("output", "output", ""), ("r", "r", "d"),
                              ("iterations", "sweeps", "d"), ("converged", "settled", ""),
                              ("optimality", "optimality", ".1e")])
    data = dict(problem=dict(n=n, system="Mikota chain, damper d = 1 at DOF 7",
                             input="force at DOF 3", output=f"displacement of DOF {n // 2}",
                             full_h2_norm=norm),
                summary=summary, convergence=convergence, rows=rows,
                total_wall_s=elapsed(start))
    path = write_json(NAME, args.quick, data)
    png = plot(read_json(NAME, args.quick), args.quick)
    print(f"wrote {path} and {png}")
    return data


def plot(data: dict, quick: bool):
    fig, ax = figure(figsize=(8, 4.6), readable=True)
    methods = dict.fromkeys((row["library"], row["method"]) for row in data["rows"])
    for (library, method) in methods:
        mine = [row for row in data["rows"] if (row["library"], row["method"]) == (library, method)
                and row.get("h2_error") is not None]
        if not mine:
            continue
        style = dict(lw=2.2, marker="o") if library == "mikota_jax" else dict(
            lw=1.0, ls="--", marker=".", alpha=0.8)
        ax.semilogy([row["r"] for row in mine], [max(row["h2_error"], 1e-16) for row in mine],
                    label=f"{method} ({'ours' if library == 'mikota_jax' else 'pyMOR'})", **style)
    ax.set_xlabel("reduced DOFs r (2r states)")
    ax.set_ylabel("||G - G_r||_H2 / ||G||_H2 (stable models)")
    ax.grid(True, which="both", alpha=0.3)
    legend(ax)
    ax.set_title(f"Section 5 map, n = {data['problem']['n']}: H2 error of every stable model\n"
                 + subtitle(data["metadata"]))
    return save_figure(fig, NAME, quick)


if __name__ == "__main__":
    main()
