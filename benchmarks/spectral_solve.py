"""exact_solve's spectral path against its dense path, scipy's expm loop and scipy's DOP853.

The Section 5 scene (``section5_damped``: Mikota's chain, n = 300, m = k = 1, one grounded damper
d = 1 at DOF 7, x_3(0) = 1), all 300 DOFs at 2001 times on [0, 20]:

* ``exact_solve(method="spectral")``: the damped modes, every output as one matrix product;
* ``exact_solve(method="dense")``: one 2n x 2n matrix exponential, a scan of N products;
* scipy: ``expm(A h)`` of the physical state matrix and a loop of 2000 matrix-vector products;
* scipy ``solve_ivp(DOP853)`` with a CSR right-hand side at rtol 1e-8 (atol 1e-12).

Correctness first: each method's error, max over DOFs and times of |x - x_ref| / max |x_ref|,
against a reference by scipy's ``expm(A t)`` at each of 21 times (every 100th: one exponential per
time, no accumulation). Compile time apart (``lower().compile()`` of the jitted solve), run time
the median of 5 calls of the public ``exact_solve`` (DOP853: 3), every comparison in one
process. The targets: exact to 1e-12; >= 3x faster than the scipy expm loop; >= 20x
faster than DOP853 at rtol 1e-8.
"""

import jax
import jax.numpy as jnp
import numpy as np
import scipy.integrate as si
import scipy.linalg as sl
import scipy.sparse as sp
from _common import (
    Compiled,
    figure,
    parse_args,
    print_table,
    read_json,
    save_figure,
    subtitle,
    timed,
    write_json,
)

import mikota_jax as mj
from mikota_jax.testing import dense_solve_with_result, spectral_solve_with_result

TARGETS = {"error": 1e-12, "vs_scipy_expm": 3.0, "vs_dop853": 20.0}


def scene(quick: bool):
    base = mj.app.load_scene("section5_damped")
    n = 60 if quick else base.system.size
    system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(7.0, 1.0)]) if quick else base.system
    x0 = np.zeros(n)
    x0[2] = 1.0
    return system, np.linspace(0.0, 20.0, 2001), x0


def scipy_methods(system, ts, x0):
    M, D, K = (np.asarray(a) for a in system.dense())
    n = x0.shape[0]
    inverse = 1.0 / np.diag(M)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-inverse[:, None] * K, -inverse[:, None] * D]])
    y0 = np.concatenate([x0, np.zeros(n)])

    def expm_loop():
        p = sl.expm(a * (ts[1] - ts[0]))
        out, z = np.empty((ts.shape[0], n)), y0
        out[0] = x0
        for k in range(1, ts.shape[0]):
            z = p @ z
            out[k] = z[:n]
        return out

    a_csr = sp.csr_matrix(a)

    def dop853():
        sol = si.solve_ivp(lambda t, y: a_csr @ y, (ts[0], ts[-1]), y0, method="DOP853",
                           t_eval=ts, rtol=1e-8, atol=1e-12)
        return sol.y[:n].T

    def reference(every):
        return np.stack([(sl.expm(a * t) @ y0)[:n] for t in ts[::every]])

    return expm_loop, dop853, reference


def plot(data: dict) -> None:
    """Run time against error, each point labelled with its time and its ratio to spectral's."""
    fig, ax = figure(figsize=(7, 4.4), readable=True)
    errors = [max(row["error"], 1e-17) for row in data["rows"]]
    low, high = min(errors) / 10, max(errors) * 10
    for i, (x, row) in enumerate(zip(errors, data["rows"])):
        ax.semilogx(x, row["run_s"], "o", ms=8, color=f"C{i}")
        text = f"{row['method']}: {row['run_s']:.3f} s" + (
            f"\n= {row['speedup_of_spectral']:.1f}x spectral's time" if i else "")
        right = x > np.sqrt(low * high)  # labelled on the side with room
        ax.annotate(text, (x, row["run_s"]), xytext=(-8 if right else 8, 0),
                    textcoords="offset points", ha="right" if right else "left", va="center",
                    color=f"C{i}")
    ax.set_xlim(low, high)
    ax.set_ylim(0, 1.15 * max(r["run_s"] for r in data["rows"]))
    ax.set_xlabel("max error relative to max |x| (dimensionless)")
    ax.set_ylabel("run time [s] (median)")
    ax.set_title(f"Section 5 scene, n = {data['n']}, {data['times']} times on "
                 f"[0, {data['horizon']:g}], all DOFs\n{subtitle(data['metadata'])}")
    save_figure(fig, "spectral_solve", data["quick"])


