"""The maintained benchmarks as one suite: accuracy against cost (work-precision), scaling in n,
gradients, compile and cold start, damper design, reductions' error against cost, and the exact
path across critical damping. One command runs them all, each in its own process (so that one
script's compiled programs and memory do not colour the next one's figures):

    OPENBLAS_NUM_THREADS=1 python benchmarks/suite.py --quick   # smoke runs, a few minutes
    OPENBLAS_NUM_THREADS=1 python benchmarks/suite.py           # full runs (hours), quiet machine

``--only NAME,NAME`` picks some. Full runs write ``results/NAME.{json,png}`` (the benchmark page
of the docs is generated from them); quick runs, the same code on smaller problems, write
``results/NAME_quick.*``, which git ignores. The exit code is 1 if any script failed (CI runs
``--quick``). Investigations answered once are notes in ``docs/notes/``, not scripts.
"""

import importlib.metadata
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from _common import parse_args

HERE = Path(__file__).resolve().parent
SUITE = {
    "work_precision": "error against run time on the Section 5 scene, every method and scipy",
    "scaling": "cost against n, full and reduced models, memory, fitted exponents",
    "gradients": "dJ/d(position, coefficient) through the ROM: modes and adjoints",
    "compile": "compile time of every entry point, cold and cached; time to first result",
    "placement": "damper placement: the certified optimiser against a brute-force sweep",
    "viscosity": "optimal viscosities at full order: FastOptimalDamping.jl's example, cold",
    "reductions": "seven reductions of the Section 5 scene: error against size and cost",
    "critical_damping": "the exact path across critical damping: values, gradients, memory",
    "io_models": "input-output models: frequency response against scipy, H2 errors of reductions",
    "engine": "the spectral engine: energy gradient against scipy, compile, all-DOF histories, "
              "batched designs",
}


# smoke runs only: XLA's cheapest backend optimisation and its classic fusion emitters
# (compiling is most of a quick run; the programs compute the same, only slower), as the tests;
# XLA aborts on a flag it does not know, and jaxlib has the second from 0.6 on
_JAXLIB = tuple(int(p) for p in importlib.metadata.version("jaxlib").split(".")[:2])
QUICK_ENV = {"XLA_FLAGS": " ".join(["--xla_backend_optimization_level=0"] + (
    ["--xla_cpu_use_fusion_emitters=false"] if _JAXLIB >= (0, 6) else []))}


def run_one(name: str, quick: bool) -> dict:
    """One script in its own process (``--quick`` passed on): outcome, wall and CPU seconds."""
    argv = [sys.executable, str(HERE / f"{name}.py")] + (["--quick"] if quick else [])
    env = dict(os.environ)
    if quick:
        env["XLA_FLAGS"] = " ".join(filter(None, (env.get("XLA_FLAGS"), QUICK_ENV["XLA_FLAGS"])))
    start = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out:
        child = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, text=True, env=env)
        _, status, usage = os.wait4(child.pid, 0)  # the child's own CPU time, not its siblings'
        child.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        text = out.read()
    # the error's last lines (JAX appends a note on traceback filtering after them)
    lines = [line for line in text.strip().splitlines()
             if line.strip() and not line.startswith(("For simplicity, JAX", "-----"))]
    return {"name": name, "ok": child.returncode == 0, "seconds": time.perf_counter() - start,
            "cpu_seconds": usage.ru_utime + usage.ru_stime, "tail": lines[-4:]}


def run(names: list[str], quick: bool, jobs: int = 1) -> list[dict]:
    """Run the scripts, ``jobs`` at a time; their outcomes in the order of ``names``."""
    def report(outcome: dict) -> dict:
        status = "ok" if outcome["ok"] else "FAILED"
        print(f"{outcome['name']:18s} {outcome['seconds']:7.1f} s  "
              f"(CPU {outcome['cpu_seconds']:6.1f} s)  {status}", flush=True)
        if not outcome["ok"]:
            print("\n".join("    " + line for line in outcome["tail"]), flush=True)
        return outcome

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(lambda n=name: report(run_one(n, quick))) for name in names]
        return [f.result() for f in futures]


def main(argv=None) -> int:
    args = parse_args(__doc__, argv, only={"help": "comma-separated names (default: all)",
                                           "default": None},
                      jobs={"type": int, "default": None,
                            "help": "scripts run at a time (default: 2 with --quick, else 1)"})
    names = list(SUITE) if args.only is None else [n.strip() for n in args.only.split(",")]
    unknown = [n for n in names if n not in SUITE]
    if unknown:
        raise SystemExit(f"--only: unknown benchmark(s) {unknown}; the suite is {list(SUITE)}")
    jobs = args.jobs or (2 if args.quick else 1)
    start = time.perf_counter()
    outcomes = run(names, args.quick, jobs)
    failed = [o["name"] for o in outcomes if not o["ok"]]
    cpu = sum(o["cpu_seconds"] for o in outcomes)
    wall = time.perf_counter() - start
    print(f"{len(outcomes) - len(failed)} of {len(outcomes)} ran in {wall:.0f} s ({jobs} at a "
          f"time; {cpu:.0f} CPU seconds)"
          + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
