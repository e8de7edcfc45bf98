"""The default exact path across critical damping, against truths far stronger than float64.

At a critical point two damped roots meet (a double root with one eigenvector). The spectral path
sums such a pair by a contour integral (``_spectral_clusters``); here J, the trace X and x(t),
and their derivatives in the damper coefficient, are swept through c = c* (1 + delta) for delta
from 0 to 1e-2 on both sides and compared with

* one mass (m = k = 1, c* = 2): closed forms (x(t) from the two roots in mpmath at 50 digits, or
  (1 + t) e^-t at c = 2; trace X = c / 2 + 2 / c, d/dc = 1 / 2 - 2 / c^2 exactly);
* the other cases: mpmath's eigen-expansion at 80 digits (``_helpers.mp_truths``; at delta ~ 1e-16
  it loses ~8 digits to the near-defective pair, keeping ~70), and for the derivatives central
  differences of it with h = 1e-12 c in exact arithmetic (truncation ~1e-24).

c* of the cases we picked (a relative damper, two dampers of which one sweeps, and a damper with
Rayleigh internal damping) were found by
mpmath's findroot on det Q(lambda, c) = d/dlambda det Q(lambda, c) = 0 at 60 digits; a wrong c*
would only move the probe, not the truth (which is computed at the float c used).
"""

import jax
import jax.numpy as jnp
import mpmath as mp
import numpy as np
import pytest
from _helpers import mp_truths
from hypothesis import given, settings
from hypothesis import strategies as st

import mikota_jax as mj
from mikota_jax._solver.spectral.modes import damped_modes

T = 10.0
TS = np.linspace(0.0, T, 41)


def one_dof(c):
    return mj.mikota_chain(1, dampers=[mj.GroundedDamper(1.0, c)])


CASES = {
    # name: (system of c, c* to 40 digits, x0, v0)
    "one mass": (one_dof, "2", np.array([1.0]), np.array([0.0])),
    "two masses": (lambda c: mj.chain(np.ones(2), np.ones(2), [mj.GroundedDamper(2.0, c)]),
                   "1.553026040673962751124894081872586606709", np.array([1.0, 0.0]),
                   np.array([0.0, 0.5])),
    "mikota 8": (lambda c: mj.mikota_chain(8, dampers=[mj.GroundedDamper(1.0, c)]),
                 "6.857092135881596014188153624389535170610", np.eye(8)[2],
                 np.linspace(0.0, 1.0, 8)),
    "relative damper": (lambda c: mj.chain(np.ones(3), np.ones(3), [mj.RelativeDamper((1, 3),
                                                                                      c)]),
                        "1.177365133083064040670286858679642877963", np.array([1.0, 0.0, 0.0]),
                        np.array([0.0, 0.3, -0.2])),
    "two dampers": (lambda c: mj.mikota_chain(4, dampers=[mj.GroundedDamper(1.0, c),
                                                          mj.GroundedDamper(3.0, 0.5)]),
                    "4.694514930203024326374913585441467183263", np.array([0.0, 1.0, 0.0, 0.0]),
                    np.array([0.5, 0.0, 0.0, -0.5])),
    "rayleigh": (lambda c: mj.chain(np.ones(3), np.ones(3), [mj.GroundedDamper(3.0, c)],
                                    internal_damping=mj.Rayleigh(0.05, 0.02)),
                 "1.316502064663267425137348944804009733692", np.array([1.0, 0.0, 0.0]),
                 np.array([0.0, 0.5, 0.0])),
}
DELTAS = [0.0, -1e-12]
SLOW_DELTAS = [1e-16, -1e-16, 1e-14, -1e-14, 1e-12, 1e-10, -1e-10, 1e-8, -1e-8, 1e-6, -1e-6,
               1e-4, -1e-4, 1e-2, -1e-2]


