"""Stability on stiff and extreme cases: every measured row of ``results/stability.md``.

Sections: size (n = 1 ... 10^5: which solver "auto" picks, what Dopri8, the structured Kvaerno5
and the exact solver cost, and their error against the analytic first-mode solution), a strong
damper, precision (float32 against float64), gradients at the edges, failures made loud; then the
rows of ``_stability_extremes.py`` (damping and parameter extremes) and ``_stability_pod.py``
(POD edge cases, hypothesis invariants). Each row names the test that asserts it.

    OPENBLAS_NUM_THREADS=1 python benchmarks/stability.py [--quick]
"""

import time

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from _common import (
    figure,
    legend,
    metadata,
    ode,
    parse_args,
    print_table,
    read_json,
    save_figure,
    subtitle,
    write_json,
)

import mikota_jax as mj
from mikota_jax.testing import choose_solver, stiffness_rate

T = 20.0


def _timed_solve(fn, repeats):
    """(result, first-call seconds, median run seconds): compile = first - run."""
    start = time.perf_counter()
    result = jax.block_until_ready(fn())
    first = time.perf_counter() - start
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = jax.block_until_ready(fn())
        runs.append(time.perf_counter() - start)
    return result, first, float(np.median(runs))


def size_rows(sizes, dopri_max):
    """First-mode free vibration x0 = i / n, x(t) = x0 cos(t), on [0, 20] (10 outputs)."""
    rows = []
    ts = np.linspace(0.0, T, 11)
    for n in sizes:
        system = mj.mikota_chain(n)
        x0 = np.arange(1.0, n + 1) / n
        truth = np.cos(ts)[:, None] * x0[[0, n - 1]][None, :]
        row = dict(n=n, auto=choose_solver(system, ts), rho_T=stiffness_rate(system) * T)
        for solver in ("dopri8", "kvaerno5"):
            if solver == "dopri8" and n > dopri_max:
                continue
            out, first, run = _timed_solve(lambda s=solver, system=system, x0=x0, n=n: mj.solve(
                system, ts, x0, dofs=[1, n],
                method=ode(s, rtol=1e-8, atol=1e-12, max_steps=1_000_000)),
                repeats=1 if n >= 10_000 else 3)
            row[solver] = dict(steps=int(out.num_steps), run_s=run, compile_s=first - run,
                               error=float(np.max(np.abs(np.asarray(out.displacement) - truth))))
        if n <= 1000:
            out, first, run = _timed_solve(
                lambda system=system, x0=x0, n=n: mj.solve(system, ts, x0, dofs=[1, n],
                                                           method=mj.DenseExponential()),
                repeats=3)
            row["exact"] = dict(run_s=run, compile_s=first - run, error=float(
                np.max(np.abs(np.asarray(out.displacement) - truth))))
        else:
            try:
                mj.solve(system, ts, x0, dofs=[1, n], method=mj.DenseExponential())
                row["exact"] = dict(note="ran")
            except ValueError as error:
                row["exact"] = dict(note="refused: " + str(error).split(":")[1].split(".")[0])
        rows.append(row)
        print(n, row, flush=True)
    return rows


def damper_rows(coefficients):
    """Paper chain n = 300, x_3(0) = 1, one grounded damper at DOF 7 (rate c * 7 / m)."""
    rows = []
    ts = np.linspace(0.0, T, 201)
    x0 = np.eye(300)[2]
    for c in coefficients:
        system = mj.mikota_chain(300, dampers=[mj.GroundedDamper(7.0, c)])
        exact = np.asarray(mj.solve(system, ts, x0, dofs=[3, 7, 300],
                                    method=mj.Spectral()).displacement)
        row = dict(coefficient=c, auto=choose_solver(system, ts))
        for solver in ("dopri8", "kvaerno5"):
            try:
                out, first, run = _timed_solve(lambda s=solver, system=system: mj.solve(
                    system, ts, x0, dofs=[3, 7, 300],
                    method=ode(s, rtol=1e-8, atol=1e-10, max_steps=100_000)), repeats=1)
                row[solver] = dict(steps=int(out.num_steps), run_s=run, error=float(
                    np.max(np.abs(np.asarray(out.displacement) - exact))))
            except ValueError as error:
                row[solver] = dict(note="stops: " + str(error).split(":")[1].split(".")[0])
        rows.append(row)
        print(c, row, flush=True)
    return rows


