"""What every benchmark script shares: thread setup, compile/run timing, metadata, JSON, tables.

Import this module before jax or numpy (it sets ``OPENBLAS_NUM_THREADS=1`` unless already set, so
that LAPACK calls do not busy-wait on a loaded machine). The conventions, probdiffeq's way:

* compile time apart from run time: ``Compiled`` wraps a function in ``jax.jit`` and compiles it
  ahead of time (``lower(...).compile()``), timing trace + lower + XLA compile;
* run time: the median of repeated calls, each ended by ``jax.block_until_ready``;
* every comparison in one process, one JSON per script under ``benchmarks/results/`` with the
  environment metadata, plus a PNG; ``--quick`` runs write ``NAME_quick.json`` / ``.png`` beside
  (never over) the full results;
* ``--replot`` redraws ``results/NAME[_quick].png`` from the committed JSON alone (no timing):
  every script draws its figure from the dict it wrote (``read_json``), so a full run and a
  replot draw the same figure from the same data.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import datetime
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import jax
import numpy as np

import mikota_jax as mj
from mikota_jax.app import write_json as write_json_file

RESULTS = Path(__file__).resolve().parent / "results"


class Compiled:
    """``jax.jit(fn)`` compiled ahead of time for the example arguments; calls block until ready.

    ``trace_s`` is trace + lower, ``xla_s`` the XLA compile, ``compile_s`` their sum.
    """

    def __init__(self, fn, *example_args):
        jitted = jax.jit(fn)
        start = time.perf_counter()
        lowered = jitted.lower(*example_args)
        middle = time.perf_counter()
        self.executable = lowered.compile()
        end = time.perf_counter()
        self.trace_s, self.xla_s = middle - start, end - middle
        self.compile_s = end - start

    def __call__(self, *args):
        return jax.block_until_ready(self.executable(*args))


def timed(fn, *args, repeats: int):
    """(result of the last call, median seconds, all seconds) over ``repeats`` calls of ``fn``.

    ``fn`` must block until its result is ready (a ``Compiled``, or plain numpy/scipy code).
    """
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return result, statistics.median(times), times


def parse_args(doc: str, argv=None, replot: bool = False, **extra) -> argparse.Namespace:
    """``--quick`` (a minute or less), ``--replot`` where the script supports it (``replot``),
    plus ``extra`` flags (name -> add_argument kwargs)."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a smoke run of a minute or less")
    if replot:
        parser.add_argument("--replot", action="store_true",
                            help="only redraw results/NAME.png from results/NAME.json (no timing)")
    for flag, kwargs in extra.items():
        parser.add_argument("--" + flag.replace("_", "-"), **kwargs)
    return parser.parse_args(argv)


def metadata() -> dict:
    """Versions, backend, device, CPU count and the x64 flag: stored with every result."""
    import diffrax
    import equinox
    import jaxlib

    try:
        import scipy

        scipy_version = scipy.__version__
    except ImportError:  # scipy is only a comparison baseline
        scipy_version = None
    device = jax.devices()[0]
    return {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "mikota_jax": mj.__version__, "jax": jax.__version__, "jaxlib": jaxlib.__version__,
        "diffrax": diffrax.__version__, "equinox": equinox.__version__,
        "numpy": np.__version__, "scipy": scipy_version,
        "python": platform.python_version(), "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "backend": jax.default_backend(),
        "device": getattr(device, "device_kind", None) or str(device),
        "device_count": jax.device_count(),
        "cpu_count": os.cpu_count(), "x64": bool(jax.config.read("jax_enable_x64")),
        "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS"),
        "argv": sys.argv[1:],
    }


def result_stem(name: str, quick: bool) -> Path:
    """``results/NAME`` (or ``results/NAME_quick``): add ``.json`` / ``.png``."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    return RESULTS / (f"{name}_quick" if quick else name)


def write_json(name: str, quick: bool, data: dict, meta: dict | None = None) -> Path:
    """Write ``data`` (with metadata added: this run's, or ``meta``, the measuring run's when
    results are only recomputed from stored measurements) atomically to
    ``results/NAME[_quick].json``.

    The package's one JSON writer (``mikota_jax.app.write_json``: arrays by ``to_plain``, NaN or
    inf refused).
    """
    path = result_stem(name, quick).with_suffix(".json")
    payload = {"benchmark": name, "quick": quick, "metadata": meta or metadata(), **data}
    return write_json_file(payload, path, newline=True)


def read_json(name: str, quick: bool) -> dict:
    """``results/NAME[_quick].json`` as written (what every figure is drawn from)."""
    return json.loads(result_stem(name, quick).with_suffix(".json").read_text())


def print_table(rows: list[dict], columns: list[tuple[str, str, str]]) -> None:
    """Print ``rows`` as a table; ``columns`` are (key, header, format spec) with None as '-'."""
    widths = [max(len(header), 10) for _, header, _ in columns]
    cells = [[("-" if r.get(key) is None else format(r[key], spec)) for key, _, spec in columns]
             for r in rows]
    for line in cells:
        widths = [max(w, len(c)) for w, c in zip(widths, line)]
    header = "  ".join(h.rjust(w) if i else h.ljust(w)
                       for i, ((_, h, _), w) in enumerate(zip(columns, widths)))
    print("\n" + header + "\n" + "-" * len(header))
    for line in cells:
        print("  ".join(c.rjust(w) if i else c.ljust(w)
                        for i, (c, w) in enumerate(zip(line, widths))))


DPI = 150
DISPLAY_PX = 900  # the width a README shows a figure at
MIN_POINTS = 7.0  # the smallest text there, in points at DPI


def figure(*, readable: bool = False, **kwargs):
    """A matplotlib (fig, axes) on the Agg backend (no display needed).

    ``readable``: every font scaled to the figure's width, so that the smallest text (ticks,
    legends; titles are 1.2x) is ``MIN_POINTS`` when the PNG is shown ``DISPLAY_PX`` wide.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if readable:
        width = kwargs.get("figsize", plt.rcParams["figure.figsize"])[0]
        size = MIN_POINTS * max(1.0, width * DPI / DISPLAY_PX)
        plt.rcParams.update({key: size for key in (
            "font.size", "axes.labelsize", "xtick.labelsize", "ytick.labelsize",
            "legend.fontsize", "legend.title_fontsize")})
        plt.rcParams.update({"axes.titlesize": 1.2 * size, "figure.titlesize": 1.2 * size})
    return plt.subplots(**kwargs)


