"""The spectral engine against its targets: gradients, compile, all-DOF histories, batches.

The Section 5 setup at several n: Mikota's chain, a grounded damper (position p = 7, c = 1),
x_3(0) = 1, v(0) = 0. Every comparison of a row runs in this one process, compile timed apart
(``Compiled``: trace + lower, then XLA), run times the median of warm calls:

* **Energy and gradient**: ``jax.jit(jax.value_and_grad(J))`` of J(p, c) = ``mj.Energy(20.0,
  x0=e_3)`` of ``mikota_chain(n, dampers=[GroundedDamper(p, c)])`` (the damped modes in closed
  form), at n = 300 and 1000; against one value of the same J by scipy: Van Loan's block
  exponential expm([[-A^T, Q], [0, A]] T) of the first-order form (A = [[0, I], [-M^-1 K,
  -M^-1 D]], Q = diag(K, M)), J = s0^T (F22^T F12) s0 / 2, timed once (n = 300 only: at
  n = 1000 it is a 4000 x 4000 exponential). The two values' relative difference is scipy's
  error as much as ours (its exponential of a 1200 x 1200 matrix of norm ~6000 T); the
  engine's own accuracy is the trust tests' (mpmath truths).
* **First call** of that gradient: trace + lower and XLA compile, apart.
* **All DOFs at 2001 times** on [0, 20] (the paper's output grid): ``mj.solve`` with
  ``Spectral()``, our ``ODE()`` (Dopri8, rtol 1e-8, atol 1e-10) and scipy's ``solve_ivp``
  DOP853 (rtol 1e-8, atol 1e-10, the chain applied in O(n), ``t_eval`` the grid; one run),
  n = 300, 1000, 3000; each one's largest error over all DOFs and times against the spectral
  history, relative to max |x| (the spectral path is the truth here: 1e-14 against the dense
  exponential in ``scaling.py``).
* **A long chain, one DOF**: n = 10^4, the history of DOF 150 at the same 2001 times, the
  spectral path (the chain's modes a chunk at a time, no U) against our Dopri8 at rtol 1e-10
  (atol 1e-12), first call and one warm call each (full runs only), the Dopri8 history's
  error relative to max |x|.
* **Batched designs**: ``jax.jit(jax.vmap(jax.value_and_grad(J)))`` over B designs (p in [5,
  2n/3], c in [0.5, 3]), n = 300: time per design against one design alone (p = 7, c = 1) and
  against the mean of the same designs run one by one (their root iterations differ: 3 sweeps
  at p = 7, up to 14 for a damper inside the chain), and XLA's temporary memory per design
  (``memory_analysis``); and the same designs through ``mj.sweep`` (its CPU default, one design
  after another in a ``lax.map``), its second call.
* **Blocks of roots**: the same gradient with the O(n^2) per-root work done a block of roots at
  a time (the library's choice, ``row_block``) and all at once (``block=0``), n = 100, 300,
  1000, 3000: run time and XLA's temporary memory (a block's rows stay in cache).

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/engine.py [--quick] [--replot]``
(``--quick``: n = 60 for every row, n = 100 for the blocks, the history without scipy,
B = 4). Writes ``results/engine[_quick].json`` and ``.png``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (Compiled, elapsed, figure, legend, ode, parse_args,  # noqa: I001
                     print_table, read_json, save_figure, subtitle, timed, write_json)

import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg as sl
from scipy.integrate import solve_ivp

import mikota_jax as mj
from mikota_jax.testing import spectral_energy_with_result

NAME = "engine"
GRADIENT_SIZES, QUICK_GRADIENT_SIZES = (300, 1000), (60,)
VAN_LOAN_MAX = 300
HISTORY_SIZES, QUICK_HISTORY_SIZES = (300, 1000, 3000), (60,)
BATCH, QUICK_BATCH = 16, 4
BATCH_N, QUICK_BATCH_N = 300, 60
HORIZON, TIMES = 20.0, 2001
RTOL, ATOL = 1e-8, 1e-10
REPEATS, QUICK_REPEATS = 5, 2
BLOCK_SIZES, QUICK_BLOCK_SIZES = (100, 300, 1000, 3000), (100,)


def chain(n: int, p=7.0, c=1.0) -> mj.SecondOrderSystem:
    return mj.mikota_chain(n, dampers=[mj.GroundedDamper(p, c)])


def energy_function(n: int):
    """J(p, c): the Section 5 energy on [0, 20] of the chain with its damper at (p, c)."""
    energy = mj.Energy(HORIZON, x0=mj.unit_vector(n, 3))
    return lambda p, c: energy(chain(n, p, c))


def van_loan_energy(system: mj.SecondOrderSystem, x0) -> float:
    """J by scipy: Van Loan's block exponential of the first-order form (dense, O(n^3))."""
    m, d, k = (np.asarray(a) for a in system.dense())
    n = m.shape[0]
    m_inv = np.linalg.inv(m)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-m_inv @ k, -m_inv @ d]])
    q = np.block([[k, np.zeros((n, n))], [np.zeros((n, n)), m]])
    block = np.block([[-a.T, q], [np.zeros_like(a), a]])
    e = sl.expm(block * HORIZON)
    gramian = e[2 * n:, 2 * n:].T @ e[:2 * n, 2 * n:]
    s0 = np.concatenate([np.asarray(x0), np.zeros(n)])
    return float(s0 @ gramian @ s0 / 2)