def precision_rows(n):
    """Undamped paper chain, x_3(0) = 1 on [0, 20]: float32 against float64 (reference: float64
    exact). float32 cannot enter the package (it is an error), so both float32 solvers are
    written out here: the same modal propagator and the same diffrax Tsit5 on the stencil."""
    ts = np.linspace(0.0, T, 201)
    system = mj.mikota_chain(n)
    x0 = np.eye(n)[2]
    reference = np.asarray(mj.solve(system, ts, x0, method=mj.DenseExponential()).displacement)
    scale = np.max(np.abs(reference))
    rows = []
    for dtype in (jnp.float32, jnp.float64):
        m = np.asarray(system.mass.diagonal)
        k = np.asarray(system.stiffness.as_matrix())
        s = (k / np.sqrt(m)[:, None] / np.sqrt(m)[None, :]).astype(dtype)
        w2, v = jnp.linalg.eigh(jnp.asarray(s))
        modes = v / jnp.sqrt(jnp.asarray(m, dtype))[:, None]
        omega = jnp.sqrt(jnp.abs(w2))
        eta0 = modes.T @ jnp.asarray(m * x0, dtype)
        tt = jnp.asarray(ts, dtype)
        exact = (modes @ (jnp.cos(omega[:, None] * tt[None, :]) * eta0[:, None])).T
        diagonal = jnp.asarray(np.diag(k), dtype)
        off = jnp.asarray(np.diag(k, 1), dtype)
        inverse_mass = jnp.asarray(1.0 / m, dtype)

        def field(t, y, args, diagonal=diagonal, off=off, inverse_mass=inverse_mass):
            x, v = y[:n], y[n:]
            kx = diagonal * x + jnp.pad(off * x[1:], (0, 1)) + jnp.pad(off * x[:-1], (1, 0))
            return jnp.concatenate([v, -inverse_mass * kx])

        rtol = 1e-6
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(field), diffrax.Tsit5(), tt[0], tt[-1], None,
            jnp.concatenate([jnp.asarray(x0, dtype), jnp.zeros(n, dtype)]),
            saveat=diffrax.SaveAt(ts=tt), max_steps=1_000_000,
            stepsize_controller=diffrax.PIDController(rtol=rtol, atol=rtol * 1e-2))
        rows.append(dict(
            dtype=jnp.dtype(dtype).name,
            exact_error=float(np.max(np.abs(np.asarray(exact, np.float64) - reference))) / scale,
            tsit5_error=float(np.max(np.abs(np.asarray(sol.ys[:, :n], np.float64) - reference)))
            / scale, tsit5_steps=int(sol.stats["num_steps"]), tsit5_rtol=rtol))
        print(rows[-1], flush=True)
    return rows


def gradient_rows():
    """AD against finite differences of the exact energy (n = 8, x_3(0) = 1, T = 20)."""
    n = 8
    x0 = np.eye(n)[2]

    def energy(p, c, horizon=20.0):
        system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(p, c)])
        return mj.Energy(horizon, x0)(system)

    def side(f, x, h):
        return float((-3 * f(x) + 4 * f(x + h) - f(x + 2 * h)) / (2 * h))

    def rel(a, b):
        return abs(float(a) - b) / abs(b)

    rows = []
    g = jax.grad(energy, argnums=1)(4.5, 0.0)
    rows.append(("d -> 0: dJ/dc at c = 0", f"AD {float(g):.6g}, one-sided FD rel. diff "
                 f"{rel(g, side(lambda c: energy(4.5, c), 0.0, 1e-5)):.1e}; dJ/dp = "
                 f"{float(jax.grad(energy)(4.5, 0.0)):.1g} (exactly 0)",
                 "test_the_coefficient_gradient_is_finite_and_right_as_the_damper_vanishes"))
    for p, h, name in ((1.0, 1e-4, "p = 1 (right-sided)"), (float(n), -1e-4, f"p = n = {n} "
                                                                           "(left-sided)")):
        g = jax.grad(energy)(p, 0.8)
        rows.append((f"position at the end, {name}", f"AD {float(g):.6g}, FD rel. diff "
                     f"{rel(g, side(lambda q: energy(q, 0.8), p, h)):.1e}",
                     "test_position_gradients_at_the_chain_ends_are_the_inward_one_sided_"
                     "derivatives"))
    right = side(lambda q: energy(q, 0.8), 5.0, 1e-5)
    left = side(lambda q: energy(q, 0.8), 5.0, -1e-5)
    g = jax.grad(energy)(5.0, 0.8)
    rows.append(("integer position p = 5 (kink)", f"right {right:.6g}, left {left:.6g}; AD "
                 f"{float(g):.6g} = right-sided (rel. diff {rel(g, right):.1e})",
                 "test_the_kink_at_an_integer_position_gives_the_right_sided_derivative"))
    g = jax.grad(lambda c: energy(3.5, c, 1000.0))(1e-3)
    fd = float((energy(3.5, 1e-3 + 1e-6, 1000.0) - energy(3.5, 1e-3 - 1e-6, 1000.0)) / 2e-6)
    rows.append(("long horizon T = 1000, c = 1e-3", f"AD {float(g):.6g}, central FD rel. diff "
                 f"{rel(g, fd):.1e}, finite",
                 "test_gradients_through_a_long_horizon_stay_finite_and_match_differences"))
    return [dict(area="Gradients at the edges", case=c, measured=m, test=t) for c, m, t in rows]