def one_dof_truth(c, exact=False):
    """(J, trace, x(TS)) of one mass from its two roots at 50 digits (the limit at c = 2)."""
    with mp.workdps(50):
        c = mp.mpf(c)
        if c == 2:
            x = lambda t: (1 + t) * mp.exp(-t)  # noqa: E731
            v = lambda t: -t * mp.exp(-t)  # noqa: E731
        else:
            d = mp.sqrt(mp.mpc(c**2 / 4 - 1))
            l1, l2 = -c / 2 + d, -c / 2 - d
            a, b = -l2 / (l1 - l2), l1 / (l1 - l2)
            x = lambda t: mp.re(a * mp.exp(l1 * t) + b * mp.exp(l2 * t))  # noqa: E731
            v = lambda t: mp.re(a * l1 * mp.exp(l1 * t) + b * l2 * mp.exp(l2 * t))  # noqa: E731
        energy = mp.quad(lambda t: (x(t) ** 2 + v(t) ** 2) / 2, [0, 1, 3, T])
        trace = c / 2 + 2 / c
        xs = np.array([[float(x(t))] for t in TS])
        return (energy, trace, xs) if exact else (float(energy), float(trace), xs)


def truths(name, c):
    make, _, x0, v0 = CASES[name]
    if name == "one mass":
        return one_dof_truth(c)
    return mp_truths(make(c).dense(), T, x0, v0, TS)


def derivative_truths(name, c):
    """(dJ/dc, dtrace/dc) at the float c by central differences at 80 digits."""
    make, _, x0, v0 = CASES[name]
    with mp.workdps(80):
        h = mp.mpf(c) * mp.mpf("1e-12")
        if name == "one mass":
            jp, tp, _ = one_dof_truth(mp.mpf(c) + h, exact=True)
            jm, tm, _ = one_dof_truth(mp.mpf(c) - h, exact=True)
            return float((jp - jm) / (2 * h)), float(mp.mpf(0.5) - 2 / mp.mpf(c) ** 2)
        at = mp_system(make, x0, v0)
        jp, tp = at(mp.mpf(c) + h)
        jm, tm = at(mp.mpf(c) - h)
        return float((jp - jm) / (2 * h)), float((tp - tm) / (2 * h))


def mp_system(make, x0, v0):
    """c (an mpmath number) -> (J, trace) of ``make(c)`` from mpmath's eigen-expansion at 80
    digits, with D(c) = D0 + c D1 built exactly (D1's entries 0, +-1 and the fixed dampers')."""
    m, with_one, k = (np.asarray(a) for a in make(1.0).dense())
    d0 = np.asarray(make(0.0).dense()[1])
    d1 = with_one - d0

    def at(c):
        damping = mp.matrix(d0.tolist()) + c * mp.matrix(d1.tolist())
        energy, trace, _ = mp_truths((m, damping, k), T, x0, v0, [], exact=True)
        return energy, trace

    return at


def spectral_values(name, c):
    make, _, x0, v0 = CASES[name]
    system = make(c)
    energy = mj.Energy(T, x0, v0)(system)
    trace = mj.AverageEnergy()(system)
    history = mj.solve(system, TS, x0, v0, method=mj.Spectral()).displacement
    return float(energy), float(trace), np.asarray(history)


def probe(name, delta):
    _, cstar, _, _ = CASES[name]
    return float(mp.mpf(cstar) * (1 + mp.mpf(delta)))


def check_values(name, delta, close):
    c = probe(name, delta)
    energy, trace, history = truths(name, c)
    ours = spectral_values(name, c)
    close(ours[0], energy, rtol=1e-12, what="J")
    close(ours[1], trace, rtol=1e-12, what="trace")
    scale = np.max(np.abs(history))
    close(ours[2] / scale, history / scale, atol=1e-12, what="x(t)")


