"""``python -m mikota_jax reproduce``: every number Weber & Zastrau (2018) state, beside ours.

Each row carries the paper's printed value, ours, the reading used, and a status:

* ``reproduced``: ours agrees to the paper's printed precision (or the stated property holds);
* ``MISSED``: a number that a sound reading reproduces misses the printed precision: exit code 1;
* ``not reproduced``: no sound reading of the paper reproduces it; the closest reading is given and
  nothing is tuned to hit the printed value.

All references are exact solutions (``solve`` with ``DenseExponential()``: modal coordinates, a
matrix exponential; ``Spectral()`` for the damped chain: its damped modes), so the numbers carry
no integration error. The paper's own solver (MATLAB) is unknown.
"""

import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from .. import DenseExponential, Spectral, mikota_chain, modal_decomposition, solve
from .._model.reduced import galerkin
from .._rom.pod import pod
from ..analytic import mode_shape, paper_mode_shape
from ..metrics import phase_error
from . import figures
from .results import write_json
from .scene_file import load_scene

REPRODUCED, MISSED, NOT_REPRODUCED = "reproduced", "MISSED", "not reproduced"


@dataclass
class Row:
    section: str
    quantity: str
    paper: str
    ours: str
    status: str
    reading: str = ""
    value: float | None = None


def printed_tolerance(printed: str) -> float:
    """Half a unit in the last printed digit: '0.0184' -> 5e-5, '2.4e-4' -> 5e-6."""
    mantissa, _, exponent = printed.lower().partition("e")
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    return 0.5 * 10.0 ** (-decimals + (int(exponent) if exponent else 0))


def compare(section, quantity, printed: str, ours: float, reading: str, digits: int = 6) -> Row:
    ok = abs(ours - float(printed)) <= printed_tolerance(printed) * (1 + 1e-12)
    return Row(section, quantity, printed, f"{ours:.{digits}g}", REPRODUCED if ok else MISSED,
               reading, float(ours))


def holds(section, quantity, paper: str, ours: float, ok: bool, reading: str) -> Row:
    return Row(section, quantity, paper, f"{ours:.3g}", REPRODUCED if ok else MISSED, reading,
               float(ours))


def _normalised(v):
    v = np.asarray(v, dtype=float)
    v = v / np.linalg.norm(v)
    return v * np.sign(v[np.argmax(np.abs(v))])


def _section2(out: Path | None) -> list[Row]:
    rows = []
    for n in (10, 300):
        # computed here by a plain dense eigh, not by ``modal_decomposition``: for chains of 256
        # DOFs or more the package recognises Mikota's chain and sets l^2 k / m exactly, which
        # would make this check circular
        mass, _, stiffness = (np.asarray(a) for a in mikota_chain(n).dense())
        scale = 1 / np.sqrt(np.diag(mass))
        omega = np.sqrt(np.linalg.eigvalsh(scale[:, None] * stiffness * scale[None, :]))
        worst = float(np.max(np.abs(omega / np.arange(1, n + 1) - 1)))
        rows.append(holds("2", f"Omega_l = l*Omega, l = 1..{n} (max rel. deviation)", "exact",
                          worst, worst < 1e-10, "numpy eigh of M^-1/2 K M^-1/2, float64"))
    n = 10
    omega, modes = modal_decomposition(mikota_chain(n))
    modes = np.asarray(modes)
    for l in (1, 2, 3):
        diff = np.linalg.norm(_normalised(modes[:, l - 1]) - _normalised(paper_mode_shape(n, l)))
        rows.append(holds("2", f"mode shape u_{l} = p_{l}(i) of eq. (2.6), n = 10 (norm of diff.)",
                          "exact", diff, diff < 1e-12, "unit-norm eigenvector vs polynomial"))
    u = np.stack([np.asarray(mode_shape(n, l)) for l in range(1, n + 1)], axis=1)
    utu = u.T @ u
    off = np.abs(np.triu(utu, 2)).max() / np.abs(utu).max()
    rows.append(holds("2", "U^T U tridiagonal, n = 10 (largest entry off the band, rel.)", "0",
                      off, off < 1e-13, "exact polynomial mode shapes"))
    if out is not None:
        shapes = np.stack([np.asarray(mode_shape(n, l)) for l in range(1, 6)])
        figures.eigensolutions(out / "fig2_eigensolutions.png", np.asarray(omega) ** 2, shapes)
    return rows


