"""The spectral engine's objectives against today's dense paths and scipy, in one process.

Two targets (each ratio measured in this process, compile time apart):

* **Integrated energy and its gradient**, the full n = 300 Section 5 system (Mikota's chain,
  m = k = 1, a grounded damper d = 1 at DOF 7.3 so that the position derivative is smooth,
  x_3(0) = 1, T = 20): ``Energy(method=Spectral())`` against ``method=DenseExponential()``
  (Van Loan's block exponential and doubling, today's exact path), value and
  ``jax.grad`` with respect to (position, coefficient). Target: >= 100x, agreeing to 1e-10.
* **Total average energy** (s = 27 lowest modes) and its gradient with respect to the three
  viscosities, FastOptimalDamping.jl's small example (n = 801: two chains of 400 masses, k_1 =
  100 and k_2 = 150, joined by m_0 = 1200 grounded by k_3 = 200; internal damping Gamma = 0.02
  Omega, i.e. modal zeta = 0.01; a grounded damper at DOF 50, a relative one between DOFs 550
  and 520, a grounded one at DOF 120; viscosities (100, 200, 300)): the spectral trace against
  scipy's ``solve_continuous_lyapunov`` on the same scaled modal matrix A = [[0, Omega],
  [-Omega, -U^T D U]] (its time excludes the eigendecomposition that builds A; ours includes
  the modes). Target: >= 100x, agreeing to 1e-9. The reference is scipy's solution with one
  step of iterative refinement.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/spectral_objectives.py [--quick]`` (``--quick``:
n = 100 and one chain of 2 x 100; fewer repeats). Writes ``results/spectral_objectives.json``
and ``.png``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (Compiled, figure, legend, metadata, parse_args,  # noqa: I001
                     print_table, read_json, save_figure, subtitle, timed, write_json)

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sl

import mikota_jax as mj

NAME = "spectral_objectives"


def section5(n):
    x0 = np.zeros(n)
    x0[2] = 1.0

    def energy(position, coefficient, method):
        system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(position, coefficient)])
        return mj.Energy(20.0, x0, method=method)(system)

    return energy


def two_chains(n1):
    """(M diagonal, K dense) of FastOptimalDamping.jl's small example (``GenerateExamples``)."""
    i = np.arange(1, n1 + 1)
    first = np.where(i <= n1 // 2, 1000.0 - 4 * i * 400 / n1, 3.0 * i * 400 / n1 - 400)
    masses = np.concatenate([first, 500.0 + i * 400 / n1, [1200.0]])
    n = 2 * n1 + 1
    base = 2 * np.eye(n1) - np.eye(n1, k=1) - np.eye(n1, k=-1)
    k = np.zeros((n, n))
    k[:n1, :n1], k[n1:2 * n1, n1:2 * n1] = 100.0 * base, 150.0 * base
    k[n1 - 1, -1] = k[-1, n1 - 1] = -100.0
    k[2 * n1 - 1, -1] = k[-1, 2 * n1 - 1] = -150.0
    k[-1, -1] = 100.0 + 150.0 + 200.0
    return masses, k


def fod_system(n1, viscosities):
    """The example's damped system: dampers at DOFs 50, (550, 520) and 120 for n1 = 400
    (scaled with n1 for a quick run)."""
    masses, k = two_chains(n1)
    at = lambda dof: dof * n1 // 400  # noqa: E731
    dampers = [mj.GroundedDamper(float(at(50)), viscosities[0]),
               mj.RelativeDamper((at(550), at(520)), viscosities[1]),
               mj.GroundedDamper(float(at(120)), viscosities[2])]
    return mj.system(masses, k, dampers=dampers, internal_damping=mj.ModalDamping(0.01))


def scaled_modal_matrix(system):
    m, d, k = (np.asarray(a) for a in system.dense())
    omega2, u = sl.eigh(k, m)
    omega = np.sqrt(omega2)
    n = omega.shape[0]
    return np.block([[np.zeros((n, n)), np.diag(omega)], [-np.diag(omega), -u.T @ d @ u]])


def lyapunov_trace(a, lowest):
    n = a.shape[0] // 2
    select = (np.arange(n) < lowest).astype(float)
    z = np.diag(np.concatenate([select, select]))
    x = sl.solve_continuous_lyapunov(a.T, -z)
    return np.trace(x), x, z


def energy_size(quick: bool) -> int:
    return 100 if quick else 300


def plot(data: dict) -> None:
    """Spectral against the dense / scipy baseline per quantity: times on the bars, the ratio
    above each pair."""
    spectral, dense, trace = data["energy_spectral"], data["energy_dense"], data["trace"]
    n = energy_size(data["quick"])
    cases = [(f"energy value\n(n = {n})", spectral["value_s"], dense["value_s"]),
             (f"energy gradient\n(n = {n})", spectral["gradient_s"], dense["gradient_s"]),
             (f"trace value\n(n = {trace['n']})", trace["value_s"], trace["scipy_lyapunov_s"]),
             (f"trace gradient\n(n = {trace['n']})", trace["gradient_s"], None)]
    fig, ax = figure(figsize=(7, 4.8), readable=True)
    x = np.arange(len(cases))
    ours = [c[1] for c in cases]
    base = [c[2] or np.nan for c in cases]
    bars = ax.bar(x - 0.2, ours, 0.4, label="spectral (ours)")
    ax.bar_label(bars, [f"{t:.3g} s" for t in ours], padding=2)
    bars = ax.bar(x + 0.2, base, 0.4,
                  label="dense Van Loan (energy) / scipy Lyapunov (trace value only)")
    ax.bar_label(bars, [f"{t:.3g} s" if np.isfinite(t) else "" for t in base], padding=2)
    for i, (_, t, b) in enumerate(cases):
        if b is not None:
            ax.text(i, 2.2 * max(t, b), f"spectral {b / t:.1f}x faster", ha="center",
                    weight="bold")
    ax.set_yscale("log")
    ax.set_ylim(0.5 * min(ours), 6 * np.nanmax(base))
    ax.set_xticks(x, [c[0] for c in cases])
    ax.set_ylabel("run time [s] (median; compile apart)")
    legend(ax, "below")
    ax.set_title("Spectral objectives vs dense and scipy\n" + subtitle(data["metadata"]))
    save_figure(fig, NAME, data["quick"])


def main(argv=None):
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return plot(read_json(NAME, args.quick))
    repeats = 3 if args.quick else 5
    rows, data = [], {}

    # --- integrated energy, Section 5 -----------------------------------------------------
    n = energy_size(args.quick)
    energy = section5(n)
    point = (jnp.array(7.3), jnp.array(1.0))
    for method, m in (("spectral", mj.Spectral()), ("dense", mj.DenseExponential())):
        value = Compiled(lambda p, c, m=m: energy(p, c, m), *point)
        grad = Compiled(jax.grad(lambda p, c, m=m: energy(p, c, m), argnums=(0, 1)), *point)
        v, t_value, _ = timed(value, *point, repeats=repeats)
        g, t_grad, _ = timed(grad, *point, repeats=repeats)
        data[f"energy_{method}"] = dict(value=float(v), gradient=[float(x) for x in g],
                                        value_s=t_value, gradient_s=t_grad,
                                        compile_value_s=value.compile_s,
                                        compile_gradient_s=grad.compile_s)
    spectral, dense = data["energy_spectral"], data["energy_dense"]
    agree_value = abs(spectral["value"] / dense["value"] - 1)
    agree_grad = max(abs(a / b - 1) for a, b in zip(spectral["gradient"], dense["gradient"]))
    for method in ("spectral", "dense"):
        entry = data[f"energy_{method}"]
        rows.append(dict(case=f"energy n={n}", method=method, value_s=entry["value_s"],
                         gradient_s=entry["gradient_s"], compile_s=entry["compile_value_s"]
                         + entry["compile_gradient_s"]))
    data["energy_speedup"] = dict(value=dense["value_s"] / spectral["value_s"],
                                  gradient=dense["gradient_s"] / spectral["gradient_s"],
                                  agreement_value=agree_value, agreement_gradient=agree_grad)

    # --- total average energy, FastOptimalDamping's small example --------------------------
    n1 = 100 if args.quick else 400
    lowest = 27
    viscosities = (100.0, 200.0, 300.0)
    system = fod_system(n1, viscosities)
    a = scaled_modal_matrix(system)
    (reference_raw, x, z), t_scipy, _ = timed(lambda: lyapunov_trace(a, lowest), repeats=1 if
                                              not args.quick else 3)
    refined = x + sl.solve_continuous_lyapunov(a.T, -(a.T @ x + x @ a + z))
    reference = float(np.trace(refined))

    def trace(c):
        return mj.AverageEnergy(lowest)(fod_system(n1, c))  # the spectral path (it applies)

    c0 = jnp.array(viscosities)
    value = Compiled(trace, c0)
    grad = Compiled(jax.grad(trace), c0)
    v, t_value, _ = timed(value, c0, repeats=repeats)
    g, t_grad, _ = timed(grad, c0, repeats=repeats)
    h = 1e-4 * c0
    fd = [(float(trace(c0.at[i].add(h[i]))) - float(trace(c0.at[i].add(-h[i])))) / (2 * h[i])
          for i in range(3)]
    data["trace"] = dict(n=2 * n1 + 1, lowest=lowest, viscosities=list(viscosities),
                         value=float(v), reference=reference, scipy_raw=float(reference_raw),
                         agreement=abs(float(v) / reference - 1), gradient=[float(x) for x in g],
                         central_differences=[float(x) for x in fd], value_s=t_value,
                         gradient_s=t_grad, scipy_lyapunov_s=t_scipy,
                         compile_value_s=value.compile_s, compile_gradient_s=grad.compile_s,
                         speedup_value=t_scipy / t_value)
    rows.append(dict(case=f"trace n={2 * n1 + 1}", method="spectral", value_s=t_value,
                     gradient_s=t_grad, compile_s=value.compile_s + grad.compile_s))
    rows.append(dict(case=f"trace n={2 * n1 + 1}", method="scipy lyapunov", value_s=t_scipy,
                     gradient_s=None, compile_s=None))
    print_table(rows, [("case", "case", ""), ("method", "method", ""),
                       ("value_s", "value s", ".4f"), ("gradient_s", "gradient s", ".4f"),
                       ("compile_s", "compile s", ".1f")])
    e = data["energy_speedup"]
    print(f"energy: spectral {e['value']:.0f}x faster (value), {e['gradient']:.0f}x (gradient) "
          f"than dense; agreement {e['agreement_value']:.1e} / {e['agreement_gradient']:.1e}")
    t = data["trace"]
    print(f"trace: spectral {t['speedup_value']:.1f}x faster than scipy Lyapunov; agreement "
          f"{t['agreement']:.1e} (raw scipy {abs(t['scipy_raw'] / reference - 1):.1e}); gradient "
          f"{t['gradient']} vs central differences {t['central_differences']}")
    data["meta"] = metadata()
    write_json(NAME, args.quick, data)
    plot(read_json(NAME, args.quick))


if __name__ == "__main__":
    main()