def check_gradients(name, delta, close):
    make, _, x0, v0 = CASES[name]
    c = probe(name, delta)
    d_energy, d_trace = derivative_truths(name, c)
    grad_energy = jax.grad(lambda c: mj.Energy(T, x0, v0)(make(c)))(c)
    grad_trace = jax.grad(lambda c: mj.AverageEnergy()(make(c)))(c)
    # relative to the derivative, or to value / c where that is 0 (the one-mass trace optimum)
    energy, trace, _ = truths(name, c)
    close(grad_energy, d_energy, rtol=1e-10, atol=1e-10 * abs(energy / c), what="dJ/dc")
    close(grad_trace, d_trace, rtol=1e-10, atol=1e-10 * abs(trace / c), what="dtrace/dc")


QUICK = ["two masses", "rayleigh"]  # the default run; every case under -m slow


@pytest.mark.parametrize("name", [pytest.param(name, marks=() if name in QUICK else
                                               pytest.mark.slow) for name in CASES])
def test_values_and_gradients_stay_exact_through_critical_damping(name, close):
    # one case's compiled paths serve every delta: the deltas cost only their truths
    for delta in DELTAS:
        check_values(name, delta, close)
        check_gradients(name, delta, close)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(CASES))
def test_the_whole_sweep_through_critical_damping_is_exact(name, close):
    for delta in SLOW_DELTAS:
        check_values(name, delta, close)
        check_gradients(name, delta, close)


@pytest.mark.parametrize("name", [pytest.param(name, marks=() if name == "two dampers" else
                                               pytest.mark.slow) for name in CASES])
def test_the_pair_at_a_critical_point_is_one_cluster(name):
    make, _, _, _ = CASES[name]
    modes = damped_modes(make(probe(name, 1e-12)))
    assert bool(modes.converged) and bool(modes.clusters.ok)
    assert int(np.sum(np.asarray(modes.clusters.member))) == 2


def test_the_trace_of_the_lowest_modes_with_internal_damping_is_exact_at_a_critical_point(close):
    """Internal damping at a critical point (the "rayleigh" case at c*, one cluster): the trace
    of the s lowest modes sums the energies of 2s unit modal states, whose cross terms with the
    pair take the Woodbury form on those s rows. With s = n it is the whole trace: mpmath at 80
    digits (about 70 right at delta = 0); with s = 1 the dense Lyapunov solution (Smith
    doubling of Van Loan's integral: rounding of its 64 doublings, ~1e-13 here), values and
    derivatives in c."""
    from mikota_jax._objective.functions import total_average_energy

    make, _, _, _ = CASES["rayleigh"]
    c = probe("rayleigh", 0.0)
    assert int(np.sum(np.asarray(damped_modes(make(c)).clusters.member))) == 2
    _, trace, _ = truths("rayleigh", c)
    close(mj.AverageEnergy(3)(make(c)), trace, rtol=1e-12)
    spectral = jax.value_and_grad(lambda c: mj.AverageEnergy(1)(make(c)))(c)
    dense = jax.value_and_grad(lambda c: total_average_energy(make(c), 1, method="dense"))(c)
    close(spectral[0], dense[0], rtol=1e-12)
    close(spectral[1], dense[1], rtol=1e-10)


def test_the_optimiser_finds_the_one_mass_trace_optimum_at_critical_damping(close):
    # trace X = c / 2 + 2 / c: minimum 2 at c = 2 (exact), where the two roots meet
    result = mj.optimise(mj.DamperDesign(one_dof(0.5), mj.AverageEnergy()), mj.Coefficients())
    assert result.result == mj.DesignResult.converged
    close(result.coefficients, [2.0], rtol=1e-8)
    close(result.value, 2.0, rtol=1e-13)


