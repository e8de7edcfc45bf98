"""Command line: ``python -m mikota_jax reproduce [--out DIR]``, ``run SCENE.toml --out DIR`` and
``optimise SCENE.toml [--out DIR]`` (damper placement: ``placement.json`` and ``placement.png``;
``--search viscosities | places`` at full order, with relative dampers and the ``output`` and
``h2`` criteria).

Bad input ends with one line on stderr and exit code 2 (no traceback); a run that fails writes no
partial ``results.json``. Compiled executables are kept in JAX's persistent compilation cache
(``~/.cache/mikota_jax/xla``, or ``$MIKOTA_JAX_CACHE_DIR``), so a second run skips most of the
compilation; ``MIKOTA_JAX_CACHE=0`` turns that off. ``run`` compiles without XLA's LLVM
optimisation passes and with its classic fusion emitters when the scene has at most 1000 DOFs (a
one-shot run compiles more than it computes there); an ``XLA_FLAGS`` that sets either is left
alone.
"""

import argparse
import os
import sys
from pathlib import Path

from .._interrupt import MESSAGE, exit_on_interrupt


def _packaged_scenes() -> str:
    """The packaged paper scenes' names, read from the package's files (no JAX import)."""
    from importlib import resources

    names = sorted(p.name[:-5] for p in resources.files("mikota_jax").joinpath("scenes").iterdir()
                   if p.name.endswith(".toml"))
    return ", ".join(names)


def _parser() -> argparse.ArgumentParser:
    # the docstring is reST; --help shows it as plain text (no ``literal`` markers)
    parser = argparse.ArgumentParser(prog="python -m mikota_jax",
                                     description=__doc__.replace("``", ""))
    commands = parser.add_subparsers(dest="command", required=True)
    reproduce = commands.add_parser("reproduce", help="reproduce Weber & Zastrau (2018)")
    reproduce.add_argument("--out", default="paper_results", help="folder for figures and JSON")
    reproduce.add_argument("--quiet", action="store_true",
                           help="no progress bar and no table (the exit code says whether a "
                           "reproducible number was missed)")
    run = commands.add_parser("run", help="run a scene file and write results.json")
    scenes = _packaged_scenes()
    run.add_argument("scene", help=f"a TOML scene file, or a packaged paper scene: {scenes}")
    run.add_argument("--out", required=True, help="folder for results.json and figures")
    run.add_argument("--quiet", action="store_true", help="no summary (errors only)")
    opt = commands.add_parser("optimise", help="optimise the positions and coefficients of a "
                              "scene's grounded dampers (gradients through the ROM, certified on "
                              "the full model)")
    opt.add_argument("scene", help=f"a TOML scene file, or a packaged paper scene: {scenes}")
    opt.add_argument("--out", default="placement_results", help="folder for JSON and plot")
    opt.add_argument("--search", default="rom", choices=["rom", "viscosities", "places"],
                     help="rom (default): positions and coefficients of the grounded dampers, "
                     "screened on the reduced model, certified on the full one; viscosities: "
                     "every damper's coefficient (grounded and relative) at its place, at full "
                     "order; places: the grounded dampers moved over --candidates (relative ones "
                     "over --pair-candidates) and every coefficient re-optimised, at full order")
    opt.add_argument("--objective", default="energy",
                     choices=["energy", "average_energy", "peak", "output", "h2"],
                     help="energy of the scene's free vibration (default), average_energy "
                     "(trace over --lowest modes), peak (smooth peak of --dof), output "
                     "(energy of the displacements at --output-dofs) and h2 (from unit forces "
                     "at --input-dofs to them): output and h2 at full order only")
    opt.add_argument("--output-dofs", type=_dofs, metavar="I,J,...",
                     help="DOFs whose displacements are the output (output, h2)")
    opt.add_argument("--input-dofs", type=_dofs, metavar="I,J,...",
                     help="DOFs of the unit forces (h2)")
    opt.add_argument("--candidates", type=_dofs, metavar="I,J,...",
                     help="DOFs the dampers may take (places; default all)")
    opt.add_argument("--pair-candidates", type=_pairs, metavar="I-J,K-L,...",
                     help="DOF pairs the relative dampers may take (places; default: they stay)")
    opt.add_argument("--method", default="bfgs", choices=["bfgs", "spg"],
                     help="viscosity search at full order: projected BFGS (default) or spectral "
                     "projected gradient")
    opt.add_argument("--dof", type=int, help="DOF of the 'peak' objective (1-based)")
    opt.add_argument("--lowest", type=int, help="'average_energy': only the s lowest modes")
    opt.add_argument("--energy", type=float,
                     help="pseudo-energy fraction of the first POD basis (default: the scene's, "
                     "at least 0.9999)")
    opt.add_argument("--starts", type=int, default=8,
                     help="starts of the relaxed search (--split, or several dampers; one "
                     "damper at a DOF is found by screening every DOF); default 8")
    opt.add_argument("--optimizer", default="adam", choices=["adam", "lbfgs"],
                     help="optimiser of the relaxed search")
    opt.add_argument("--iterations", type=int, default=80,
                     help="iterations of the relaxed search (default 80)")
    opt.add_argument("--tolerance", type=float, default=1e-4,
                     help="largest ROM error accepted at the optimum (default 1e-4)")
    opt.add_argument("--certify", default="full", choices=["full", "estimate"],
                     help="certify the optimum on the full model (J and dJ/dc, default) or by "
                     "the error estimates of J and dJ/dc (no full solve; energy objective)")
    opt.add_argument("--split", action="store_true",
                     help="allow dampers between DOFs (split over the neighbours)")
    opt.add_argument("--sweep", type=int, default=0, metavar="C",
                     help="also sweep the full model over every DOF x C coefficients (the 3 "
                     "best DOFs refined)")
    opt.add_argument("--no-progress", action="store_true", help="no progress bars")
    opt.add_argument("--quiet", action="store_true",
                     help="no progress and no summary (errors only)")
    return parser