def _section4_first_mode(out: Path | None) -> list[Row]:
    scene = load_scene("section4_first_mode")
    full = solve(scene.system, scene.ts, scene.x0, method=DenseExponential())
    q = np.asarray(full.displacement).T
    decomposition = pod(q)
    s = np.asarray(decomposition.singular_values)
    ratio = s[1] / s[0]
    level = max(q.shape) * np.finfo(float).eps
    pom = np.asarray(decomposition.modes[:, 0])
    diff = np.linalg.norm(pom - _normalised(paper_mode_shape(scene.size, 1)))
    rows = [
        holds("4", "sigma_k>1 / sigma_1, first-mode excitation", "< 1e-15", ratio, ratio < level,
              f"the paper's bound is rounding level; ours is below max(n, m) eps = {level:.1e}"),
        holds("4", "POM 1 = mode shape 1 (norm of difference)", "equal", diff, diff < 1e-12,
              "unit-norm POM vs p_1(i) = i"),
    ]
    if out is not None:
        figures.singular_values_and_modes(out / "fig3_first_mode_pod.png", s,
                                          np.asarray(decomposition.modes), [1],
                                          "POM 1 (first-mode excitation, n = 10)")
    return rows


def _section4_impulse(out: Path | None) -> list[Row]:
    scene = load_scene("section4_impulse")
    system, load = scene.system, scene.load
    delta = float(load.duration)
    grid = solve(system, scene.ts, load=load, velocity=True, method=DenseExponential())
    x, v = np.asarray(grid.displacement), np.asarray(grid.velocity)
    peak_x, peak_v = np.abs(x).max(), np.abs(v[:, 1:]).max()
    j = np.arange(1, int(float(scene.ts[-1]) // np.pi) + 1)
    rows = []
    for shift, reading in ((0.0, "at t = j*pi, as printed"),
                           (delta / 2, "at t = j*pi + delta_f/2, the pulse centre")):
        ts = jnp.asarray(np.concatenate([[0.0], j * np.pi + shift]))
        at = solve(system, ts, load=load, velocity=True, method=DenseExponential())
        xs = np.abs(np.asarray(at.displacement)[1:]).max() / peak_x
        even = np.asarray(at.velocity)[1:][j % 2 == 0][:, 1:]
        vs = np.abs(even).max() / peak_v
        if shift > 0:
            status = REPRODUCED if xs < 1e-12 else MISSED
            note = "finite pulse, delta_f = 0.05; the paper omits delta_f for clarity"
        else:
            status = NOT_REPRODUCED
            note = "finite pulse: zero only at the pulse centre (row below) or in the Dirac limit"
        rows.append(Row("4", f"x_i = 0 for all i, {reading} (max |x| / peak)", "0", f"{xs:.2g}",
                        status, note, xs))
        rows.append(Row("4", f"v_i = 0 for i > 1, {reading.replace('j*pi', '2j*pi')} "
                        "(max |v| / peak)", "0", f"{vs:.2g}", NOT_REPRODUCED,
                        "finite pulse: small, not zero; zero in the Dirac limit (rows below)", vs))
    # The Dirac limit the paper invokes: an initial velocity impulse/m_1 at DOF 1.
    impulse = float(load.direction[0]) * delta
    v0 = jnp.zeros(scene.size).at[0].set(impulse / float(system.mass.diagonal[0]))
    ts = jnp.asarray(np.concatenate([[0.0], j * np.pi]))
    at = solve(system, ts, v0=v0, velocity=True, method=DenseExponential())
    xs = np.abs(np.asarray(at.displacement)[1:]).max() / impulse
    even = np.asarray(at.velocity)[1:][j % 2 == 0]
    vs = max(np.abs(even[:, 1:]).max(), np.abs(even[:, 0] - float(v0[0])).max()) / float(v0[0])
    rows.append(holds("4", "Dirac limit: x = 0 at j*pi (max |x| / impulse)", "0", xs, xs < 1e-12,
                      "initial velocity impulse/m_1 at DOF 1"))
    rows.append(holds("4", "Dirac limit: v = v(0) at 2j*pi (max rel. deviation)", "0", vs,
                      vs < 1e-12, "initial velocity impulse/m_1 at DOF 1"))
    if out is not None:
        snapshots = pod(x.T)
        figures.histories(out / "fig4_impulse_histories.png", np.asarray(scene.ts), x, v,
                          title="impulse at DOF 1 (n = 10): displacements (a), velocities (b)")
        figures.singular_values_and_modes(out / "fig5_impulse_pod.png",
                                          np.asarray(snapshots.singular_values),
                                          np.asarray(snapshots.modes), [1, 2, 3, 4, 5],
                                          "POMs 1-5 (impulse, n = 10)")
    return rows


def _section5(out: Path | None) -> tuple[list[Row], dict]:
    scene = load_scene("section5_damped")
    window = scene.reduction.window
    ts = scene.ts
    full = solve(scene.system, ts, scene.x0, velocity=True, method=Spectral())
    x, v = np.asarray(full.displacement), np.asarray(full.velocity)
    mask = (np.asarray(ts) >= window[0] - 1e-9) & (np.asarray(ts) <= window[1] + 1e-9)
    decomposition = pod(x[mask].T)
    s = np.asarray(decomposition.singular_values)
    total = float(s.sum())
    rows = [Row("5", "E_pseudo printed as 977.5528^2: sum of sigma_k", "977.5528",
                f"{total:.7f}", NOT_REPRODUCED,
                f"sum_k sigma_k of {mask.sum()} exact snapshots on [{window[0]:g}, "
                f"{window[1]:g}]: agrees to 4 digits ({abs(total / 977.5528 - 1):.1e} rel.). The "
                "last digits depend on the authors' unpublished integrator: an ode45 emulation "
                "gives 977.24 at default tolerances (with n_red = 77 / 120, so not that) and "
                "977.44-977.59 at tighter ones, bracketing 977.5528; picking one would be tuning",
                total),
            Row("5", "sqrt(sum sigma_k^2) (eq. 3.7 read literally)", "977.5528",
                f"{math.sqrt((s**2).sum()):.6g}", NOT_REPRODUCED, "eq. (3.7) as written",
                math.sqrt((s**2).sum()))]
    ranks = {}
    for energy, printed in ((0.99, "76"), (0.9999, "98")):
        r = decomposition.rank_for_energy(energy, "paper")
        ranks[printed] = r
        rows.append(compare("5", f"n_red at {energy:.2%} pseudo-energy", printed, r,
                            "(sum_{k<=r} sigma_k / sum sigma_k)^2 >= e"))
        r2 = decomposition.rank_for_energy(energy, "squared")
        rows.append(Row("5", f"n_red at {energy:.2%}, sum of squares (eq. 3.7 literally)", printed,
                        str(r2), NOT_REPRODUCED if r2 != int(printed) else REPRODUCED,
                        "sum_{k<=r} sigma_k^2 / sum sigma_k^2 >= e", r2))
    rows.append(compare("5", "sigma_77 / sigma_max", "0.0184", s[76] / s[0], "exact snapshots"))
    rows.append(compare("5", "sigma_99 / sigma_max (first POM left out at n_red = 98)", "2.4e-4",
                        s[98] / s[0], "exact snapshots"))
    reduced = {}
    for printed_rank, printed in (("76", "0.5149"), ("98", "0.144")):
        r = ranks[printed_rank]
        model = galerkin(scene.system, decomposition.basis(r))
        red = solve(model, ts, scene.x0, velocity=True, method=DenseExponential())
        reduced[r] = red
        readings = {a: float(phase_error(x, v, red.displacement, red.velocity, a))
                    for a in ("sum", "mean", "max")}
        history = np.asarray(phase_error(x, v, red.displacement, red.velocity, "none"))
        readings["at t = 20"] = float(history[-1])
        closest = min(readings, key=lambda a: abs(readings[a] - float(printed)))
        rows.append(Row("5", f"Delta E_phase, n_red = {r} (eq. 5.4)", printed,
                        ", ".join(f"{k}: {val:.4g}" for k, val in readings.items()),
                        NOT_REPRODUCED,
                        f"closest: {closest} over t in [0, 20] = {readings[closest]:.4g}. No "
                        "aggregation of eq. (5.4) over time, window or DOFs, with exact or "
                        "ode45-like solves, gives both printed values: they differ by 3.6x, ours "
                        "by 40-300x (the nearest ratio, max over t with ode45 defaults, gives "
                        "2.04 / 0.54)",
                        readings["sum"]))
    # Figs. 8-9 agree by eye in the paper: check the DOF-150 curves on 3.25 pi <= t <= 3.75 pi.
    t = np.asarray(ts)
    shown = (t >= 3.25 * np.pi) & (t <= 3.75 * np.pi)
    for r, red in reduced.items():
        xr = np.asarray(red.displacement)
        err = np.linalg.norm(xr[shown, 149] - x[shown, 149]) / np.linalg.norm(x[shown, 149])
        rows.append(Row("5", f"Fig. {8 if r == ranks['76'] else 9}: DOF 150 displacement, full vs "
                        f"n_red = {r} on [3.25pi, 3.75pi] (rel. L2)", "good agreement" if
                        r == ranks["76"] else "no observable difference", f"{err:.2g}",
                        REPRODUCED if err < (0.1 if r == ranks["76"] else 0.005) else MISSED,
                        "exact full and reduced solutions", err))
    if out is not None:
        columns = [0, 2, 6, 99, 249]
        figures.histories(out / "fig6_damped_histories.png", t, x[:, columns],
                          dofs=[c + 1 for c in columns], stacked=True,
                          title="damped chain n = 300, damper d = 1 at DOF 7, x_3(0) = 1")
        figures.singular_values_and_modes(
            out / "fig7_damped_pod.png", s, np.asarray(decomposition.modes), [1, 10, 50, 70, 100],
            "POMs 1, 10, 50, 70, 100 (damped, n = 300)",
            marks=[(ranks["76"], f"n_red = {ranks['76']} (99 %)"),
                   (ranks["98"], f"n_red = {ranks['98']} (99.99 %)")])
        # Figs. 8-9 from the exact solutions on a fine uniform grid (0.0016, ~40 points per
        # oscillation; the 0.01 result grid has ~9 and draws the peaks as corners)
        fine = np.linspace(0.0, 3.75 * np.pi, 7501)
        window = fine >= 3.25 * np.pi
        full_fine = solve(scene.system, jnp.asarray(fine), scene.x0, dofs=[150], velocity=True,
                          method=Spectral())
        for number, r in ((8, ranks["76"]), (9, ranks["98"])):
            red_fine = solve(galerkin(scene.system, decomposition.basis(r)), jnp.asarray(fine),
                             scene.x0, dofs=[150], velocity=True, method=DenseExponential())
            figures.full_versus_reduced(
                out / f"fig{number}_dof150_nred{r}.png", fine[window],
                np.asarray(full_fine.displacement)[window, 0],
                np.asarray(full_fine.velocity)[window, 0],
                np.asarray(red_fine.displacement)[window, 0],
                np.asarray(red_fine.velocity)[window, 0], 150, r)
    return rows, {"singular_values": s.tolist(), "ranks": ranks}


def reproduce(out: str | Path | None = None, verbose: bool = True) -> dict:
    """Reproduce every number of the paper; write figures and ``reproduce.json`` under ``out``.

    Sections 2 (eqs. 2.4, 2.6), 4 and 5 (n_red by eqs. 3.7 and 5.3, eq. 5.2's pseudo-energy,
    eq. 5.4's phase error), all by ``solve``'s exact methods. Returns a dict: ``rows`` (paper's
    value, ours, status), ``section5``, ``missed`` (count of ``MISSED`` rows), ``wall_time_s``;
    ``out=None`` writes nothing. ``verbose`` prints the table.
    """
    start = time.perf_counter()
    folder = None if out is None else Path(out)
    if folder is not None:
        folder.mkdir(parents=True, exist_ok=True)
    stages = [("Section 2: eigensolutions", _section2),
              ("Section 4: first-mode excitation", _section4_first_mode),
              ("Section 4: impulse", _section4_impulse),
              ("Section 5: damped chain, n = 300", _section5)]
    rows, extra = [], {}
    with tqdm(stages, desc="reproduce", unit="section", disable=not verbose,
              file=sys.stderr) as bar:
        for label, stage in bar:
            bar.set_postfix_str(label)
            found = stage(folder)
            if isinstance(found, tuple):
                found, extra = found
            rows += found
    report = {"rows": [asdict(r) for r in rows], "section5": extra,
              "missed": sum(r.status == MISSED for r in rows),
              "wall_time_s": time.perf_counter() - start}
    if folder is not None:
        write_json(report, folder / "reproduce.json")
    if verbose:
        print(format_table(rows))
        reproduced = sum(r.status == REPRODUCED for r in rows)
        unprintable = sum(r.status == NOT_REPRODUCED for r in rows)
        print(f"\n{reproduced} reproduced, {unprintable} not reproducible as printed (the "
              f"closest reading is shown; see the guide's page on the paper), "
              f"{report['missed']} missed; {report['wall_time_s']:.1f} s"
              + (f"; written to {folder}" if folder else ""))
    return report


def format_table(rows: list[Row]) -> str:
    widths = (3, 62, 14, 22, 15)
    head = ("sec", "quantity", "paper", "ours", "status")
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths)), "-" * (sum(widths) + 8)]
    for r in rows:
        cells = (r.section, r.quantity, r.paper, r.ours, r.status)
        lines.append("  ".join(str(c).ljust(w) for c, w in zip(cells, widths)))
        if r.reading:
            lines.append(" " * (widths[0] + 2) + "  reading: " + r.reading)
    return "\n".join(lines)