@pytest.mark.slow
def test_jit_vmap_and_grad_agree_with_the_eager_values_at_the_critical_point(close):
    make, _, x0, v0 = CASES["one mass"]
    cs = jnp.array([probe("one mass", d) for d in (0.0, 1e-12, -1e-8, 1e-2)])
    energy = lambda c: mj.Energy(T, x0, v0)(make(c))  # noqa: E731
    eager = [float(energy(c)) for c in cs]
    close(jax.jit(jax.vmap(energy))(cs), eager, rtol=1e-14)
    value, grad = jax.jit(jax.value_and_grad(energy))(cs[0])
    close(value, eager[0], rtol=1e-14)
    close(grad, jax.grad(energy)(cs[0]), rtol=1e-12)


@pytest.mark.parametrize("system", [
    pytest.param(mj.mikota_chain(6, dampers=[mj.GroundedDamper(2.0, 0.0)]), id="zero coefficient"),
    pytest.param(mj.mikota_chain(6, dampers=[mj.RelativeDamper((2, 4), 0.0)]),
                 id="zero relative", marks=pytest.mark.slow),
    # mode 2 of four equal masses vanishes at DOF 3
    pytest.param(mj.chain(np.ones(4), np.ones(4), [mj.GroundedDamper(3.0, 1.0)]),
                 id="damper on a node", marks=pytest.mark.slow),
])
@pytest.mark.slow
def test_an_undamped_mode_makes_the_trace_refuse_eagerly_and_under_jit(system):
    with pytest.raises(ValueError, match="undamped"):
        mj.AverageEnergy()(system)
    with pytest.raises(jax.errors.JaxRuntimeError, match="undamped"):
        jax.jit(lambda s: mj.AverageEnergy()(s))(system)


def test_a_zero_damper_keeps_the_energy_of_free_vibration(close):
    # c = 0: nothing dissipates, J = T E(0) exactly
    system = mj.mikota_chain(6, dampers=[mj.GroundedDamper(2.0, 0.0)])
    x0, v0 = np.eye(6)[1], np.linspace(0.0, 1.0, 6)
    m, _, k = (np.asarray(a) for a in system.dense())
    close(mj.Energy(T, x0, v0)(system), T * (x0 @ k @ x0 + v0 @ m @ v0) / 2,
          rtol=1e-12)


# --- random systems at and around their critical points (hypothesis) ------------------------

DRAWS = settings(max_examples=5, deadline=None, derandomize=True, database=None)


@st.composite
def critical_oscillators(draw):
    """One mass m on a spring k with a grounded damper at c = 2 sqrt(k m) (1 + delta): the two
    roots -sqrt(k/m) (1 + delta +- sqrt(delta (2 + delta))) meet at delta = 0; delta drawn from
    0 and +-1e-16 ... 1e-2 (the decades where the root-by-root sum lost its digits)."""
    mass = draw(st.floats(1e-2, 1e2))
    stiffness = draw(st.floats(1e-2, 1e2))
    delta = draw(st.sampled_from([0.0] + [s * 10.0**-e for e in range(2, 17, 2) for s in (1, -1)]))
    return mass, stiffness, delta


