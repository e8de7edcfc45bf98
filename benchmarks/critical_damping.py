"""The default exact path across critical damping, under jit/vmap, and what it costs.

Three parts, in one process (the memory figures in child processes, one per measurement):

* **Accuracy through critical damping**: the five cases of ``tests/test_critical_damping.py``
  (one mass, c* = 2; two masses; Mikota n = 8; a relative damper; two dampers) at c = c* (1 +
  delta) for delta in +-{0, 1e-16, ..., 1e-2}: the default path's relative errors in J, the
  trace, x(t) (max over 41 times, relative to max |x|) and dJ/dc, dtrace/dc against the tests'
  truths (closed forms for one mass, mpmath's eigen-expansion at 80 digits and its central
  differences otherwise). Targets: values within 1e-9, gradients within 1e-7, nothing negative.
  With each case, the compiled J + gradient of the default path against
  ``method=DenseExponential()``.
* **Memory under jit and vmap** (peak resident memory of a child process that runs only that):
  ``jax.jit(jax.value_and_grad(energy))`` of the full Mikota chain with one grounded damper
  against the eager ``jax.grad`` at the same n; ``jax.jit(jax.vmap(energy))`` over 64 designs at
  n = 300 against 64 eager calls (wall time of each child, compilation included). Targets: jit
  at n = 2000 under 2 GB and within 2x of eager up to n = 10^4 (``--memory-only 4000 10000``
  adds sizes to the JSON); vmap within 2x of the eager calls' time and memory.
* **Section 5 before and after** (n = 300, damper d = 1 at DOF 7.3, x_3(0) = 1, T = 20): J +
  gradient and the all-DOF history at 401 times, compiled, by this package and by the package
  at ``--before`` (a git revision, imported beside it under another name). Target: no more than
  20 % slower.

* **Large** (``--large``, apart, ~30 min): ``mj.sweep`` of the full model's J over 8 designs at
  n = 3000 against one call (peak memory: a compiled chunk once carried the dense branch, 7.7
  GB), and the crossover's crowded n = 30000 design (p = 9872.4, c = 21.3; a relative
  separation of 1.6e-7 that a fixed relative threshold once refused): J and its gradient, within
  the physical bounds 0 <= J <= T E(0), time and peak memory.

* **Every pair at once** (``--all-pairs``, apart, ~3 min; merged into the JSON): Mikota's chain
  with its damper on the middle DOF meets every mode pair at c = 2 sqrt(k m), more pairs than
  the contour's slots. At n = 20 and 300 (x_3(0) = 1, T = 20) and c = 2 (1 + delta), delta from
  +-1e-1 to 0: whether the default path refuses, and otherwise its relative errors in J and
  dJ/dc against ``method=DenseExponential()`` (itself ~1e-12 there: mpmath at n = 8 and 20).
  Target: every delta either refused or J within 1e-9; dJ/dc is reported (beside the band the
  pairs summed root by root lose ~eps cond^4 of it).

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/critical_damping.py [--quick]`` (``--quick``: one
case, three deltas, jit and vmap memory at n = 200 and 50 without the eager comparisons, no
Section 5 before and after). Writes ``results/critical_damping.json`` and ``.png``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (Compiled, figure, legend, metadata, parse_args,  # noqa: I001
                     print_table, read_json, save_figure, subtitle, timed, write_json)

import importlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import mikota_jax as mj

NAME = "critical_damping"
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))  # the truths are the tests' own

DELTAS = [0.0, 1e-16, -1e-16, 1e-14, -1e-14, 1e-12, -1e-12, 1e-10, -1e-10, 1e-8, -1e-8, 1e-6,
          -1e-6, 1e-4, -1e-4, 1e-2, -1e-2]


def accuracy(quick):
    import test_critical_damping as cases

    names = list(cases.CASES)[:1] if quick else list(cases.CASES)
    deltas = [0.0, -1e-12, 1e-6] if quick else DELTAS
    table, timing = {}, {}
    for name in names:
        make, _, x0, v0 = cases.CASES[name]
        energy = jax.jit(lambda c, make=make, x0=x0, v0=v0: mj.Energy(10.0, x0, v0)(make(c)))
        grad_energy = jax.jit(jax.grad(lambda c, make=make, x0=x0, v0=v0:
                                       mj.Energy(10.0, x0, v0)(make(c))))
        trace = jax.jit(lambda c, make=make: mj.AverageEnergy()(make(c)))
        grad_trace = jax.jit(jax.grad(lambda c, make=make: mj.AverageEnergy()(make(c))))
        rows = []
        for delta in deltas:
            c = cases.probe(name, delta)
            j, t, xs = cases.truths(name, c)
            dj, dt = cases.derivative_truths(name, c)
            history = np.asarray(mj.solve(make(c), cases.TS, x0, v0,
                                          method=mj.Spectral()).displacement)
            ours = dict(J=float(energy(c)), trace=float(trace(c)), dJ=float(grad_energy(c)),
                        dtrace=float(grad_trace(c)))
            rows.append(dict(delta=delta, c=c, J=ours["J"], trace=ours["trace"],
                             error_J=abs(ours["J"] / j - 1),
                             error_trace=abs(ours["trace"] / t - 1),
                             error_x=float(np.max(np.abs(history - xs)) / np.max(np.abs(xs))),
                             # relative to the derivative, or to value / c where it is 0
                             # (the one-mass trace optimum)
                             error_dJ=abs(ours["dJ"] - dj) / max(abs(dj), abs(j / c)),
                             error_dtrace=abs(ours["dtrace"] - dt) / max(abs(dt), abs(t / c))))
            print(f"{name:16s} delta {delta:9.1e}: J {rows[-1]['error_J']:.1e} trace "
                  f"{rows[-1]['error_trace']:.1e} x {rows[-1]['error_x']:.1e} dJ "
                  f"{rows[-1]['error_dJ']:.1e} dtrace {rows[-1]['error_dtrace']:.1e}", flush=True)
        table[name] = rows
        c = jnp.array(cases.probe(name, 0.0))
        both = {}
        for method, spelling in (("exact", mj.Auto()), ("dense", mj.DenseExponential())):
            fn = Compiled(jax.value_and_grad(lambda c, make=make, x0=x0, v0=v0, m=spelling:
                                             mj.Energy(10.0, x0, v0, method=m)(make(c))), c)
            (value, _), seconds, _ = timed(fn, c, repeats=5)
            both[method] = dict(seconds=seconds, compile_s=fn.compile_s, value=float(value))
        timing[name] = both
    return table, timing


CHILD = r"""
import json, resource, sys, time
import jax, numpy as np
extra = {}
jax.config.update("jax_enable_x64", True)
import mikota_jax as mj
mode, n = sys.argv[1], int(sys.argv[2])
x0 = np.zeros(n); x0[2] = 1.0
def scene_for(n):  # the crossover's scene: the Section 5 setting at size n
    return mj.app.load_scene({
        "name": f"crossover_{n}", "chain": {"type": "mikota", "n": n, "m": 1.0, "k": 1.0},
        "damper": [{"type": "grounded", "position": 7.0, "coefficient": 1.0}],
        "initial": {"displacement": {"3": 1.0}}, "time": {"end": 20.0, "step": 0.01},
        "reduction": {"snapshots": [0.0, 10.0], "energy": 0.9999, "criterion": "paper"},
        "output": {"dofs": [n // 2], "quantities": ["displacement"]}})
def random_designs(n, count):  # the crossover's random designs (seed 20 + n)
    rng = np.random.default_rng(20 + n)
    return [(float(rng.uniform(1.0, n)), float(10 ** rng.uniform(-1.0, 3.0)))
            for _ in range(count)]
def energy(c):
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(7.0, c)])
    return mj.Energy(20.0, x0)(system)
start = time.perf_counter()
if mode == "jit":
    out = jax.jit(jax.value_and_grad(energy))(1.0)
elif mode == "eager":
    out = jax.value_and_grad(energy)(1.0)
elif mode == "vmap":
    out = jax.jit(jax.vmap(energy))(jax.numpy.linspace(0.5, 2.0, 64))
elif mode == "loop":
    out = [energy(c) for c in np.linspace(0.5, 2.0, 64)]
elif mode in ("sweep", "sweep-one"):  # crossover's scene: J of the full model per design
    function = mj.SceneFunction(scene_for(n), "energy")
    count = 8 if mode == "sweep" else 1
    points = {"positions": np.linspace(5.0, n - 5.0, count)[:, None],
              "coefficients": np.geomspace(0.3, 30.0, count)[:, None]}
    out = (mj.sweep(function, points) if mode == "sweep"
           else function(jax.tree.map(lambda a: a[0], points)))
elif mode == "crowded":  # the crossover design whose pair the old rule called near-defective
    function = mj.SceneFunction(scene_for(n), "energy")
    position, coefficient = random_designs(n, 2)[int(sys.argv[4])]
    def energy(p):  # the full model's J by the spectral path, J as jacfwd's aux
        value = mj.Energy(20.0, function.scene.x0, method=mj.Spectral())(function.system(p))
        return value, value
    jacobian, value = jax.jacfwd(energy, has_aux=True)(
        {"positions": jax.numpy.array([position]), "coefficients": jax.numpy.array([coefficient])})
    out = value
    # physical bounds: 0 <= J <= T E(0), E(0) = K_33 / 2 = (k_3 + k_4) / 2 = (2n - 5) / 2
    extra = dict(position=position, coefficient=coefficient, J=float(value),
                 dJ={k: float(np.ravel(v)[0]) for k, v in jacobian.items()},
                 bound=20.0 * (2 * n - 5) / 2)
jax.block_until_ready(out)
print(json.dumps(dict(seconds=time.perf_counter() - start,
                      peak_gib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
                      **extra)))
"""


def child(mode, n, which=0):
    done = subprocess.run([sys.executable, "-c", CHILD, mode, str(n), str(ROOT / "benchmarks"),
                           str(which)], capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def memory(quick):
    sizes = [200] if quick else [1000, 2000]
    out = {"gradient": {}, "vmap": {}}
    # --quick: the library's jit and vmap children only (each child is a JAX start-up and a
    # compile; the eager comparisons are the full run's)
    for n in sizes:
        out["gradient"][str(n)] = {mode: child(mode, n)
                                   for mode in (("jit",) if quick else ("jit", "eager"))}
        print(f"n = {n}: {out['gradient'][str(n)]}", flush=True)
    n = 50 if quick else 300
    out["vmap"] = dict(n=n, designs=64, **{mode: child(mode, n)
                                           for mode in (("vmap",) if quick else ("vmap", "loop"))})
    print(f"vmap over 64 designs at n = {n}: {out['vmap']}", flush=True)
    return out


def large(data: dict, measured: dict | None = None) -> dict:
    """``mj.sweep`` of the full model at n = 3000 (8 designs against one call: peak memory) and
    the crowded n = 30000 design, each in its own child, merged into ``data["large"]``."""
    measured = measured or {"sweep_one": child("sweep-one", 3000),
                            "sweep": child("sweep", 3000),
                            # crossover's two random designs at n = 30000: the first is
                            # the one the old rule refused, the second the one it solved
                            "crowded": child("crowded", 30000, 0),
                            "solved": child("crowded", 30000, 1)}
    data["large"] = measured
    crowded = measured["crowded"]
    print(f"mj.sweep n = 3000, 8 designs: {measured['sweep']}; one call: "
          f"{measured['sweep_one']}\ncrowded n = 30000 design p = {crowded['position']:.1f}, c = "
          f"{crowded['coefficient']:.3g}: J = {crowded['J']:.10g} (bound {crowded['bound']:.6g}), "
          f"{crowded['seconds']:.0f} s, peak {crowded['peak_gib']:.2f} GiB", flush=True)
    return data


PAIR_DELTAS = [1e-1, 3e-2, 1e-2, 5e-3, 3e-3, 2e-3, 1e-3, 1e-4, 1e-6, 1e-9, 0.0]


def all_pairs() -> dict:
    """The middle damper's c = 2 (1 + delta) at n = 20 and 300: refused, or the errors of J and
    dJ/dc against the dense path."""
    out = {}
    for n in (20, 300):
        energy = mj.Energy(20.0, mj.unit_vector(n, 3))
        dense_energy = mj.Energy(20.0, mj.unit_vector(n, 3), method=mj.DenseExponential())

        def make(c, n=n):
            return mj.mikota_chain(n, dampers=[mj.GroundedDamper(n / 2, c)])

        default = jax.jit(jax.value_and_grad(lambda c, e=energy: e(make(c))))
        dense = jax.jit(jax.value_and_grad(lambda c, e=dense_energy: e(make(c))))
        rows = []
        for delta in PAIR_DELTAS:
            for sign in (1, -1) if delta else (1,):
                c = 2 * (1 + sign * delta)
                truth, slope = (float(v) for v in dense(c))
                try:
                    value, grad = (float(v) for v in default(c))
                except Exception as error:  # raised when the result is read (jit's callback)
                    if "spectral path did not hold" not in str(error):
                        raise
                    rows.append(dict(delta=sign * delta, refused=True))
                    continue
                rows.append(dict(delta=sign * delta, refused=False,
                                 error_J=abs(value - truth) / abs(truth),
                                 error_dJ=abs(grad - slope) / abs(slope)))
            print(f"n = {n}, delta = {delta:.0e}: {rows[-1]}", flush=True)
        out[str(n)] = rows
    return out


def pair_summary(pairs: dict) -> dict:
    summary = {}
    for n, rows in pairs.items():
        kept = [r for r in rows if not r["refused"]]
        summary[f"every pair at once, n = {n}: largest |delta| refused"] = max(
            (abs(r["delta"]) for r in rows if r["refused"]), default=0.0)
        summary[f"every pair at once, n = {n}: worst J error where not refused"] = max(
            r["error_J"] for r in kept)
        summary[f"every pair at once, n = {n}: worst dJ/dc error where not refused"] = max(
            r["error_dJ"] for r in kept)
    return summary


def package_at(revision):
    """The package at a git revision, importable beside this one as ``mikota_jax_before``."""
    where = Path(tempfile.mkdtemp())
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", revision, "mikota_jax"],
                             capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(where)], input=archive, check=True)
    (where / "mikota_jax").rename(where / "mikota_jax_before")
    sys.path.insert(0, str(where))
    return importlib.import_module("mikota_jax_before")


def section5(package, n, repeats):
    x0 = jnp.zeros(n).at[2].set(1.0)
    ts = jnp.linspace(0.0, 20.0, 401)

    def energy(p, c):
        system = package.mikota_chain(n, dampers=[package.GroundedDamper(p, c)])
        return package.Energy(20.0, x0)(system)

    def history(p, c):
        system = package.mikota_chain(n, dampers=[package.GroundedDamper(p, c)])
        return package.solve(system, ts, x0, method=package.Spectral()).displacement

    point = (jnp.array(7.3), jnp.array(1.0))
    out = {}
    for key, fn in (("energy_gradient", jax.value_and_grad(energy, argnums=(0, 1))),
                    ("history", history)):
        compiled = Compiled(fn, *point)
        result, seconds, _ = timed(compiled, *point, repeats=repeats)
        out[key] = dict(seconds=seconds, compile_s=compiled.compile_s)
        out[key + "_value"] = (float(result[0]) if key == "energy_gradient"
                               else float(jnp.max(jnp.abs(result))))
    return out


def _delta_axes(ax, deltas, xlabel, ylabel, title) -> None:
    """An errors-against-delta panel: one tick per delta, the 1e-9 line, log errors."""
    ax.set_xticks(range(len(deltas)), [f"{d:.0e}" for d in deltas], rotation=90)
    ax.axhline(1e-9, color="grey", ls="--", lw=1)
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    legend(ax, "below")


def plot(data: dict) -> None:
    pairs = data.get("all_pairs")
    if pairs:  # a second row for the middle damper, the fourth panel empty
        fig, axes = figure(readable=True, nrows=2, ncols=2, figsize=(12, 11))
        axes = axes.ravel()
        axes[3].axis("off")
    else:
        fig, axes = figure(readable=True, ncols=2, figsize=(12, 5.2))
    ax = axes[0]
    for name, rows in data["accuracy"].items():
        order = sorted(rows, key=lambda r: (np.sign(r["delta"]), abs(r["delta"])))
        x = [r["delta"] for r in order]
        worst = [max(r["error_J"], r["error_trace"], r["error_x"], r["error_dJ"],
                     r["error_dtrace"], 1e-17) for r in order]
        ax.plot(range(len(x)), worst, "o-", label=name)
    _delta_axes(ax, x, "delta (c = c* (1 + delta))",
                "worst relative error (J, trace, x, dJ/dc, dtrace/dc)",
                "default path through critical damping")
    ax = axes[1]
    sizes = sorted(data["memory"]["gradient"], key=int)
    for mode, marker in (("jit", "o-"), ("eager", "s--")):
        if any(mode not in data["memory"]["gradient"][n] for n in sizes):
            continue
        ax.plot([int(n) for n in sizes], [data["memory"]["gradient"][n][mode]["peak_gib"]
                                          for n in sizes], marker, label=f"{mode} value_and_grad")
    ax.set_xlabel("n")
    ax.set_ylabel("peak resident memory (GiB)")
    ax.set_title("J + gradient of the full chain: jit against eager")
    legend(ax, "below")
    if pairs:
        ax = axes[2]
        for n, rows in pairs.items():
            order = sorted(rows, key=lambda r: r["delta"])
            x = [r["delta"] for r in order]
            for key, marker in (("error_J", "o-"), ("error_dJ", "s--")):
                ax.plot(range(len(x)), [np.nan if r["refused"] else max(r[key], 1e-17)
                                        for r in order], marker, label=f"n = {n}: {key[6:]}")
            refused = [i for i, r in enumerate(order) if r["refused"]]
            ax.plot(refused, [1.0] * len(refused), "kx", ms=9)
        _delta_axes(ax, x, "delta (c = 2 (1 + delta)); x at the top: refused",
                    "relative error against the dense path",
                    "middle damper: every mode pair meets at c = 2")
    fig.suptitle(subtitle(data.get("meta")), fontsize=9)
    save_figure(fig, NAME, data.get("quick", False))


def main(argv=None):
    args = parse_args(__doc__, argv, replot=True,
                      before=dict(default="7ebd474", help="the revision to compare Section 5 "
                                  "with (before the contour clusters)"),
                      memory_only=dict(type=int, nargs="+", default=None, help="only measure "
                                       "the jit/eager memory at these n, merged into the JSON"),
                      large=dict(action="store_true", help="only mj.sweep at n = 3000 and the "
                                 "crowded n = 30000 design (~30 min), merged into the JSON"),
                      all_pairs=dict(action="store_true", help="only the middle damper where "
                                     "every mode pair meets (~3 min), merged into the JSON"))
    if args.replot:
        return plot(read_json(NAME, args.quick))
    if args.large:
        data = large(read_json(NAME, args.quick))
        write_json(NAME, args.quick, data, data["meta"])
        return plot(data)
    if args.all_pairs:
        data = read_json(NAME, args.quick)
        data["all_pairs"] = all_pairs()
        data["summary"] = {**data.get("summary", {}), **pair_summary(data["all_pairs"])}
        write_json(NAME, args.quick, data, data["meta"])
        return plot(data)
    if args.memory_only:
        data = read_json(NAME, args.quick)
        for n in args.memory_only:
            data["memory"]["gradient"][str(n)] = {mode: child(mode, n) for mode in ("jit",
                                                                                     "eager")}
            print(f"n = {n}: {data['memory']['gradient'][str(n)]}", flush=True)
        write_json(NAME, args.quick, data, data["meta"])
        return plot(data)
    table, timing = accuracy(args.quick)
    mem = memory(args.quick)
    n = 100 if args.quick else 300
    repeats = 3 if args.quick else 7
    # --quick: no before and after (a shallow clone, as in CI, may not hold the earlier revision)
    after = None if args.quick else section5(mj, n, repeats)
    before = None if args.quick else section5(package_at(args.before), n, repeats)
    data = dict(quick=args.quick, accuracy=table, timing=timing, memory=mem,
                section5=dict(n=n, before=before, after=after, revision=args.before),
                meta=metadata())
    rows = [dict(case=name, exact_s=t["exact"]["seconds"], dense_s=t["dense"]["seconds"],
                 ratio=t["dense"]["seconds"] / t["exact"]["seconds"],
                 worst_value=max(max(r["error_J"], r["error_trace"], r["error_x"])
                                 for r in table[name]),
                 worst_gradient=max(max(r["error_dJ"], r["error_dtrace"]) for r in table[name]),
                 negative=any(r["J"] < 0 or r["trace"] < 0 for r in table[name]))
            for name, t in timing.items()]
    print_table(rows, [("case", "case", ""), ("exact_s", "default J+grad s", ".4f"),
                       ("dense_s", "dense J+grad s", ".4f"), ("ratio", "dense / default", ".1f"),
                       ("worst_value", "worst value err", ".1e"),
                       ("worst_gradient", "worst gradient err", ".1e"),
                       ("negative", "negative?", "")])
    for key in ("energy_gradient", "history") if before is not None else ():
        b, a = before[key]["seconds"], after[key]["seconds"]
        print(f"Section 5 {key}: before {b:.4f} s, after {a:.4f} s ({a / b - 1:+.0%}); values "
              f"{before[key + '_value']:.15g} / {after[key + '_value']:.15g}")
    write_json(NAME, args.quick, data, data["meta"])
    plot(data)


if __name__ == "__main__":
    main()
