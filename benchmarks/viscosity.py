"""Optimal viscosities at full order: FastOptimalDamping.jl's small example (the target).

The example (``spectral_objectives.fod_system``: n = 801, two chains of 400 masses joined by
m_0 = 1200, internal damping Gamma = 0.02 Omega, a grounded damper at DOF 50, a relative one
between DOFs 550 and 520, a grounded one at DOF 120; the trace of X over the s = 27 lowest
modes). ``Coefficients`` from their start [100, 100, 100], timed whole (compile
included, one process, nothing warm), against:

* the published optimum: FastOptimalDamping.jl's ``src/ResultsSmall`` prints the viscosities
  [561.342, 651.789, 310.626] in its order l = [50, 550, 120], i.e. (DOF 50, relative (550, 520),
  DOF 120), and the minimal trace 66434.859 (Optim.jl conjugate gradients with finite
  differences, x_tol = 1e-2, f_tol = 1e-6: 9 iterations, 19 values, 3320 s). Our coefficient
  vector lists the grounded dampers first, (DOF 50, DOF 120, relative), so theirs is
  (561.342, 310.626, 651.789) here. Our trace at them, and how far our optimum is. Their trace
  is taken in other coordinates (see ``fod_definition.py``): 4.4e-4 below ours at the same
  viscosities;
* ``Coefficients(SpectralProjectedGradient())`` (Li & Tisseur's spectral projected gradient;
  compiled already) and scipy's L-BFGS-B on the same compiled value and gradient (no compile in
  its time: it runs last), for the iteration and evaluation counts;
* the library minimisers that could replace the hand-written loops: ``optax.lbfgs()`` (zoom
  line search) and optimistix's ``BFGS`` and ``LBFGS``, each in u = log d on the same compiled
  value and gradient (a host callback, so no minimiser compiles the spectral engine again), each
  stopped by ``Coefficients``'s rule (relative gradient < 1e-6). Neither library takes bounds
  (optax's projections clip a step after its line search; optimistix has no box), so they are
  compared on this problem without upper bounds, where the box in log d is all of R^3.

Target: the optimum in < 60 s wall on the 2-core CPU, compile included, certified at
full order (the spectral trace is the full model's, exact), relative gradient < 1e-6.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/viscosity.py [--quick]`` (``--quick``: two chains
of 100). Writes ``results/viscosity[_quick].json`` and ``.png``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (figure, legend, parse_args, print_table, read_json,  # noqa: I001
                     save_figure, subtitle, write_json)

import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import optimistix as optx
import scipy.optimize
from spectral_objectives import fod_system

import mikota_jax as mj
from mikota_jax.testing import criterion_function

NAME = "viscosity"
START = (100.0, 100.0, 100.0)
# FastOptimalDamping.jl's src/ResultsSmall: the optimum in its order (DOF 50, relative (550, 520),
# DOF 120) and its trace; in our coefficient order (grounded first: DOF 50, DOF 120, relative)
PUBLISHED_AS_PRINTED = (561.3423561622229, 651.7892318332947, 310.62572129205705)
PUBLISHED = (561.3423561622229, 310.62572129205705, 651.7892318332947)
PUBLISHED_TRACE = 66434.85914071581  # in their coordinates (fod_definition.py)
# the other reading of the printed vector (relative and DOF 120 swapped), for the record
SWAPPED = PUBLISHED_AS_PRINTED
LOWEST = 27
TARGET_S = 60.0


def relative_gradient(d, value, gradient) -> float:
    """``Coefficients``'s stopping measure: max |d_i df/dd_i| / |f| (no bound is active)."""
    return float(np.max(np.abs(np.asarray(gradient) * np.asarray(d))) / abs(float(value)))


def in_log_d(evaluate, counts):
    """u -> f(exp u), traceable, its gradient by the same host evaluation: one (f, df/dd) per
    value-and-gradient that a minimiser asks for, counted in ``counts``."""

    def host(u):
        counts["evaluations"] += 1
        d = np.exp(np.asarray(u))
        value, gradient = evaluate(d)
        return np.float64(value), gradient * d

    def both(u):
        shapes = (jax.ShapeDtypeStruct((), jnp.float64), jax.ShapeDtypeStruct(u.shape, u.dtype))
        return jax.pure_callback(host, shapes, u)

    @jax.custom_jvp
    def value(u):
        return both(u)[0]

    @value.defjvp
    def _(primals, tangents):
        f, g = both(primals[0])
        return f, g @ tangents[0]

    return value


