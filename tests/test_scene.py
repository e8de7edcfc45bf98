"""Scenes: TOML validation (one clear error per bad key); run_scene computes only what is asked."""

import json
import re

import numpy as np
import pytest

import mikota_jax as mj
from mikota_jax._rom.pod import rank_for_energy
from mikota_jax._scenes.scene import QUANTITIES
from mikota_jax.app import result_dict, write_json
from mikota_jax.app.results import HISTORIES, OUTPUTS

SMALL = """
[chain]
type = "mikota"
n = 12

[[damper]]
type = "grounded"
position = 4.5
coefficient = 0.5

[initial]
displacement = { 3 = 1.0 }

[time]
end = 4.0
step = 0.05
"""


def scene_text(**tables: str) -> str:
    return SMALL + "\n".join(f"\n[{name}]\n{body}" for name, body in tables.items())


def test_paper_scenes_load_with_the_papers_parameters():
    s5 = mj.app.load_scene("section5_damped")
    assert s5.size == 300 and s5.ts.shape == (2001,) and float(s5.ts[-1]) == pytest.approx(20.0)
    np.testing.assert_allclose(np.asarray(s5.system.mass.diagonal)[[0, 6, 299]],
                               [1.0, 1 / 7, 1 / 300])
    assert float(s5.system.damping.positions[0]) == 7.0
    assert float(s5.x0[2]) == 1.0 and float(np.abs(s5.x0).sum()) == 1.0
    assert s5.reduction.window == (0.0, 10.0) and s5.reduction.criterion == "paper"
    impulse = mj.app.load_scene("section4_impulse")
    assert float(impulse.load.duration) == 0.05 and impulse.system.damping is None
    first = mj.app.load_scene("section4_first_mode")
    np.testing.assert_allclose(np.asarray(first.x0), np.arange(1, 11) / 10, rtol=1e-15)


def test_a_fractional_damper_and_a_relative_damper_are_parsed(tmp_path):
    text = SMALL + '\n[[damper]]\ntype = "relative"\ndofs = [2, 9]\ncoefficient = 0.25\n'
    scene = mj.app.load_scene(text)
    d = np.asarray(scene.system.damping.as_matrix())
    assert d[3, 3] == pytest.approx(0.25) and d[4, 4] == pytest.approx(0.25)
    assert d[1, 8] == pytest.approx(-0.25) and d[8, 8] == pytest.approx(0.25)


def test_an_undamped_scene_builds_no_damping_matrix():
    text = SMALL.replace('[[damper]]\ntype = "grounded"\nposition = 4.5\ncoefficient = 0.5\n', "")
    assert mj.app.load_scene(text).system.damping is None