def _dofs(text: str) -> list[int]:
    """'3,7,12' -> [3, 7, 12] (1-based DOFs; their range is checked with the scene)."""
    try:
        return [int(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected DOFs as I,J,..., got {text!r}") from None


def _pairs(text: str) -> list[tuple[int, int]]:
    """'5-9,2-12' -> [(5, 9), (2, 12)] (1-based DOF pairs; checked with the scene)."""
    try:
        pairs = [tuple(int(x) for x in part.split("-")) for part in text.split(",")]
    except ValueError:
        pairs = None
    if not pairs or any(len(pair) != 2 for pair in pairs):
        raise argparse.ArgumentTypeError(f"expected DOF pairs as I-J,K-L,..., got {text!r}")
    return pairs


def _writable_folder(out: str) -> Path:
    """``--out`` made (with its parents) and checked writable before anything is computed."""
    path = Path(out)
    if path.exists() and not path.is_dir():
        raise ValueError(f"mikota_jax: --out {out!r} exists and is not a folder.")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(f"mikota_jax: --out {out!r} cannot be made: {error.strerror}.") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise ValueError(f"mikota_jax: --out {out!r} is not writable.")
    return path


def _enable_cache() -> None:
    """The persistent compilation cache, or one warning line and none (an unusable folder)."""
    from .._cache import enable_compilation_cache

    try:
        enable_compilation_cache()
    except OSError as error:
        print(f"warning: no compilation cache ({error}); set MIKOTA_JAX_CACHE_DIR to a writable "
              "folder, or MIKOTA_JAX_CACHE=0 to silence this.", file=sys.stderr)


# ``run`` on a scene of at most this many DOFs compiles at XLA's optimisation level 0 and with
# the classic fusion emitters instead of the MLIR ones (``fast_compile_flags``): the LLVM passes
# and the per-kernel MLIR pipeline are most of a cold start. The compiled code computes the same
# IEEE operations, slower, which beyond this size costs more than the compile it saves (the
# ``compile`` benchmark's cold starts).
FAST_COMPILE_MAX_DOFS = 1000
_LEVEL = "--xla_backend_optimization_level"
_EMITTERS = "--xla_cpu_use_fusion_emitters"


def fast_compile_flags(flags: str) -> str:
    """``flags`` (an ``XLA_FLAGS`` value) with XLA's optimisation level 0 and its classic fusion
    emitters added, each only where ``flags`` does not set it already. For the command line's
    small scenes and the test suite (compile-bound: most tests build a few small systems once);
    no JAX import, so that it can run before JAX's backend starts."""
    extra = [] if _LEVEL in flags else [f"{_LEVEL}=0"]
    if _EMITTERS not in flags and _knows_emitters_flag():
        extra.append(f"{_EMITTERS}=false")
    return " ".join(filter(None, [flags, *extra]))


def _knows_emitters_flag() -> bool:
    """Whether the installed jaxlib's XLA has ``--xla_cpu_use_fusion_emitters`` (0.6 and later):
    XLA aborts the process on a flag it does not know."""
    from importlib.metadata import version

    try:
        return tuple(int(p) for p in version("jaxlib").split(".")[:2]) >= (0, 6)
    except (ValueError, ImportError):
        return False


def _scene_size(source: str) -> int | None:
    """The DOF count a scene's ``[chain]`` states (mikota n, custom masses, branched lengths),
    read with ``tomllib`` only (before JAX starts); None where only its matrices would say."""
    import tomllib
    from importlib import resources

    from .scene_file import PAPER_SCENES

    try:
        if source in PAPER_SCENES:
            text = resources.files("mikota_jax").joinpath("scenes", f"{source}.toml").read_text()
        elif "\n" not in source and Path(source).is_file():
            text = Path(source).read_text(encoding="utf-8-sig")
        else:
            text = source
        chain = tomllib.loads(text)["chain"]
        kind = chain.get("type")
        if kind == "mikota":
            return int(chain["n"])
        if kind == "custom" and "masses" in chain:
            return len(chain["masses"])
        if kind == "branched" and "lengths" in chain:
            return sum(int(length) for length in chain["lengths"]) + 1
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        pass  # load_scene reports a bad scene properly
    return None


def _compile_level(args) -> None:
    """XLA's optimisation level 0 and classic fusion emitters for ``run`` on a small scene (see
    ``FAST_COMPILE_MAX_DOFS``), set before JAX's backend starts; a flag the user set in
    ``XLA_FLAGS`` wins."""
    if args.command != "run":
        return
    size = _scene_size(args.scene)
    if size is not None and size <= FAST_COMPILE_MAX_DOFS:
        os.environ["XLA_FLAGS"] = fast_compile_flags(os.environ.get("XLA_FLAGS", ""))


def main(argv=None) -> int:
    """The command line on ``argv`` (default ``sys.argv[1:]``); returns the exit code.

    Without ``argv`` (the ``mikota-jax`` console script, ``python -m mikota_jax``) it is the
    process's own command line: Ctrl-C then ends the process with one line and exit code 130
    (``mikota_jax._interrupt``, installed before the package imported JAX, again here)."""
    if argv is None:
        exit_on_interrupt()
    try:
        return _command(argv)
    except KeyboardInterrupt:  # the handler not installed (called in-process, or off the main
        print(MESSAGE, file=sys.stderr)  # thread): the same line, no traceback
        return 130


def _command(argv) -> int:
    args = _parser().parse_args(argv)
    _compile_level(args)
    say = (lambda *_: None) if args.quiet else print  # --quiet: errors only
    if os.environ.get("MIKOTA_JAX_CACHE", "1") != "0":
        _enable_cache()
    try:
        _writable_folder(args.out)
        if args.command == "reproduce":
            from .reproduction import reproduce

            report = reproduce(args.out, verbose=not args.quiet)
            return 1 if report["missed"] else 0
        if args.command == "optimise" and args.search != "rom":
            from .. import ProjectedBFGS, SpectralProjectedGradient
            from .placement import full_order_scene

            minimiser = dict(bfgs=ProjectedBFGS(),
                             spg=SpectralProjectedGradient())[args.method]
            report = full_order_scene(
                args.scene, args.out, search=args.search, objective=args.objective,
                lowest=args.lowest, dof=args.dof, output_dofs=args.output_dofs,
                input_dofs=args.input_dofs,
                candidates=args.candidates, pair_candidates=args.pair_candidates,
                minimiser=minimiser, progress=not (args.no_progress or args.quiet))
            result = report["result"]
            positions = [float(p) for p in result["positions"]]
            say(f"{result['status']}\noptimum: positions {positions}, "
                f"relative pairs {result['pairs']}, coefficients "
                f"{[round(float(c), 6) for c in result['coefficients']]}, {args.objective} "
                f"(full model) {result['value']:.10g}, {result['seconds']:.1f} s"
                f"\nwrote {Path(args.out) / 'placement.json'}")
            return 0
        if args.command == "optimise":
            if args.objective in ("output", "h2"):
                raise ValueError(f"mikota_jax: --objective {args.objective} needs a full-order "
                                 "search (--search viscosities or places).")
            from .placement import optimise_scene

            report = optimise_scene(
                args.scene, args.out, objective=args.objective, dof=args.dof, lowest=args.lowest,
                energy=args.energy, starts=args.starts, optimizer=args.optimizer,
                iterations=args.iterations, split=args.split, tolerance=args.tolerance,
                certify=args.certify, sweep=args.sweep,
                progress=not (args.no_progress or args.quiet))
            result = report["result"]
            which = "full model" if args.certify == "full" else "reduced model, estimated"
            say(f"{result['stats']['status']}\noptimum: positions {result['positions']}, "
                f"coefficients {result['coefficients']}, objective ({which}) "
                f"{result['value']:.10g}"
                f"\nwrote {Path(args.out) / 'placement.json'}")
            return 0
        from .. import run_scene
        from .figures import scene_figures
        from .results import result_dict, run_summary, write_json
        from .scene_file import load_scene

        scene = load_scene(args.scene)
        result = run_scene(scene)
        data = result_dict(result)
        out = Path(args.out)
        if scene.output.figures:
            out.mkdir(parents=True, exist_ok=True)
            data["figures"] = [str(p.name) for p in scene_figures(result, out)]
        write_json(data, out / "results.json")
        say(run_summary(result, out, data.get("figures", ())))
        return 0
    except ValueError as error:
        print(f"error: {str(error).splitlines()[0]}", file=sys.stderr)
        return 2
    except OSError as error:  # writing the results (the folder was checked before computing)
        print(f"error: mikota_jax: could not write the results: {error}", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"error: {_OUT_OF_MEMORY}", file=sys.stderr)
        return 2
    except RuntimeError as error:  # the XLA runtime: out of memory, or a check under jit
        message = _runtime_message(error)
        if message is None:
            raise
        print(f"error: {message}", file=sys.stderr)
        return 2


_OUT_OF_MEMORY = ("mikota_jax: the computation ran out of memory; make the scene smaller ([chain] "
                  "n, [time] end / step, [output] dofs) or use a reduced model.")


def _runtime_message(error: RuntimeError) -> str | None:
    """One line for a runtime error of the XLA runtime (out of memory, or one of our checks that
    fired inside a compiled computation); None for anything else (a bug: its traceback shows)."""
    text = str(error)
    if "RESOURCE_EXHAUSTED" in text or "Out of memory" in text:
        return _OUT_OF_MEMORY
    ours = [line.strip() for line in text.splitlines() if "mikota_jax:" in line]
    return ours[0][ours[0].index("mikota_jax:"):] if ours else None