def optax_lbfgs(evaluate, start, tolerance=1e-6, max_iterations=200):
    """``optax.lbfgs()`` in log d until the relative gradient is below ``tolerance``."""
    counts = {"evaluations": 0}
    f = in_log_d(evaluate, counts)
    solver = optax.lbfgs()

    @jax.jit
    def step(u, state):
        value, gradient = optax.value_and_grad_from_state(f)(u, state=state)
        updates, state = solver.update(gradient, state, u, value=value, grad=gradient,
                                       value_fn=f)
        return optax.apply_updates(u, updates), state

    clock = time.perf_counter()
    u = jnp.log(jnp.asarray(start))
    state, iterations = solver.init(u), 0
    value, gradient = jax.value_and_grad(f)(u)
    while (relative_gradient(np.ones_like(u), value, gradient) >= tolerance
           and iterations < max_iterations):
        u, state = step(u, state)
        iterations += 1
        value = optax.tree.get(state, "value")
        gradient = optax.tree.get(state, "grad")
    return dict(coefficients=np.exp(np.asarray(u)).tolist(), value=float(value),
                iterations=iterations, evaluations=counts["evaluations"],
                relative_gradient=relative_gradient(np.ones_like(u), value, gradient),
                seconds=time.perf_counter() - clock)


def optimistix(solver, evaluate, start, tolerance=1e-6, max_iterations=200):
    """An optimistix minimiser's steps in log d until the relative gradient at its iterate is
    below ``tolerance`` (the check's own evaluations are not counted)."""
    counts = {"evaluations": 0}
    f = in_log_d(evaluate, counts)
    fn = lambda u, args: (f(u), None)  # noqa: E731
    options, tags = {}, frozenset()
    u = jnp.log(jnp.asarray(start))
    clock = time.perf_counter()
    state = solver.init(fn, u, None, options, jax.ShapeDtypeStruct((), jnp.float64), None, tags)
    step = eqx.filter_jit(lambda u, state: solver.step(fn, u, None, options, state, tags))
    iterations, measure = 0, np.inf
    while iterations < max_iterations:
        u, state, _ = step(u, state)
        iterations += 1
        value, gradient = evaluate(np.exp(np.asarray(u)))
        measure = relative_gradient(np.exp(np.asarray(u)), value, gradient)
        if measure < tolerance:
            break
    return dict(coefficients=np.exp(np.asarray(u)).tolist(), value=float(value),
                iterations=iterations, evaluations=counts["evaluations"],
                relative_gradient=measure, seconds=time.perf_counter() - clock)


LIBRARY = {"optax.lbfgs()": lambda evaluate, start: optax_lbfgs(evaluate, start),
           "optimistix BFGS": lambda evaluate, start: optimistix(
               optx.BFGS(rtol=1e-14, atol=1e-14), evaluate, start),
           "optimistix LBFGS": lambda evaluate, start: optimistix(
               optx.LBFGS(rtol=1e-14, atol=1e-14), evaluate, start)}


