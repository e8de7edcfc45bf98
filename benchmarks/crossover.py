"""Error against cost for every reduction, and the chain size n from which each one pays off for
one query and a 1000-design sweep of J and dJ/d(p, c), ROM against the best
full-order path at equal accuracy.

Problem at every n: Mikota's chain (m = k = 1), a grounded damper at p = 7 with c = 1 (the nominal
design), x_3(0) = 1, v(0) = 0, J = the energy integrated over [0, T = 20] (``"energy"``), outputs
every 0.01 (2001 times), POD snapshots on [0, 10] (1001 times): the paper's Section 5 scene at
n = 300. n in {300, 1000, 3000}; ``--quick``: {300, 1000}.

**n = 30000** is not in the default run; it is measured apart (``--sizes 30000 --rank-hint
crossover_30000 --name crossover_30000``, ~80 min) and merged into ``results/crossover`` with
``--merge crossover_30000``. From ``LARGE`` = 10^4 on (``--large-from N`` moves that threshold,
a check of the path at small n) the same spectral paths run in O(n) memory
(the roots a block at a time and, above n = 4096, no U: ``spectral_energy_large.py``): the
reference J + gradient timed once, the histories and the POD snapshots by the spectral
``exact_solve``. Dopri8 there is its J alone at rtol 1e-6 (a lower bound on its J + gradient,
which took > 25 min on 2 cores); the spectral reference is checked against Dopri8 J + gradient
at rtol 1e-10 from ``results/crossover_reference_gpu.json`` (``--reference-out FILE`` computes
it, on a GPU machine: 192 s on one H100). Bases there: POD and the snapshot-free ones (modal,
modal + static, modal + 2 moments, Craig-Bampton: O(n r) builds for a chain), ranks up to
``RANK_CAP_LARGE`` = 1200; 2 random designs. Left out there: Krylov (no r <= 400 met TOL at
n = 3000) and the enriched POD (0.2x at n = 3000, its offline cost 5x POD's).
``--rank-hint NAME`` starts each rank search at the r of an earlier run's results (within 1 %;
the numpy J costs ~30 s a rank there; POD starts at the modal basis' r).

Per n, one process, compile time apart from run time (``Compiled``), run time = median of repeats
(3 at n <= 1000, 2 beyond and in ``--quick``):

* **Full model, spectral** (the reference and the first baseline): J + dJ/dp + dJ/dc as
  ``Energy(method=Spectral())`` under ``jax.jacfwd``, compiled ahead of time. This is
  what ``sensitivities(scene, "energy", model="full")`` computes (checked equal at the smallest
  n), without its dense fallback (compiled into ``sensitivities`` as a ``lax.cond`` branch): a
  spectral failure at a random design raises here (the design is skipped and recorded) instead
  of running a 4n x 4n matrix exponential for hours at n = 3000.
* **Full model, Dopri8**: J alone (``Energy(method=ODE(...))``, tolerances traced) at
  rtol in {1e-5, 1e-6, 1e-8} (atol = 1e-2 rtol; 1e-4 is 1e-3 off in J); "equal accuracy" is the
  loosest rtol whose J is within TOL of the spectral J. Then J + gradient from that rtol down until
  J and gradient both meet TOL, in forward mode (``diffrax.ForwardMode()``) as two ``jax.jvp``
  calls, one per parameter. ``sensitivities`` on a Dopri8 scene uses ``jax.jacfwd`` (a vmapped
  jvp), which costs ~13 x one jvp here (2.9 s against 0.22 s at n = 300, rtol 1e-6; 29 s at
  n = 1000): it is timed once at the smallest n (``dopri8.jacfwd``), and the faster two-jvp path is
  the baseline. Dopri8 is not run at the random designs (a strong damper near the free end makes
  it stiff); its sweep is 1000 x its nominal time, a lower bound. The J alone is reported beside,
  a lower bound on any Dopri8 gradient (which needs at least one more solve).
* **Reductions**: POD (the paper's), sensitivity-enriched POD (``EnrichedPOD``), modal
  truncation, modal + static correction (modes + the split damper's two static directions, r in
  all: ``ModalStatic(r)``), modal + 2 moments (modes + K^-1 b and K^-1 M K^-1 b of both:
  ``ModalStatic(r, moments=2)``), second-order Krylov (SOAR; inputs M x0 and the damper
  directions), built as ``reductions.py`` builds them, and Craig-Bampton with the start kept (modes
  held at the damper + 3 moments of its two DOFs + x0: ``CraigBampton(r, states=x0)``, the
  basis that holds the Section 5 gradients, ``rom_gradients.py``), at the nominal design. Rank: the
  smallest r whose ROM J is within TOL = 1e-4 (relative) of the full J at the nominal design, found
  by a ladder r = 16, 16 * 1.4, ... (up to min(n, 400, the POD's numerical rank): a ROM query at r =
  400 costs ~20 s, and the cap keeps the full run near 25 min) then bisection between the last rung
  that misses and the first that meets TOL (the error is assumed to fall with r), with a numpy
  evaluation of the ROM's J (modes of the Galerkin matrices, expm, a Lyapunov solve: the same
  integral as ``integrated_energy``). The library's J at that r is then checked (r is raised by 5 %
  until it meets TOL). The search is not counted in the offline cost (a user would pick r by an
  energy rule). The rule is on J only, as asked: the gradient and history errors at that r are
  reported beside it, not matched.
* **Errors** at that r, against the full model: relative J, max over (p, c) of the relative
  gradient error (right-sided derivative in p at the integer position, as the library defines
  it, for the full model and the ROM alike), and the displacement history: relative L2 over all
  DOFs at t = 0, 0.05, ..., 20 (401 of the 2001 outputs, to keep the n = 3000 reference solve
  short), the ROM solved by a numpy modal propagator (exact_solve's algorithm), the full model by
  ``exact_solve``'s spectral path.
* **Offline cost**: the basis build at that r, warm (compile apart), including the full solve it
  needs: the spectral ``exact_solve`` on the snapshot window (1001 times) + ``reduce`` for POD,
  ``enriched_reduce`` on a scene that ends at t = 10 (the snapshot window: it solves the whole
  grid of the scene it is given) for the enriched POD, ``modal_basis``, ``modal_static_basis``
  (each with the chain's O(n^2) modes), ``krylov_basis``. One call for the two POD builds (the
  rank search's call warmed them up), the median of repeats for the others.
* **Online cost**: one ROM query, J + gradient on the fixed basis: ``SceneFunction(scene,
  "energy", model="reduced", basis=..., forward=True)`` and ``jax.jacfwd`` of it, compiled ahead
  of time: the computation ``sensitivities(..., model="reduced", basis=...)`` runs (checked equal
  for POD at the smallest n), without that function's per-call eager checks (~0.1 s). A compile
  time of ~0 is a jit cache hit (an earlier method had the same r).
* **One query** = offline + online; full = the cheaper of spectral and Dopri8 J + gradient.
  **Sweep of 1000 designs** = offline + 1000 x (the median per-design time over the random designs
  below): a per-design median times 1000, NOT a measured 1000-run; the basis is built once, at the
  nominal design. Full: 1000 x the spectral median over the same designs, or 1000 x Dopri8's
  nominal time (a lower bound), whichever is cheaper.
* **Sweep accuracy**: random designs (p uniform in [1, n], c log-uniform in [0.1, 1000]; 10 at n =
  300, 4 at n = 1000, 2 at n = 3000, ``--quick``: 2 per n, fewer than the 10-20 hoped for, to fit
  the time: each costs one full query, itself ~1.5-2 x the nominal one since a damper between two
  DOFs has two columns, plus one query per ROM). Each ROM's J and gradient on its nominal basis
  against the full model; the worst error is reported, however large (a basis built at one design
  need not hold at another). Histories are not compared there (a full history per design costs more
  than the query). **Rebuild variant** for the bases that need no full solve (modal + static, modal
  + 2 moments, Krylov, Craig-Bampton): the basis rebuilt at each design (same r), its build time
  added to every query of the sweep; the modal basis does not depend on the damper, so its
  rebuild is its fixed basis.
* **Crossover** per method: the smallest measured n from which (that n and every larger measured
  one) the ROM is cheaper than the best full path, for one query and for the sweep, with the ROM
  at TOL in J at the nominal design (gradient, history and random-design errors reported beside;
  the sweep's statement quotes its worst random-design J error). If none up to the largest n: a
  power-law fit of both costs over the measured n and the n where the fits cross, flagged as an
  EXTRAPOLATION (None where they do not cross).

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/crossover.py [--quick] [--replot] [--sizes N ...]
[--large-from N] [--name NAME]`` (~22 min on 2 cores; ``--quick`` ~8 min; ``--sizes``/
``--large-from`` write ``crossover_sizes`` unless ``--name``). Writes
``results/crossover[_quick].json`` and ``.png``. n = 30000: ``--sizes 30000 --reference-out
FILE`` on a GPU machine (~200 s), then ``--sizes 30000 --reference FILE --name crossover_30000``
here, then ``--merge crossover_30000`` (rewrites ``crossover.json`` and its figure).
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import (Compiled, elapsed, figure, fit_exponent, legend,  # noqa: I001
                     metadata, parse_args, print_table, read_json, save_figure, subtitle, timed,
                     write_json)

import json
import math
import statistics
import time
import warnings
from pathlib import Path

import diffrax
import jax
import matplotlib.ticker
import jax.numpy as jnp
import numpy as np
import scipy.linalg
import scipy.sparse

import mikota_jax as mj

NAME = "crossover"
SIZES = (300, 1000, 3000)  # 30000: apart, see the module docstring
QUICK_SIZES = (300, 1000)
LARGE = 10_000  # from here: the spectral reference timed once, Dopri8's J alone, 2 designs
LARGE_RTOL = 1e-10  # the GPU's Dopri8 reference (--reference-out): an independent check
REFERENCE_FILE = Path(__file__).parent / "results" / "crossover_reference_gpu.json"
NOT_RUN = {30000: "not in the default run: measured apart (--sizes 30000 --rank-hint "
                  "crossover_30000 --name crossover_30000) and merged (--merge crossover_30000)"}
HORIZON, STEP, WINDOW = 20.0, 0.01, (0.0, 10.0)
HISTORY_EVERY = 5  # history errors at t = 0, 0.05, ..., 20 (401 times, all DOFs)
POSITION, COEFFICIENT, INITIAL_DOF = 7.0, 1.0, 3
WRT = ("positions", "coefficients")
TOL = 1e-4  # relative J error of the ROM at the nominal design: "equal accuracy"
METHODS = ("POD", "enriched POD", "modal", "modal + static", "modal + 2 moments", "Krylov",
           "Craig-Bampton")
LARGE_METHODS = ("POD", "modal", "modal + static", "modal + 2 moments", "Craig-Bampton")
# bases that need no full solve: rebuilt per design
REBUILD = ("modal + static", "modal + 2 moments", "Krylov", "Craig-Bampton")
# columns besides the modes: the split damper's 2 DOFs x moments (+ x0 for Craig-Bampton)
SWEEP = 1000
RANK_START, RANK_FACTOR, RANK_CAP = 16, 1.4, 400
HINT_FACTOR = 1.04  # the ladder's step from a --rank-hint
RANK_CAP_LARGE = 1200  # r ~ n^0.5 from n = 300-3000 puts TOL at r ~ 850 for n = 30000
RANK_BUMPS = 4  # tries at r * 1.05 when the library's J misses TOL at the searched r
DOPRI_RTOLS = (1e-5, 1e-6, 1e-8)  # 1e-4: J 1e-3 off at n = 300, 1000
DOPRI_ATOL = 1e-2  # atol = DOPRI_ATOL * rtol (displacements ~1)
DOPRI_MAX_STEPS = 1_000_000
SEED = 20


def repeats_for(n: int, quick: bool) -> int:
    return 2 if quick or n > 1000 else 3


def designs_for(n: int, quick: bool, large: bool) -> int:
    """Random designs per n: each costs one full query (2 x the nominal one: a damper between
    two DOFs has two columns) and one query per ROM, so fewer at larger n."""
    return 2 if quick or large else 10 if n <= 300 else 4 if n <= 1000 else 2


def scene_for(n: int, end: float = HORIZON):
    return mj.app.load_scene({
        "name": f"crossover_{n}", "chain": {"type": "mikota", "n": n, "m": 1.0, "k": 1.0},
        "damper": [{"type": "grounded", "position": POSITION, "coefficient": COEFFICIENT}],
        "initial": {"displacement": {str(INITIAL_DOF): 1.0}},
        "time": {"end": end, "step": STEP},
        "reduction": {"snapshots": list(WINDOW), "energy": 0.9999, "criterion": "paper"},
        "output": {"dofs": [n // 2], "quantities": ["displacement"]}})


def design(position: float, coefficient: float) -> dict:
    return {"positions": jnp.array([position]), "coefficients": jnp.array([coefficient])}


def random_designs(n: int, count: int) -> list[tuple[float, float]]:
    rng = np.random.default_rng(SEED + n)
    return [(float(rng.uniform(1.0, n)), float(10 ** rng.uniform(-1.0, 3.0)))
            for _ in range(count)]


# --------------------------------------------------------------------------- compiled queries


def full_query(function, parameters):
    """(J, dJ/d parameters) of the full model by the spectral path (``sensitivities``' "full"
    computation without its dense fallback)."""
    # J rides along as jacfwd's aux: one forward pass (J computed beside jacfwd found the roots
    # twice, 1.7x the time at n = 5000; the committed results before 2026-11-27 did that)
    def energy(p):
        value = mj.Energy(HORIZON, function.scene.x0, method=mj.Spectral())(function.system(p))
        return value, value
    jacobian, value = jax.jacfwd(energy, has_aux=True)(parameters)
    return value, jacobian


def rom_query(function, parameters):
    """(J, dJ/d parameters) of a ``SceneFunction(model="reduced", forward=True)``: what
    ``sensitivities(model="reduced")`` computes."""
    return function(parameters), jax.jacfwd(function)(parameters)


def dopri_energy(function, parameters, rtol):
    method = mj.ODE(rtol=rtol, atol=DOPRI_ATOL * rtol, max_steps=DOPRI_MAX_STEPS)
    return mj.Energy(HORIZON, function.scene.x0, method=method)(function.system(parameters))


def dopri_query(function, parameters, rtol, batched: bool = False):
    """(J, dJ/d parameters) by Dopri8 in forward mode (``diffrax.ForwardMode``): one ``jax.jvp``
    per parameter (J comes with the first), or ``batched``: ``jax.jacfwd`` (a vmapped jvp, which
    ``sensitivities`` uses: ~13 x the cost of one jvp here, see the module docstring)."""
    def energy(p):
        method = mj.ODE(rtol=rtol, atol=DOPRI_ATOL * rtol, max_steps=DOPRI_MAX_STEPS,
                        adjoint=diffrax.ForwardMode())
        return mj.Energy(HORIZON, function.scene.x0, method=method)(function.system(p))
    if batched:
        return energy(parameters), jax.jacfwd(energy)(parameters)
    value, jacobian = None, {}
    for name in parameters:
        tangent = {k: jnp.zeros_like(v) if k != name else jnp.ones_like(v)
                   for k, v in parameters.items()}
        value, derivative = jax.jvp(energy, (parameters,), (tangent,))
        jacobian[name] = jnp.reshape(derivative, parameters[name].shape)
    return value, jacobian


def errors_of(value, jacobian, reference) -> dict:
    """Relative J error and the max over (p, c) of the relative gradient errors."""
    j_ref, g_ref = reference
    return {"J": abs(float(value) / float(j_ref) - 1),
            "gradient": max(abs(float(jacobian[k][0]) / float(g_ref[k][0]) - 1) for k in WRT)}


# --------------------------------------------------------------------------- numpy ROM tools


class Projection:
    """Galerkin matrices (Phi^T M Phi, Phi^T D Phi, Phi^T K Phi, Phi^T x0) of a basis, in numpy
    (sparse M, D, K): the rank search and the ROM histories without a compile per rank."""

    def __init__(self, system, x0):
        damping = system.damping_operator()
        self.operators = [jax.jit(jax.vmap(op.mv, in_axes=1, out_axes=1)) if op is not None
                          else None for op in (system.mass, damping, system.stiffness)]
        self.x0 = np.asarray(x0)

    def __call__(self, basis):
        b = np.asarray(basis)
        return tuple(b.T @ np.asarray(op(jnp.asarray(b))) if op is not None
                     else np.zeros((b.shape[1], b.shape[1])) for op in self.operators) + (
            b.T @ self.x0,)


def leading(matrices, r: int):
    m, d, k, q0 = matrices
    return m[:r, :r], d[:r, :r], k[:r, :r], q0[:r]


def modal_form(m, d, k):
    """(omega, U, A) of a reduced model in scaled modal coordinates (``exact_solve``'s)."""
    omega2, u = scipy.linalg.eigh(k, m)
    omega = np.sqrt(omega2)
    r = omega.size
    a = np.block([[np.zeros((r, r)), np.diag(omega)], [-np.diag(omega), -u.T @ d @ u]])
    return omega, u, a


def rom_energy(matrices) -> float:
    """J = z0^T W z0 / 2, A^T W + W A = P^T P - I, P = exp(A T): the ROM's integrated energy."""
    m, d, k, q0 = matrices
    omega, u, a = modal_form(m, d, k)
    z0 = np.concatenate([omega * (u.T @ (m @ q0)), np.zeros(omega.size)])
    p = scipy.linalg.expm(a * HORIZON)
    with warnings.catch_warnings():  # a nearly undamped ROM mode (Krylov): scipy perturbs the
        warnings.simplefilter("ignore", RuntimeWarning)  # Lyapunov; the library J is checked
        w = scipy.linalg.solve_continuous_lyapunov(a.T, p.T @ p - np.eye(a.shape[0]))
    return float(z0 @ w @ z0) / 2


def rom_history(matrices, basis, count: int) -> np.ndarray:
    """(count, n) displacements of the ROM at t = 0, h, 2 h, ... (h = HISTORY_EVERY STEP):
    z_{k+1} = exp(A STEP)^HISTORY_EVERY z_k."""
    m, d, k, q0 = matrices
    omega, u, a = modal_form(m, d, k)
    r = omega.size
    propagator = scipy.linalg.expm(a * STEP)
    propagator = np.linalg.matrix_power(propagator, HISTORY_EVERY)
    z = np.concatenate([omega * (u.T @ (m @ q0)), np.zeros(r)])
    states = np.empty((count, r))
    for i in range(count):
        states[i] = z[:r]
        z = propagator @ z
    return (states / omega) @ (np.asarray(basis) @ u).T


def rank_search(energy_at, cap: int, j_full: float, hint: int | None = None):
    """(smallest r with |J_r / J - 1| <= TOL or None, {r: error}): a ladder, then bisection.
    ``hint`` (an earlier run's r): the ladder starts there and steps by HINT_FACTOR down or up,
    and the bisection stops within 1 % (each numpy J at r ~ 850 costs ~30 s)."""
    errors = {}

    def error(r):
        if r not in errors:
            errors[r] = abs(energy_at(r) / j_full - 1)
        return errors[r]

    if hint is not None:
        high = min(cap, hint)
        while error(high) > TOL:
            if high == cap:
                return None, errors
            high = min(cap, math.ceil(high * HINT_FACTOR))
        low = high
        while low > 1 and error(low) <= TOL:
            high, low = low, max(1, math.floor(low / HINT_FACTOR))
        if error(low) <= TOL:
            return low, errors
    else:
        low, r = 0, min(RANK_START, cap)
        while error(r) > TOL:
            if r == cap:
                return None, errors
            low, r = r, min(cap, math.ceil(r * RANK_FACTOR))
        high = r
    while high - low > (1 if hint is None else max(1, high // 100)):
        middle = (low + high) // 2
        if error(middle) <= TOL:
            high = middle
        else:
            low = middle
    return high, errors


def damper_columns(n: int, position: float = POSITION) -> np.ndarray:
    """(n, 2) the directions B of one grounded damper at ``position`` (D = B diag(w) B^T): the
    unit vectors of the two DOFs its coefficient is split over (1-based floor(p) and the next)."""
    left = int(np.floor(position)) - 1
    b = np.zeros((n, 2))
    b[left, 0], b[min(left + 1, n - 1), 1] = 1.0, 1.0
    return b


def _stiffness_solve(system, y: np.ndarray) -> np.ndarray:
    stiffness = system.stiffness
    diagonal, off = np.asarray(stiffness.diagonal), np.asarray(stiffness.off_diagonal)
    bands = np.zeros((2, diagonal.size))
    bands[0, 1:], bands[1] = off, diagonal
    return scipy.linalg.solveh_banded(bands, y)


def static_directions(system) -> np.ndarray:
    """K^-1 B for the damper directions B (tridiagonal K, banded solve)."""
    return _stiffness_solve(system, damper_columns(system.size))


def static_moments(system) -> np.ndarray:
    """K^-1 B and K^-1 M K^-1 B, each column of unit length (``ModalStatic(moments=2)``'s)."""
    first = static_directions(system)
    second = _stiffness_solve(system, np.asarray(system.mass.diagonal)[:, None] * first)
    moments = np.concatenate([first, second], axis=1)
    return moments / np.linalg.norm(moments, axis=0)[None, :]


def modal_static_columns(modes: np.ndarray, static: np.ndarray, r: int) -> np.ndarray:
    """``ModalStatic(r)`` in numpy, from precomputed modes and the s static columns (K^-1 B, or
    ``static_moments``: K^-1 B and K^-1 M K^-1 B, each of unit length)."""
    kept = modes[:, : r - static.shape[1]]
    scale = float(np.max(np.linalg.norm(static, axis=0)))
    rest = static.copy()
    for _ in range(2):
        rest = rest - kept @ (kept.T @ rest)
    q, triangle = np.linalg.qr(rest)
    keep = np.flatnonzero(np.abs(np.diag(triangle)) > 1e-10 * scale)
    return np.concatenate([kept, q[:, keep]], axis=1)


def craig_bampton(system, x0, r: int):
    """Craig-Bampton with the start kept, r columns: modes held at the damper, 3 moments of
    its two DOFs and x0 (``CraigBampton(r, states=x0)``)."""
    return mj.reduce(system, mj.CraigBampton(r, states=x0)).basis


def krylov_inputs(system, x0) -> np.ndarray:
    """The Krylov inputs of free vibration from x0: M x0 and the damper directions."""
    return np.column_stack([np.asarray(system.mass.mv(x0)), damper_columns(system.size)])


# --------------------------------------------------------------------------- one n


def measure(n: int, quick: bool, check_public: bool, large_from: int = LARGE,
            hints: dict | None = None) -> dict:
    start = time.perf_counter()
    repeats = repeats_for(n, quick)
    say = lambda text: print(f"  n={n}: {text} ({elapsed(start):.0f} s)", flush=True)  # noqa: E731
    scene, window_scene = scene_for(n), scene_for(n, WINDOW[1])
    system, x0 = scene.system, scene.x0
    nominal = design(POSITION, COEFFICIENT)
    function = mj.SceneFunction(scene, "energy")
    large = n >= large_from
    out = {"n": n, "repeats": repeats, "large": large}
    reference, full, history, (snapshot_exe, ts_window, snapshots) = measure_full(
        n, scene, window_scene, function, nominal, out, 1 if large else repeats,
        check_public and not large, large, say)  # sensitivities' check: ~7 min at n = 30000
    j_full = reference[0]

    # ---- reductions: rank search, offline, online, errors at the nominal design
    projection = Projection(system, x0)
    forcing = krylov_inputs(system, x0)
    cap = min(n, RANK_CAP_LARGE if large else RANK_CAP)
    modes = np.asarray(mj.reduce(system, mj.Modal(cap)).basis)
    static = static_directions(system)
    moments = static_moments(system)
    nested = {"modal": modes}
    pod = mj.reduce(window_scene, scene.reduction).stats.decomposition  # warm-up
    nested["POD"] = np.asarray(pod.basis(min(cap, pod.numerical_rank())))
    if not large:
        enriched = mj.reduce(window_scene, mj.EnrichedPOD(WRT)).stats.decomposition  # warm-up
        nested.update({
            "enriched POD": np.asarray(enriched.basis(min(cap, enriched.numerical_rank()))),
            "Krylov": np.asarray(mj.reduce(system, mj.Krylov(cap, forcing)).basis)})
    say("bases for the rank search")

    def pod_build(r):
        return mj.reduce(window_scene, mj.POD(scene.reduction.window, rank=r)).basis

    builds = {
        "POD": pod_build,
        "enriched POD": lambda r: mj.reduce(window_scene, mj.EnrichedPOD(WRT, rank=r)).basis,
        "modal": lambda r: mj.reduce(system, mj.Modal(r)).basis,
        "modal + static": lambda r: mj.reduce(system, mj.ModalStatic(r)).basis,
        "modal + 2 moments": lambda r: mj.reduce(system, mj.ModalStatic(r, moments=2)).basis,
        "Krylov": lambda r: mj.reduce(system, mj.Krylov(r, forcing)).basis,
        "Craig-Bampton": lambda r: craig_bampton(system, x0, r),
    }
    methods, queries = {}, {}
    for method in LARGE_METHODS if large else METHODS:
        row = {"method": method}
        if method in nested:
            big = nested[method]
            matrices = projection(big)
            search_cap = big.shape[1]
            energy_at = lambda r, matrices=matrices: rom_energy(leading(matrices, r))  # noqa: E731
        elif method == "Craig-Bampton":
            search_cap = cap
            energy_at = lambda r: rom_energy(projection(craig_bampton(system, x0, r)))  # noqa: E731
        else:
            search_cap = cap
            extra = moments if method == "modal + 2 moments" else static
            energy_at = lambda r, extra=extra: rom_energy(projection(  # noqa: E731
                modal_static_columns(modes, extra, r)))
        t0 = time.perf_counter()
        hint = (hints or {}).get(method, (hints or {}).get("modal"))  # POD: modal's r
        r, searched = rank_search(energy_at, search_cap, float(j_full), hint)
        row.update(search_cap=search_cap, search_s=elapsed(t0),
                   search={str(k): v for k, v in sorted(searched.items())})
        if r is None:
            row.update(r=None, reached=False, error_at_cap=searched[search_cap])
            methods[method] = row
            say(f"{method}: TOL not reached up to r = {search_cap} (J error "
                f"{searched[search_cap]:.1e})")
            continue
        solves = method in ("POD", "enriched POD")  # a full solve inside: warmed by the search
        for bump in range(RANK_BUMPS + 1):
            if not solves:
                jax.block_until_ready(builds[method](r))  # warm-up (compiles the shapes of r)
            basis, offline_s, offline_times = timed(builds[method], r,
                                                    repeats=1 if solves else repeats)
            rom = mj.SceneFunction(scene, "energy", model="reduced", basis=basis, forward=True)
            query = Compiled(rom_query, rom, nominal)
            (value, jacobian), online_s, online_times = timed(query, rom, nominal,
                                                              repeats=repeats)
            errors = errors_of(value, jacobian, reference)
            if errors["J"] <= TOL or bump == RANK_BUMPS or r >= search_cap:
                break
            r = min(search_cap, math.ceil(1.05 * r))
        matrices = projection(basis)
        history_error = float(np.linalg.norm(rom_history(matrices, basis, history.shape[0])
                                             - history) / np.linalg.norm(history))
        row.update(r=int(basis.shape[1]), reached=errors["J"] <= TOL, bumps=bump,
                   numpy_J=abs(rom_energy(matrices) / float(j_full) - 1),
                   J=errors["J"], gradient=errors["gradient"], history=history_error,
                   offline_s=offline_s, offline_times_s=offline_times,
                   online_s=online_s, online_times_s=online_times, compile_s=query.compile_s)
        if query.compile_s < 0.5:
            row["compile_note"] = "jit cache hit: an earlier method had the same r"
        if check_public and method == "POD":
            public = mj.sensitivities(scene, "energy", wrt=WRT, model="reduced", basis=basis)
            row["vs_sensitivities"] = errors_of(public.value, public.jacobian,
                                                (value, jacobian))
        methods[method] = row
        queries[method] = (query, basis)
        say(f"{method}: r = {row['r']}, J {errors['J']:.1e}, gradient {errors['gradient']:.1e}, "
            f"history {history_error:.1e}, offline {offline_s:.2f} s, online {online_s:.3f} s "
            f"(compile {query.compile_s:.1f} s)")
    out["methods"] = methods

    # ---- random designs: sweep accuracy and per-design cost
    out["designs"] = measure_designs(n, quick, large, scene, function, full, queries, forcing,
                                     say)
    return out


def measure_full(n, scene, window_scene, function, nominal, out, repeats, check_public, large,
                 say):
    """The spectral reference (J, gradient; timed), the full histories, the snapshot solve, and
    Dopri8 (``large``: its J alone at rtol 1e-6, and the spectral reference checked against the
    GPU's Dopri8 one where ``REFERENCE_FILE`` has this n). (reference, the compiled spectral
    query, the history, (the compiled snapshot solve, its times, the snapshots))."""
    system, x0 = scene.system, scene.x0
    # ---- full model, spectral: the reference J and gradient, timed
    full = Compiled(full_query, function, nominal)
    (j_full, g_full), run_s, times = timed(full, function, nominal, repeats=repeats)
    reference = (j_full, g_full)
    out["full_spectral"] = {"compile_s": full.compile_s, "run_s": run_s, "run_times_s": times,
                            "J": float(j_full),
                            "gradient": {k: float(g_full[k][0]) for k in WRT}}
    if check_public:  # the compiled query is what sensitivities() computes
        public = mj.sensitivities(scene, "energy", wrt=WRT)
        out["full_spectral"]["vs_sensitivities"] = errors_of(public.value, public.jacobian,
                                                             reference)
    say(f"full spectral J + gradient {run_s:.3f} s (compile {full.compile_s:.1f} s)")

    # ---- full histories: the reference (401 times) and the POD snapshots (window, 1001 times)
    ts_history = scene.ts[::HISTORY_EVERY]
    history_exe = Compiled(lambda s, x: mj.solve(s, ts_history, x, method=mj.Spectral()),
                           system, x0)
    history = np.asarray(history_exe(system, x0).displacement)
    ts_window = window_scene.ts
    snapshot_exe = Compiled(lambda s, x: mj.solve(s, ts_window, x, method=mj.Spectral()),
                            system, x0)
    snapshots = snapshot_exe(system, x0).displacement
    common = (ts_window.shape[0] - 1) // HISTORY_EVERY + 1  # history times inside the window
    gap = float(np.max(np.abs(np.asarray(snapshots)[::HISTORY_EVERY] - history[:common])))
    if gap > 1e-9:
        raise SystemExit(f"n={n}: the window solve differs from the history by {gap:.2e}.")
    out["history"] = {"compile_s": history_exe.compile_s, "max_abs_x": float(np.max(np.abs(
        history))), "window_vs_history": gap, "snapshot_compile_s": snapshot_exe.compile_s}
    say("full histories")

    # ---- full model, Dopri8
    if large:
        out["dopri8"] = dopri_alone(function, nominal, reference, say)
        gpu = load_references(REFERENCE_FILE).get(n) if REFERENCE_FILE.exists() else None
        if gpu is not None:
            out["full_spectral"]["vs_gpu_dopri8"] = dict(
                errors_of(*gpu[0], reference), file=REFERENCE_FILE.name,
                method=gpu[1]["method"], device=gpu[1]["device"])
            say(f"spectral vs the GPU's Dopri8 reference: {out['full_spectral']['vs_gpu_dopri8']}")
    else:
        out["dopri8"] = measure_dopri(n, function, nominal, reference, repeats, check_public, say)
    return reference, full, history, (snapshot_exe, ts_window, snapshots)


def dopri_reference(function, nominal, say):
    """J + gradient by Dopri8 at rtol LARGE_RTOL (two jvps), timed once (``--reference-out``,
    run on a GPU machine: > 25 min on 2 CPU cores at n = 30000): an independent check of the
    spectral reference at large n. (reference, its record)."""
    query = Compiled(dopri_query, function, nominal, LARGE_RTOL)
    reference, run_s, times = timed(query, function, nominal, LARGE_RTOL, repeats=1)
    record = {"method": f"Dopri8, rtol {LARGE_RTOL:g}, atol {DOPRI_ATOL:g} rtol, two jax.jvp",
              "compile_s": query.compile_s, "run_s": run_s, "run_times_s": times,
              "J": float(reference[0]),
              "gradient": {k: float(reference[1][k][0]) for k in WRT},
              "device": str(jax.devices()[0])}
    say(f"Dopri8 reference J + gradient at rtol {LARGE_RTOL:g}: {run_s:.1f} s (compile "
        f"{query.compile_s:.1f} s)")
    return reference, record


def dopri_alone(function, nominal, reference, say) -> dict:
    """n >= LARGE: Dopri8's J alone at rtol 1e-6, timed once: a lower bound on any Dopri8
    gradient (which needs at least one more solve)."""
    energy = Compiled(dopri_energy, function, nominal, 1e-6)
    value, alone_s, alone_times = timed(energy, function, nominal, 1e-6, repeats=1)
    alone = {"rtol": 1e-6, "J": abs(float(value) / float(reference[0]) - 1), "run_s": alone_s,
             "run_times_s": alone_times}
    say(f"Dopri8 J alone at rtol 1e-6: {alone_s:.1f} s (J {alone['J']:.1e})")
    gradient = {"run": False, "reason": "n >= LARGE: Dopri8 J + gradient (two jvps) took > 25 "
                "min on 2 CPU cores at n = 30000 (stopped); J alone is its lower bound"}
    return {"compile_s": energy.compile_s, "J_only": [alone],
            "equal_accuracy": alone if alone["J"] <= TOL else None,
            "atol": f"{DOPRI_ATOL:g} rtol", "gradient": gradient}


def load_references(path) -> dict:
    """{n: (reference, record)} from a ``--reference-out`` file."""
    data = json.loads(Path(path).read_text())
    out = {}
    for key, record in data["references"].items():
        record = dict(record, file=Path(path).name)
        out[int(key)] = ((record["J"], {k: np.array([v]) for k, v in
                                        record["gradient"].items()}), record)
    return out


def measure_dopri(n, function, nominal, reference, repeats, batched: bool, say) -> dict:
    """Dopri8: J alone at the rtol ladder (each once; the loosest meeting TOL repeated), then J +
    gradient (two jvps) from that rtol down until J and gradient meet TOL; ``batched``: also
    ``jax.jacfwd`` once at that rtol (what ``sensitivities`` runs for a Dopri8 scene)."""
    energy = Compiled(dopri_energy, function, nominal, DOPRI_RTOLS[0])
    rows, chosen = [], None
    for rtol in DOPRI_RTOLS:
        value, run_s, times = timed(energy, function, nominal, rtol, repeats=1)
        rel = abs(float(value) / float(reference[0]) - 1)
        rows.append({"rtol": rtol, "J": rel, "run_s": run_s, "run_times_s": times})
        if rel <= TOL:
            chosen = rows[-1]
            chosen["run_times_s"] += timed(energy, function, nominal, rtol,
                                           repeats=repeats - 1)[2] if repeats > 1 else []
            chosen["run_s"] = statistics.median(chosen["run_times_s"])
            break
    out = {"compile_s": energy.compile_s, "J_only": rows, "equal_accuracy": chosen,
           "atol": f"{DOPRI_ATOL:g} rtol"}
    if chosen is None:
        say("Dopri8 J alone: no rtol meets TOL")
        out["gradient"] = {"run": False, "reason": "no rtol met TOL in J"}
        return out
    say(f"Dopri8 J alone at rtol {chosen['rtol']:g}: {chosen['run_s']:.3f} s")
    query = Compiled(dopri_query, function, nominal, chosen["rtol"])
    for rtol in [r for r in DOPRI_RTOLS if r <= chosen["rtol"]]:
        two_jvp, run_s, times = timed(query, function, nominal, rtol, repeats=1)
        errors = errors_of(*two_jvp, reference)
        if max(errors.values()) <= TOL or rtol == DOPRI_RTOLS[-1]:
            break
    if repeats > 1 and n <= 1000:  # beyond, one call (tens of seconds) is enough to rank it
        times += timed(query, function, nominal, rtol, repeats=repeats - 1)[2]
        run_s = statistics.median(times)
    out["gradient"] = {"run": True, "rtol": rtol, "method": "two jax.jvp (ForwardMode)",
                       "compile_s": query.compile_s, "run_s": run_s, "run_times_s": times,
                       **errors, "ratio_to_J_alone": run_s / chosen["run_s"]}
    say(f"Dopri8 J + gradient (2 jvp) at rtol {rtol:g}: {run_s:.3f} s (J {errors['J']:.1e}, "
        f"gradient {errors['gradient']:.1e})")
    if batched:
        jacfwd = Compiled(lambda f, p, r: dopri_query(f, p, r, batched=True), function, nominal,
                          rtol)
        (value, jacobian), run_s, _ = timed(jacfwd, function, nominal, rtol, repeats=1)
        out["jacfwd"] = {"compile_s": jacfwd.compile_s, "run_s": run_s,
                         "ratio_to_two_jvp": run_s / out["gradient"]["run_s"],
                         "vs_two_jvp": errors_of(value, jacobian, two_jvp)}
        say(f"Dopri8 J + gradient by jax.jacfwd (as sensitivities): {run_s:.3f} s")
    return out


def evaluate(exe, function, point, reference) -> dict:
    """One timed query at ``point``: seconds and errors, or why it failed (a ROM's energy may
    refuse a design, e.g. a Van Loan step too long for a strong damper)."""
    try:
        (value, jacobian), seconds, _ = timed(exe, function, point, repeats=1)
    except Exception as error:  # recorded, never hidden
        return {"failed": str(error).splitlines()[0][:300]}
    return {"s": seconds, **errors_of(value, jacobian, reference)}


def measure_designs(n, quick, large, scene, function, full, queries, forcing, say) -> dict:
    """At random designs: the full model and every ROM (nominal basis; rebuilt basis where
    cheap), each timed once per design (the per-design time is their median)."""
    rebuild_exes = {}
    rows = []
    for position, coefficient in random_designs(n, designs_for(n, quick, large)):
        point = design(position, coefficient)
        row = {"position": position, "coefficient": coefficient}
        try:
            reference, row["full_s"], _ = timed(full, function, point, repeats=1)
        except Exception as error:  # a spectral failure: this design is skipped, and recorded
            row["skipped"] = str(error).splitlines()[0][:300]
            rows.append(row)
            say(f"design p = {position:.1f}, c = {coefficient:.3g}: full model failed, skipped")
            continue
        row["full_J"] = float(reference[0])
        system = function.system(point)
        for method, (query, basis) in queries.items():
            rom = mj.SceneFunction(scene, "energy", model="reduced", basis=basis, forward=True)
            row[method] = evaluate(query, rom, point, reference)
            if method not in REBUILD:
                continue
            t0 = time.perf_counter()
            if method == "Krylov":
                strategy = mj.Krylov(basis.shape[1], forcing[:, 0], dampers=True)
                fresh = jax.block_until_ready(mj.reduce(system, strategy).basis)
            elif method == "Craig-Bampton":
                fresh = jax.block_until_ready(craig_bampton(system, scene.x0, basis.shape[1]))
            else:
                fresh = jax.block_until_ready(mj.reduce(system, mj.ModalStatic(
                    basis.shape[1], moments=2 if method == "modal + 2 moments" else 1)).basis)
            build_s = elapsed(t0)
            rom = mj.SceneFunction(scene, "energy", model="reduced", basis=fresh, forward=True)
            exe = query
            if fresh.shape != basis.shape:  # fewer columns: another shape, compiled apart
                key = (method, fresh.shape)
                if key not in rebuild_exes:
                    rebuild_exes[key] = Compiled(rom_query, rom, point)
                exe = rebuild_exes[key]
            row[method + " (rebuilt)"] = {"build_s": build_s, "r": int(fresh.shape[1]),
                                          **evaluate(exe, rom, point, reference)}
        rows.append(row)
        say(f"design p = {position:.1f}, c = {coefficient:.3g}: full {row['full_s']:.3f} s; J "
            "error " + ", ".join(f"{m} {row[m]['J']:.1e}" if "J" in row[m] else f"{m} failed"
                                 for m in queries))
    summary = {}
    done = [r for r in rows if "skipped" not in r]
    keys = list(queries) + [m + " (rebuilt)" for m in REBUILD if m in queries]
    if done:
        summary["full"] = {"median_s": statistics.median(r["full_s"] for r in done)}
    for key in keys:
        mine = [r[key] for r in done if key in r]
        good = [v for v in mine if "failed" not in v]
        if not mine:
            continue
        summary[key] = {"failed": len(mine) - len(good)}
        if good:
            summary[key].update(median_s=statistics.median(v["s"] for v in good),
                                worst_J=max(v["J"] for v in good),
                                worst_gradient=max(v["gradient"] for v in good),
                                median_J=statistics.median(v["J"] for v in good))
            if "build_s" in good[0]:
                summary[key]["median_build_s"] = statistics.median(v["build_s"] for v in good)
    return {"rows": rows, "summary": summary, "skipped": len(rows) - len(done)}


# --------------------------------------------------------------------------- costs, crossover


def costs(per_n: list[dict]) -> list[dict]:
    """Flat rows per (n, path): one-query and sweep cost, errors; full paths first."""
    rows = []
    for m in per_n:
        n, designs = m["n"], m["designs"]["summary"]
        spectral = m["full_spectral"].get("run_s")  # None: not run (n >= LARGE)
        dopri = m["dopri8"].get("gradient", {})
        dopri_s = dopri.get("run_s")
        spectral_sweep = (None if spectral is None
                          else SWEEP * designs.get("full", {}).get("median_s", spectral))
        alone = m["dopri8"]["equal_accuracy"]
        if spectral is None and dopri_s is None:  # the reference came from another machine:
            full_one = alone["run_s"]  # Dopri8's J alone, a lower bound on J + gradient
            full_sweep = SWEEP * full_one
        else:
            full_one = min(s for s in (spectral, dopri_s) if s is not None)
            full_sweep = min(s for s in (spectral_sweep,
                                         None if dopri_s is None else SWEEP * dopri_s)
                             if s is not None)
        if spectral is not None:
            rows.append(dict(n=n, path="full spectral", one_query_s=spectral,
                             sweep_s=spectral_sweep, note="the reference"))
        if dopri_s is not None:
            rows.append(dict(n=n, path="full Dopri8", one_query_s=dopri_s, sweep_s=SWEEP * dopri_s,
                             J=dopri["J"], gradient=dopri["gradient"], rtol=dopri["rtol"]))
        if alone is not None:
            rows.append(dict(n=n, path="full Dopri8, J alone", one_query_s=alone["run_s"],
                             sweep_s=SWEEP * alone["run_s"], J=alone["J"], rtol=alone["rtol"],
                             note=None if spectral is not None or dopri_s is not None else
                             "the best full path measured here: a lower bound on J + gradient"))
        for method, row in m["methods"].items():
            if row.get("r") is None:
                rows.append(dict(n=n, path=method, r=None, note=f"TOL not reached up to r = "
                                 f"{row['search_cap']}"))
                continue
            sweep = designs.get(method, {})
            per_design = sweep.get("median_s", row["online_s"])
            one = row["offline_s"] + row["online_s"]
            total = row["offline_s"] + SWEEP * per_design
            rows.append(dict(n=n, path=method, r=row["r"], J=row["J"], gradient=row["gradient"],
                             history=row["history"], offline_s=row["offline_s"],
                             online_s=row["online_s"], one_query_s=one, sweep_s=total,
                             sweep_worst_J=sweep.get("worst_J"),
                             sweep_worst_gradient=sweep.get("worst_gradient"),
                             sweep_failed=sweep.get("failed"), one_query_speedup=full_one / one,
                             sweep_speedup=full_sweep / total))
            rebuilt = designs.get(method + " (rebuilt)", {})
            if "median_s" in rebuilt:
                total = SWEEP * (rebuilt["median_build_s"] + rebuilt["median_s"])
                rows.append(dict(n=n, path=method + " (rebuilt)", r=row["r"], sweep_s=total,
                                 sweep_worst_J=rebuilt["worst_J"],
                                 sweep_worst_gradient=rebuilt["worst_gradient"],
                                 sweep_failed=rebuilt["failed"],
                                 sweep_speedup=full_sweep / total))
            elif method in REBUILD and not m["designs"]["rows"]:  # no random designs (n >= LARGE):
                total = SWEEP * one  # build + query at the nominal design, accuracy not measured
                rows.append(dict(n=n, path=method + " (rebuilt)", r=row["r"], sweep_s=total,
                                 sweep_speedup=full_sweep / total,
                                 note="cost at the nominal design; accuracy not measured"))
    return rows


def best_full(rows, n: int, key: str) -> float:
    """The best full path's cost at n: spectral or Dopri8 J + gradient, or, where neither was
    timed on this machine (a reference from another), Dopri8's J alone (a lower bound)."""
    costs = [r[key] for r in rows if r["n"] == n and r["path"] in ("full spectral",
                                                                   "full Dopri8")]
    return min(costs) if costs else min(r[key] for r in rows if r["n"] == n and r["path"]
                                        == "full Dopri8, J alone")


def crossover(rows, sizes) -> dict:
    """Per method and mode: the smallest measured n from which the ROM is cheaper, or the
    n where power-law fits of both costs cross (an extrapolation)."""
    out = {}
    paths = list(METHODS) + [m + " (rebuilt)" for m in REBUILD]
    for path in paths:
        entry = {}
        for key, mode in (("one_query_s", "one query"), ("sweep_s", "sweep")):
            mine = {r["n"]: r.get(key) for r in rows if r["path"] == path}
            if not mine or all(v is None for v in mine.values()):
                continue
            # None: no r <= the cap met TOL there, so no ROM at equal accuracy to time: such an
            # n is left out of the comparison (and named), not counted as "not cheaper"
            capped = [n for n in sizes if n in mine and mine[n] is None]
            ns = [n for n in sizes if n in mine and mine[n] is not None]
            full = {n: best_full(rows, n, key) for n in ns}
            cheaper = [mine[n] is not None and mine[n] < full[n] for n in ns]
            first = None
            for i, n in enumerate(ns):
                if all(cheaper[i:]):
                    first = n
                    break
            result = {"measured_n": ns, "rom_s": [mine[n] for n in ns],
                      "full_s": [full[n] for n in ns], "cheaper": cheaper}
            if first is not None:
                result["crossover_n"] = first
                result["statement"] = (f"pays off from n = {first}" if first != ns[0] else
                                       f"pays off at every measured n (already at n = {first})")
            else:
                result["crossover_n"] = None
                known = [n for n in ns if mine[n] is not None]
                result.update(extrapolate(known, [mine[n] for n in known],
                                          [full[n] for n in known]))
                predicted = result.get("extrapolated_n")
                some = [n for n, c in zip(ns, cheaper) if c]
                result["statement"] = (f"cheaper at n = {some} only; " if some else "") + (
                    f"not reached up to n = {ns[-1]}; EXTRAPOLATION (power-law fits over n = "
                    f"{known}): n ~ {predicted:.3g}" if predicted else
                    f"not reached up to n = {ns[-1]}; the power-law fits do not cross beyond it")
            if capped:
                result["no_rank_at_tol_n"] = capped
                result["statement"] += (f" (at n = {capped} no r <= {RANK_CAP} met TOL, so "
                                        "no ROM at equal accuracy was timed there)")
            if mode == "sweep":
                worst = [r.get("sweep_worst_J") for r in rows if r["path"] == path]
                worst = [w for w in worst if w is not None]
                if worst:
                    result["worst_random_design_J"] = max(worst)
                    result["statement"] += (f" (its J is up to {max(worst):.1e} off at the "
                                            "random designs)")
            entry[mode] = result
        if entry:
            out[path] = entry
    return out


def extrapolate(ns, rom, full) -> dict:
    if len(ns) < 2:
        return {"extrapolated_n": None}
    b_rom, b_full = fit_exponent(ns, rom), fit_exponent(ns, full)
    a_rom = float(np.mean(np.log(rom) - b_rom * np.log(ns)))
    a_full = float(np.mean(np.log(full) - b_full * np.log(ns)))
    out = {"rom_exponent": b_rom, "full_exponent": b_full, "extrapolated_n": None,
           "extrapolation": True}
    if b_full > b_rom:
        crossing = math.exp((a_rom - a_full) / (b_full - b_rom))
        if crossing > ns[-1]:
            out["extrapolated_n"] = crossing
    return out


# --------------------------------------------------------------------------- main, plot


def main(argv=None) -> dict:
    args = parse_args(__doc__, argv, replot=True, sizes=dict(
        type=int, nargs="+", help="these n instead (a check: writes crossover_sizes.json)"),
        large_from=dict(type=int, default=LARGE, help="the large-n path from this n (a check "
                        "of it against the spectral one at small n)"),
        recompute=dict(action="store_true", help="the costs and crossover statements again "
                       "from the stored measurements (no timing)"),
        reference_out=dict(default=None, metavar="FILE", help="only the Dopri8 reference (J + "
                           "gradient) of each n, written to FILE (e.g. on a GPU machine)"),
        rank_hint=dict(default=None, metavar="NAME", help="start each rank search at the r "
                       "results/NAME.json found (same n; the search within 1 %%)"),
        name=dict(default=None, help="the results' name (default crossover, or crossover_sizes "
                  "with --sizes / --large-from)"),
        merge=dict(default=None, metavar="NAME", help="add results/NAME.json's sizes to "
                   "results/crossover.json and recompute its costs and crossovers (no timing)"))
    name = args.name or (NAME if args.sizes is None and args.large_from == LARGE
                         else NAME + "_sizes")
    if args.replot:
        return print(plot(read_json(name, args.quick), args.quick, name))
    if args.recompute or args.merge:  # costs and crossovers again from stored measurements
        data = read_json(name, args.quick)
        if args.merge:
            extra = read_json(args.merge, False)
            data["per_n"] = [m for m in data["per_n"] if m["n"] not in extra["sizes"]] + extra[
                "per_n"]
            data["sizes"] = sorted(set(data["sizes"]) | set(extra["sizes"]))
            data["merged"] = {str(n): f"{args.merge}.json ({extra['metadata']['date']})"
                              for n in extra["sizes"]}
            data["not_run"] = [x for x in data["not_run"] if x["n"] not in extra["sizes"]]
        data["rows"] = costs(data["per_n"])
        data["crossover"] = crossover(data["rows"], data["sizes"])
        print_tables(data["rows"], data["crossover"])
        path = write_json(name, args.quick, {k: v for k, v in data.items() if k not in (
            "benchmark", "quick", "metadata")}, data["metadata"])
        return print(f"rewrote {path} and {plot(read_json(name, args.quick), args.quick, name)}")
    sizes = args.sizes or (QUICK_SIZES if args.quick else SIZES)
    start = time.perf_counter()
    if args.reference_out:
        references = {}
        for n in sizes:
            say = lambda text, n=n: print(f"  n={n}: {text} ({elapsed(start):.0f} s)",  # noqa: E731
                                          flush=True)
            function = mj.SceneFunction(scene_for(n), "energy")
            references[str(n)] = dopri_reference(function, design(POSITION, COEFFICIENT), say)[1]
            Path(args.reference_out).write_text(json.dumps(
                {"references": references, "metadata": metadata()}, indent=1))
        return print(f"wrote {args.reference_out}")
    hints = {}
    if args.rank_hint:
        for m in read_json(args.rank_hint, False)["per_n"]:
            hints[m["n"]] = {k: v["r"] for k, v in m["methods"].items() if v.get("r")}
    per_n = []
    for i, n in enumerate(sizes):
        print(f"n = {n}", flush=True)
        per_n.append(measure(n, args.quick, check_public=i == 0, large_from=args.large_from,
                             hints=hints.get(n)))
    rows = costs(per_n)
    cross = crossover(rows, list(sizes))
    print_tables(rows, cross)
    data = dict(
        problem=dict(chain="Mikota, m = k = 1", design=dict(position=POSITION,
                                                            coefficient=COEFFICIENT),
                     x0=f"x_{INITIAL_DOF}(0) = 1, v0 = 0", J=f"energy on [0, {HORIZON:g}]",
                     outputs_every=STEP, snapshots=list(WINDOW), wrt=list(WRT), tol=TOL,
                     sweep=SWEEP, rank_rule="smallest r with ROM J within TOL at the nominal "
                     "design (ladder + bisection, numpy J; library J checked)",
                     sweep_cost="offline + SWEEP x the median per-design time over the random "
                     "designs (not a measured SWEEP-run)",
                     modal_static="r - 2 modes + the split damper's two static directions",
                     errors="relative to the full model's spectral path"),
        sizes=list(sizes), not_run=[{"n": n, "reason": why} for n, why in NOT_RUN.items()],
        per_n=per_n, rows=rows, crossover=cross, total_wall_s=elapsed(start))
    path = write_json(name, args.quick, data)
    png = plot(read_json(name, args.quick), args.quick, name)
    print(f"wrote {path} and {png} ({elapsed(start):.0f} s)")
    return data


def print_tables(rows, cross) -> None:
    print_table(rows, [("n", "n", "d"), ("path", "path", ""), ("r", "r", "d"),
                       ("J", "J err", ".1e"), ("gradient", "dJ err", ".1e"),
                       ("history", "x err", ".1e"), ("offline_s", "offline s", ".3f"),
                       ("online_s", "online s", ".3f"), ("one_query_s", "1 query s", ".3f"),
                       ("sweep_s", f"{SWEEP} designs s", ".1f"),
                       ("sweep_worst_J", "sweep J err", ".1e"),
                       ("sweep_worst_gradient", "sweep dJ err", ".1e"),
                       ("one_query_speedup", "x 1 query", ".2f"),
                       ("sweep_speedup", "x sweep", ".2f")])
    table = [{"path": path, "one": entry.get("one query", {}).get("statement"),
              "sweep": entry.get("sweep", {}).get("statement")} for path, entry in cross.items()]
    print_table(table, [("path", "method", ""), ("one", "one query", ""),
                        ("sweep", f"{SWEEP}-design sweep", "")])


COLOURS = dict(zip(list(METHODS) + [m + " (rebuilt)" for m in REBUILD], (
    "tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown",
    "darkgoldenrod", "tab:pink", "tab:olive", "tab:cyan", "goldenrod")))  # black: full paths
STYLES = {"POD": "o-", "enriched POD": "s-", "modal": "^--", "modal + static": "v--",
          "Krylov": "d-.", "modal + static (rebuilt)": "v:", "Krylov (rebuilt)": "d:",
          "modal + 2 moments": "P--", "modal + 2 moments (rebuilt)": "P:",
          "Craig-Bampton": "h-", "Craig-Bampton (rebuilt)": "h:",
          "full spectral": "*-", "full Dopri8": "x-", "full Dopri8, J alone": "x:"}


def plot(data: dict, quick: bool, name: str = NAME):
    rows, sweep_size = data["rows"], data["problem"]["sweep"]
    fig, axes = figure(nrows=2, ncols=2, figsize=(12, 9.5), readable=True)
    (one, sweep), (err_one, err_sweep) = axes
    for ax, key, title in ((one, "one_query_s", "(a) one query: offline + online"),
                           (sweep, "sweep_s", f"(b) {sweep_size} designs: offline + "
                                              f"{sweep_size} x median")):
        for path, style in STYLES.items():
            mine = [r for r in rows if r["path"] == path and r.get(key) is not None]
            if mine:
                ax.loglog([r["n"] for r in mine], [r[key] for r in mine], style,
                          color=COLOURS.get(path, "k"), label=path)
        sizes = sorted({r["n"] for r in rows})
        ax.set_xticks(sizes, [str(n) for n in sizes])
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("chain size n")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
    one.set_ylabel("wall time, J + gradient (s)")
    for ax, cost, keys, title in (
            (err_one, "one_query_s", (("J", "o"), ("gradient", "s"), ("history", "^")),
             "(c) error at the nominal design"),
            (err_sweep, "sweep_s", (("sweep_worst_J", "o"), ("sweep_worst_gradient", "s")),
             "(d) worst error over the random designs")):
        for r in rows:
            if r.get(cost) is None or r["path"].startswith("full"):
                continue
            for key, marker in keys:
                if r.get(key) is not None:
                    ax.loglog(r[cost], max(r[key], 1e-16), marker, color=COLOURS[r["path"]],
                              markersize=3 + 2 * math.log10(r["n"] / 100), alpha=0.8)
        for n in sorted({r["n"] for r in rows}):  # the best full path's cost at each n
            best = best_full(rows, n, cost)
            ax.axvline(best, color="k", lw=0.8, ls=":")
            ax.annotate(f"full n = {n}", (best, 0.02), rotation=90,
                        xycoords=ax.get_xaxis_transform(), va="bottom", ha="right")
        ax.axhline(TOL, color="grey", lw=0.8, ls="--")
        ax.set_xlabel("wall time (s)" if ax is err_one else "sweep wall time (s)")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
    err_one.set_ylabel("relative error")
    legend(err_one, "below", handles=sweep.get_legend_handles_labels()[0], ncol=2)
    markers = [err_sweep.plot([], [], m, color="grey", label=label)[0] for m, label in (
        ("o", "J"), ("s", "max(dJ/dp, dJ/dc)"), ("^", "x(t), all DOFs (nominal only)"))]
    markers.append(err_sweep.plot([], [], "k:", label="best full path's cost")[0])
    markers.append(err_sweep.plot([], [], "--", color="grey", label=f"TOL = {TOL:g}")[0])
    legend(err_sweep, "below", handles=markers, ncol=1, title="marker size grows with n")
    fig.suptitle(f"Error against cost: Mikota chain, damper at DOF 7 (c = 1), J on [0, 20] + "
                 f"gradient;\nROM rank: J within {TOL:g} at the nominal design. "
                 + subtitle(data["metadata"]))
    return save_figure(fig, name, quick)


if __name__ == "__main__":
    main()
