"""Sensitivities: Jacobians of scene outputs against central differences, forward against reverse
mode, analytic truths (undamped energy, k/m scaling, amplitude linearity), the chain rule between
Mikota's (m, k) and the chain's mass and spring vectors, and refusals."""

import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj

SMALL = """
[chain]
type = "mikota"
n = 20
[[damper]]
position = 7.3
coefficient = 0.8
[initial]
displacement = {{ 3 = 1.0 }}
[time]
end = 4.0
step = 0.02
{solver}
[reduction]
snapshots = [0.0, 2.0]
rank = 8
[output]
dofs = [10, 15]
"""


@pytest.fixture(scope="module")
def scene():
    return mj.app.load_scene(SMALL.format(solver=""))


def central_differences(function, parameters, name, entry=None, step=1e-4):
    """d function / d parameters[name][entry], step relative to the entry's size."""
    value = np.array(parameters[name], dtype=float)
    flat = value.reshape(-1)
    j = 0 if entry is None else entry
    h = step * max(abs(flat[j]), 1.0)
    shifted = []
    for sign in (1, -1):
        moved = flat.copy()
        moved[j] += sign * h
        shifted.append(np.asarray(function({**parameters,
                                            name: jnp.asarray(moved.reshape(value.shape))})))
    return (shifted[0] - shifted[1]) / (2 * h)


def jacobian_column(result, name, entry=None):
    block = np.asarray(result.jacobian[name])
    out_ndim = np.ndim(result.value)
    if np.ndim(result.parameters[name]) == 0:
        return block
    return block.reshape(block.shape[:out_ndim] + (-1,))[..., 0 if entry is None else entry]


# step of the central differences: the exact energy carries rounding of ~1e-12 relative (so a
# larger step), histories a phase drift t Omega that makes their third derivative large
STEPS = {"energy": 1e-4, "displacement": 1e-6, "phase_error": 1e-6, "singular_values": 1e-6}
# what a linear system must give for the excitation amplitude a (normalised: a dy/da / scale)
LINEARITY = {"energy": 2.0, "displacement": None, "phase_error": 0.0, "singular_values": 1.0}


@pytest.mark.parametrize("output,model,mode", [
    pytest.param("energy", "full", "forward", marks=pytest.mark.slow),  # 30-110 s each
    pytest.param("energy", "reduced", "forward", marks=pytest.mark.slow),
    pytest.param("displacement", "full", "forward", marks=pytest.mark.slow),
    pytest.param("displacement", "reduced", "forward", marks=pytest.mark.slow),
    pytest.param("phase_error", "reduced", "forward", marks=pytest.mark.slow),
    pytest.param("singular_values", "full", "forward", marks=pytest.mark.slow),
    pytest.param("singular_values", "reduced", "forward", marks=pytest.mark.slow)])
def test_jacobian_matches_central_differences(scene, output, model, mode, close):
    """Every parameter against central differences; the amplitude against linearity; "auto"
    picks forward mode for a few parameters (reverse for many: the mass and spring vectors)."""
    count = 5 if output == "singular_values" else None
    result = mj.sensitivities(scene, output, model=model, count=count)
    assert result.mode == mode
    function = mj.SceneFunction(scene, output, model=model, count=count)
    assert set(result.jacobian) == {"m", "k", "positions", "coefficients", "amplitude"}
    for name in result.jacobian:
        exact = jacobian_column(result, name)
        approx = central_differences(function, result.parameters, name, step=STEPS[output])
        scale = max(np.max(np.abs(exact)), 1e-3 * np.max(np.abs(np.asarray(result.value))))
        close(np.max(np.abs(exact - approx)) / scale, 0.0, atol=1e-6, what=f"{output} d/d{name}")
    amplitude = np.asarray(result.normalised["amplitude"])
    if LINEARITY[output] is None:  # a history: dy/da = y, so max|a dy/da| / max|y| = 1
        # rounding of the largest entry, not of each (one entry 1e-3 of the largest was
        # 2.6e-12 off relative once the n = 300 modes came from chain_modes)
        close(result.jacobian["amplitude"], result.value, rtol=1e-12,
              atol=1e-13 * np.max(np.abs(np.asarray(result.value))))
        close(np.max(np.abs(amplitude)), 1.0, rtol=1e-12)
    else:
        close(amplitude, np.full(amplitude.shape, LINEARITY[output]), rtol=1e-10, atol=1e-12)


@pytest.mark.slow  # 17 s; forward and reverse are each checked against differences above
def test_forward_and_reverse_mode_agree(scene, close):
    forward = mj.sensitivities(scene, "displacement", wrt=["k", "positions"], mode="forward")
    reverse = mj.sensitivities(scene, "displacement", wrt=["k", "positions"], mode="reverse")
    assert (forward.mode, reverse.mode) == ("forward", "reverse")
    for name in forward.jacobian:
        close(reverse.jacobian[name], forward.jacobian[name], rtol=1e-11,
              atol=1e-12 * float(np.max(np.abs(forward.jacobian[name]))), what=name)


@pytest.mark.slow  # 27 s; the ODE paths' gradients are also tested in test_gradients_adjoints
def test_integrated_ode_scene_gradients_match_central_differences(close):
    """Dopri8 scenes: the energy by forward mode (diffrax.ForwardMode), a history by reverse."""
    scene = mj.app.load_scene(SMALL.format(solver='[solver]\nmethod = "dopri8"\nrtol = 1e-10\n'
                                              'atol = 1e-12'))
    for output, mode, name in (("energy", "forward", "k"),
                               ("displacement", "reverse", "coefficients")):
        result = mj.sensitivities(scene, output, wrt=[name], mode=mode)
        exact = jacobian_column(result, name)
        approx = central_differences(mj.SceneFunction(scene, output), result.parameters, name)
        close(np.max(np.abs(exact - approx)) / np.max(np.abs(exact)), 0.0, atol=1e-6,
              what=f"{output} d/d{name}")