def plot(data: dict) -> None:
    """(a) the projected BFGS history, (b) our optimum against the published one."""
    result = data["result"]
    fig, axes = figure(ncols=2, figsize=(10, 4.6), readable=True)
    values = np.array([h[0] for h in result["history"]])
    iterations = np.arange(values.shape[0])
    best = min(values.min(), data["scipy"]["value"])
    axes[0].semilogy(iterations, values - best + 1e-16 * values[-1], "o-",
                     label="trace - best trace found")
    axes[0].semilogy(iterations, [h[1] for h in result["history"]], "s--",
                     label="relative gradient max |d_i df/dd_i| / f")
    axes[0].axhline(1e-6, color="gray", linestyle=":", label="tolerance 1e-6")
    axes[0].set_xlabel("iteration")
    axes[0].set_ylabel("trace - best trace; relative gradient\n(dimensionless)")
    start = ", ".join(f"{d:g}" for d in data["start"])
    axes[0].set_title(f"(a) projected BFGS from ({start}): {result['seconds']:.1f} s")
    legend(axes[0], "below")
    x = np.arange(3)
    for shift, d, label in ((-0.2, result["coefficients"], "ours (projected BFGS): trace "
                             f"{result['value']:.9g}"),
                            (0.2, data["published"], "published: our trace there "
                             f"{data['published_trace']:.9g}")):
        bars = axes[1].bar(x + shift, d, 0.4, label=label)
        axes[1].bar_label(bars, [f"{v:.1f}" for v in d], padding=2)
    axes[1].set_xticks(x, ["d(50)", "d(120)", "d(550, 520)"])
    axes[1].set_xlabel("damper (DOF, or relative between DOFs)")
    axes[1].set_ylabel("viscosity d (dimensionless)")
    axes[1].set_ylim(top=1.15 * max(max(result["coefficients"]), max(data["published"])))
    axes[1].set_title("(b) optimal viscosities")
    legend(axes[1], "below")
    fig.suptitle(f"FastOptimalDamping small example, n = {data['n']}, s = {data['lowest']}\n"
                 + subtitle(data["metadata"]))
    save_figure(fig, NAME, data["quick"])