def gradient_row(n: int, repeats: int) -> dict:
    fn = Compiled(jax.value_and_grad(energy_function(n), argnums=(0, 1)), 7.0, 1.0)
    (value, grad), run_s, _ = timed(fn, 7.0, 1.0, repeats=repeats)
    row = dict(n=n, trace_s=fn.trace_s, xla_s=fn.xla_s, first_call_s=fn.compile_s + run_s,
               run_s=run_s, J=float(value), dJ_dp=float(grad[0]), dJ_dc=float(grad[1]),
               temp_mb=fn.executable.memory_analysis().temp_size_in_bytes / 1e6)
    if n <= VAN_LOAN_MAX:
        reference, scipy_s, _ = timed(van_loan_energy, chain(n), mj.unit_vector(n, 3),
                                      repeats=1)
        row.update(van_loan_s=scipy_s, van_loan_J=reference, speedup=scipy_s / run_s,
                   difference=abs(float(value) - reference) / abs(reference))
    return row


def scipy_history(system: mj.SecondOrderSystem, ts, x0) -> np.ndarray:
    """All DOFs at ``ts`` by scipy's DOP853, the chain's K x and D v applied in O(n)."""
    m, d, k = (np.asarray(a) for a in system.dense())
    masses = np.diag(m)
    bands = [np.diag(k, 1), np.diag(k), np.diag(k, -1)]
    damping = np.diag(d).copy()
    n = masses.size

    def tridiagonal(x):
        out = bands[1] * x
        out[:-1] += bands[0] * x[1:]
        out[1:] += bands[2] * x[:-1]
        return out

    def rhs(_, s):
        x, v = s[:n], s[n:]
        return np.concatenate([v, -(tridiagonal(x) + damping * v) / masses])

    sol = solve_ivp(rhs, (ts[0], ts[-1]), np.concatenate([x0, np.zeros(n)]), method="DOP853",
                    t_eval=ts, rtol=RTOL, atol=ATOL)
    return sol.y[:n].T