def failure_rows():
    """Each failure and the first line of what the user is told."""
    n = 12
    ts = np.linspace(0.0, 6.0, 7)
    strong = mj.mikota_chain(n, dampers=[mj.GroundedDamper(4.0, 1e6)])
    cases = [
        ("diffrax runs out of steps (c = 1e6, Dopri8, max_steps = 2000)",
         lambda: mj.solve(strong, ts, np.ones(n), method=mj.ODE(max_steps=2000)),
         "test_a_very_strong_damper_is_cheap_and_accurate_for_kvaerno5_and_stiff_for_dopri8"),
        ("the same, under jax.jit",
         lambda: jax.jit(lambda c: mj.solve(
             mj.mikota_chain(n, dampers=[mj.GroundedDamper(4.0, c)]), ts, np.ones(n),
             method=mj.ODE(max_steps=2000)).displacement)(1e6),
         "test_extremes / test_solvers (jit failure tests)"),
        ("non-finite initial state", lambda: mj.solve(strong, ts, np.full(n, np.nan),
                                                      method=mj.ODE()),
         "tests/test_solvers.py"),
        ("solver='auto' under jit", lambda: jax.jit(lambda k: mj.solve(
            mj.mikota_chain(n, k=k), ts, np.ones(n), method=mj.Auto()).displacement)(1.0),
         "test_auto_needs_concrete_values_and_says_so"),
        ("exact_solve at n = 200 000 (dense)", lambda: mj.solve(
            mj.mikota_chain(200_000), ts, np.ones(200_000), method=mj.DenseExponential()),
         "test_dense_methods_refuse_a_size_that_cannot_fit_in_memory"),
        ("float32 input", lambda: mj.solve(strong, ts, np.ones(n, np.float32), method=mj.ODE()),
         "tests/test_solvers.py, test_chain.py"),
    ]
    rows = []
    for case, fn, test in cases:
        try:
            fn()
            measured = "NO ERROR (silent)"
        except Exception as error:  # under jit: equinox's runtime error carries our message
            text = str(error)
            line = text[text.index("mikota_jax: "):].splitlines()[0] if "mikota_jax: " in text \
                else text.splitlines()[0]
            measured = f"{type(error).__name__}: " + line.removeprefix("mikota_jax: ")[:160]
        rows.append(dict(area="Failures made loud", case=case, measured=measured, test=test))
    return rows


def _markdown(sections, meta) -> str:
    lines = ["# Stability on stiff and extreme cases", "",
             f"Measured by `benchmarks/stability.py` on {meta['date']} ({subtitle(meta)}). "
             "Each row names the test that asserts it; the tables above the rows are the "
             "measured solver costs.", ""]
    for title, header, rows in sections:
        lines += [f"## {title}", "", "| " + " | ".join(header) + " |",
                  "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(str(c).replace("|", "/") for c in row) + " |"
                  for row in rows]
        lines.append("")
    return "\n".join(lines)


def _fmt(entry, key, spec):
    if entry is None:
        return "-"
    if "note" in entry:
        return entry["note"]
    return format(entry[key], spec)