def test_undamped_energy_sensitivities_are_analytic(close):
    """Undamped free vibration keeps E0 = x0^T K x0 / 2, so J = T E0 grows like k, not with m;
    the displacement depends on k/m only (Omega = sqrt(k/m), eq. 2.4): d/d ln k = -d/d ln m."""
    scene = mj.app.load_scene(SMALL.replace('[[damper]]\nposition = 7.3\ncoefficient = 0.8\n', '')
                          .format(solver=""))
    energy = mj.sensitivities(scene, "energy", wrt=["m", "k"])
    close(energy.normalised["k"], 1.0, rtol=1e-9)
    close(energy.normalised["m"], 0.0, atol=1e-9)
    n = 20  # x0 = e_3: E0 = (k_3 + k_4) / 2 with k_i = n - i + 1, and J = T E0 with T = 4
    close(energy.value, 4.0 * ((n - 2) + (n - 3)) / 2, rtol=1e-10)
    history = mj.sensitivities(scene, "displacement", wrt=["m", "k"])
    scale = float(np.max(np.abs(history.jacobian["k"])))
    close(history.jacobian["k"], -history.jacobian["m"], atol=1e-10 * scale)


@pytest.mark.slow  # 11 s in CI; the chain rule (m from masses)
def test_mikota_scalars_are_the_sum_of_the_vector_sensitivities(scene, close):
    """Chain rule: d/d ln m = sum_i d/d ln m_i for m_i = m / i, likewise for k and the springs."""
    scalars = mj.sensitivities(scene, "energy", wrt=["m", "k"])
    vectors = mj.sensitivities(scene, "energy", wrt=["masses", "springs"])
    assert vectors.mode == "reverse"
    assert vectors.jacobian["masses"].shape == (20,)
    close(np.sum(vectors.normalised["masses"]), scalars.normalised["m"], rtol=1e-10)
    close(np.sum(vectors.normalised["springs"]), scalars.normalised["k"], rtol=1e-10)
    function = mj.SceneFunction(scene, "energy")
    for entry in (0, 6, 19):
        approx = central_differences(function, vectors.parameters, "masses", entry)
        close(vectors.jacobian["masses"][entry], approx, rtol=1e-6,  # the energy's rounding
              atol=1e-6 * float(np.max(np.abs(vectors.jacobian["masses"]))))
    labels = [label for label, _ in vectors.ranking()]
    assert "masses[1]" in labels and "springs[20]" in labels and len(labels) == 40


def test_a_general_chain_offers_masses_and_springs_not_m_and_k():
    scene = mj.app.load_scene({
        "chain": {"type": "custom", "masses": [1.0, 2.0, 1.5], "springs": [3.0, 1.0, 2.0]},
        "initial": {"displacement": {"3": 1.0}}, "time": {"end": 2.0, "step": 0.1}})
    assert set(scene.parameters()) == {"masses", "springs", "amplitude"}
    with pytest.raises(ValueError, match="not Mikota"):
        scene.parameters(wrt=["m"])
    with pytest.raises(ValueError, match="scene must be a Scene .* got SecondOrderSystem"):
        mj.sensitivities(scene.system, "energy")  # one line, not an AttributeError


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_evaluating_at_other_parameters_changes_the_value(scene, close):
    nominal = mj.sensitivities(scene, "energy", wrt=["coefficients"])
    moved = mj.sensitivities(scene, "energy", wrt=["coefficients"],
                             parameters={"coefficients": jnp.asarray([2.0])})
    direct = mj.SceneFunction(scene, "energy")({"coefficients": jnp.asarray([2.0])})
    close(moved.value, direct, rtol=1e-13)
    assert abs(float(moved.value) - float(nominal.value)) > 1e-3


@pytest.mark.parametrize("kwargs,match", [
    (dict(wrt=["mass"]), "unknown parameter"),
    (dict(wrt=["m", "masses"]), "not both"),
    (dict(wrt=["relative_coefficients"]), "no such damper"),
    (dict(mode="sideways"), "mode must be"),
    (dict(output="acceleration"), "output must be"),
    (dict(model="tiny"), "model must be"),
    (dict(output="singular_values", count=400), "count must be"),
    (dict(output="energy", count=3), "count applies"),
    (dict(parameters={"k": jnp.ones(3)}), "shape"),
    (dict(parameters={"springs": jnp.ones(20)}), "not among"),
])
def test_bad_requests_are_refused_by_name(scene, kwargs, match):
    output = kwargs.pop("output", "energy")
    with pytest.raises(ValueError, match=match):
        mj.sensitivities(scene, output, **kwargs)


def test_repeated_singular_values_have_no_derivative():
    """First-mode excitation: the snapshot matrix has rank 1 (Section 4), sigma_2 vanishes."""
    scene = mj.app.load_scene({"chain": {"n": 10}, "initial": {"displacement": "mode 1"},
                           "time": {"end": 2.0, "step": 0.1}})
    assert float(mj.sensitivities(scene, "singular_values", count=1).value[0]) > 0
    with pytest.raises(ValueError, match="repeated or vanishing"):
        mj.sensitivities(scene, "singular_values", count=2)


def test_phase_error_and_reduced_model_need_a_reduction():
    scene = mj.app.load_scene({"chain": {"n": 10}, "initial": {"displacement": {"3": 1.0}},
                           "time": {"end": 2.0, "step": 0.1}})
    for kwargs in (dict(output="phase_error"), dict(model="reduced")):
        with pytest.raises(ValueError, match=r"\[reduction\]"):
            mj.SceneFunction(scene, **kwargs)