def history_row(n: int, repeats: int, with_scipy: bool) -> dict:
    ts = jnp.linspace(0.0, HORIZON, TIMES)
    x0 = mj.unit_vector(n, 3)
    row = dict(n=n)
    histories = {}
    for key, method in (("spectral", mj.Spectral()),
                        ("dopri8", ode("dopri8", rtol=RTOL, atol=ATOL, max_steps=10**6))):
        fn = Compiled(lambda s, m=method: mj.solve(s, ts, x0, method=m).displacement, chain(n))
        histories[key], run_s, _ = timed(fn, chain(n), repeats=repeats)
        row.update({f"{key}_s": run_s, f"{key}_compile_s": fn.compile_s})
    if with_scipy:
        histories["dop853"], row["dop853_s"], _ = timed(
            scipy_history, chain(n), np.asarray(ts), np.asarray(x0), repeats=1)
    truth = np.asarray(histories["spectral"])
    scale = np.max(np.abs(truth))
    for key in ("dopri8", "dop853"):
        if key in histories:
            row[f"{key}_error"] = float(np.max(np.abs(np.asarray(histories[key]) - truth)) / scale)
            row[f"{key}_ratio"] = row[f"{key}_s"] / row["spectral_s"]
    return row


LONG_N, LONG_DOF = 10_000, 150


def long_row() -> dict:
    ts = jnp.linspace(0.0, HORIZON, TIMES)
    x0 = mj.unit_vector(LONG_N, 3)
    row = dict(n=LONG_N, dof=LONG_DOF)
    histories = {}
    for key, method in (("spectral", mj.Spectral()),
                        ("dopri8", ode("dopri8", rtol=1e-10, atol=1e-12, max_steps=10**6))):
        fn = Compiled(lambda s, m=method: mj.solve(s, ts, x0, method=m,
                                                   dofs=(LONG_DOF,)).displacement,
                      chain(LONG_N))
        first, first_s, _ = timed(fn, chain(LONG_N), repeats=1)
        histories[key], run_s, _ = timed(fn, chain(LONG_N), repeats=1)
        row.update({f"{key}_s": run_s, f"{key}_first_call_s": fn.compile_s + first_s})
    truth = np.asarray(histories["spectral"])
    row["dopri8_error"] = float(np.max(np.abs(np.asarray(histories["dopri8"]) - truth))
                                / np.max(np.abs(truth)))
    row["dopri8_ratio"] = row["dopri8_s"] / row["spectral_s"]
    return row


def batch_row(n: int, batch: int, repeats: int) -> dict:
    g = jax.value_and_grad(energy_function(n), argnums=(0, 1))
    one = Compiled(g, 7.0, 1.0)
    _, one_s, _ = timed(one, 7.0, 1.0, repeats=repeats)
    ps, cs = jnp.linspace(5.0, 2 * n / 3, batch), jnp.linspace(0.5, 3.0, batch)
    many = Compiled(jax.vmap(g), ps, cs)
    (values, _), many_s, _ = timed(many, ps, cs, repeats=repeats)
    singles = [float(one(p, c)[0]) for p, c in zip(ps[:2], cs[:2])]
    # the same designs one by one: their Aberth sweeps differ (3 at p = 7, up to 14 inside)
    alone_s = statistics.mean(timed(one, p, c, repeats=repeats)[1] for p, c in zip(ps, cs))
    # the same designs through ``mj.sweep`` (its default on a CPU: one design after another,
    # ``lax.map``), its second call (the first compiles)
    points = dict(p=np.asarray(ps), c=np.asarray(cs))
    swept = lambda point: g(point["p"], point["c"])  # noqa: E731
    mj.sweep(swept, points)
    sweep_s = min(_sweep_time(swept, points) for _ in range(2)) / batch
    return dict(n=n, batch=batch, one_s=one_s, batch_s=many_s, per_design_s=many_s / batch,
                per_design_ratio=many_s / batch / one_s, alone_s=alone_s,
                per_design_ratio_alone=many_s / batch / alone_s, sweep_per_design_s=sweep_s,
                sweep_ratio=sweep_s / one_s, sweep_ratio_alone=sweep_s / alone_s,
                one_temp_mb=one.executable.memory_analysis().temp_size_in_bytes / 1e6,
                temp_mb_per_design=many.executable.memory_analysis().temp_size_in_bytes
                / 1e6 / batch, compile_s=many.compile_s,
                agrees=float(np.max(np.abs(np.asarray(values[:2]) - singles)
                                 / np.abs(singles))))