@given(critical_oscillators())
@DRAWS
def test_a_random_oscillator_near_its_critical_point_keeps_its_exact_energy(case):
    # x(0) = 1, x'(0) = 0 on [0, T]; truth: the scaled one-mass solution at 50 digits
    # (time t sqrt(k/m), c / (2 sqrt(k m)) = 1 + delta: J scales as k (T in units of sqrt(m/k)))
    mass, stiffness, delta = case
    c = 2 * np.sqrt(stiffness * mass) * (1 + delta)
    system = mj.chain(np.array([mass]), np.array([stiffness]), [mj.GroundedDamper(1.0, c)])
    rate = np.sqrt(stiffness / mass)
    horizon = 5.0 / rate
    with mp.workdps(50):
        zeta = mp.mpf(c) / (2 * mp.sqrt(mp.mpf(stiffness) * mp.mpf(mass)))
        if zeta == 1:
            x = lambda t: (1 + t) * mp.exp(-t)  # noqa: E731
            v = lambda t: -t * mp.exp(-t)  # noqa: E731
        else:
            d = mp.sqrt(mp.mpc(zeta**2 - 1))
            l1, l2 = -zeta + d, -zeta - d
            a, b = -l2 / (l1 - l2), l1 / (l1 - l2)
            x = lambda t: mp.re(a * mp.exp(l1 * t) + b * mp.exp(l2 * t))  # noqa: E731
            v = lambda t: mp.re(a * l1 * mp.exp(l1 * t) + b * l2 * mp.exp(l2 * t))  # noqa: E731
        # E = (k x^2 + m x'^2) / 2 with x'(t) = rate v(rate t); dt = d(rate t) / rate
        scaled = mp.quad(lambda s: (x(s) ** 2 + v(s) ** 2) / 2, [0, 1, 3, 5])
        truth = float(scaled * mp.mpf(stiffness) / mp.mpf(rate))
    value = float(mj.Energy(horizon, np.array([1.0]))(system))
    assert value == pytest.approx(truth, rel=1e-12)


@pytest.mark.slow
def test_the_refusal_names_the_undamped_mode_eagerly():
    # four equal masses: mode 2 has a node at DOF 3, where the damper sits
    system = mj.chain(np.ones(4), np.ones(4), [mj.GroundedDamper(3.0, 1.0)])
    with pytest.raises(ValueError, match=r"mode 2 \(1-based, by frequency\) is undamped"):
        mj.AverageEnergy()(system)
    assert float(mj.AverageEnergy(lowest=1)(system)) > 0  # mode 1 alone is damped


def test_the_h2_norm_at_a_critical_point_equals_the_dense_gramians(close):
    # the clusters' terms of the output energies (``_cluster_output``) against the dense path of
    # a full-rank reduced model (Van Loan / Lyapunov by doubling, right to ~1e-13 here)
    make, _, _, _ = CASES["two masses"]
    system = make(probe("two masses", 0.0))
    inputs, outputs = np.array([1.0, 0.3]), np.array([[0.2, 1.0]])
    dense = mj.reduce(system, mj.Projection(np.eye(2)))
    close(mj.H2Norm(inputs, outputs)(system), mj.H2Norm(inputs, outputs)(dense), rtol=1e-12)


@st.composite
def unreachable_modes(draw):
    """A chain with a mode no damper moves, and that mode's number (1-based, by frequency).

    Either a uniform fixed-free chain (masses m, springs k) with its damper on a node: mode l is
    sin((2l - 1) pi i / (2n + 1)), which vanishes at DOF i = q when 2n + 1 = (2l - 1) q; or any
    chain whose only damper has coefficient 0 (every mode undamped, the first named)."""
    if draw(st.booleans()):
        # n = 4 (mode 2 at DOF 3), n = 7 (mode 3 at DOF 3; modes 2 and 5 at DOF 5, the first
        # named): two sizes, so that the draws share their compiled programs
        odd, q = draw(st.sampled_from([(3, 3), (5, 3), (3, 5)]))
        n, mode = (odd * q - 1) // 2, (odd + 1) // 2
        mass, spring = draw(st.floats(0.1, 10.0)), draw(st.floats(0.1, 10.0))
        c = draw(st.floats(1e-2, 1e2))
        damper = mj.GroundedDamper(float(q), c)
        return mj.chain(np.full(n, mass), np.full(n, spring), [damper]), mode
    n = draw(st.sampled_from([4, 7]))
    masses = np.array(draw(st.lists(st.floats(0.1, 10.0), min_size=n, max_size=n)))
    springs = np.array(draw(st.lists(st.floats(0.1, 10.0), min_size=n, max_size=n)))
    position = draw(st.floats(1.0, float(n)))
    return mj.chain(masses, springs, [mj.GroundedDamper(position, 0.0)]), 1