@pytest.mark.parametrize("text, match", [
    (SMALL + "\n[chain2]\n", r"unknown top-level key"),
    (SMALL.replace("n = 12", "n = 12\nstiffness = 2"), r"\[chain\].*unknown key.*stiffness"),
    (SMALL.replace("n = 12", "n = 0"), r"\[chain\] n.*>= 1"),
    (SMALL.replace("n = 12", 'n = "twelve"'), r"\[chain\] n.*integer"),
    (SMALL.replace('type = "mikota"', 'type = "spring"'), r"\[chain\] type.*one of"),
    (SMALL.replace("position = 4.5", "position = 13"), r"position.*<= 12"),
    (SMALL.replace("position = 4.5", "position = 0.5"), r"position.*>= 1"),
    (SMALL.replace("coefficient = 0.5", "coefficient = -1.0"), r"coefficient.*>= 0"),
    (SMALL.replace("displacement = { 3 = 1.0 }", "displacement = { 13 = 1.0 }"),
     r"\[initial\] displacement.*1\.\.12"),
    (SMALL.replace("displacement = { 3 = 1.0 }", 'displacement = "mode 13"'), r"mode.*1\.\.12"),
    (SMALL.replace("end = 4.0", "end = -1.0"), r"\[time\] end.*greater than start"),
    (SMALL.replace("step = 0.05", "step = 0.0"), r"\[time\] step.*> 0"),
    (SMALL.replace("step = 0.05", "step = 0.03"), r"\[time\] step.*whole steps"),
    (scene_text(reduction="energy = 1.5"), r"\[reduction\] energy.*<= 1"),
    (scene_text(reduction="energy = 0.9\nrank = 3"), r"exactly one of energy"),
    (scene_text(reduction="rank = 13"), r"\[reduction\] rank.*<= 12"),
    (scene_text(reduction="rank = 2", output='quantities = ["speed"]'), r"\[output\] quantities"),
    (scene_text(output='quantities = ["rank"]'), r"need a \[reduction\]"),
    (scene_text(solver='method = "euler"'), r"\[solver\] method.*one of"),
    (scene_text(load='type = "pulse"\ndof = 1\nduration = 0.0'), r"\[load\] duration.*> 0"),
    ("this is = not toml [", r"not valid TOML"),
    # sizes refused from the scene, with the numbers, before anything is allocated (issue 18)
    (SMALL.replace("end = 4.0", "end = 1e9").replace("step = 0.05", "step = 0.001"),
     r"\[time\] step.*1e\+12 output times.*at most 1e\+08"),
    (SMALL.replace("step = 0.05", "step = 1e-300"), r"\[time\] step.*at most 1e\+08"),
    (SMALL.replace("n = 12", "n = 1_000_000_000"), r"\[chain\] n.*GiB.*available"),
])
def test_bad_scene_input_names_the_key(text, match):
    with pytest.raises(ValueError, match=match):
        mj.app.load_scene(text)


def test_a_missing_scene_file_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        mj.app.load_scene(tmp_path / "nope.toml")
    with pytest.raises(ValueError, match="is a directory, not a TOML file"):
        mj.app.load_scene(tmp_path)
    (tmp_path / "latin1.toml").write_bytes(b"name = \"caf\xe9\"\n")
    with pytest.raises(ValueError, match="latin1.toml.*is not UTF-8 text"):
        mj.app.load_scene(tmp_path / "latin1.toml")


def test_a_scene_file_with_a_byte_order_mark_loads_and_a_broken_one_names_the_file(tmp_path):
    bom = "\ufeff".encode()  # UTF-8's byte-order mark, which Windows editors write
    (tmp_path / "marked.toml").write_bytes(bom + SMALL.encode())
    plain = mj.app.load_scene(SMALL)
    marked = mj.app.load_scene(tmp_path / "marked.toml")
    assert marked.name == "marked" and marked.system.size == plain.system.size == 12
    assert mj.app.load_scene("\ufeff" + SMALL).system.size == 12  # text that kept the mark
    (tmp_path / "broken.toml").write_bytes(bom + b"[chain\n")
    path = str(tmp_path / "broken.toml")
    with pytest.raises(ValueError, match=rf"^mikota_jax: scene file {re.escape(repr(path))} is "
                       r"not valid TOML: .*\(at line 1, column 7\)$"):
        mj.app.load_scene(path)
    with pytest.raises(ValueError, match=r"^mikota_jax: scene text is not valid TOML"):
        mj.app.load_scene("this is = not toml [")


def test_a_scene_path_with_an_equals_sign_is_a_path(tmp_path):
    folder = tmp_path / "a=b"
    folder.mkdir()
    (folder / "scene.toml").write_text(scene_text(output="dofs = [2]"))
    scene = mj.app.load_scene(str(folder / "scene.toml"))
    assert scene.output.dofs == (2,) and scene.name == "scene"