def _sweep_time(function, points) -> float:
    start = time.perf_counter()
    jax.block_until_ready(mj.sweep(function, points))
    return time.perf_counter() - start


def block_row(n: int, repeats: int) -> dict:
    """J + gradient with the roots' rows a block at a time (automatic) and all at once."""
    x0, v0 = mj.unit_vector(n, 3), jnp.zeros(n)
    row = dict(n=n)
    values = {}
    for key, block in (("blocks", None), ("whole", 0)):
        def energy(p, c, block=block):
            return spectral_energy_with_result(chain(n, p, c), HORIZON, x0, v0, block=block)[0]

        fn = Compiled(jax.value_and_grad(energy, argnums=(0, 1)), 7.0, 1.0)
        values[key], run_s, _ = timed(fn, 7.0, 1.0, repeats=repeats)
        row.update({f"{key}_s": run_s, f"{key}_compile_s": fn.compile_s,
                    f"{key}_temp_mb": fn.executable.memory_analysis().temp_size_in_bytes / 1e6})
    (a, ga), (b, gb) = values["blocks"], values["whole"]
    row["speedup"] = row["whole_s"] / row["blocks_s"]
    row["difference"] = float(max(abs(float(a) - float(b)) / abs(float(b)),
                                  *(abs(float(x) - float(y)) / abs(float(y))
                                    for x, y in zip(ga, gb))))
    return row


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return print(plot(read_json(NAME, args.quick), args.quick))
    start = time.perf_counter()
    repeats = QUICK_REPEATS if args.quick else REPEATS
    gradients = [gradient_row(n, repeats) for n in
                 (QUICK_GRADIENT_SIZES if args.quick else GRADIENT_SIZES)]
    print_table(gradients, [("n", "n", "d"), ("trace_s", "trace s", ".2f"),
                            ("xla_s", "XLA s", ".2f"), ("run_s", "run s", ".4f"),
                            ("van_loan_s", "scipy Van Loan s", ".3f"),
                            ("speedup", "speed-up", ".1f"), ("difference", "rel. diff", ".1e")])
    histories = [history_row(n, repeats, not args.quick) for n in
                 (QUICK_HISTORY_SIZES if args.quick else HISTORY_SIZES)]
    print_table(histories, [("n", "n", "d"), ("spectral_s", "spectral s", ".3f"),
                            ("dopri8_s", "Dopri8 s", ".3f"), ("dopri8_error", "its error", ".1e"),
                            ("dop853_s", "scipy DOP853 s", ".3f"),
                            ("dop853_error", "its error", ".1e")])
    long = None if args.quick else long_row()
    if long is not None:
        print_table([long], [("n", "n", "d"), ("spectral_s", "spectral s", ".1f"),
                             ("dopri8_s", "Dopri8 rtol 1e-10 s", ".1f"),
                             ("dopri8_ratio", "ratio", ".2f"),
                             ("dopri8_error", "its error", ".1e")])
    batch = batch_row(QUICK_BATCH_N if args.quick else BATCH_N,
                      QUICK_BATCH if args.quick else BATCH, repeats)
    print_table([batch], [("n", "n", "d"), ("batch", "designs", "d"),
                          ("one_s", "one design s", ".4f"),
                          ("per_design_s", "per design in batch s", ".4f"),
                          ("per_design_ratio", "ratio", ".2f"),
                          ("alone_s", "same designs alone s", ".4f"),
                          ("per_design_ratio_alone", "ratio", ".2f"),
                          ("sweep_per_design_s", "mj.sweep per design s", ".4f"),
                          ("sweep_ratio", "ratio", ".2f"),
                          ("temp_mb_per_design", "MB per design", ".1f")])
    blocks = [block_row(n, repeats) for n in (QUICK_BLOCK_SIZES if args.quick else BLOCK_SIZES)]
    print_table(blocks, [("n", "n", "d"), ("blocks_s", "blocks s", ".4f"),
                         ("whole_s", "all at once s", ".4f"), ("speedup", "speed-up", ".2f"),
                         ("blocks_temp_mb", "blocks MB", ".1f"),
                         ("whole_temp_mb", "all at once MB", ".1f"),
                         ("difference", "rel. diff", ".1e")])
    data = dict(summary=summarise(gradients, histories, long, batch, blocks), rows=histories,
                gradients=gradients, histories=histories, long_chain=long, batch=batch,
                blocks=blocks,
                problem=dict(horizon=HORIZON, times=TIMES, rtol=RTOL, atol=ATOL,
                             damper=dict(position=7.0, coefficient=1.0), x0="e_3"),
                total_wall_s=elapsed(start))
    write_json(NAME, args.quick, data)
    print(plot(read_json(NAME, args.quick), args.quick))
    return data


