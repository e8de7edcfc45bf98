"""Restructuring parity: today's package against a reference revision, in one process.

Restructuring must cost no speed: the Section 5 Dopri8 solve, the ROM
energy gradient and the placement optimiser within 10 % of their figures before it. Both packages
are loaded into this process (the reference from ``git archive REV`` as ``mikota_jax_reference``)
and timed in turns (reference, current, reference, current, ...), so machine load affects both
alike:

* ``simulate``: the README's Section 5 solve (n = 300, damper d = 1 at DOF 7, x_3(0) = 1,
  N = 2001 times on [0, 20], Dopri8 at the default tolerances, DOF 150 saved);
* ``full_energy_gradient``: value and gradient of the exact integrated energy of the full
  Section 5 chain on [0, 20] in (position, coefficient), jitted (the README's example);
* ``rom_energy_gradient``: the same for the r = 76 ROM (the README's third snippet);
* ``placement_gradient``: value and gradient of ``testing.placement_objective`` on the same basis;
* ``reproduce``: the paper's reproduction (every number, no files written; warm: after one run);
* ``optimise_dampers``: the whole optimiser (``ScreenAndCertify``) on ``section5_damped`` (warm:
  after one run that compiles).

Each case is written in its package's own API (the reference's ``simulate``,
``integrated_energy``, ``galerkin``, ``optimise_dampers``; today's ``solve``, ``Energy``,
``reduce``, ``optimise``), so the figures include what the new API's layers cost.

Compile time is measured apart (first call); run time is the median of the repeats.

    OPENBLAS_NUM_THREADS=1 python benchmarks/refactor_parity.py [--reference REV] [--quick]
        [--reference-dir DIR] [--only CASE,CASE]

``--reference-dir`` takes the reference already extracted (``git archive REV mikota_jax`` unpacked
in DIR), for a machine without the repository's history; ``--only`` runs some cases (two
processes on separate cores can then share the cases; ``--replot`` merges nothing).
"""

import importlib
import shutil
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _common import (
    figure,
    legend,
    parse_args,
    print_table,
    read_json,
    save_figure,
    subtitle,
    write_json,
)

import mikota_jax as mj
from mikota_jax.testing import pod

REPO = Path(__file__).resolve().parent.parent
REFERENCE = "a202197"  # main before the package was restructured
NAME = "mikota_jax_reference"


def load_reference(revision: str, where: Path, extracted: Path | None = None):
    """The package at ``revision`` imported as ``mikota_jax_reference`` (its own scenes), from
    git or from ``extracted`` (a folder holding that revision's ``mikota_jax``)."""
    if extracted is not None:
        shutil.copytree(extracted / "mikota_jax", where / "mikota_jax")
    else:
        archive = subprocess.run(["git", "-C", str(REPO), "archive", revision, "mikota_jax"],
                                 check=True, capture_output=True).stdout
        with tarfile.open(fileobj=BytesIO(archive)) as tar:
            tar.extractall(where, filter="data")
    (where / "mikota_jax").rename(where / NAME)
    for path in (where / NAME).rglob("*.py"):  # resources by the package's own name
        text = path.read_text().replace('resources.files("mikota_jax")',
                                        "resources.files(__package__)")
        path.write_text(text)
    sys.path.insert(0, str(where))
    return importlib.import_module(NAME)


def cases(pkg, basis: np.ndarray, quick: bool, only: set[str] | None = None) -> dict:
    """name -> a zero-argument callable that blocks until its result is ready; each case written
    in the package's own API (the reference's functions, or the verbs)."""
    verbs = hasattr(pkg, "optimise")
    app = importlib.import_module(f"{pkg.__name__}.app") if verbs else pkg
    n = 300
    system = pkg.mikota_chain(n, dampers=[pkg.GroundedDamper(7.0, 1.0)])
    ts = jnp.linspace(0.0, 20.0, 2001)
    x0 = pkg.unit_vector(n, 3)
    basis = jnp.asarray(basis)

    def chain(position, coefficient):
        return pkg.mikota_chain(n, dampers=[pkg.GroundedDamper(position, coefficient)])

    if verbs:
        dopri8 = lambda: pkg.solve(system, ts, x0, dofs=[150], method=pkg.ODE())  # noqa: E731
        full_energy = lambda p, c: pkg.Energy(20.0, x0)(chain(p, c))  # noqa: E731
        rom_energy = lambda p, c: pkg.Energy(20.0, x0)(  # noqa: E731
            pkg.reduce(chain(p, c), pkg.Projection(basis)))
    else:
        dopri8 = lambda: pkg.simulate(system, ts, x0, dofs=[150])  # noqa: E731
        full_energy = lambda p, c: pkg.integrated_energy(chain(p, c), 20.0, x0)  # noqa: E731
        rom_energy = lambda p, c: pkg.integrated_energy(  # noqa: E731
            pkg.galerkin(chain(p, c), basis), 20.0, x0)
    full_gradient = jax.jit(jax.value_and_grad(full_energy, argnums=(0, 1)))
    rom_gradient = jax.jit(jax.value_and_grad(rom_energy, argnums=(0, 1)))
    scene = app.load_scene("section5_damped")
    if verbs:  # optimise(DamperDesign, ScreenAndCertify)
        testing = importlib.import_module(f"{pkg.__name__}.testing")
        design, strategy = app.problem_from_scene(scene)
        problem = testing.DamperProblem(
            design.system, strategy.ts, scene.x0, scene.v0, scene.load,
            snapshots=strategy.snapshots, energy=strategy.energy, criterion=strategy.criterion,
            rank=strategy.rank)
        objective = testing.placement_objective(problem, basis)
        optimum = lambda: pkg.optimise(design, strategy).value  # noqa: E731
    else:  # optimise_dampers(DamperProblem)
        problem = pkg.problem_from_scene(scene)
        objective = pkg.placement_objective(problem, basis)
        optimum = lambda: pkg.optimise_dampers(problem).objective  # noqa: E731
    step = jax.jit(jax.value_and_grad(objective, argnums=(0, 1)))
    p, c = problem.positions, problem.coefficients
    out = {
        "simulate": lambda: jax.block_until_ready(dopri8().displacement),
        "full_energy_gradient": lambda: jax.block_until_ready(full_gradient(7.5, 1.0)),
        "rom_energy_gradient": lambda: jax.block_until_ready(rom_gradient(7.5, 1.0)),
        "placement_gradient": lambda: jax.block_until_ready(step(p, c)),
    }
    if not quick:
        out["reproduce"] = lambda: app.reproduce(None, verbose=False)["missed"]
        out["optimise_dampers"] = optimum
    return {name: f for name, f in out.items() if only is None or name in only}