def test_a_scene_without_reduction_or_velocity_computes_neither():
    scene = mj.app.load_scene(scene_text(output="dofs = [2, 5]"))
    result = mj.run_scene(scene)
    assert isinstance(result, mj.SceneResult)
    full = result.full
    assert full.velocity is None and full.dofs == (2, 5) and result.dofs == (2, 5)
    assert result.model is None and result.reduced is None and result.metrics == {}
    data = result_dict(result)
    assert set(data["full"]) == {"displacement"} and "reduced" not in data
    assert "singular_values" not in data
    reference = mj.solve(scene.system, scene.ts, scene.x0, dofs=[2, 5], method=mj.Spectral())
    np.testing.assert_allclose(data["full"]["displacement"]["5"],
                               np.asarray(reference.displacement)[:, 1], rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.asarray(full.displacement), np.asarray(reference.displacement),
                               rtol=0, atol=1e-14)


def test_a_reduced_scene_reports_rank_singular_values_and_phase_error():
    scene = mj.app.load_scene(scene_text(
        reduction="snapshots = [0.0, 2.0]\nenergy = 0.999",
        output='dofs = [12]\nquantities = ["displacement", "velocity", "rank", '
               '"singular_values", "phase_error", "relative_error"]\nphase_error = "sum"'))
    result = mj.run_scene(scene)
    assert result.model.stats.snapshots == 41  # t = 0, 0.05, ..., 2.0
    s = np.asarray(result.model.stats.singular_values)
    assert result.rank == rank_for_energy(s, 0.999) and 1 <= result.rank < 12
    full, reduced = result.full, result.reduced
    expected = mj.metrics.phase_error(full.displacement, full.velocity, reduced.displacement,
                              reduced.velocity, aggregate="sum")
    phase = float(result.metrics["phase_error"])
    assert phase == pytest.approx(float(expected), rel=1e-12)
    assert 0 < phase < 0.2
    data = result_dict(result)  # the layout of results.json
    assert data["rank"] == result.rank and data["phase_error"] == phase
    assert data["phase_error_aggregate"] == "sum"
    assert data["relative_error"] == float(result.metrics["relative_error"])
    np.testing.assert_array_equal(data["singular_values"], s)
    assert set(data["full"]) == set(data["reduced"]) == {"displacement", "velocity"}
    assert list(data["reduced"]["velocity"]) == ["12"]


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_a_diffrax_scene_matches_the_exact_scene():
    exact = mj.run_scene(mj.app.load_scene(scene_text(output="dofs = [1, 12]")))
    dopri = mj.run_scene(mj.app.load_scene(scene_text(
        output="dofs = [1, 12]", solver='method = "dopri8"\nrtol = 1e-11\natol = 1e-13')))
    assert exact.full.dofs == dopri.full.dofs == (1, 12)
    np.testing.assert_allclose(np.asarray(dopri.full.displacement),
                               np.asarray(exact.full.displacement), rtol=0, atol=1e-8)
    assert result_dict(dopri)["meta"]["solver"] == {"method": "dopri8", "rtol": 1e-11,
                                                    "atol": 1e-13, "max_steps": 100_000}


def test_every_output_quantity_has_one_place_in_results_json():
    assert set(HISTORIES).isdisjoint(OUTPUTS) and set(HISTORIES) | set(OUTPUTS) == set(QUANTITIES)


def test_a_rank_above_the_numerical_rank_of_the_snapshots_is_refused():
    damper = '[[damper]]\ntype = "grounded"\nposition = 4.5\ncoefficient = 0.5\n'
    undamped = SMALL.replace(damper, "")
    text = undamped.replace("displacement = { 3 = 1.0 }", 'displacement = "mode 2"')
    scene = mj.app.load_scene(text + "\n[reduction]\nrank = 3\n")
    with pytest.raises(ValueError, match=r"rank = 3 exceeds the numerical rank 1"):
        mj.run_scene(scene)


def test_results_json_is_written_whole_or_not_at_all(tmp_path):
    path = tmp_path / "out" / "results.json"
    write_json({"a": [1.0, 2.0], "_arrays": object()}, path)
    assert json.loads(path.read_text()) == {"a": [1.0, 2.0]}
    with pytest.raises(ValueError):
        write_json({"a": float("nan")}, tmp_path / "bad.json")
    assert not (tmp_path / "bad.json").exists() and not list(tmp_path.glob("*.tmp"))