@given(unreachable_modes())
@DRAWS
def test_a_mode_no_damper_reaches_is_refused_by_the_trace_and_kept_by_the_energy(case):
    system, mode = case
    named = rf"modes? (\d+, )*{mode}(, \d+)* \(1-based, by frequency\)"
    with pytest.raises(ValueError, match=named):
        mj.AverageEnergy()(system)
    # the energy exists: against the dense Van Loan exponential (independent of the damped
    # modes; ~1e-12 relative at these sizes), and within 0 < J <= T E(0)
    n = system.size
    x0, v0 = np.linspace(1.0, -0.5, n), np.linspace(0.0, 0.3, n)
    m, _, k = (np.asarray(a) for a in system.dense())
    value = float(mj.Energy(T, x0, v0)(system))
    assert value == pytest.approx(float(mj.Energy(T, x0, v0, method=mj.DenseExponential())(system)),
                                  rel=1e-9)
    assert 0.0 < value <= T * (x0 @ k @ x0 + v0 @ m @ v0) / 2 * (1 + 1e-12)


@pytest.mark.parametrize("c", [17.0] + [pytest.param(c, marks=pytest.mark.slow)
                                         for c in (1.0, 10.0, 100.0)])
def test_a_damper_on_the_node_of_two_modes_keeps_the_exact_energy(c):
    # uniform n = 7 chain: modes 2 and 5 vanish at DOF 5, so two roots sit on their poles while
    # the Aberth sweep runs (once, a root anchored to such a mode made every root NaN); truths:
    # the dense Van Loan energy (~1e-12 relative) and central differences of it (h = 1e-4 c:
    # truncation ~1e-8 relative)
    def energy(c, method=None):
        method = mj.Spectral() if method is None else method
        system = mj.chain(np.full(7, 3.0), np.full(7, 10.0), [mj.GroundedDamper(5.0, c)])
        x0, v0 = np.linspace(1.0, -0.5, 7), np.linspace(0.0, 0.3, 7)
        return mj.Energy(T, x0, v0, method=method)(system)

    value, slope = jax.value_and_grad(energy)(c)
    assert float(value) == pytest.approx(float(energy(c, mj.DenseExponential())), rel=1e-9)
    h = 1e-4 * c
    dense = mj.DenseExponential()
    central = (float(energy(c + h, dense)) - float(energy(c - h, dense))) / (2 * h)
    assert float(slope) == pytest.approx(central, rel=1e-6)


# Mikota's chain with its damper on the middle DOF: at c = 2 sqrt(k m) every mode pair (1, 2),
# (3, 4), ... meets at once (n / 2 double roots, measured by the roots' separation: 1e-11
# relative at c = 2 for n = 8, 20, 300), more pairs than the contour's slots. Summed root by root,
# the old bound (2 |lambda| |y|^2 / |N| <= 1e6) let through J 4e-2 off at n = 20 and 1e-3 off at
# n = 300 for c = 2 (1 + 1e-9): such a pair is held to ``PAIR_LIMIT`` and refused beyond it.
MIDDLE = (lambda c: mj.mikota_chain(8, dampers=[mj.GroundedDamper(4.0, c)]), np.eye(8)[2],
          np.linspace(0.0, 1.0, 8))


def middle_truths(c):
    """(J, trace, dJ/dc) of ``MIDDLE`` at the float c: mpmath's eigen-expansion at 80 digits
    (at 1e-2 from the meeting point the pairs cost ~1 digit) and central differences of it with
    h = 1e-12 c at 80 digits (truncation ~1e-24)."""
    with mp.workdps(80):
        at = mp_system(*MIDDLE)
        energy, trace = at(mp.mpf(c))
        h = mp.mpf(c) * mp.mpf("1e-12")
        slope = (at(mp.mpf(c) + h)[0] - at(mp.mpf(c) - h)[0]) / (2 * h)
        return float(energy), float(trace), float(slope)


