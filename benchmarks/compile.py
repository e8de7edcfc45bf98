"""Compile time of every public entry point, cold and with JAX's persistent compilation cache;
traces when only values change; time to first result of ``python -m mikota_jax reproduce``.

The problem is the paper's Section 5 setting: Mikota's chain n = 300, a grounded damper d = 1 at
DOF 7, x_3(0) = 1, 2001 outputs on [0, 20]; POD of the exact snapshots on [0, 10], rank 76.

* **Cold vs warm.** A child process (``sys.executable``) with an empty cache directory calls every
  entry point as a user does (eager; plus ``jax.jit``-wrapped where a user would jit): the first
  call (trace + compile or cache load + run) and then ``repeats`` calls (median = run time);
  compile = first - run. Then this process, fresh as well (nothing compiled before), does the
  same with the cache the child filled (warm). ``jax.monitoring`` events split each first call
  into tracing, lowering to MLIR and the backend step (XLA compile, or a cache load), and say for
  every executable whether it came from the cache, was written to it, or could not be stored
  (host callbacks). Shared small kernels (eager ``jnp`` ops) compile once, in the first entry
  that needs them: entries are timed in the order listed.
* **Retracing.** Every entry is called again with new values only (damper position, damper
  coefficient, rtol/atol, x0/v0, masses/springs, snapshots, basis): there must be no trace and no
  compile of anything after the first call, and the entry's own jitted function is traced once in
  total. (JAX records trace events only for top-level traces: under an eager ``jax.grad`` the
  inner traces are invisible, so there the check rests on "no compile", which any retrace of a
  jitted function would cause.)
* **Correctness.** Each process checks what it timed (the ODE solve vs the Spectral one, the
  paper's rank 76, the ROM's phase error, eager vs jitted results, cold vs warm results equal)
  before anything is written; a failed check stops the script.
* **Scene.** ``run_scene(load_scene("section5_damped"))`` in a fresh process, cold and warm.
* **Cold start of a scene.** ``python -m mikota_jax run section5_damped --quiet`` from process
  start to exit, each cold run with a new empty cache directory, each warm run after it with the
  filled one (median of the repeats): as the CLI runs it (XLA optimisation level 0 and the
  classic fusion emitters for scenes of <= 1000 DOFs), at level 0 with the MLIR emitters, and at
  XLA's defaults (level 3, MLIR emitters; ``XLA_FLAGS``), same machine, same process. Target:
  < 5 s cold. Runs in ``--quick`` too (one repeat, the CLI's own flags only).
* **Time to first result.** ``python -m mikota_jax reproduce`` from process start to exit, cold and
  warm cache, each split into startup + import, compile (trace + lower + backend, summed from
  ``jax.monitoring``) and run (the rest); one more plain ``python -m`` warm run (no listener) is a
  cross-check. Target: compile / run <= 3 on a warm cache.

Diagnostic (full run): the ODE solve cold/warm with ``EQX_ON_ERROR=nan``, which removes the host
callbacks of diffrax's input checks, to show what the cache would save if that solve were storable.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/compile.py [--quick]``. ``--quick``: mikota_chain,
solve ODE(Dopri8), solve Spectral and POD cold/warm plus their retrace checks; no scene, no
reproduce. Writes ``benchmarks/results/compile[_quick].json`` and ``.png``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (elapsed, figure, legend, parse_args, print_table,  # noqa: I001
                     save_figure, subtitle, write_json)

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

import mikota_jax as mj
from mikota_jax.testing import pod

NAME = "compile"
SCENE = "section5_damped"
N, RANK, DOF = 300, 76, 150
TS = np.linspace(0.0, 20.0, 2001)
WINDOW = 1001  # snapshots on [0, 10]
RATIO_TARGET = 3.0
TRACE = "/jax/core/compile/jaxpr_trace_duration"
LOWER = "/jax/core/compile/jaxpr_to_mlir_module_duration"
BACKEND = "/jax/core/compile/backend_compile_duration"
CACHE = "/jax/compilation_cache/"


def unit(dof: int, value: float = 1.0) -> np.ndarray:
    x = np.zeros(N)
    x[dof - 1] = value
    return x


X0 = unit(3)


def damped(position=7.0, coefficient=1.0, m=1.0, k=1.0):
    return mj.mikota_chain(N, m, k, dampers=[mj.GroundedDamper(position, coefficient)])


# --------------------------------------------------------------------------- jax.monitoring


class Recorder:
    """Every compile-related ``jax.monitoring`` event, in order: (event, seconds, fun_name)."""

    def __init__(self):
        self.log: list[tuple[str, float | None, str | None]] = []
        jax.monitoring.register_event_duration_secs_listener(self._duration)
        jax.monitoring.register_event_listener(self._event)

    def _duration(self, event, seconds, **kwargs):
        self.log.append((event, seconds, kwargs.get("fun_name")))

    def _event(self, event, **kwargs):
        if event.startswith(CACHE):
            self.log.append((event, None, None))

    def close(self):
        jax.monitoring.unregister_event_duration_listener(self._duration)
        jax.monitoring.unregister_event_listener(self._event)

    def mark(self) -> int:
        return len(self.log)

    def summary(self, since: int = 0) -> dict:
        return summarize(self.log[since:])


def summarize(log) -> dict:
    """Totals and a per-function split; each backend step is classified by the cache events
    recorded inside it: ``hit`` (loaded), ``written`` (compiled, stored), ``uncacheable``
    (compiled, not storable: host callbacks), ``no_cache`` (cache off)."""
    out = dict(trace_s=0.0, lower_s=0.0, backend_s=0.0, traces=0, compiles=0, hit=0,
               written=0, uncacheable=0, no_cache=0, retrieval_s=0.0)
    functions: dict[str, dict] = {}
    pending: list[str] = []
    for event, seconds, fun in log:
        if seconds is None:
            pending.append(event)
            continue
        if event == "/jax/compilation_cache/cache_retrieval_time_sec":
            out["retrieval_s"] += seconds
        if event not in (TRACE, LOWER, BACKEND):
            continue
        name = (fun or "?").removeprefix("jit(").removesuffix(")")
        f = functions.setdefault(name, dict(trace_s=0.0, lower_s=0.0, backend_s=0.0, traces=0,
                                            compiles=0, hit=0, uncacheable=0))
        if event == TRACE:
            out["trace_s"] += seconds
            out["traces"] += 1
            f["trace_s"] += seconds
            f["traces"] += 1
        elif event == LOWER:
            out["lower_s"] += seconds
            f["lower_s"] += seconds
        else:
            out["backend_s"] += seconds
            out["compiles"] += 1
            f["backend_s"] += seconds
            f["compiles"] += 1
            kind = ("hit" if CACHE + "cache_hits" in pending else
                    "written" if CACHE + "cache_misses" in pending else
                    "uncacheable" if CACHE + "compile_requests_use_cache" in pending else
                    "no_cache")
            out[kind] += 1
            if kind in f:
                f[kind] += 1
            pending = []
    out["compile_s"] = out["trace_s"] + out["lower_s"] + out["backend_s"]
    top = sorted(functions.items(), key=lambda kv: -(kv[1]["trace_s"] + kv[1]["lower_s"]
                                                       + kv[1]["backend_s"]))
    out["top"] = [dict(function=k, total_s=v["trace_s"] + v["lower_s"] + v["backend_s"], **v)
                  for k, v in top[:8]]
    out["functions"] = len(functions)
    return out


# --------------------------------------------------------------------------- entry points


@dataclass
class Entry:
    name: str
    call: object  # ctx -> result, exactly the user's call
    main: str | None = None  # the jitted function behind it (its trace-event name)
    quick: bool = False


def snapshots(ctx) -> np.ndarray:
    return np.asarray(ctx["solve Spectral"].displacement)[:WINDOW].T  # (n, m), eq. (3.5)


def make_objective(basis):
    """Energy at DOF 150 of the ROM response: d/d(position, coefficient), basis held fixed."""

    def energy_at_dof_150(position, coefficient):
        rom = mj.reduce(damped(position, coefficient), mj.Projection(basis))
        out = mj.solve(rom, TS, X0, dofs=[DOF], method=mj.ODE(rtol=1e-8, atol=1e-10))
        return jnp.sum(out.displacement**2) * (TS[1] - TS[0])

    return energy_at_dof_150


def jit_simulate(system, x0, rtol):
    return mj.solve(system, TS, x0, method=mj.ODE(rtol=rtol, atol=rtol * 1e-2))


def jit_exact_solve(system, x0):
    return mj.solve(system, TS, x0, velocity=True, method=mj.Spectral())


def grad_fn(ctx, jitted: bool = False):
    """``jax.grad`` of the objective w.r.t. (position, coefficient), or its ``jax.jit``."""
    if "grad" not in ctx:
        ctx["grad"] = jax.grad(make_objective(ctx["POD.basis"]), argnums=(0, 1))
        ctx["jit(grad)"] = jax.jit(ctx["grad"])
    return ctx["jit(grad)" if jitted else "grad"]


JITTED = {"jit_simulate": jax.jit(jit_simulate), "jit_exact_solve": jax.jit(jit_exact_solve)}

ENTRIES = [
    Entry("mikota_chain", lambda c: damped(), quick=True),
    Entry("load_scene", lambda c: mj.app.load_scene(SCENE)),
    Entry("solve ODE(Dopri8)", lambda c: mj.solve(c["mikota_chain"], TS, X0,
                                                method=mj.ODE(rtol=1e-8, atol=1e-10)),
          "simulate_with_result", True),
    Entry("solve ODE(Tsit5)", lambda c: mj.solve(c["mikota_chain"], TS, X0,
                                               method=mj.ODE(diffrax.Tsit5(), rtol=1e-6,
                                                             atol=1e-8)),
          "simulate_with_result"),
    Entry("solve Spectral", lambda c: mj.solve(c["mikota_chain"], TS, X0, velocity=True,
                                            method=mj.Spectral()),
          "_exact", True),
    Entry("modal_decomposition", lambda c: mj.modal_decomposition(c["mikota_chain"])),
    Entry("POD svd", lambda c: pod(c["snapshots"]), "_pod_svd", True),
    Entry("POD snapshots", lambda c: pod(c["snapshots"], method="snapshots"),
          "_pod_snapshots"),
    Entry("POD.basis", lambda c: c["POD svd"].basis(RANK)),
    Entry("reduce Projection",
          lambda c: mj.reduce(c["mikota_chain"], mj.Projection(c["POD.basis"]))),
    Entry("solve ROM ODE(Dopri8)", lambda c: mj.solve(c["reduce Projection"], TS, X0,
                                                    method=mj.ODE(rtol=1e-8, atol=1e-10)),
          "simulate_with_result"),
    Entry("solve ROM DenseExponential",
          lambda c: mj.solve(c["reduce Projection"], TS, X0, velocity=True,
                             method=mj.DenseExponential()),
          "_exact"),
    Entry("phase_error", lambda c: mj.metrics.phase_error(
        c["solve Spectral"].displacement, c["solve Spectral"].velocity,
        c["solve ROM DenseExponential"].displacement, c["solve ROM DenseExponential"].velocity)),
    Entry("relative_error", lambda c: mj.metrics.relative_error(
        c["solve Spectral"].displacement, c["solve ROM DenseExponential"].displacement)),
    Entry("pseudo_energy", lambda c: mj.metrics.pseudo_energy(c["POD svd"].singular_values)),
    Entry("grad ROM solve", lambda c: grad_fn(c)(7.5, 1.0)),
    Entry("jit(grad) ROM solve", lambda c: grad_fn(c, jitted=True)(7.5, 1.0),
          "energy_at_dof_150"),
    Entry("jit(solve ODE(Dopri8))", lambda c: JITTED["jit_simulate"](c["mikota_chain"], X0, 1e-8),
          "jit_simulate"),
    Entry("jit(solve Spectral)", lambda c: JITTED["jit_exact_solve"](c["mikota_chain"], X0),
          "jit_exact_solve"),
]


def variations(ctx, quick: bool) -> list[tuple[str, str, list]]:
    """(entry, parameter, [zero-argument calls with new values only, same shapes and options])."""
    rng = np.random.default_rng(1)
    masses, springs = 1.0 / np.arange(1, N + 1), N + 1.0 - np.arange(1, N + 1)
    dampers = [mj.GroundedDamper(7.0, 1.0)]
    sys_a = lambda: damped(7.5, 2.0)
    snaps = ctx.get("snapshots")
    other_basis = lambda: pod(snaps[:, ::-1] * 1.5).basis(RANK)
    cases = {
        "mikota_chain": {"m, k, damper": [lambda: damped(9.5, 0.3, m=2.0, k=0.5),
                                          lambda: damped(1.0, 4.0, m=0.7, k=1.9)]},
        "load_scene": {"damper, x0": [lambda: mj.app.load_scene(scene_dict(9, 0.5, 2.0)),
                                      lambda: mj.app.load_scene(scene_dict(4.5, 3.0, -1.0))]},
        "POD svd": {"snapshots": [lambda: pod(snaps * 2.0), lambda: pod(snaps[:, ::-1])]},
        "POD snapshots": {"snapshots": [lambda: pod(snaps * 2.0, method="snapshots"),
                                        lambda: pod(snaps[:, ::-1], method="snapshots")]},
        "POD.basis": {"POD values": [lambda: pod(snaps * 0.5).basis(RANK)]},
        "reduce Projection": {"system, basis": [
            lambda: mj.reduce(sys_a(), mj.Projection(other_basis()))]},
        "modal_decomposition": {"damper, masses/springs": [
            lambda: mj.modal_decomposition(sys_a()),
            lambda: mj.modal_decomposition(mj.chain(masses * 1.1, springs * 0.9, dampers))]},
        "pseudo_energy": {"singular values": [
            lambda: mj.metrics.pseudo_energy(np.asarray(ctx["POD svd"].singular_values) * 2)]},
    }

    def solver_cases(name, call, tolerances):
        cases[name] = {
            "damper position": [lambda: call(damped(7.5, 1.0)), lambda: call(damped(12.25, 1.0))],
            "damper coefficient": [lambda: call(damped(7.0, 0.5)),
                                   lambda: call(damped(7.0, 2.0))],
            "x0/v0": [lambda: call(damped(), unit(5, 0.5), unit(1, 0.2)),
                      lambda: call(damped(), 1e-2 * rng.standard_normal(N), np.zeros(N))],
            "masses/springs": [lambda: call(mj.chain(masses * 1.1, springs * 0.9, dampers)),
                               lambda: call(damped(m=1.3, k=0.8))],
        }
        if tolerances:
            cases[name]["rtol/atol"] = [lambda r=r: call(damped(), rtol=r, atol=r * 1e-2)
                                        for r in tolerances]

    def sim(solver, rtol):
        return lambda s, x0=X0, v0=None, rtol=rtol, atol=rtol * 1e-2: mj.solve(
            s, TS, x0, v0, method=mj.ODE(solver, rtol=rtol, atol=atol))

    solver_cases("solve ODE(Dopri8)", sim(diffrax.Dopri8(), 1e-8), (1e-6, 1e-9))
    solver_cases("solve ODE(Tsit5)", sim(diffrax.Tsit5(), 1e-6), (1e-5, 1e-7))
    solver_cases("solve Spectral", lambda s, x0=X0, v0=None: mj.solve(s, TS, x0, v0, velocity=True,
                                                                   method=mj.Spectral()), ())
    if "POD.basis" in ctx:
        basis = ctx["POD.basis"]
        rom_sim = lambda s, b=basis, x0=X0, v0=None, rtol=1e-8: mj.solve(
            mj.reduce(s, mj.Projection(b)), TS, x0, v0,
            method=mj.ODE(rtol=rtol, atol=rtol * 1e-2))
        rom_exact = lambda s, b=basis: mj.solve(mj.reduce(s, mj.Projection(b)), TS, X0,
                                                velocity=True, method=mj.DenseExponential())
        full, red = ctx["solve Spectral"], ctx["solve ROM DenseExponential"]
        cases.update({
            "solve ROM ODE(Dopri8)": {
                "damper position, coefficient": [lambda: rom_sim(damped(9.5, 1.0)),
                                                 lambda: rom_sim(damped(7.0, 3.0))],
                "basis": [lambda: rom_sim(damped(), other_basis())],
                "x0/v0": [lambda: rom_sim(damped(), x0=unit(5, 0.5), v0=unit(1, 0.2))],
                "rtol/atol": [lambda: rom_sim(damped(), rtol=1e-6)]},
            "solve ROM DenseExponential": {
                "damper position, coefficient": [lambda: rom_exact(damped(9.5, 3.0))],
                "basis": [lambda: rom_exact(damped(), other_basis())]},
            "phase_error": {"trajectories": [lambda: mj.metrics.phase_error(
                red.displacement, red.velocity, full.displacement, full.velocity)]},
            "relative_error": {"trajectories": [
                lambda: mj.metrics.relative_error(red.displacement, full.displacement)]},
            "grad ROM solve": {"damper position, coefficient": [
                lambda: ctx["grad"](8.25, 0.5), lambda: ctx["grad"](12.0, 2.0)]},
            "jit(grad) ROM solve": {"damper position, coefficient": [
                lambda: ctx["jit(grad)"](8.25, 0.5), lambda: ctx["jit(grad)"](12.0, 2.0)]},
            "jit(solve ODE(Dopri8))": {"system, x0, rtol": [
                lambda: JITTED["jit_simulate"](sys_a(), unit(5, 0.5), 1e-7)]},
            "jit(solve Spectral)": {"system, x0": [
                lambda: JITTED["jit_exact_solve"](sys_a(), unit(5, 0.5))]},
        })
    out = []
    for entry in (e.name for e in ENTRIES if e.name in ctx):
        for parameter, calls in cases.get(entry, {}).items():
            out.append((entry, parameter, calls[:1] if quick else calls))
    return out


def scene_dict(position, coefficient, x3, rank=None) -> dict:
    text = resources.files("mikota_jax").joinpath("scenes", f"{SCENE}.toml").read_text()
    data = tomllib.loads(text)
    data["damper"][0].update(position=position, coefficient=coefficient)
    data["initial"]["displacement"] = {"3": x3}
    if rank is not None:  # a fixed rank: new values must not change the ROM's shape
        data["reduction"].pop("energy")
        data["reduction"]["rank"] = rank
    return data


def digest(value) -> float:
    """One number per result, to check that cached executables compute what fresh ones do."""
    if isinstance(value, mj.SceneResult):  # run_scene
        return float(value.metrics["phase_error"] + value.rank
                     + np.sum(value.model.stats.singular_values))
    leaves = [np.asarray(x) for x in jax.tree.leaves(value) if isinstance(x, jax.Array)]
    return float(sum(np.sum(np.abs(x)) for x in leaves if x.dtype.kind in "fi"))


# --------------------------------------------------------------------------- one process's run


def time_entries(entries, ctx, recorder, repeats: int) -> list[dict]:
    rows = []
    for entry in entries:
        if entry.name == "POD svd":
            ctx["snapshots"] = snapshots(ctx)  # numpy, no compile
        mark = recorder.mark()
        start = time.perf_counter()
        result = jax.block_until_ready(entry.call(ctx))
        first = elapsed(start)
        events = recorder.summary(mark)
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            jax.block_until_ready(entry.call(ctx))
            times.append(elapsed(start))
        after = recorder.summary(mark)
        ctx[entry.name] = result
        run = statistics.median(times)
        main_traces = None
        if entry.main is not None:
            main_traces = sum(1 for e, _, f in recorder.log[mark:] if e == TRACE
                              and f == entry.main)
        rows.append(dict(entry=entry.name, first_s=first, run_s=run, run_times_s=times,
                         compile_s=first - run, events=events, main=entry.main,
                         main_traces=main_traces, repeat_traces=after["traces"] -
                         events["traces"], digest=digest(result)))
        print(f"  {entry.name:<24} first {first:7.2f} s  run {run:8.4f} s  "
              f"(trace {events['trace_s']:.2f}, lower {events['lower_s']:.2f}, backend "
              f"{events['backend_s']:.2f}; cache hit {events['hit']}, written "
              f"{events['written']}, uncacheable {events['uncacheable']})", flush=True)
    return rows


def retrace(ctx, recorder, rows, quick: bool) -> list[dict]:
    main_traces = {r["entry"]: r["main_traces"] for r in rows}
    out = []
    for entry, parameter, calls in variations(ctx, quick):
        mark = recorder.mark()
        for call in calls:
            jax.block_until_ready(call())
        events = recorder.summary(mark)
        first = main_traces.get(entry)
        ok = events["traces"] == 0 and events["compiles"] == 0 and (first is None or first <= 1)
        out.append(dict(entry=entry, parameter=parameter, calls=len(calls),
                        traces_after=events["traces"], compiles_after=events["compiles"],
                        main_traces_total=None if first is None else first + events["traces"],
                        ok=ok, functions=[t["function"] for t in events["top"]]))
    return out


def checks(ctx) -> dict:
    """Correctness of what was timed (max abs differences, or flags)."""
    found = {}
    exact = ctx.get("solve Spectral")

    def diff(a, b):
        return float(np.max(np.abs(np.asarray(a) - np.asarray(b))))

    if exact is not None and "solve ODE(Dopri8)" in ctx:
        found["ODE(Dopri8) rtol 1e-8 vs Spectral"] = (
            diff(ctx["solve ODE(Dopri8)"].displacement, exact.displacement), 1e-4)
    if exact is not None and "solve ODE(Tsit5)" in ctx:
        found["ODE(Tsit5) rtol 1e-6 vs Spectral"] = (
            diff(ctx["solve ODE(Tsit5)"].displacement, exact.displacement), 1e-2)
    if "POD svd" in ctx:
        rank = ctx["POD svd"].rank_for_energy(0.99, "paper")
        found["paper rank at 99 % is 76"] = (abs(rank - RANK), 0.5)
    if "POD snapshots" in ctx:
        found["POD snapshots vs svd, sigma_1..10 (rel.)"] = (
            diff(ctx["POD snapshots"].singular_values[:10], ctx["POD svd"].singular_values[:10])
            / float(ctx["POD svd"].singular_values[0]), 1e-8)
    if "phase_error" in ctx:
        found["phase error r = 76 (sum) < 0.1"] = (float(ctx["phase_error"]), 0.1)
        found["ROM ODE vs ROM DenseExponential"] = (
            diff(ctx["solve ROM ODE(Dopri8)"].displacement,
                 ctx["solve ROM DenseExponential"].displacement), 1e-4)
    if "jit(grad) ROM solve" in ctx:
        g, gj = (np.asarray(ctx[k]) for k in ("grad ROM solve", "jit(grad) ROM solve"))
        found["grad eager vs jit (rel.)"] = (float(np.max(np.abs(g - gj) / np.abs(g))), 1e-6)
        found["jit(solve ODE) vs solve ODE"] = (diff(ctx["jit(solve ODE(Dopri8))"].displacement,
                                                   ctx["solve ODE(Dopri8)"].displacement), 1e-9)
        found["jit(solve Spectral) vs solve Spectral"] = (
            diff(ctx["jit(solve Spectral)"].displacement, exact.displacement), 1e-10)
    return {k: dict(value=v, limit=limit, ok=bool(np.isfinite(v) and v < limit))
            for k, (v, limit) in found.items()}


def run_entries(cache_dir, quick: bool, repeats: int, only: str | None = None) -> dict:
    """Time every entry in this process (which must not have compiled anything yet)."""
    mj.enable_compilation_cache(cache_dir)
    recorder = Recorder()
    entries = [e for e in ENTRIES if (e.quick or not quick)
               and (only is None or e.name in only.split(","))]
    ctx: dict = {}
    rows = time_entries(entries, ctx, recorder, repeats)
    found = checks(ctx)
    retraced = retrace(ctx, recorder, rows, quick)
    recorder.close()
    return dict(rows=rows, checks=found, retrace=retraced)


def run_scene_entry(cache_dir, repeats: int) -> dict:
    mj.enable_compilation_cache(cache_dir)
    recorder = Recorder()
    ctx: dict = {}
    entry = Entry("run_scene(load_scene)", lambda c: mj.run_scene(mj.app.load_scene(SCENE)))
    rows = time_entries([entry], ctx, recorder, repeats)
    mark = recorder.mark()
    for x3 in (2.0, -0.5):
        mj.run_scene(mj.app.load_scene(scene_dict(9.5, 0.5 + x3**2, x3, rank=RANK)))
    events = recorder.summary(mark)
    retraced = [dict(entry=entry.name, parameter="damper, x0 (rank fixed)", calls=2,
                     traces_after=events["traces"], compiles_after=events["compiles"],
                     main_traces_total=None, ok=events["traces"] == events["compiles"] == 0,
                     functions=[t["function"] for t in events["top"]])]
    recorder.close()
    return dict(rows=rows, retrace=retraced)


def run_reproduce_child(out_dir) -> dict:
    """``python -m mikota_jax reproduce --out DIR``, run as ``-m`` does, with a listener."""
    import runpy

    recorder = Recorder()
    sys.argv = ["mikota_jax", "reproduce", "--out", str(out_dir)]
    start = time.perf_counter()
    code = 0
    try:
        runpy.run_module("mikota_jax", run_name="__main__", alter_sys=True)
    except SystemExit as stop:
        code = stop.code or 0
    main_s = elapsed(start)
    events = recorder.summary()
    return dict(code=code, main_s=main_s, events=events,
                cache_dir=os.environ.get("MIKOTA_JAX_CACHE_DIR"))


# --------------------------------------------------------------------------- child processes


def child_env(cache_dir=None) -> dict:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    env.pop("MIKOTA_JAX_CACHE", None)
    if cache_dir is not None:
        env["MIKOTA_JAX_CACHE_DIR"] = str(cache_dir)
    return env


def spawn(command: list[str], env: dict, cwd=None) -> tuple[float, str]:
    """Run a child; (process start-to-exit seconds, stdout). A failed child stops the benchmark."""
    start = time.perf_counter()
    done = subprocess.run(command, env=env, cwd=cwd, capture_output=True, text=True)
    wall = elapsed(start)
    if done.returncode != 0:
        raise SystemExit(f"child {' '.join(command[1:4])} failed (exit {done.returncode}):\n"
                         f"{done.stdout[-2000:]}\n{done.stderr[-3000:]}")
    return wall, done.stdout


def child(kind: str, tmp: Path, cache_dir: Path, quick: bool, echo: bool = True,
          env: dict | None = None, **extra) -> dict:
    out = tmp / f"{kind}_{time.monotonic_ns()}.json"
    command = [sys.executable, str(Path(__file__).resolve()), "--child", kind,
               "--cache-dir", str(cache_dir), "--child-out", str(out)]
    command += ["--quick"] if quick else []
    for key, value in extra.items():
        command += [f"--{key.replace('_', '-')}", str(value)]
    wall, stdout = spawn(command, {**child_env(cache_dir), **(env or {})}, cwd=tmp)
    if echo:
        print(stdout, end="", flush=True)
    data = json.loads(out.read_text())
    data["wall_s"] = wall
    return data


def cache_size(path: Path) -> dict:
    files = [p for p in path.rglob("*") if p.is_file()]
    return dict(files=len(files), bytes=sum(p.stat().st_size for p in files))


CLI_TARGET_S = 5.0
CLI_VARIANTS = {"CLI (level 0, classic emitters)": {},
                "level 0, MLIR emitters": {"XLA_FLAGS": "--xla_backend_optimization_level=0 "
                                           "--xla_cpu_use_fusion_emitters=true"},
                "XLA default (level 3)": {"XLA_FLAGS": "--xla_backend_optimization_level=3 "
                                          "--xla_cpu_use_fusion_emitters=true"}}


def cli_runs(tmp: Path, repeats: int, quick: bool = False) -> dict:
    """``python -m mikota_jax run SCENE --quiet``: process start to exit, cold and warm (quick:
    the CLI's own optimisation level only)."""
    runs = {}
    for label, extra in list(CLI_VARIANTS.items())[:1 if quick else None]:
        cold, warm = [], []
        for k in range(repeats):
            cache = tmp / f"cli_cache_{len(runs)}_{k}"
            command = [sys.executable, "-m", "mikota_jax", "run", SCENE, "--quiet", "--out",
                       str(tmp / "cli_out")]
            env = {**child_env(cache), **extra}
            cold.append(spawn(command, env, cwd=tmp)[0])
            warm.append(spawn(command, env, cwd=tmp)[0])
        runs[label] = dict(cold_s=statistics.median(cold), warm_s=statistics.median(warm),
                           cold_runs=cold, warm_runs=warm, xla_flags=extra.get("XLA_FLAGS", ""))
        print(f"  {label}: cold {runs[label]['cold_s']:.1f} s, warm {runs[label]['warm_s']:.1f} s "
              f"(median of {repeats})", flush=True)
    first = runs[next(iter(CLI_VARIANTS))]
    return dict(runs=runs, repeats=repeats, target_cold_s=CLI_TARGET_S,
                target_met=first["cold_s"] < CLI_TARGET_S)


def reproduce_runs(tmp: Path) -> dict:
    cache = tmp / "reproduce_cache"
    runs = {}
    print("\nreproduce, cold cache (instrumented python -m mikota_jax reproduce) ...", flush=True)
    runs["cold"] = child("reproduce", tmp, cache, False, echo=False, out_dir=tmp / "paper_cold")
    print("reproduce, warm cache (plain python -m mikota_jax reproduce) ...", flush=True)
    wall, _ = spawn([sys.executable, "-m", "mikota_jax", "reproduce", "--out",
                     str(tmp / "paper_plain")], child_env(cache), cwd=tmp)
    runs["warm_plain"] = dict(wall_s=wall)
    print("reproduce, warm cache (instrumented) ...", flush=True)
    runs["warm"] = child("reproduce", tmp, cache, False, echo=False, out_dir=tmp / "paper_warm")
    for key in ("cold", "warm"):
        r = runs[key]
        e = r["events"]
        r["startup_import_s"] = r["wall_s"] - r["main_s"]
        r["compile_s"] = e["compile_s"]
        r["run_s"] = r["main_s"] - e["compile_s"]
        r["compile_over_run"] = r["compile_s"] / r["run_s"]
    runs["cache"] = cache_size(cache)
    runs["target_compile_over_run_warm"] = RATIO_TARGET
    runs["target_met"] = runs["warm"]["compile_over_run"] <= RATIO_TARGET
    return runs


# --------------------------------------------------------------------------- report


def merge(cold_rows, warm_rows) -> list[dict]:
    warm = {r["entry"]: r for r in warm_rows}
    rows = []
    for c in cold_rows:
        w = warm[c["entry"]]
        ce, we = c["events"], w["events"]
        rows.append(dict(
            entry=c["entry"], cold_first_s=c["first_s"], cold_compile_s=c["compile_s"],
            warm_first_s=w["first_s"], warm_compile_s=w["compile_s"],
            run_s=statistics.median([c["run_s"], w["run_s"]]),
            cold_events={k: ce[k] for k in ce if k != "top"},
            warm_events={k: we[k] for k in we if k != "top"},
            cold_top=ce["top"], warm_top=we["top"],
            warm_cache=f"{we['hit']}/{we['uncacheable']}",
            warm_trace_lower_s=we["trace_s"] + we["lower_s"],
            speedup=c["compile_s"] / w["compile_s"] if w["compile_s"] > 0 else None,
            digest_cold=c["digest"], digest_warm=w["digest"],
            same_result=abs(c["digest"] - w["digest"]) <= 1e-9 * max(1.0, abs(c["digest"])),
            main=c["main"], main_traces=w["main_traces"]))
    return rows


def plot(rows, repro, quick: bool, meta, cli=None) -> Path:
    panels = 1 + (repro is not None) + (cli is not None)
    fig, axes = figure(nrows=panels, figsize=(8, 0.32 * len(rows) + 2.2 + 2.6 * (panels - 1)),
                       readable=True, height_ratios=[0.32 * len(rows) + 1.2] + [2.0] * (panels - 1),
                       squeeze=False)
    ax = axes[0][0]
    y = np.arange(len(rows))
    floor = 1e-3
    cold = [max(r["cold_compile_s"], floor) for r in rows]
    warm = [max(r["warm_compile_s"], floor) for r in rows]
    ax.barh(y - 0.2, cold, height=0.4, color="C3", label="cold (empty cache)")
    ax.barh(y + 0.2, warm, height=0.4, color="C0", label="warm (persistent cache)")
    for i, r in enumerate(rows):
        if r["warm_events"]["uncacheable"]:
            ax.annotate("not storable", (warm[i], y[i] + 0.2), xytext=(3, -3),
                        textcoords="offset points", color="C0")
    ax.set_yticks(y, [r["entry"] for r in rows])
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlabel("compile = first call - run [s] (log; floor 1 ms)")
    ax.set_title(f"first-call overhead per entry point (n = {N}, 2001 outputs)\n"
                 + subtitle(meta))
    ax.grid(True, axis="x", which="both", alpha=0.3)
    legend(ax, "right")
    if repro is not None:
        ax = axes[1][0]
        labels, parts = [], []
        for key in ("cold", "warm"):
            r = repro[key]
            labels.append(f"{key}\n{r['wall_s']:.1f} s")
            parts.append((r["startup_import_s"], r["compile_s"], r["run_s"]))
        left = np.zeros(2)
        for k, (label, color) in enumerate((("startup + import", "C7"),
                                            ("compile (trace, lower, XLA/cache)", "C3"),
                                            ("run", "C2"))):
            values = np.array([p[k] for p in parts])
            ax.barh([0, 1], values, left=left, color=color, label=label)
            left += values
        ax.set_yticks([0, 1], labels)
        ax.invert_yaxis()
        ax.set_xlabel("seconds, process start to exit")
        ax.set_title("python -m mikota_jax reproduce: time to first result\n"
                     f"warm compile / run = {repro['warm']['compile_over_run']:.2f} "
                     f"(target <= {RATIO_TARGET:g})")
        legend(ax, "right")
        ax.grid(True, axis="x", alpha=0.3)
    if cli is not None:
        ax = axes[panels - 1][0]
        labels = list(cli["runs"])
        y = np.arange(len(labels))
        ax.barh(y - 0.2, [cli["runs"][k]["cold_s"] for k in labels], height=0.4, color="C3",
                label="cold (empty cache)")
        ax.barh(y + 0.2, [cli["runs"][k]["warm_s"] for k in labels], height=0.4, color="C0",
                label="warm (persistent cache)")
        ax.axvline(cli["target_cold_s"], color="k", ls="--", lw=1,
                   label=f"target, cold: {cli['target_cold_s']:g} s")
        ax.set_yticks(y, labels)
        ax.invert_yaxis()
        ax.set_xlabel("seconds, process start to exit")
        ax.set_title(f"python -m mikota_jax run {SCENE}\n(median of {cli['repeats']}; the "
                     "CLI's flags apply up to 1000 DOFs)")
        legend(ax, "right")
        ax.grid(True, axis="x", alpha=0.3)
    return save_figure(fig, NAME, quick)


def report(rows, retraced, repro) -> None:
    print_table(rows, [("entry", "entry point", ""), ("cold_first_s", "cold 1st s", ".2f"),
                       ("cold_compile_s", "cold comp s", ".2f"),
                       ("warm_first_s", "warm 1st s", ".2f"),
                       ("warm_compile_s", "warm comp s", ".2f"),
                       ("warm_trace_lower_s", "warm trace+lower", ".2f"),
                       ("warm_cache", "hit/uncacheable", ""), ("run_s", "run s", ".4f")])
    print_table(retraced, [("entry", "entry point", ""), ("parameter", "new values of", ""),
                           ("calls", "calls", "d"), ("traces_after", "traces", "d"),
                           ("compiles_after", "compiles", "d"),
                           ("main_traces_total", "main fn traces", "d"), ("ok", "ok", "")])
    if repro is not None:
        lines = [dict(run=k, wall_s=repro[k]["wall_s"],
                      startup_import_s=repro[k].get("startup_import_s"),
                      compile_s=repro[k].get("compile_s"), run_s=repro[k].get("run_s"),
                      ratio=repro[k].get("compile_over_run"))
                 for k in ("cold", "warm_plain", "warm")]
        print_table(lines, [("run", "reproduce", ""), ("wall_s", "wall s", ".1f"),
                            ("startup_import_s", "start+import s", ".1f"),
                            ("compile_s", "compile s", ".1f"), ("run_s", "run s", ".1f"),
                            ("ratio", "compile/run", ".2f")])
        warm = repro["warm"]["events"]
        print(f"\nwarm reproduce: trace {warm['trace_s']:.1f} s ({warm['traces']} traces), "
              f"lower {warm['lower_s']:.1f} s, backend {warm['backend_s']:.1f} s for "
              f"{warm['compiles']} executables ({warm['hit']} from the cache, "
              f"{warm['uncacheable']} not storable, {warm['written']} compiled and written)")
        for t in warm["top"]:
            print(f"  {t['function']:<32} {t['total_s']:6.2f} s  (trace {t['trace_s']:.2f}, "
                  f"lower {t['lower_s']:.2f}, backend {t['backend_s']:.2f}; {t['compiles']} "
                  f"executables, {t['hit']} hits, {t['uncacheable']} uncacheable)")


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, child=dict(help=argparse.SUPPRESS),
                      cache_dir=dict(help=argparse.SUPPRESS),
                      child_out=dict(help=argparse.SUPPRESS),
                      out_dir=dict(help=argparse.SUPPRESS), only=dict(help=argparse.SUPPRESS))
    repeats = 2 if args.quick else 3
    if args.child:  # one measurement in this fresh process; the parent reads the JSON
        if args.child == "entries":
            data = run_entries(args.cache_dir, args.quick, repeats, args.only)
        elif args.child == "scene":
            data = run_scene_entry(args.cache_dir, repeats)
        else:
            data = run_reproduce_child(args.out_dir)
        Path(args.child_out).write_text(json.dumps(data, default=float))
        if data.get("code"):
            raise SystemExit(f"reproduce exited with {data['code']}")
        return data

    wall_start = time.perf_counter()
    tmp = Path(tempfile.mkdtemp(prefix="mikota_compile_"))
    try:
        cache = tmp / "entries_cache"
        print("cold: entry points in a child process with an empty cache ...", flush=True)
        cold = child("entries", tmp, cache, args.quick)
        print("warm: the same in this process, with the cache the child filled ...", flush=True)
        warm = run_entries(cache, args.quick, repeats)
        entries_cache = cache_size(cache)
        retraced = warm["retrace"]
        scene = repro = diagnostic = None
        print(f"\npython -m mikota_jax run {SCENE}: cold (new cache) and warm ...", flush=True)
        cli = cli_runs(tmp, 1 if args.quick else 3, args.quick)
        if not args.quick:
            scene_cache = tmp / "scene_cache"
            print("\nrun_scene(load_scene(...)) in fresh processes, cold then warm ...",
                  flush=True)
            scene = dict(cold=child("scene", tmp, scene_cache, False),
                         warm=child("scene", tmp, scene_cache, False))
            retraced = retraced + scene["warm"]["retrace"]
            repro = reproduce_runs(tmp)
            print("\ndiagnostic: solve ODE with EQX_ON_ERROR=nan (no host callbacks), cold then "
                  "warm ...", flush=True)
            nan_cache, nan_env = tmp / "eqx_nan_cache", {"EQX_ON_ERROR": "nan"}
            diagnostic = [child("entries", tmp, nan_cache, True, env=nan_env,
                                only="mikota_chain,solve ODE(Dopri8)") for _ in range(2)]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    rows = merge(cold["rows"], warm["rows"])
    if scene is not None:
        rows += merge(scene["cold"]["rows"], scene["warm"]["rows"])
    failed = [k for part in (cold, warm) for k, c in part["checks"].items() if not c["ok"]]
    failed += [f"cold and warm results differ: {r['entry']}" for r in rows
               if not r["same_result"]]
    for name, c in warm["checks"].items():
        print(f"check: {name}: {c['value']:.3g} (< {c['limit']:g}) "
              f"{'ok' if c['ok'] else 'FAILED'}")
    if failed:
        raise SystemExit("correctness check failed: " + "; ".join(failed))
    report(rows, retraced, repro)
    diag_rows = None if diagnostic is None else merge(diagnostic[0]["rows"], diagnostic[1]["rows"])
    for r in [r for r in diag_rows or [] if r["entry"].startswith("solve ODE")]:
        print(f"\nwith EQX_ON_ERROR=nan: {r['entry']}: compile cold {r['cold_compile_s']:.2f} s, "
              f"warm {r['warm_compile_s']:.2f} s (trace + lower {r['warm_trace_lower_s']:.2f} s; "
              f"cache hit/uncacheable {r['warm_cache']})")
    retrace_ok = all(r["ok"] for r in retraced)
    print(f"\nretrace check: {'ok' if retrace_ok else 'FAILED'} "
          f"({sum(r['calls'] for r in retraced)} calls with new values only)")
    data = dict(
        problem=dict(n=N, outputs=len(TS), t_end=float(TS[-1]), rank=RANK, scene=SCENE,
                     repeats=repeats, order=[r["entry"] for r in rows],
                     compile="first call - median run (same arguments)",
                     events="jax.monitoring: trace, lower (jaxpr -> MLIR), backend (XLA "
                            "compile or persistent-cache load) durations; cache events"),
        rows=rows, retrace=retraced, retrace_ok=retrace_ok,
        checks=dict(cold=cold["checks"], warm=warm["checks"]),
        cold_child_wall_s=cold["wall_s"], entries_cache=entries_cache,
        scene=None if scene is None else {k: v["wall_s"] for k, v in scene.items()},
        cli_run=cli,
        reproduce=repro, diagnostic_eqx_on_error_nan=None if diagnostic is None else dict(
            note="diffrax's SaveAt checks (eqx.error_if) put host callbacks into every ODE solve "
                 "executable, so the persistent cache cannot store it; EQX_ON_ERROR=nan turns "
                 "those checks into NaN-poisoning (no callback): this shows what the cache "
                 "would save. A diagnostic only; not a recommended setting.",
            rows=diag_rows),
        total_wall_s=elapsed(wall_start))
    path = write_json(NAME, args.quick, data)
    png = plot(rows, repro, args.quick, None, cli)
    print(f"wrote {path} and {png} ({data['total_wall_s']:.0f} s)")
    if not retrace_ok:
        raise SystemExit("retrace check failed: a value-only change traced or compiled again.")
    return data


if __name__ == "__main__":
    main()
