"""Command line: ``python -m mikota_jax reproduce [--out DIR]`` and ``run SCENE.toml --out DIR``.

Bad input ends with one line on stderr and exit code 2 (no traceback); a run that fails writes no
partial ``results.json``. Compiled executables are kept in JAX's persistent compilation cache
(``~/.cache/mikota_jax/xla``, or ``$MIKOTA_JAX_CACHE_DIR``), so a second run skips most of the
compilation; ``MIKOTA_JAX_CACHE=0`` turns that off.
"""

import argparse
import os
import sys
from pathlib import Path


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m mikota_jax", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)
    reproduce = commands.add_parser("reproduce", help="reproduce Weber & Zastrau (2018)")
    reproduce.add_argument("--out", default="paper_results", help="folder for figures and JSON")
    run = commands.add_parser("run", help="run a scene file and write results.json")
    run.add_argument("scene", help="a TOML scene file, or a packaged paper scene name")
    run.add_argument("--out", required=True, help="folder for results.json and figures")
    return parser


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    if os.environ.get("MIKOTA_JAX_CACHE", "1") != "0":
        from ._cache import enable_compilation_cache

        enable_compilation_cache()
    try:
        if args.command == "reproduce":
            from ._reproduce import reproduce

            report = reproduce(args.out)
            return 1 if report["missed"] else 0
        from ._figures import scene_figures
        from ._run import run_scene, write_json
        from ._scene import load_scene

        scene = load_scene(args.scene)
        result = run_scene(scene)
        out = Path(args.out)
        if scene.output.figures:
            out.mkdir(parents=True, exist_ok=True)
            result["figures"] = [str(p.name) for p in scene_figures(result, out)]
        write_json(result, out / "results.json")
        print(f"wrote {out / 'results.json'}")
        return 0
    except ValueError as error:
        print(f"error: {str(error).splitlines()[0]}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