@pytest.mark.parametrize("delta", [1e-2, pytest.param(-1e-2, marks=pytest.mark.slow),
                                   pytest.param(3e-3, marks=pytest.mark.slow)])
def test_every_pair_meeting_at_once_keeps_the_exact_energy_outside_the_refusal(delta, close):
    make, x0, v0 = MIDDLE
    c = 2 * (1 + delta)
    energy, trace, slope = middle_truths(c)
    value, grad = jax.value_and_grad(lambda c: mj.Energy(T, x0, v0)(make(c)))(c)
    close(value, energy, rtol=1e-12, what="J")
    close(mj.AverageEnergy()(make(c)), trace, rtol=1e-12, what="trace")
    # measured 1.2e-10 at delta = -1e-2, 1e-9 at 3e-3: the pairs the contour rule leaves to the
    # root-by-root sums lose ~eps cond^4 in the derivative
    close(grad, slope, rtol=2e-9, what="dJ/dc")


@pytest.mark.parametrize("delta", [1e-4, -1e-9, 0.0])
def test_every_pair_meeting_at_once_is_refused_eagerly_and_under_jit(delta):
    make, x0, v0 = MIDDLE
    energy = mj.Energy(T, x0, v0)
    with pytest.raises(ValueError, match="spectral path did not hold"):
        energy(make(2 * (1 + delta)))
    with pytest.raises(jax.errors.JaxRuntimeError, match="spectral path did not hold"):
        jax.jit(lambda c: energy(make(c)))(2 * (1 + delta))
    # the dense path the message names holds there: against mpmath's expansion at 80 digits (at
    # the defective point itself, c = 2, against it at c = 2 (1 + 1e-9): dJ/dc ~ 1, so within
    # ~2e-9 J)
    dense = mj.Energy(T, x0, v0, method=mj.DenseExponential())(make(2 * (1 + delta)))
    m, d, k = make(2 * (1 + (delta or 1e-9))).dense()
    truth, _, _ = mp_truths((m, d, k), T, x0, v0, [])
    assert float(dense) == pytest.approx(truth, rel=1e-11 if delta else 1e-8)


@pytest.mark.slow
def test_the_optimiser_says_why_it_stops_before_the_middle_dampers_trace_optimum():
    # the trace of MIDDLE is smallest at c = 2 (the dense path's gradient there: 2e-14), inside
    # the refusal: the search stops at the band's edge, fails, and its status says why
    make, _, _ = MIDDLE
    solution = mj.optimise(mj.DamperDesign(make(1.0), mj.AverageEnergy()), mj.Coefficients())
    assert solution.result == mj.DesignResult.failed
    assert "no finite criterion" in solution.stats["status"]
    assert abs(float(solution.coefficients[0]) - 2.0) < 1e-2
    # a feasible design's trace lies above the minimum: mpmath at 80 digits next to c = 2
    m, d, k = make(2 * (1 + 1e-9)).dense()
    _, minimum, _ = mp_truths((m, d, k), T, np.zeros(8), np.zeros(8), [])
    assert minimum < solution.value < minimum * (1 + 1e-5)


def test_the_dense_trace_takes_the_optimiser_to_the_middle_dampers_optimum(close):
    # where the damped modes refuse, the objective's own method=DenseExponential() holds: the
    # search ends at c = 2, the trace at its minimum (mpmath at 80 digits next to c = 2)
    make, _, _ = MIDDLE
    objective = mj.AverageEnergy(method=mj.DenseExponential())
    solution = mj.optimise(mj.DamperDesign(make(1.0), objective), mj.Coefficients())
    assert solution.result == mj.DesignResult.converged
    close(solution.coefficients, [2.0], rtol=1e-6)
    m, d, k = make(2 * (1 + 1e-9)).dense()
    _, minimum, _ = mp_truths((m, d, k), T, np.zeros(8), np.zeros(8), [])
    close(solution.value, minimum, rtol=1e-11)