def main(argv=None) -> None:
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return plot(read_json("spectral_solve", args.quick))
    system, ts, x0 = scene(args.quick)
    n = x0.shape[0]
    every = 100
    expm_loop, dop853, reference = scipy_methods(system, ts, x0)
    x_ref = reference(every)
    ts_j, x0_j, zeros = jnp.asarray(ts), jnp.asarray(x0), jnp.zeros(n)
    options = dict(dofs=tuple(range(1, n + 1)), displacement=True, velocity=False)
    compiled = {
        "spectral": Compiled(lambda s, x: spectral_solve_with_result(s, ts_j, x, zeros, None,
                                                                     **options), system, x0_j),
        "dense": Compiled(lambda s, x: dense_solve_with_result(s, ts_j, x, zeros, None,
                                                               **options), system, x0_j),
    }
    methods = {
        "exact_solve spectral": lambda: np.asarray(
            mj.solve(system, ts, x0, method=mj.Spectral()).displacement),
        "exact_solve dense": lambda: np.asarray(
            mj.solve(system, ts, x0, method=mj.DenseExponential()).displacement),
        "scipy expm + loop": expm_loop,
        "scipy DOP853 rtol 1e-8 (CSR)": dop853,
    }
    scale = np.max(np.abs(x_ref))
    rows = []
    for name, fn in methods.items():
        x = fn()  # correctness first (and the first call's compile for exact_solve)
        error = float(np.max(np.abs(x[::every] - x_ref)) / scale)
        rows.append(dict(method=name, error=error))
        print(f"{name}: relative error {error:.1e}", flush=True)
    for row in rows:
        repeats = 3 if "DOP853" in row["method"] else 5
        _, median, samples = timed(methods[row["method"]], repeats=repeats)
        row.update(run_s=median, samples=samples)
        print(f"{row['method']}: {median:.4f} s", flush=True)
    rows[0]["compile_s"] = compiled["spectral"].compile_s
    rows[1]["compile_s"] = compiled["dense"].compile_s
    spectral = rows[0]["run_s"]
    for row in rows:
        row["speedup_of_spectral"] = row["run_s"] / spectral
    difference = float(np.max(np.abs(methods["exact_solve spectral"]()
                                      - methods["exact_solve dense"]())) / scale)
    verdict = {
        "error": rows[0]["error"] <= TARGETS["error"],
        "vs_scipy_expm": rows[2]["speedup_of_spectral"] >= TARGETS["vs_scipy_expm"],
        "vs_dop853": rows[3]["speedup_of_spectral"] >= TARGETS["vs_dop853"],
    }
    print_table(rows, [("method", "method", "s"), ("error", "rel. error", ".1e"),
                       ("run_s", "run s (median)", ".4f"), ("compile_s", "compile s", ".2f"),
                       ("speedup_of_spectral", "time / spectral", ".2f")])
    print(f"\nspectral vs dense, all times: {difference:.1e} relative; targets {TARGETS}; "
          f"met: {verdict}")
    path = write_json("spectral_solve", args.quick, dict(
        scene="section5_damped", n=n, times=int(ts.shape[0]), horizon=float(ts[-1]),
        reference=f"scipy expm(A t) at every {every}th time", rows=rows,
        spectral_vs_dense=difference, targets=TARGETS, met=verdict))
    plot(read_json("spectral_solve", args.quick))
    print(f"wrote {path}")
    jax.block_until_ready(jnp.zeros(()))


if __name__ == "__main__":
    main()
