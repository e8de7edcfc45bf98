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

import subprocess
import sys
import time
from pathlib import Path

from _common import parse_args

HERE = Path(__file__).resolve().parent
SUITE = {
    "work_precision": "error against run time on the Section 5 scene, every method and scipy",
    "scaling": "cost against n, full and reduced models, memory, fitted exponents",
    "gradients": "dJ/d(position, coefficient) through the ROM: modes and adjoints",
    "compile": "compile time of every entry point, cold and cached; time to first result",
    "placement": "damper placement: the certified optimiser against a brute-force sweep",
    "reductions": "seven reductions of the Section 5 scene: error against size and cost",
    "critical_damping": "the exact path across critical damping: values, gradients, memory",
}


def run(names: list[str], quick: bool) -> list[dict]:
    """Run each script (``--quick`` passed on); their outcome and wall time, in order."""
    outcomes = []
    for name in names:
        start = time.perf_counter()
        argv = [sys.executable, str(HERE / f"{name}.py")] + (["--quick"] if quick else [])
        done = subprocess.run(argv, capture_output=True, text=True)
        seconds = time.perf_counter() - start
        # the error's last lines (JAX appends a note on traceback filtering after them)
        lines = [line for line in (done.stderr or done.stdout).strip().splitlines()
                 if line.strip() and not line.startswith(("For simplicity, JAX", "-----"))]
        outcomes.append({"name": name, "ok": done.returncode == 0, "seconds": seconds,
                         "tail": lines[-4:]})
        print(f"{name:18s} {seconds:7.1f} s  {'ok' if done.returncode == 0 else 'FAILED'}",
              flush=True)
        if done.returncode != 0:
            print("\n".join("    " + line for line in outcomes[-1]["tail"]), flush=True)
    return outcomes


def main(argv=None) -> int:
    args = parse_args(__doc__, argv, only={"help": "comma-separated names (default: all)",
                                           "default": None})
    names = list(SUITE) if args.only is None else [n.strip() for n in args.only.split(",")]
    unknown = [n for n in names if n not in SUITE]
    if unknown:
        raise SystemExit(f"--only: unknown benchmark(s) {unknown}; the suite is {list(SUITE)}")
    outcomes = run(names, args.quick)
    failed = [o["name"] for o in outcomes if not o["ok"]]
    total = sum(o["seconds"] for o in outcomes)
    print(f"{len(outcomes) - len(failed)} of {len(outcomes)} ran in {total:.0f} s"
          + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
