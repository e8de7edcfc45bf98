"""Gradients of a damper objective through the reduced model, per differentiation mode.

Section 5 scene (``load_scene("section5_damped")``: Mikota's chain, n = 300, x_3(0) = 1, outputs at
t = 0, 0.01, ..., 20). The basis is held fixed (not differentiated): POD of the exact displacement
snapshots on [0, 10] of the paper's system (damper d = 1 at DOF 7), r = 76 and 98. The objective is
the time-integrated total energy of the reduced model with a grounded damper at (position p,
coefficient c),

    J(p, c) = int_0^T (x^T K x + v^T M v) / 2 dt     (trapezoid over the 2001 outputs),

evaluated in reduced coordinates: x = Phi q, so x^T K x = q^T (Phi^T K Phi) q and v^T M v =
qd^T (Phi^T M Phi) qd exactly; the solve is
``mj.solve(rom.system, ts, Phi^T x0, method=mj.ODE(...))`` -- the same ODE as
``mj.solve(rom, ts, x0, method=mj.ODE(...))`` without lifting 2 x 300 outputs per time (the full
run checks that both give the same J). Design point (p, c) = (7.3, 1.0): the linear damper split
has a kink at integer positions, where JAX returns the right-sided derivative (reported at p = 7).

Gradient modes, each ``jax.jit``-compiled ahead of time (``Compiled``) and timed as the median of
repeated calls, as a ratio to one compiled forward solve of J at the same rank and tolerance
(Dopri8, rtol 1e-10, atol 1e-12, ``max_steps`` = 16384 in every solve):

* forward mode, ``jax.jacfwd`` with ``diffrax.ForwardMode()`` (both directions in one vmapped pass);
* forward mode, two ``jax.jvp`` calls (one per direction) of one executable;
* reverse mode, ``diffrax.RecursiveCheckpointAdjoint()`` (the default, checkpoints chosen by
  diffrax) and ``RecursiveCheckpointAdjoint(checkpoints=max_steps)`` (every step stored);
* reverse mode, ``diffrax.DirectAdjoint()`` (r = 76 only, one timed call and checked at the
  timing tolerance only: it is by far the slowest);
* ``diffrax.BacksolveAdjoint()``: tried; it refuses ``SaveAt(fn=...)``, which ``mj.ODE`` uses;
* the reduced model solved by ``mj.DenseExponential()`` (modal coordinates, a matrix exponential):
  reverse (``jax.grad``) and forward (``jax.jacfwd``), ratio to its own forward solve.

Correctness first: central differences of the same objective (rtol 1e-12, steps 1e-4 in p and in
c) against every gradient (computed once at rtol 1e-12 and again at the timing tolerance, rtol
1e-10); the run stops if any relative difference exceeds 1e-4 (a wrong gradient), and reports
pass/fail of the target 1e-6. Full model (``--quick`` skips it): central differences of the same
objective on the full n = 300 model with scipy ``solve_ivp`` DOP853 (rtol 1e-12; 4 solves, timed)
and the JAX full-model gradient (forward mode, two jvps), against the ROM gradient (the difference
is the ROM truncation error of J and of its gradient).

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/gradients.py [--quick]``. Writes
``benchmarks/results/gradients.json`` and ``.png`` (``--quick``: ``gradients_quick.*``; the
scene at n = 60, r = 20, forward jacfwd and default recursive checkpointing only, no exact-solve
rows, no full model, fewer repeats).
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (Compiled, elapsed, figure, legend, parse_args,  # noqa: I001
                     print_table, read_json, save_figure, section5_scene, subtitle, timed,
                     write_json)

import time

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp

import mikota_jax as mj
from mikota_jax.testing import pod

NAME = "gradients"
RANKS = (76, 98)  # the paper's n_red for 99 % and 99.99 % pseudo-energy (Section 5)
QUICK_RANKS = (20,)  # --quick: the scene at n = 60
DESIGN = (7.3, 1.0)  # (position, coefficient): fractional, away from the kinks
INTEGER_POSITION = 7.0  # a kink of the linear damper split: JAX gives the right-sided derivative
RTOL, ATOL = 1e-10, 1e-12  # every timed solve
CHECK_RTOL, CHECK_ATOL = 1e-12, 1e-14  # finite differences and the tight gradients
STEPS = (1e-4, 1e-4)  # central-difference steps in p and in c (c = 1: relative 1e-4)
MAX_STEPS = 16_384  # every simulate call; also the checkpoint count of "every step stored"
TARGET_RATIO, TARGET_AGREEMENT = 4.0, 1e-6
LIFTED_TOLERANCE = 1e-10  # J from lifted outputs vs reduced coordinates: rounding only
SANITY = 1e-4  # a relative difference above this means a wrong gradient: stop before timing


# --------------------------------------------------------------------------- objectives


def reduced_energy(red, q, qd, ts):
    """Trapezoid of (q^T K_r q + qd^T M_r qd) / 2 over ts: the full energy of x = Phi q."""
    stiffness, mass = red.stiffness.as_matrix(), red.mass.as_matrix()
    energy = 0.5 * (jnp.sum((q @ stiffness) * q, axis=1) + jnp.sum((qd @ mass) * qd, axis=1))
    return jnp.trapezoid(energy, ts)


def full_energy(system, x, v, ts):
    kx = jax.vmap(system.stiffness.mv)(x)
    energy = 0.5 * (jnp.sum(kx * x, axis=1) + jnp.sum(system.mass.diagonal * v * v, axis=1))
    return jnp.trapezoid(energy, ts)


def objectives(n, ts, x0):
    """J by ``simulate`` (reduced coordinates, or lifted to all DOFs) and by ``exact_solve``."""

    def reduced_system(p, c, basis):
        system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(p, c)])
        return mj.reduce(system, mj.Projection(basis)).system

    def simulated(p, c, rtol, atol, basis, adjoint=None):
        red = reduced_system(p, c, basis)
        out = mj.solve(red, ts, basis.T @ x0, displacement=True, velocity=True,
                       method=mj.ODE(rtol=rtol, atol=atol, max_steps=MAX_STEPS, adjoint=adjoint))
        return reduced_energy(red, out.displacement, out.velocity, ts), out.num_steps

    def lifted(p, c, rtol, atol, basis):  # the same J from all 300 lifted DOFs (a check)
        system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(p, c)])
        rom = mj.reduce(system, mj.Projection(basis))
        out = mj.solve(rom, ts, x0, displacement=True, velocity=True,
                       method=mj.ODE(rtol=rtol, atol=atol, max_steps=MAX_STEPS))
        return full_energy(system, out.displacement, out.velocity, ts)

    def exact(p, c, basis):
        red = reduced_system(p, c, basis)
        out = mj.solve(red, ts, basis.T @ x0, displacement=True, velocity=True,
                       method=mj.DenseExponential())
        return reduced_energy(red, out.displacement, out.velocity, ts)

    def full(p, c, rtol, atol, adjoint=None):
        system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(p, c)])
        out = mj.solve(system, ts, x0, displacement=True, velocity=True,
                       method=mj.ODE(rtol=rtol, atol=atol, max_steps=MAX_STEPS, adjoint=adjoint))
        return full_energy(system, out.displacement, out.velocity, ts)

    return simulated, lifted, exact, full


def simulated_modes(simulated, quick: bool, direct: bool):
    """name -> (function of (p, c, rtol, atol, basis) -> (dJ/dp, dJ/dc), calls per gradient)."""

    def value(adjoint):
        return lambda p, c, rtol, atol, basis: simulated(p, c, rtol, atol, basis, adjoint)[0]

    def reverse(adjoint):
        return lambda p, c, rtol, atol, basis: jax.grad(
            lambda p, c: value(adjoint)(p, c, rtol, atol, basis), argnums=(0, 1))(p, c)

    def jacfwd(p, c, rtol, atol, basis):
        return jax.jacfwd(lambda p, c: value(diffrax.ForwardMode())(p, c, rtol, atol, basis),
                          argnums=(0, 1))(p, c)

    modes = {"forward (jacfwd)": jacfwd,
             "reverse, recursive checkpoint": reverse(diffrax.RecursiveCheckpointAdjoint())}
    if not quick:
        modes["reverse, checkpoint every step"] = reverse(
            diffrax.RecursiveCheckpointAdjoint(checkpoints=MAX_STEPS))
        if direct:
            modes["reverse, direct"] = reverse(diffrax.DirectAdjoint())
        modes["reverse, backsolve"] = reverse(diffrax.BacksolveAdjoint())
    return modes


def directional(fn):
    """(p, c, tp, tc, rtol, atol, basis) -> the derivative of fn along (tp, tc), by one jvp."""

    def derivative(p, c, tp, tc, *rest):
        return jax.jvp(lambda p, c: fn(p, c, *rest), (p, c), (tp, tc))[1]

    return derivative


class TwoJvps:
    """A gradient as two calls of one compiled jvp executable, one per direction."""

    def __init__(self, fn, *example_rest):
        self.compiled = Compiled(directional(fn), *DESIGN, 1.0, 0.0, *example_rest)
        self.compile_s = self.compiled.compile_s

    def __call__(self, p, c, *rest):
        return (self.compiled(p, c, 1.0, 0.0, *rest), self.compiled(p, c, 0.0, 1.0, *rest))


def central(fn, p, c, *rest):
    """Central differences of fn(p, c, *rest) with STEPS."""
    hp, hc = STEPS
    return (float((fn(p + hp, c, *rest) - fn(p - hp, c, *rest)) / (2 * hp)),
            float((fn(p, c + hc, *rest) - fn(p, c - hc, *rest)) / (2 * hc)))


def one_sided(fn, p, c, h, *rest):
    """Second-order one-sided differences in p: (right, left), smooth on each side of p."""
    f0, right = fn(p, c, *rest), (fn(p + h, c, *rest), fn(p + 2 * h, c, *rest))
    left = (fn(p - h, c, *rest), fn(p - 2 * h, c, *rest))
    return (float((-3 * f0 + 4 * right[0] - right[1]) / (2 * h)),
            float((3 * f0 - 4 * left[0] + left[1]) / (2 * h)))


def relative(gradient, reference) -> float:
    """max over (p, c) of |g - g_ref| / |g_ref|."""
    g, ref = np.asarray(gradient, dtype=float), np.asarray(reference, dtype=float)
    return float(np.max(np.abs(g - ref) / np.abs(ref)))


# --------------------------------------------------------------------------- scipy full model


def scipy_objective(n, ts, x0, rtol):
    """J(p, c) of the full model by solve_ivp DOP853, with an O(n) numpy right-hand side."""
    ts_np, x0_np = np.asarray(ts), np.asarray(x0)

    def objective(p, c):
        system = mj.mikota_chain(n, dampers=[mj.GroundedDamper(p, c)])
        mass, damping, stiffness = (np.asarray(a) for a in system.dense())
        m, d = np.diag(mass).copy(), np.diag(damping).copy()
        k_diag, k_off = np.diag(stiffness).copy(), np.diag(stiffness, 1).copy()

        def k_times(x):
            out = k_diag[:, None] * x if x.ndim == 2 else k_diag * x
            out[:-1] += k_off.reshape(-1, *([1] * (x.ndim - 1))) * x[1:]
            out[1:] += k_off.reshape(-1, *([1] * (x.ndim - 1))) * x[:-1]
            return out

        def rhs(t, y):
            x, v = y[:n], y[n:]
            return np.concatenate([v, (-k_times(x) - d * v) / m])

        sol = solve_ivp(rhs, (ts_np[0], ts_np[-1]), np.concatenate([x0_np, np.zeros(n)]),
                        method="DOP853", t_eval=ts_np, rtol=rtol, atol=rtol * 1e-2)
        if not sol.success:
            raise RuntimeError(f"solve_ivp DOP853 failed: {sol.message}")
        x, v = sol.y[:n], sol.y[n:]
        energy = 0.5 * (np.sum(k_times(x) * x, axis=0) + np.sum(m[:, None] * v * v, axis=0))
        return float(np.trapezoid(energy, ts_np)), int(sol.nfev)

    return objective


# --------------------------------------------------------------------------- the benchmark


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True)
    if args.replot:
        return plot(read_json(NAME, args.quick))
    quick = args.quick
    ranks = QUICK_RANKS if quick else RANKS
    repeats_forward, repeats_gradient = (3, 1) if quick else (5, 3)
    wall_start = time.perf_counter()

    scene = section5_scene(quick)
    system, ts, x0 = scene.system, scene.ts, scene.x0
    if scene.v0 is not None or scene.load is not None:
        raise ValueError("this benchmark expects the Section 5 scene: x(0), v(0) = 0, no load.")
    n, ts_np = system.size, np.asarray(ts)
    window = scene.reduction.window
    mask = (ts_np >= window[0] - 1e-9) & (ts_np <= window[1] + 1e-9)
    start = time.perf_counter()
    # the exact snapshots; --quick by the dense path (one cheaper compile, the same numbers)
    out = mj.solve(system, ts, x0, method=mj.DenseExponential() if quick else mj.Spectral())
    snapshots = np.asarray(out.displacement)[mask].T  # (n, m)
    decomposition = pod(snapshots)
    offline_s = elapsed(start)
    simulated, lifted, exact, full = objectives(n, ts, x0)
    p, c = DESIGN
    rows, checks, per_rank, failures = [], [], {}, []

    for rank in ranks:
        basis = decomposition.basis(rank)
        tol, check_tol = (RTOL, ATOL, basis), (CHECK_RTOL, CHECK_ATOL, basis)
        forward = Compiled(simulated, p, c, *tol)
        value = lambda *a, forward=forward: forward(*a)[0]  # noqa: E731
        j_check, steps_check = (float(v) for v in forward(p, c, *check_tol))
        fd = central(value, p, c, *check_tol)  # the reference: same objective, rtol 1e-12
        info = dict(J=j_check, steps_check_rtol=int(steps_check), fd_check_rtol=fd)
        print(f"r = {rank}: J = {j_check:.10g} ({int(steps_check)} steps at rtol {CHECK_RTOL:g}),"
              f" central differences (h = {STEPS}) = ({fd[0]:.10g}, {fd[1]:.10g})")

        # ---- compile every gradient mode; check each against the differences before timing
        modes = {}
        for name, fn in simulated_modes(simulated, quick, rank == ranks[0]).items():
            try:
                modes[name] = Compiled(fn, p, c, *tol)
            except NotImplementedError as error:  # BacksolveAdjoint vs SaveAt(fn=...)
                rows.append(dict(rank=rank, mode=name, solve="simulate dopri8",
                                 unusable=f"{type(error).__name__}: {error}"))
                print(f"  {name}: not usable here ({type(error).__name__}: {error})")
        if not quick:
            modes["forward (2 x jvp)"] = TwoJvps(
                lambda p, c, *rest: simulated(p, c, *rest, diffrax.ForwardMode())[0], *tol)
        tight = {}
        for name, fn in modes.items():
            if "direct" in name:  # the slowest mode: checked at the timing tolerance only
                continue
            tight[name] = relative(fn(p, c, *check_tol), fd)
        exact_modes = {}
        if not quick:
            exact_forward = Compiled(exact, p, c, basis)
            exact_modes = {"exact_solve, reverse (grad)": Compiled(
                jax.grad(exact, argnums=(0, 1)), p, c, basis),
                "exact_solve, forward (jacfwd)": Compiled(
                jax.jacfwd(exact, argnums=(0, 1)), p, c, basis)}
            fd_exact = central(exact_forward, p, c, basis)
            info.update(J_exact=float(exact_forward(p, c, basis)), fd_exact=fd_exact)
            for name, fn in exact_modes.items():
                tight[name] = relative(fn(p, c, basis), fd_exact)
            info["fd_simulate_vs_fd_exact"] = relative(fd, fd_exact)
        if not quick and rank == ranks[0]:  # J from all 300 lifted DOFs: the same number
            lifted_c = Compiled(lifted, p, c, *tol)
            lifted_error = relative(lifted_c(p, c, *check_tol), j_check)
            status = "ok" if lifted_error < LIFTED_TOLERANCE else "FAILED"
            print(f"  check J lifted to all DOFs vs reduced coordinates: {lifted_error:.1e} "
                  f"(< {LIFTED_TOLERANCE:g}) {status}")
            if lifted_error >= LIFTED_TOLERANCE:
                failures.append(f"r={rank} lifted J")
        for name, error in tight.items():
            status = "ok" if error < SANITY else "FAILED"
            checks.append(dict(rank=rank, mode=name, rtol=CHECK_RTOL, relative=error))
            print(f"  check {name}: |g - FD| / |FD| = {error:.1e} (< {SANITY:g}) {status}")
            if error >= SANITY:
                failures.append(f"r={rank} {name}")
        if failures:
            raise SystemExit(f"gradient check failed ({', '.join(failures)}); no timings taken.")

        # ---- integer position: which side does JAX take?
        forward_grad = modes["forward (jacfwd)"]
        at_integer = float(forward_grad(INTEGER_POSITION, c, *check_tol)[0])
        right, left = one_sided(value, INTEGER_POSITION, c, STEPS[0], *check_tol)
        side = "right" if abs(at_integer - right) < abs(at_integer - left) else "left"
        info["integer_position"] = dict(
            position=INTEGER_POSITION, ad=at_integer, right_difference=right,
            left_difference=left, side=side, relative_to_right=relative(at_integer, right))
        print(f"  p = {INTEGER_POSITION:g} (kink): dJ/dp by AD = {at_integer:.8g}, right-sided "
              f"{right:.8g}, left-sided {left:.8g}: AD is the {side}-sided derivative")

        # ---- timing, at RTOL (tolerance traced: the same executables)
        (j_value, steps), forward_s, forward_times = timed(forward, p, c, *tol,
                                                           repeats=repeats_forward)
        steps = int(steps)
        fd_reference = info.get("fd_exact", fd)
        rows.append(dict(rank=rank, mode="forward solve of J", solve="simulate dopri8",
                         compile_s=forward.compile_s, run_s=forward_s, run_times_s=forward_times,
                         ratio=1.0, steps=steps, J=float(j_value)))
        for name, fn in modes.items():
            repeats = 1 if "direct" in name else repeats_gradient
            gradient, run_s, times = timed(fn, p, c, *tol, repeats=repeats)
            gradient = tuple(float(g) for g in gradient)
            rows.append(dict(rank=rank, mode=name, solve="simulate dopri8",
                             compile_s=fn.compile_s, run_s=run_s, run_times_s=times,
                             ratio=run_s / forward_s, steps=steps, gradient=gradient,
                             agreement=relative(gradient, fd), tight=tight.get(name),
                             agreement_exact_fd=relative(gradient, fd_reference)))
        if exact_modes:
            _, exact_s, exact_times = timed(exact_forward, p, c, basis, repeats=repeats_forward)
            rows.append(dict(rank=rank, mode="forward solve of J", solve="exact_solve",
                             compile_s=exact_forward.compile_s, run_s=exact_s,
                             run_times_s=exact_times, ratio=1.0, vs_simulate=exact_s / forward_s))
            for name, fn in exact_modes.items():
                gradient, run_s, times = timed(fn, p, c, basis, repeats=repeats_gradient)
                gradient = tuple(float(g) for g in gradient)
                rows.append(dict(rank=rank, mode=name, solve="exact_solve",
                                 compile_s=fn.compile_s, run_s=run_s, run_times_s=times,
                                 ratio=run_s / exact_s, vs_simulate=run_s / forward_s,
                                 gradient=gradient, agreement=relative(gradient, fd_exact),
                                 tight=tight[name]))
        if not quick and rank == ranks[0]:
            lifted_value, lifted_s, lifted_times = timed(lifted_c, p, c, *tol,
                                                         repeats=repeats_forward)
            info["lifted"] = dict(
                J=float(lifted_value), relative_to_reduced=relative(lifted_value, j_value),
                relative_check_rtol=lifted_error, compile_s=lifted_c.compile_s, run_s=lifted_s,
                run_times_s=lifted_times, ratio=lifted_s / forward_s)
        per_rank[str(rank)] = info

    # ---- the full model: scipy central differences and the JAX forward-mode gradient
    full_model = None
    if not quick:
        scipy_j = scipy_objective(n, ts, x0, CHECK_RTOL)
        start = time.perf_counter()
        j_full, nfev = scipy_j(p, c)
        solve_s = elapsed(start)
        start = time.perf_counter()
        fd_full = central(lambda *a: scipy_j(*a)[0], p, c)
        fd_s = elapsed(start)
        full_forward = Compiled(full, p, c, RTOL, ATOL)
        full_grad = TwoJvps(lambda *a: full(*a, diffrax.ForwardMode()), RTOL, ATOL)
        _, full_s, full_times = timed(full_forward, p, c, RTOL, ATOL, repeats=repeats_gradient)
        jax_full, grad_s, grad_times = timed(full_grad, p, c, RTOL, ATOL,
                                             repeats=repeats_gradient)
        jax_full = tuple(float(g) for g in jax_full)
        full_model = dict(
            J_scipy=j_full, nfev=nfev, scipy_rtol=CHECK_RTOL, scipy_solve_s=solve_s,
            scipy_fd=fd_full, scipy_fd_s=fd_s, jax_gradient=jax_full,
            jax_vs_scipy_fd=relative(jax_full, fd_full),
            jax_forward_compile_s=full_forward.compile_s, jax_forward_s=full_s,
            jax_forward_times_s=full_times,
            jax_gradient_compile_s=full_grad.compile_s, jax_gradient_s=grad_s,
            jax_gradient_times_s=grad_times, jax_gradient_ratio=grad_s / full_s,
            rom={r: dict(J_relative=relative(per_rank[r]["J"], j_full),
                         gradient_relative=relative(per_rank[r]["fd_check_rtol"], fd_full),
                         gradient_relative_p=relative(per_rank[r]["fd_check_rtol"][0], fd_full[0]),
                         gradient_relative_c=relative(per_rank[r]["fd_check_rtol"][1], fd_full[1]))
                 for r in per_rank})

    # ---- report
    print_table([r for r in rows if "unusable" not in r], [
        ("rank", "r", "d"), ("mode", "mode", ""), ("solve", "solve", ""),
        ("compile_s", "compile s", ".2f"), ("run_s", "run s", ".4f"), ("ratio", "ratio", ".2f"),
        ("agreement", "vs FD", ".1e"), ("tight", f"vs FD @{CHECK_RTOL:g}", ".1e"),
        ("steps", "steps", "d")])
    for r in (r for r in rows if "unusable" in r):
        print(f"r = {r['rank']} {r['mode']}: not usable: {r['unusable']}")
    gradients = [r for r in rows if "gradient" in r]
    best = {rank: min((r for r in gradients if r["rank"] == rank and r["solve"] != "exact_solve"),
                      key=lambda r: r["ratio"]) for rank in ranks}
    for rank, r in best.items():
        cost = "met" if r["ratio"] <= TARGET_RATIO else "MISSED"
        agreement = "met" if r["agreement"] <= TARGET_AGREEMENT else "MISSED"
        print(f"r = {rank}: cheapest simulate gradient {r['mode']}: {r['ratio']:.2f}x the forward "
              f"solve (target <= {TARGET_RATIO:g}x: {cost}), {r['agreement']:.1e} from central "
              f"differences (target <= {TARGET_AGREEMENT:g}: {agreement})")
    if full_model:
        print(f"full model: scipy DOP853 J = {full_model['J_scipy']:.10g}, central differences "
              f"({full_model['scipy_fd'][0]:.8g}, {full_model['scipy_fd'][1]:.8g}) in "
              f"{full_model['scipy_fd_s']:.1f} s (4 solves, rtol {CHECK_RTOL:g}); JAX "
              f"forward-mode gradient {full_model['jax_gradient_s']:.2f} s "
              f"({full_model['jax_gradient_ratio']:.2f}x its forward solve), "
              f"{full_model['jax_vs_scipy_fd']:.1e} from scipy's differences")
        for r, d in full_model["rom"].items():
            print(f"  ROM r = {r} vs full model: J {d['J_relative']:.1e}, dJ/dp "
                  f"{d['gradient_relative_p']:.1e}, dJ/dc {d['gradient_relative_c']:.1e} "
                  "(truncation)")

    data = {
        "scene": scene.name,
        "problem": {
            "n": n, "times": {"start": float(ts_np[0]), "end": float(ts_np[-1]),
                              "count": int(ts_np.shape[0])},
            "objective": "J(p, c) = trapezoid over ts of (x^T K x + v^T M v) / 2, evaluated in "
                         "reduced coordinates (q^T K_r q + qd^T M_r qd) / 2",
            "basis": f"POD of exact displacement snapshots on {list(window)} with the damper at "
                     "DOF 7, d = 1; held fixed (not differentiated)",
            "design": {"position": DESIGN[0], "coefficient": DESIGN[1]},
            "integer_position": INTEGER_POSITION,
            "rtol": RTOL, "atol": ATOL, "check_rtol": CHECK_RTOL, "check_atol": CHECK_ATOL,
            "solver": "dopri8", "max_steps": MAX_STEPS, "fd_steps": list(STEPS),
            "repeats": {"forward": repeats_forward, "gradient": repeats_gradient,
                        "direct": 1},
            "ratio": "gradient run time / forward solve of J (same rank, same solve, same rtol)",
            "agreement": "max over (p, c) of |g - FD| / |FD|; FD = central differences of the "
                         "same objective at rtol 1e-12 (exact_solve rows: of the exact objective)",
            "offline_s": offline_s,
        },
        "targets": {"ratio": TARGET_RATIO, "agreement": TARGET_AGREEMENT},
        "checks": {"sanity": SANITY, "rows": checks},
        "per_rank": per_rank,
        "rows": rows,
        "full_model": full_model,
        "total_wall_s": elapsed(wall_start),
    }
    path = write_json(NAME, quick, data)
    png = plot(read_json(NAME, quick))
    print(f"wrote {path} and {png} ({data['total_wall_s']:.0f} s)")
    return data


def plot(data: dict):
    """(a) cost ratio and (b) agreement per gradient mode (rows) and rank (bars)."""
    rows, full_model, problem = data["rows"], data["full_model"], data["problem"]
    targets = data["targets"]
    fig, (left, right) = figure(ncols=2, sharey=True, figsize=(11, 8.0), readable=True)
    gradients = [r for r in rows if "gradient" in r]
    labels = list(dict.fromkeys(r["mode"] for r in gradients))
    ranks = sorted({r["rank"] for r in gradients})
    height = 0.8 / len(ranks)
    for k, rank in enumerate(ranks):
        by_mode = {r["mode"]: r for r in gradients if r["rank"] == rank}
        ys = [i + (k - (len(ranks) - 1) / 2) * height for i in range(len(labels))]
        ratio = [by_mode[m]["ratio"] if m in by_mode else np.nan for m in labels]
        agree = [by_mode[m]["agreement"] if m in by_mode else np.nan for m in labels]
        bars = left.barh(ys, ratio, height, color=f"C{k}", label=f"r = {rank}")
        left.bar_label(bars, [f"{v:.1f}x" if np.isfinite(v) else "" for v in ratio], padding=2,
                       bbox=dict(fc="white", ec="none", alpha=0.8, pad=0.5))
        right.barh(ys, agree, height, color=f"C{k}", label=f"r = {rank}")
    left.axvline(targets["ratio"], color="k", linestyle="--", linewidth=1,
                 label=f"target {targets['ratio']:g}x")
    left.set_xscale("log")
    left.set_xlim(1.0, 2.5 * max(r["ratio"] for r in gradients))
    left.set_xlabel("gradient run time / forward solve of J\n(dimensionless)")
    left.set_title("(a) cost of the gradient")
    right.axvline(targets["agreement"], color="k", linestyle="--", linewidth=1,
                  label=f"target {targets['agreement']:g}")
    if full_model:
        for k, (rank, d) in enumerate(full_model["rom"].items()):
            right.axvline(d["gradient_relative"], color=f"C{k}", linestyle=":", linewidth=1.5,
                          label=f"ROM r = {rank} vs full model (truncation)")
        right.axvline(full_model["jax_vs_scipy_fd"], color="C3", linestyle="-.", linewidth=1,
                      label="full model: JAX jvp vs scipy FD")
    right.set_xscale("log")
    right.set_xlabel("max relative difference from central\ndifferences (dimensionless)")
    right.set_title("(b) agreement")
    left.set_yticks(range(len(labels)), labels)
    left.invert_yaxis()
    for ax in (left, right):
        ax.grid(True, axis="x", which="both", alpha=0.3)
        legend(ax, "below")
    fig.suptitle(f"dJ/d(position, coefficient) through the Section 5 ROM\ngradient at rtol "
                 f"{problem['rtol']:g}, FD at {problem['check_rtol']:g}; exact_solve rows: "
                 f"ratio to exact_solve's own J\n{subtitle(data['metadata'])}")
    return save_figure(fig, NAME, data["quick"])


if __name__ == "__main__":
    main()