def plot(data: dict) -> None:
    """Run time per solve against n, per solver (the size rows)."""
    fig, ax = figure(figsize=(7, 4.5), readable=True)
    for solver, style in (("dopri8", "o-"), ("kvaerno5", "s-"), ("exact", "^-")):
        points = [(r["n"], r[solver]["run_s"]) for r in data["size"]
                  if r.get(solver) and "run_s" in r[solver]]
        if points:
            ax.plot(*zip(*points), style, label=solver + {"kvaerno5": " (structured)",
                                                          "exact": " (dense)"}.get(solver, ""))
    ax.set(xscale="log", yscale="log", xlabel="chain size n (DOFs)",
           ylabel="run time per solve [s]",
           title="First-mode free vibration on [0, 20]\n" + subtitle(data["metadata"]))
    legend(ax)
    save_figure(fig, "stability", data["quick"])


def main(argv=None) -> None:
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return plot(read_json("stability", args.quick))
    sizes = [1, 10, 100, 1000] if args.quick else [1, 10, 100, 1000, 10_000, 100_000]
    size = size_rows(sizes, dopri_max=1000 if args.quick else 10_000)
    dampers = damper_rows([1e-8, 1.0, 1e3] if args.quick else [1e-8, 1.0, 1e3, 1e6])
    precision_n = 60 if args.quick else 300
    precision = precision_rows(precision_n)
    rows = gradient_rows() + failure_rows()
    for module in ("_stability_extremes", "_stability_pod"):
        try:
            rows += __import__(module).rows()
        except ImportError:
            print(f"({module} not found: its rows are left out)")
    meta = metadata()

    def solver_cell(entry):
        if entry is None:
            return "not run (> 5e5 explicit steps)"
        if "note" in entry:
            return entry["note"]
        steps = f"{entry['steps']} steps, " if "steps" in entry else ""
        return f"{steps}{entry['run_s']:.3g} s (+{entry['compile_s']:.2g} s compile), " \
               f"err {entry['error']:.1e}"

    size_table = [(r["n"], f"{r['rho_T']:.2g}", r["auto"], solver_cell(r.get("dopri8")),
                   solver_cell(r.get("kvaerno5")), solver_cell(r.get("exact")),
                   "test_kvaerno5_at_ten_thousand_dofs_keeps_the_analytic_mode_shape_solution"
                   if r["n"] >= 10_000 else "test_solvers.py / test_stiff.py") for r in size]
    damper_table = [(f"{r['coefficient']:.0e}", r["auto"],
                     *(r[s]["note"] if "note" in r[s] else
                       f"{r[s]['steps']} steps, {r[s]['run_s']:.3g} s, err {r[s]['error']:.1e}"
                       for s in ("dopri8", "kvaerno5")),
                     "test_a_very_strong_damper_is_cheap_and_accurate_for_kvaerno5_and_stiff_"
                     "for_dopri8") for r in dampers]
    precision_table = [(r["dtype"], f"{r['exact_error']:.1e}",
                        f"{r['tsit5_error']:.1e} ({r['tsit5_steps']} steps, rtol "
                        f"{r['tsit5_rtol']:g})",
                        "float32 in: ValueError (test_chain_rejects_float32_arrays)")
                       for r in precision]
    areas = {}
    for r in rows:
        areas.setdefault(r["area"], []).append((r["case"], r["measured"], r["test"]))
    sections = [
        ("Size: first-mode free vibration of Mikota's chain on [0, 20], rtol 1e-8",
         ["n", "rho T", "auto picks", "Dopri8", "Kvaerno5 (structured)", "exact (dense)",
          "test"], size_table),
        ("A strong damper: n = 300, x_3(0) = 1, damper at DOF 7, rtol 1e-8, max_steps 1e5",
         ["c", "auto picks", "Dopri8", "Kvaerno5 (structured)", "test"], damper_table),
        (f"Precision: undamped n = {precision_n}, x_3(0) = 1, "
         "relative max error against the float64 exact solution",
         ["dtype", "exact (modal)", "Tsit5", "package behaviour"], precision_table),
    ] + [(area, ["case", "measured", "test"], items) for area, items in areas.items()]
    text = _markdown(sections, meta)
    path = write_json("stability", args.quick,
                      dict(size=size, dampers=dampers, precision=precision, rows=rows))
    path.with_suffix(".md").write_text(text + "\n")
    print_table([dict(n=r["n"], auto=r["auto"],
                      dopri=(r.get("dopri8") or {}).get("run_s"),
                      kvaerno=(r.get("kvaerno5") or {}).get("run_s")) for r in size],
                [("n", "n", "d"), ("auto", "auto", "s"), ("dopri", "Dopri8 s", ".3g"),
                 ("kvaerno", "Kvaerno5 s", ".3g")])

    plot(read_json("stability", args.quick))


if __name__ == "__main__":
    main()