def main(argv=None):
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return plot(read_json(NAME, args.quick))
    n1 = 100 if args.quick else 400
    system = fod_system(n1, START)
    print(f"n = {system.size}: optimising 3 viscosities from {START}", flush=True)
    design = mj.DamperDesign(system, mj.AverageEnergy(LOWEST))
    result = mj.optimise(design, mj.Coefficients(progress=True))
    stats = result.stats
    print(f"{stats['status']} in {stats['seconds']:.1f} s (compile included): d = "
          f"{np.array2string(result.coefficients, precision=3)}, trace {result.value:.10g}, "
          f"relative gradient {stats['relative_gradient']:.1e}, {stats['iterations']} "
          f"iterations, {stats['evaluations']} evaluations", flush=True)

    function = criterion_function(system, mj.AverageEnergy(LOWEST))
    evaluate = lambda d: tuple(np.asarray(a, dtype=float) for a in function(np.asarray(d)))  # noqa: E731
    published_value, published_gradient = evaluate(np.asarray(PUBLISHED))
    swapped_value = float(evaluate(np.asarray(SWAPPED))[0])
    evaluate(np.asarray(START))  # compiled already; warm the call path
    counts = {"evaluations": 0}

    def counted(d):
        counts["evaluations"] += 1
        return evaluate(d)

    # scipy's pgtol is absolute: the same stopping point as our relative 1e-6, max |g_i| d_i / f
    gtol = 1e-6 * result.value / float(np.max(result.coefficients))
    start = time.perf_counter()
    reference = scipy.optimize.minimize(counted, np.asarray(START), jac=True, method="L-BFGS-B",
                                        bounds=[(0, None)] * 3,
                                        options=dict(ftol=1e-13, gtol=gtol, maxiter=100))
    scipy_s = time.perf_counter() - start
    spg = mj.optimise(design, mj.Coefficients(mj.SpectralProjectedGradient()))
    spg_stats = spg.stats
    print(f"SPG: {spg_stats['status']} in {spg_stats['seconds']:.1f} s (compiled already): "
          f"trace {spg.value:.10g}, {spg_stats['iterations']} iterations, "
          f"{spg_stats['evaluations']} evaluations", flush=True)
    library = {}
    for name, run in LIBRARY.items():
        library[name] = run(evaluate, START)
        print(f"{name}: trace {library[name]['value']:.10g}, {library[name]['iterations']} "
              f"iterations, {library[name]['evaluations']} evaluations, relative gradient "
              f"{library[name]['relative_gradient']:.1e}", flush=True)
    rows = [
        dict(method="Coefficients() (projected BFGS)", seconds=stats["seconds"],
             iterations=stats["iterations"], evaluations=stats["evaluations"],
             trace=result.value, d1=result.coefficients[0], d2=result.coefficients[1],
             d3=result.coefficients[2]),
        dict(method="Coefficients(SpectralProjectedGradient()) (compiled already)",
             seconds=spg_stats["seconds"], iterations=spg_stats["iterations"],
             evaluations=spg_stats["evaluations"],
             trace=spg.value, d1=spg.coefficients[0], d2=spg.coefficients[1],
             d3=spg.coefficients[2]),
        dict(method="scipy L-BFGS-B, same function (compiled already)", seconds=scipy_s,
             iterations=reference.nit, evaluations=counts["evaluations"], trace=reference.fun,
             d1=reference.x[0], d2=reference.x[1], d3=reference.x[2]),
        *[dict(method=f"{name} in log d (its step compiled)", seconds=run["seconds"],
               iterations=run["iterations"], evaluations=run["evaluations"], trace=run["value"],
               d1=run["coefficients"][0], d2=run["coefficients"][1],
               d3=run["coefficients"][2]) for name, run in library.items()],
        dict(method="published optimum (FastOptimalDamping.jl, CG + finite differences)",
             seconds=3320.0,
             iterations=None, evaluations=None, trace=float(published_value), d1=PUBLISHED[0],
             d2=PUBLISHED[1], d3=PUBLISHED[2]),
    ]
    print_table(rows, [("method", "method", "s"), ("seconds", "wall s", ".1f"),
                       ("iterations", "iterations", "d"), ("evaluations", "evaluations", "d"),
                       ("trace", "trace X (s = 27)", ".10g"), ("d1", "d(50)", ".3f"),
                       ("d2", "d(120)", ".3f"), ("d3", "d(550, 520)", ".3f")])
    relative_published = float(np.max(np.abs(published_gradient * np.asarray(PUBLISHED)))
                               / published_value)
    print(f"at the published viscosities our trace is {published_value:.10g} "
          f"({published_value / result.value - 1:+.2e} relative to our optimum), relative "
          f"gradient {relative_published:.1e} (their own trace there: {PUBLISHED_TRACE:.10g}, "
          f"in their coordinates); with relative and DOF 120 swapped it would be "
          f"{swapped_value:.10g}", flush=True)
    met = (result.result == "converged") and stats["seconds"] < TARGET_S
    print(f"target: < {TARGET_S:.0f} s with relative gradient < 1e-6: "
          f"{'met' if met else 'MISSED'} ({stats['seconds']:.1f} s, "
          f"{stats['relative_gradient']:.1e})")

    write_json(NAME, args.quick, dict(
        n=system.size, lowest=LOWEST, start=list(START), published=list(PUBLISHED),
        published_trace_their_coordinates=PUBLISHED_TRACE,
        coefficient_order=["DOF 50", "DOF 120", "relative (550, 520)"],
        published_as_printed=list(PUBLISHED_AS_PRINTED), swapped_trace=swapped_value,
        result=dict(coefficients=result.coefficients.tolist(), value=result.value,
                    relative_gradient=stats["relative_gradient"],
                    converged=result.result == "converged",
                    iterations=stats["iterations"], evaluations=stats["evaluations"],
                    seconds=stats["seconds"], status=stats["status"],
                    history=[list(h) for h in result.history]),
        spg=dict(coefficients=spg.coefficients.tolist(), value=spg.value,
                 relative_gradient=spg_stats["relative_gradient"],
                 converged=spg.result == "converged", iterations=spg_stats["iterations"],
                 evaluations=spg_stats["evaluations"], seconds=spg_stats["seconds"],
                 status=spg_stats["status"], history=[list(h) for h in spg.history]),
        library=library,
        scipy=dict(coefficients=reference.x.tolist(), value=float(reference.fun),
                   iterations=int(reference.nit), evaluations=counts["evaluations"],
                   seconds=scipy_s, message=str(reference.message)),
        published_trace=float(published_value), published_relative_gradient=relative_published,
        target_s=TARGET_S, met=bool(met)))
    plot(read_json(NAME, args.quick))


if __name__ == "__main__":
    main()
