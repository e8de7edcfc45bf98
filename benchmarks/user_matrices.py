"""User matrices keep their structure: one branched chain handed in five ways, solved the same.

Problem: three equal branches of L unit masses (springs 1, the last of each tied to a hub of mass
1, itself grounded by a spring 1), n = 3 L + 1 DOFs (hub last) for L in {100, 333, 1000}: n = 301,
1000, 3001. A grounded damper c = 1 at DOF L (branch 1's mass next to the hub, tied to it by a
link spring), Rayleigh damping alpha = 1e-3, beta = 1e-4, v_hub(0) = 1 (so the hub's three links
carry the motion into every branch), x(0) = 0, no load, displacements at all DOFs at t = 0, 0.1,
..., 20 (201 outputs).

M (an (n,) diagonal) and K (scipy.sparse) are assembled here in numpy, as a user's own code would,
and checked against ``mj.branched_chain``'s. The same system, five ways, each checked to become
the operators it names (``EXPECTED``; the script stops otherwise):

* ``branched``: ``mj.branched_chain``: ``Diagonal`` M, ``SymmetricTridiagonal`` K + 2 link
  springs (branch 3's last mass is the hub's neighbour: its spring lies on the band);
* ``scipy_csr``: ``mj.system(csr(M), csr(K))``: ``system`` finds the structure in the user's
  sparse matrices: ``Diagonal`` M, ``SymmetricTridiagonal`` K + 2 links, the very operators of
  ``branched`` (checked equal);
* ``sparse_coo``: ``mj.system(Diagonal(m), Sparse(rows, cols, values, n))``, K an explicit
  coordinate operator from the csr's COO arrays (operators passed in are kept as they are): the
  O(nnz) gather + segment-sum product, and a dense Cholesky per step in Kvaerno5;
* ``dense_k``: ``mj.system(Diagonal(m), Dense(K))``: dense K (O(n^2) products), diagonal M,
  physical coordinates, a dense Cholesky per step in Kvaerno5;
* ``dense_mass``: ``mj.system(Dense(diag(m)), Dense(K))``: a non-diagonal mass *operator* is solved
  in M-orthonormal modal coordinates, so every call starts with a dense n x n generalized
  eigendecomposition (O(n^3)) and lifts the outputs with the n x n modes. (A concrete dense
  ``np.diag(m)`` array would now be recognised as ``Diagonal``; the explicit ``Dense`` operator
  keeps the modal path measurable.)

Each with ``mj.ODE(rtol=1e-8)`` (Dopri8) and ``mj.ODE(mj.StructuredKvaerno5())`` (rtol 1e-8; the
structured ESDIRK: tridiagonal solve + Woodbury for the links for ``branched`` and ``scipy_csr``,
diagonal + Woodbury for the projected damper in modal coordinates for ``dense_mass``, one dense
Cholesky factorization of M + s D + s^2 K per step for ``sparse_coo`` and ``dense_k``). Default
atol (1e-2 rtol x max|v0| = 1e-10).

Correctness before timing, per n and solver: each format's first call against ``branched``'s,
max |x - x_branched| / max |x_branched| over all DOFs and times. Formats solved in the same
(physical) coordinates take the same steps, so must agree to SAME_COORDINATES = 1e-10;
``dense_mass`` is solved in modal coordinates, where the step-size controller sees other
components, so it agrees only to the integration error, MODAL_COORDINATES = 1e-5 (at n = 301 every
row is also checked against ``mj.Spectral()``, EXACT_CHECK = 1e-5, which measures that error:
~1e-7 to 1e-6 at rtol 1e-8). At the smallest n the Dopri8 executables are also called at rtol 1e-11
(the tolerance is traced: no recompile), where every format must agree with ``branched`` to
TIGHT_CHECK = 1e-8: the modal path's gap at rtol 1e-8 is integration error, not a wrong system.

Compile time apart (``jax.jit(f).lower(...).compile()``); run time the median of 5 calls (3 when
one takes over 2 s), each ended by ``block_until_ready``; building the system (``branched_chain``
/ ``system``, with its symmetry and definiteness checks) is timed too (a second build, after the
first compiled the eager kernels). A combination whose predicted call (the previous size's, scaled
by n^p with p its asymptotic cost exponent) exceeds ``--budget`` seconds (20: three repeats ~ a
minute) is skipped and recorded with the reason.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/user_matrices.py [--quick]`` (quick: L = 10, 33,
three repeats). Writes ``benchmarks/results/user_matrices[_quick].{json,png}``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before numpy and jax load.
from _common import (  # noqa: I001
    Compiled, elapsed, figure, fit_exponent, legend, ode, parse_args, print_table, read_json,
    save_figure, subtitle, timed, write_json)

import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

import mikota_jax as mj
from mikota_jax.testing import Dense, Diagonal, Sparse

NAME = "user_matrices"
BRANCHES = 3
LENGTHS = (100, 333, 1000)  # n = 3 L + 1 = 301, 1000, 3001
QUICK_LENGTHS = (10, 33)
ALPHA, BETA = 1e-3, 1e-4
DAMPER_COEFFICIENT = 1.0
RTOL = 1e-8
HORIZON, OUTPUTS = 20.0, 201
SOLVERS = ("dopri8", "kvaerno5")
FORMATS = ("branched", "scipy_csr", "sparse_coo", "dense_k", "dense_mass")
MODAL_FORMATS = ("dense_mass",)  # solved in modal coordinates (a non-diagonal mass operator)
# what each format must become: (mass, stiffness, number of K's links; None: no links field)
EXPECTED = {"branched": ("Diagonal", "SymmetricTridiagonal", 2),
            "scipy_csr": ("Diagonal", "SymmetricTridiagonal", 2),
            "sparse_coo": ("Diagonal", "Sparse", None),
            "dense_k": ("Diagonal", "Dense", None),
            "dense_mass": ("Dense", "Dense", None)}
SAME_COORDINATES = 1e-10  # relative agreement with branched, physical coordinates
MODAL_COORDINATES = 1e-5  # relative agreement with branched, the modal path
EXACT_CHECK = 1e-5  # relative error against exact_solve at the smallest n (rtol 1e-8: ~1e-6)
EXACT_MAX_N = 400
TIGHT_RTOL, TIGHT_CHECK = 1e-11, 1e-8  # smallest n, Dopri8: every format, branched vs the others
# asymptotic cost exponent of one call in n (skip prediction): O(n) stencils and O(nnz) products,
# O(n^2) dense products, O(n^3) dense factorizations (eigh of the modal path, Cholesky per step)
EXPONENT = {("branched", "dopri8"): 1, ("scipy_csr", "dopri8"): 1, ("sparse_coo", "dopri8"): 1,
            ("dense_k", "dopri8"): 2, ("dense_mass", "dopri8"): 3,
            ("branched", "kvaerno5"): 1, ("scipy_csr", "kvaerno5"): 1,
            ("sparse_coo", "kvaerno5"): 3, ("dense_k", "kvaerno5"): 3,
            ("dense_mass", "kvaerno5"): 3}
PATHS = {
    ("branched", "dopri8"): "physical: tridiagonal stencil + 2 links",
    ("scipy_csr", "dopri8"): "physical: detected tridiagonal stencil + 2 links",
    ("sparse_coo", "dopri8"): "physical: COO gather + segment sum",
    ("dense_k", "dopri8"): "physical: dense K matvec",
    ("dense_mass", "dopri8"): "modal: dense eigh per call, diagonal K, low-rank damper, dense lift",
    ("branched", "kvaerno5"): "physical: tridiagonal solve + Woodbury (links)",
    ("scipy_csr", "kvaerno5"): "physical: detected tridiagonal solve + Woodbury (links)",
    ("sparse_coo", "kvaerno5"): "physical: dense Cholesky per step",
    ("dense_k", "kvaerno5"): "physical: dense Cholesky per step",
    ("dense_mass", "kvaerno5"): "modal: dense eigh per call, diagonal + Woodbury (damper)",
}


def assemble(length: int):
    """(m (n,), K scipy csr): the branched chain written out by hand, hub = DOF n (1-based)."""
    n = BRANCHES * length + 1
    hub = n - 1
    rows, cols, values = [], [], []

    def spring(i, j, k=1.0):  # 0-based DOFs; j = None: to the ground
        rows.append(i), cols.append(i), values.append(k)
        if j is not None:
            rows.extend([j, i, j]), cols.extend([j, j, i]), values.extend([k, -k, -k])

    spring(hub, None)
    for b in range(BRANCHES):
        first = b * length
        spring(first, None)
        for i in range(first, first + length - 1):
            spring(i, i + 1)
        spring(first + length - 1, hub)
    stiffness = sp.coo_array((values, (rows, cols)), shape=(n, n)).tocsr()
    return np.ones(n), stiffness


def build(name: str, length: int, m, k):
    """The system in format ``name`` (see the module docstring)."""
    dampers = [mj.GroundedDamper(float(length), DAMPER_COEFFICIENT)]
    rayleigh = mj.Rayleigh(ALPHA, BETA)
    if name == "branched":
        masses = [np.ones(length)] * BRANCHES
        springs = [np.ones(length + 1)] * BRANCHES
        return mj.branched_chain(masses, springs, 1.0, 1.0, dampers, internal_damping=rayleigh)
    if name == "scipy_csr":
        mass, stiffness = sp.csr_matrix(sp.diags(m)), k
    elif name == "sparse_coo":
        coo = k.tocoo()
        mass = Diagonal(jnp.asarray(m))
        stiffness = Sparse(jnp.asarray(coo.row.astype(np.int64)),
                           jnp.asarray(coo.col.astype(np.int64)), jnp.asarray(coo.data),
                           k.shape[0])
    elif name == "dense_k":
        mass, stiffness = Diagonal(jnp.asarray(m)), Dense(jnp.asarray(k.toarray()))
    elif name == "dense_mass":
        mass, stiffness = Dense(jnp.asarray(np.diag(m))), Dense(jnp.asarray(k.toarray()))
    else:
        raise ValueError(name)
    return mj.system(mass, stiffness, dampers=dampers, internal_damping=rayleigh)


def operators(system) -> dict:
    stiffness = system.stiffness
    return {"mass": type(system.mass).__name__, "stiffness": type(stiffness).__name__,
            "stiffness_links": (None if not hasattr(stiffness, "links") else
                                [list(pair) for pair in stiffness.links]),
            "damping": type(system.damping).__name__,
            "internal": None if system.internal is None else (
                "Rayleigh" if system.internal.rayleigh is not None else
                type(system.internal.matrix).__name__)}


def check_operators(name: str, system, n: int) -> dict:
    """The operators ``system`` holds; stop unless they are the ones format ``name`` claims."""
    found = operators(system)
    got = (found["mass"], found["stiffness"],
           None if found["stiffness_links"] is None else len(found["stiffness_links"]))
    if got != EXPECTED[name]:
        raise SystemExit(f"n = {n}: format {name} became {got}, expected {EXPECTED[name]}")
    return found


def compile_solve(system, solver: str, ts, v0):
    """The solve, compiled once; rtol is traced (an argument), so ``TIGHT_RTOL`` reuses it."""
    return Compiled(lambda s, v, rtol: mj.solve(s, ts, None, v, method=ode(solver, rtol=rtol)),
                    system, v0, RTOL)


def measure_size(length: int, quick: bool, budget: float, last: dict, say) -> list[dict]:
    """Every (format, solver) row at one n; ``last`` maps (format, solver) -> (n, run_s)."""
    m, k = assemble(length)
    n = m.shape[0]
    ts = jnp.linspace(0.0, HORIZON, OUTPUTS)
    v0 = mj.unit_vector(n, n)  # the hub
    rows = []
    start = time.perf_counter()
    systems, build_s = {}, {}
    for name in FORMATS:  # the second build is timed: the first compiles the eager checks
        jax.block_until_ready(build(name, length, m, k))
        begin = time.perf_counter()
        systems[name] = jax.block_until_ready(build(name, length, m, k))
        build_s[name] = elapsed(begin)
    # the hand-assembled K is the branched chain's (an independent check of both)
    k_chain = np.asarray(systems["branched"].stiffness.as_matrix())
    if not np.array_equal(k_chain, k.toarray()):
        raise SystemExit(f"n = {n}: branched_chain's K differs from the assembled K by "
                         f"{np.max(np.abs(k_chain - k.toarray())):.3g}")
    found = {name: check_operators(name, systems[name], n) for name in FORMATS}
    # detection: the csr's K became branched_chain's very operator (same bands, links, springs)
    ours, theirs = systems["scipy_csr"].stiffness, systems["branched"].stiffness
    if not (ours.links == theirs.links and all(
            np.array_equal(np.asarray(getattr(ours, f)), np.asarray(getattr(theirs, f)))
            for f in ("diagonal", "off_diagonal", "link_springs"))):
        raise SystemExit(f"n = {n}: scipy_csr's detected K differs from branched_chain's")
    say(f"n = {n}: operators " + ", ".join(
        f"{name}: M {f['mass']}, K {f['stiffness']}"
        + (f" + links {f['stiffness_links']}" if f["stiffness_links"] else "")
        for name, f in found.items()))
    reference = None
    if n <= EXACT_MAX_N:
        reference = np.asarray(mj.solve(systems["branched"], ts, None, v0,
                                        method=mj.Spectral()).displacement)
    say(f"n = {n}: systems built")

    for solver in SOLVERS:
        firsts, calls = {}, {}
        for name in FORMATS:
            row = dict(n=n, format=name, solver=solver, path=PATHS[name, solver],
                       operators=found[name], build_s=build_s[name],
                       compile_s=None, run_s=None,
                       run_times_s=[], steps=None, skipped=None)
            rows.append(row)
            previous = last.get((name, solver))
            if previous is None and n != _first_n(quick):
                row["skipped"] = "skipped at a smaller n"
                say(f"n = {n}: {name} {solver} skipped ({row['skipped']})")
                continue
            if previous is not None:
                predicted = previous[1] * (n / previous[0]) ** EXPONENT[name, solver]
                if predicted > budget:
                    row["predicted_s"] = predicted
                    row["skipped"] = (f"predicted {predicted:.0f} s per call (n = {previous[0]}: "
                                      f"{previous[1]:.2g} s, times (n ratio)^"
                                      f"{EXPONENT[name, solver]}) > budget {budget:g} s")
                    say(f"n = {n}: {name} {solver} skipped ({row['skipped']})")
                    continue
            system = systems[name]
            call = compile_solve(system, solver, ts, v0)
            row["compile_s"] = call.compile_s
            first, _, times = timed(call, system, v0, RTOL, repeats=1)
            firsts[name], calls[name] = np.asarray(first.displacement), (call, system, times)
            row["steps"] = int(first.num_steps)
        # correctness before timing
        here = [r for r in rows if r["solver"] == solver and r["format"] in firsts]
        for row in here:
            x = firsts[row["format"]]
            row["max_abs_x"] = float(np.max(np.abs(x)))
            limit = (MODAL_COORDINATES if row["format"] in MODAL_FORMATS
                     else SAME_COORDINATES)
            row["vs_branched_limit"] = limit
            require(row, "vs_branched", relative(x, firsts["branched"]), limit)
            if reference is not None:
                require(row, "vs_exact", relative(x, reference), EXACT_CHECK)
        if solver == "dopri8" and n == _first_n(quick):
            # the modal path's gap is integration error: it closes at a tight tolerance
            tight = {name: np.asarray(call(system, v0, TIGHT_RTOL).displacement)
                     for name, (call, system, _) in calls.items()}
            for row in here:
                x = tight[row["format"]]
                require(row, "vs_branched_at_tight_rtol", relative(x, tight["branched"]),
                        TIGHT_CHECK)
                if reference is not None:
                    row["vs_exact_at_tight_rtol"] = relative(x, reference)
        say(f"n = {n}: {solver} checks passed")
        for row in rows:
            if row["solver"] != solver or row["format"] not in calls:
                continue
            call, system, times = calls[row["format"]]
            repeats = 3 if quick or times[0] > 2.0 else 5
            times = times + timed(call, system, v0, RTOL, repeats=repeats - 1)[2]
            row["run_times_s"] = times
            row["run_s"] = float(np.median(times))
            last[row["format"], solver] = (n, row["run_s"])
        say(f"n = {n}: {solver} timed ({elapsed(start):.0f} s at this n)")
    return rows


def relative(x, reference) -> float:
    """max |x - reference| / max |reference| over every DOF and time."""
    return float(np.max(np.abs(x - reference))) / float(np.max(np.abs(reference)))


def require(row: dict, key: str, value: float, limit: float) -> None:
    """Store ``row[key] = value``; stop the script unless value <= limit."""
    row[key] = value
    if not value <= limit:
        raise SystemExit(f"check failed: n = {row['n']}, {row['format']} {row['solver']}: "
                         f"{key} = {value:.2e} > {limit:g}")


def _first_n(quick: bool) -> int:
    return BRANCHES * (QUICK_LENGTHS if quick else LENGTHS)[0] + 1


def plot(data: dict):
    """(a) Dopri8 and (b) Kvaerno5 run time per format against n, (c) compile time."""
    rows, rtol = data["rows"], data["problem"]["rtol"]
    fig, axes = figure(nrows=3, sharex=True, figsize=(8, 13), readable=True)
    sizes = sorted({r["n"] for r in rows})
    colours = dict(zip(FORMATS, ("C0", "C4", "C1", "C3", "C2")))
    for ax, solver, letter in zip(axes[:2], SOLVERS, "ab"):
        for name in FORMATS:
            done = [r for r in rows if r["solver"] == solver and r["format"] == name
                    and r["run_s"] is not None]
            skipped = [r for r in rows if r["solver"] == solver and r["format"] == name
                       and r.get("predicted_s")]
            note = " (x: skipped, predicted)" if skipped else ""
            if done:
                ax.loglog([r["n"] for r in done], [r["run_s"] for r in done], "o-",
                          color=colours[name],
                          label=f"{name}: {data['paths'][f'{name} {solver}']}{note}")
            if done and skipped:
                ax.loglog([done[-1]["n"]] + [r["n"] for r in skipped],
                          [done[-1]["run_s"]] + [r["predicted_s"] for r in skipped], "x:",
                          color=colours[name])
        ax.set_title(f"({letter}) {solver} (rtol {rtol:g}): run time, median")
        ax.set_ylabel("run time per call [s]")
    ax = axes[2]
    for solver, marker in zip(SOLVERS, ("o", "s")):
        for name in FORMATS:
            done = [r for r in rows if r["solver"] == solver and r["format"] == name
                    and r["compile_s"] is not None]
            if done:
                ax.semilogx([r["n"] for r in done], [r["compile_s"] for r in done],
                            marker + ("-" if solver == "dopri8" else "--"), color=colours[name])
    ax.set_title("(c) compile time (trace + lower + XLA), colours as above")
    ax.set_ylabel("compile time [s]")
    ax.set_ylim(bottom=0)
    ax.plot([], [], "ko-", label="dopri8")
    ax.plot([], [], "ks--", label="kvaerno5")
    for ax in axes:
        ax.set_xlabel("chain size n (DOFs)")
        ax.xaxis.set_tick_params(labelbottom=True)
        ax.set_xticks(sizes, [str(n) for n in sizes])
        ax.minorticks_off()
        ax.grid(True, which="both", alpha=0.3)
        legend(ax, "below", ncol=2 if ax is axes[2] else 1)
    fig.suptitle("One branched chain (3 branches + hub) as branched_chain / scipy csr (detected) "
                 f"/\nSparse / Dense K / Dense M and K: {subtitle(data['metadata'])}")
    return save_figure(fig, NAME, data["quick"])


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True, budget=dict(
        type=float, default=20.0, help="skip a combination whose predicted call exceeds this (s)"))
    if args.replot:
        return plot(read_json(NAME, args.quick))
    quick, budget = args.quick, args.budget
    lengths = QUICK_LENGTHS if quick else LENGTHS
    wall = time.perf_counter()
    say = lambda text: print(f"{text} [{elapsed(wall):.0f} s]", flush=True)  # noqa: E731
    rows, last = [], {}
    for length in lengths:
        rows += measure_size(length, quick, budget, last, say)

    print_table(rows, [("n", "n", "d"), ("format", "format", "s"), ("solver", "solver", "s"),
                       ("build_s", "build s", ".3f"), ("compile_s", "compile s", ".2f"),
                       ("run_s", "run s (median)", ".4f"), ("steps", "steps", "d"),
                       ("vs_branched", "vs branched", ".1e"), ("vs_exact", "vs exact", ".1e")])
    for r in rows:
        if r["skipped"]:
            print(f"skipped: n = {r['n']} {r['format']} {r['solver']}: {r['skipped']}")
    exponents = {f"{name} {solver}": fit_exponent(
        [r["n"] for r in rows if r["format"] == name and r["solver"] == solver],
        [r["run_s"] for r in rows if r["format"] == name and r["solver"] == solver])
        for name in FORMATS for solver in SOLVERS}
    data = {
        "problem": {"branches": BRANCHES, "lengths": list(lengths),
                    "n": [BRANCHES * L + 1 for L in lengths], "masses": 1.0, "springs": 1.0,
                    "hub_mass": 1.0, "hub_spring": 1.0,
                    "damper": {"kind": "grounded", "dof": "L (branch 1's mass next to the hub)",
                               "coefficient": DAMPER_COEFFICIENT},
                    "rayleigh": {"alpha": ALPHA, "beta": BETA},
                    "initial": "v(0) = 1 at the hub (DOF n), x(0) = 0", "load": None,
                    "ts": f"linspace(0, {HORIZON:g}, {OUTPUTS})", "rtol": RTOL,
                    "atol": "default: 1e-2 rtol max|v0| = 1e-10"},
        "checks": {"same_coordinates_vs_branched": SAME_COORDINATES,
                   "modal_coordinates_vs_branched": MODAL_COORDINATES,
                   "vs_exact_solve": EXACT_CHECK, "exact_max_n": EXACT_MAX_N,
                   "tight_rtol": TIGHT_RTOL, "all_vs_branched_at_tight_rtol": TIGHT_CHECK,
                   "measure": "max |x - x_ref| / max |x_ref| over all DOFs and 201 times"},
        "budget_s_per_call": budget,
        "cost_exponents": {f"{name} {solver}": p for (name, solver), p in EXPONENT.items()},
        "expected_operators": {name: dict(zip(("mass", "stiffness", "stiffness_links"), v))
                               for name, v in EXPECTED.items()},
        "operators_found": {r["format"]: r["operators"] for r in rows if r["n"] == rows[-1]["n"]},
        "paths": {
            f"{name} {solver}": PATHS[name, solver] for name, solver in PATHS},
        "fitted_run_time_exponents": exponents, "rows": rows,
        "skipped": [f"n = {r['n']} {r['format']} {r['solver']}: {r['skipped']}" for r in rows
                    if r["skipped"]],
        "wall_s": elapsed(wall),
    }
    path = write_json(NAME, quick, data)
    png = plot(read_json(NAME, quick))
    print(f"\nwrote {path} and {png} in {elapsed(wall):.0f} s")
    return data


if __name__ == "__main__":
    main()