def plot(data: dict, name: str = "refactor_parity") -> None:
    """Bars of current / reference run time per case, the ratio and both times on each, the
    10 % budget marked."""
    rows = data["rows"]
    fig, ax = figure(figsize=(7, 3.8), readable=True)
    y = np.arange(len(rows))
    bars = ax.barh(y, [r["ratio"] for r in rows], color="tab:blue", height=0.6)
    ax.bar_label(bars, [f"{r['ratio']:.2f}x (current {r['current_s']:.3g} s, reference "
                        f"{r['reference_s']:.3g} s)"
                        for r in rows], label_type="edge", padding=3, fontsize=8)
    ax.axvline(1.0, color="k", lw=0.8)
    ax.axvline(1.1, color="tab:red", ls="--", lw=0.8, label="10 % budget")
    ax.set_yticks(y, [r["case"] for r in rows])
    ax.set_xlim(0.0, 2.2)
    ax.set_xlabel("run time, current / reference (dimensionless)")
    where = data.get("machine", subtitle(data["metadata"]))
    ax.set_title(f"restructuring parity vs {data['reference']}\n{where}", fontsize=9)
    legend(ax, "below", frameon=False)
    save_figure(fig, name, data["quick"])


def main(argv=None) -> None:
    args = parse_args(__doc__, argv, replot=True, reference=dict(default=REFERENCE),
                      repeats=dict(type=int, default=5), reference_dir=dict(default=None),
                      only=dict(default=None), name=dict(default="refactor_parity"))
    if args.replot:
        return plot(read_json("refactor_parity", args.quick))
    repeats = 2 if args.quick else args.repeats
    with tempfile.TemporaryDirectory() as tmp:
        extracted = None if args.reference_dir is None else Path(args.reference_dir)
        reference = load_reference(args.reference, Path(tmp), extracted)
        only = None if args.only is None else set(args.only.split(","))
        full = mj.solve(mj.mikota_chain(300, dampers=[mj.GroundedDamper(7.0, 1.0)]),
                        jnp.linspace(0.0, 20.0, 2001), mj.unit_vector(300, 3), method=mj.Spectral())
        decomposition = pod(full.displacement[:1001].T)
        basis = np.asarray(decomposition.basis(decomposition.rank_for_energy(0.99, "paper")))
        packages = {"reference": reference, "current": mj}
        work = {label: cases(pkg, basis, args.quick, only) for label, pkg in packages.items()}
        compile_s, samples, values = {}, {}, {}
        for name in work["current"]:
            for label in packages:  # first calls: trace + compile (+ one run)
                start = time.perf_counter()
                values[label, name] = work[label][name]()
                compile_s[label, name] = time.perf_counter() - start
            long = name in ("optimise_dampers", "reproduce")
            runs = min(repeats, 2) if long else repeats
            for _ in range(runs):
                for label in packages:
                    start = time.perf_counter()
                    work[label][name]()
                    samples.setdefault((label, name), []).append(time.perf_counter() - start)
            print(f"{name}: reference {statistics.median(samples['reference', name]):.4f} s, "
                  f"current {statistics.median(samples['current', name]):.4f} s", flush=True)

    rows = []
    for name in work["current"]:
        ref = statistics.median(samples["reference", name])
        cur = statistics.median(samples["current", name])
        same = jax.tree.map(lambda a, b: float(np.max(np.abs(np.asarray(a) - np.asarray(b)))),
                            values["reference", name], values["current", name])
        rows.append(dict(case=name, reference_s=ref, current_s=cur, ratio=cur / ref,
                         reference_compile_s=compile_s["reference", name],
                         current_compile_s=compile_s["current", name],
                         max_difference=max(jax.tree.leaves(same)),
                         reference_samples=samples["reference", name],
                         current_samples=samples["current", name]))
    print_table(rows, [("case", "case", "s"), ("reference_s", "reference s", ".4f"),
                       ("current_s", "current s", ".4f"), ("ratio", "current/ref", ".3f"),
                       ("reference_compile_s", "ref first call s", ".2f"),
                       ("current_compile_s", "cur first call s", ".2f"),
                       ("max_difference", "max |diff|", ".1e")])
    path = write_json(args.name, args.quick, dict(reference=args.reference, rows=rows))
    plot(read_json(args.name, args.quick), args.name)
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