def legend(ax, where: str = "right", handles=None, **kwargs):
    """A legend outside the axes, covering no data: beside them ("right", top-aligned) or
    centred under their x label ("below", placed by ``save_figure`` once the label is drawn)."""
    if handles is not None:
        kwargs["handles"] = handles
    if where == "right":
        return ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0,
                         **kwargs)
    box = ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0.0), borderaxespad=0.0, **kwargs)
    box.below = True
    return box


def save_figure(fig, name: str, quick: bool) -> Path:
    """Lay out (legends below their axes' x labels), save at ``DPI`` cropped to the drawn
    content, and warn when text would read smaller than ``MIN_POINTS`` at ``DISPLAY_PX`` wide."""
    import matplotlib.pyplot as plt
    from matplotlib.text import Text
    from matplotlib.transforms import ScaledTranslation

    renderer = fig.canvas.get_renderer()
    for ax in fig.axes:
        box = ax.get_legend()
        if box is not None and getattr(box, "below", False):
            drop = ax.get_window_extent(renderer).y0 - ax.xaxis.get_tightbbox(renderer).y0
            box.set_bbox_to_anchor((0.5, 0.0), transform=ax.transAxes + ScaledTranslation(
                0.0, -(drop / fig.dpi + 0.08), fig.dpi_scale_trans))
    path = result_stem(name, quick).with_suffix(".png")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI, bbox_inches="tight", pad_inches=0.05)
    width = int.from_bytes(path.read_bytes()[16:20], "big")
    smallest = min(t.get_fontsize() for t in fig.findobj(Text) if t.get_visible() and t.get_text())
    shown = smallest * min(1.0, DISPLAY_PX / width)
    if shown < MIN_POINTS:
        print(f"warning: {path.name}: {width} px wide, its smallest text reads {shown:.1f} pt "
              f"at {DISPLAY_PX} px (< {MIN_POINTS:g})")
    plt.close(fig)
    return path


def subtitle(meta: dict | None = None) -> str:
    meta = meta or metadata()
    return (f"{meta['backend']} / {meta['device']}, {meta['cpu_count']} CPUs, jax {meta['jax']}, "
            f"x64 {meta['x64']}")


def fit_exponent(sizes, costs) -> float | None:
    """Least-squares slope of log(cost) on log(size): cost ~ size^slope (None below 2 points)."""
    pairs = [(s, c) for s, c in zip(sizes, costs) if c is not None and c > 0]
    if len(pairs) < 2:
        return None
    x, y = np.log([p[0] for p in pairs]), np.log([p[1] for p in pairs])
    return float(np.polyfit(x, y, 1)[0])


def max_error(displacement, reference) -> float:
    """max |x_i(t_k) - x_i^ref(t_k)| over every DOF and time."""
    return float(np.max(np.abs(np.asarray(displacement) - np.asarray(reference))))


def elapsed(start: float) -> float:
    return time.perf_counter() - start


SECTION5 = "section5_damped"
QUICK_N = 60  # the chain size of the Section 5 scene in a --quick run


def section5_scene(quick: bool = False) -> "mj.Scene":
    """The paper's Section 5 scene (``load_scene("section5_damped")``: Mikota's chain n = 300, a
    damper d = 1 at DOF 7, x_3(0) = 1, 2001 outputs on [0, 20], snapshots on [0, 10]); with
    ``quick``, the same scene at n = ``QUICK_N`` (a smoke run's smaller problem, same code)."""
    if not quick:
        return mj.app.load_scene(SECTION5)
    import tomllib
    from importlib import resources

    data = tomllib.loads(resources.files("mikota_jax").joinpath("scenes", f"{SECTION5}.toml")
                         .read_text(encoding="utf-8"))
    data["name"] = f"{SECTION5}_{QUICK_N}"
    data["chain"]["n"] = QUICK_N
    data["output"]["dofs"] = [QUICK_N // 2]
    return mj.app.load_scene(data)


def ode(solver: str, **options) -> "mj.ODE":
    """``mj.ODE`` with the diffrax solver a benchmark names: "dopri8", "tsit5", "dopri5" or
    "kvaerno5" (``mj.StructuredKvaerno5()``); ``options`` as ``mj.ODE``'s (rtol, atol, ...)."""
    import diffrax

    solvers = {"dopri8": diffrax.Dopri8, "tsit5": diffrax.Tsit5, "dopri5": diffrax.Dopri5,
               "kvaerno5": mj.StructuredKvaerno5}
    return mj.ODE(solvers[solver](), **options)