def summarise(gradients, histories, long, batch, blocks) -> dict:
    """The issue's target rows, one quantity each (the benchmark page shows them)."""
    out = {}
    for row in gradients:
        out[f"gradient n={row['n']}: run s"] = row["run_s"]
        out[f"gradient n={row['n']}: first call s"] = row["first_call_s"]
        if "speedup" in row:
            out[f"gradient n={row['n']}: x scipy Van Loan value"] = row["speedup"]
            out[f"gradient n={row['n']}: difference to scipy"] = row["difference"]
    for row in histories:
        for key in ("dopri8", "dop853"):
            if f"{key}_ratio" in row:
                out[f"all DOFs n={row['n']}: {key} time / spectral time"] = row[f"{key}_ratio"]
    if long is not None:
        out[f"DOF {long['dof']} n={long['n']}: Dopri8 1e-10 time / spectral time"] = (
            long["dopri8_ratio"])
    out[f"{batch['batch']} designs n={batch['n']}: time per design / one alone"] = (
        batch["per_design_ratio"])
    if "per_design_ratio_alone" in batch:
        out[f"{batch['batch']} designs n={batch['n']}: time per design / the same designs "
            "alone"] = batch["per_design_ratio_alone"]
    if "sweep_ratio" in batch:
        out[f"{batch['batch']} designs n={batch['n']} through mj.sweep: time per design / one "
            "alone"] = batch["sweep_ratio"]
        out[f"{batch['batch']} designs n={batch['n']} through mj.sweep: time per design / the "
            "same designs alone"] = batch["sweep_ratio_alone"]
    out[f"{batch['batch']} designs n={batch['n']}: MB per design"] = batch["temp_mb_per_design"]
    for row in blocks:
        out[f"gradient n={row['n']}: all at once / blocks of roots"] = row["speedup"]
    return out


def plot(data: dict, quick: bool):
    fig, (left, right) = figure(readable=True, ncols=2, figsize=(11, 4.2))
    rows = data["histories"]
    sizes = [r["n"] for r in rows]
    for key, label, style in (("spectral_s", "spectral (exact)", "o-"),
                              ("dopri8_s", "our Dopri8, rtol 1e-8", "s--"),
                              ("dop853_s", "scipy DOP853, rtol 1e-8", "^:")):
        if all(key in r for r in rows):
            left.loglog(sizes, [r[key] for r in rows], style, label=label)
    left.set_xticks(sizes, [str(n) for n in sizes])
    left.minorticks_off()
    left.set_xlabel("n")
    left.set_ylabel("seconds (warm)")
    left.set_title("all DOFs at 2001 times")
    legend(left, "below")
    grads = data["gradients"]
    labels = [f"n = {r['n']}" for r in grads]
    x = np.arange(len(grads))
    right.bar(x - 0.2, [r["trace_s"] + r["xla_s"] for r in grads], 0.4,
              label="first call: trace + compile")
    right.bar(x + 0.2, [r["run_s"] for r in grads], 0.4, label="warm run")
    right.set_yscale("log")
    right.set_xticks(x, labels)
    right.set_ylabel("seconds")
    right.set_title("jit(value_and_grad) of the energy")
    legend(right, "below")
    fig.suptitle(subtitle(data.get("metadata")))
    return save_figure(fig, NAME, quick)


if __name__ == "__main__":
    main()
