"""The command line: ``run`` writes results.json and figures; bad input: one line, exit code 2."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sl

import mikota_jax as mj
from mikota_jax.app.cli import main

SCENE = """
[chain]
type = "custom"
masses = [1.0, 0.5, 0.5, 0.25, 0.2, 0.2]
springs = [6.0, 5.0, 4.0, 3.0, 2.0, 1.0]

[[damper]]
type = "relative"
dofs = [2, 5]
coefficient = 0.3

[initial]
velocity = { 6 = 1.0 }

[time]
end = 3.0
step = 0.1

[reduction]
snapshots = [0.0, 3.0]
rank = 3

[output]
dofs = [1, 6]
quantities = ["displacement", "rank", "singular_values", "phase_error"]
figures = true
"""


def test_run_writes_the_requested_results_and_figures(tmp_path, capsys):
    scene = tmp_path / "chain.toml"
    scene.write_text(SCENE)
    assert main(["run", str(scene), "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "results.json").read_text())
    assert len(result["times"]) == 31 and result["rank"] == 3
    assert set(result["full"]) == {"displacement"} == set(result["reduced"])
    assert set(result["full"]["displacement"]) == {"1", "6"}
    assert len(result["singular_values"]) == 6
    assert 0 < result["phase_error"] < 1
    assert result["meta"]["x64"] is True and result["meta"]["solver"]["method"] == "spectral"
    for name in result["figures"]:
        assert (tmp_path / "out" / name).read_bytes()[:4] == b"\x89PNG"
    # a summary a person can read: the system, the POD rank, the metric as in the JSON, the files
    printed = capsys.readouterr().out
    assert "n = 6 DOFs" in printed and "at 31 times" in printed and ": r = 3 (rank 3)" in printed
    assert f"phase error: {result['phase_error']:.6g}" in printed
    assert "results.json" in printed and all(name in printed for name in result["figures"])
    # --quiet: the same files, nothing on stdout
    assert main(["run", str(scene), "--out", str(tmp_path / "quiet"), "--quiet"]) == 0
    assert capsys.readouterr().out == "" and (tmp_path / "quiet" / "results.json").exists()


def test_bad_input_is_one_line_on_stderr_with_exit_code_2(tmp_path, capsys):
    scene = tmp_path / "bad.toml"
    scene.write_text(SCENE.replace("coefficient = 0.3", "coefficient = -0.3"))
    assert main(["run", str(scene), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "coefficient" in err and ">= 0" in err
    assert not (tmp_path / "out" / "results.json").exists()


def test_a_failing_run_writes_no_partial_results(tmp_path, capsys):
    scene = tmp_path / "rank.toml"
    scene.write_text(SCENE.replace('velocity = { 6 = 1.0 }', '').replace(
        "[reduction]", "[reduction]\nquantity = \"velocity\"").replace(
        "[[damper]]\ntype = \"relative\"\ndofs = [2, 5]\ncoefficient = 0.3\n", ""))
    # Zero initial state: every snapshot is zero, so no rank is available.
    assert main(["run", str(scene), "--out", str(tmp_path / "out")]) == 2
    assert "rank" in capsys.readouterr().err
    assert not (tmp_path / "out" / "results.json").exists()


def test_the_module_entry_point_prints_no_traceback(tmp_path):
    scene = tmp_path / "bad.toml"
    scene.write_text(SCENE.replace("[time]", "[time]\nfinish = 3.0"))
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-m", "mikota_jax", "run", str(scene), "--out",
                           str(tmp_path / "out")], capture_output=True, text=True, env=env,
                          timeout=300)
    assert done.returncode == 2
    assert "Traceback" not in done.stderr and "[time]" in done.stderr and "finish" in done.stderr
    assert done.stderr.strip().count("\n") == 0


@pytest.mark.parametrize("argv", [["run"], ["frobnicate"]])
def test_usage_errors_exit_with_code_2(argv):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2


def test_help_is_plain_text_without_rest_markup(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--help"])
    text = capsys.readouterr().out
    assert stop.value.code == 0 and "python -m mikota_jax reproduce" in text
    assert "``" not in text


def test_help_loads_no_jax_and_run_help_lists_the_packaged_scenes():
    # the help needs argparse and the scene folder's listing, nothing that computes
    code = ("import sys, runpy\n"
            "sys.argv = ['mikota_jax', 'run', '--help']\n"
            "try:\n"
            "    runpy.run_module('mikota_jax', run_name='__main__')\n"
            "except SystemExit:\n"
            "    pass\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('jax', 'diffrax')))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300, check=True)
    assert "section4_first_mode, section4_impulse, section5_damped" in done.stdout
    assert done.stdout.strip().splitlines()[-1] == "[]"


def test_results_json_respects_the_umask(tmp_path):
    from mikota_jax.app.results import write_json

    old = os.umask(0o022)
    try:
        path = write_json({"a": 1.0}, tmp_path / "out" / "results.json")
    finally:
        os.umask(old)
    assert (path.stat().st_mode & 0o777) == 0o644  # not mkstemp's 0600


def test_an_unusable_out_or_cache_folder_is_one_line_before_any_work(tmp_path, capsys,
                                                                     monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    monkeypatch.setenv("MIKOTA_JAX_CACHE", "1")
    monkeypatch.setenv("MIKOTA_JAX_CACHE_DIR", str(blocker))  # the cache cannot live there
    assert main(["run", "section5_damped", "--out", str(blocker)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2, err
    assert err[0].startswith("warning: no compilation cache") and "is not a folder" in err[0]
    assert err[1] == f"error: mikota_jax: --out {str(blocker)!r} exists and is not a folder."


def test_ctrl_c_stops_a_long_run_within_seconds_and_writes_nothing(tmp_path):
    import signal
    import time

    scene = tmp_path / "long.toml"  # a Dopri8 run of half a minute or more
    scene.write_text('[chain]\ntype = "mikota"\nn = 5000\n\n[[damper]]\ntype = "grounded"\n'
                     "position = 7\ncoefficient = 1.0\n\n[initial]\ndisplacement = { 3 = 1.0 }"
                     '\n\n[time]\nend = 40.0\nstep = 0.01\n\n[solver]\nmethod = "dopri8"\n')
    env = dict(os.environ, MIKOTA_JAX_CACHE="0", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-m", "mikota_jax", "run", str(scene), "--out",
                             str(tmp_path / "out")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
    time.sleep(10)  # imported, compiling or solving
    assert proc.poll() is None, proc.communicate()
    start = time.monotonic()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert time.monotonic() - start < 5, err
    assert proc.returncode == 130 and "interrupted" in err and "Traceback" not in err, err
    assert not (tmp_path / "out" / "results.json").exists()



def test_the_console_script_and_python_m_share_one_interrupt_handler_installed_first(
        tmp_path, capsys, monkeypatch):
    import builtins
    import tomllib

    import mikota_jax.__main__ as as_module
    from mikota_jax.app import cli

    root = Path(mj.__file__).parent.parent
    scripts = tomllib.loads((root / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts == {"mikota-jax": "mikota_jax.app.cli:main"}
    assert as_module.main is cli.main  # python -m runs the console script's function
    events = []
    monkeypatch.setattr(cli, "exit_on_interrupt", lambda: events.append("handler"))
    real_import = builtins.__import__

    def interrupted_import(name, *args, **kwargs):  # Ctrl-C while main imports the heavy part
        if name == "reproduction":
            events.append("import")
            raise KeyboardInterrupt
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", interrupted_import)
    monkeypatch.setattr(sys, "argv", ["mikota-jax", "reproduce", "--out", str(tmp_path)])
    assert main() == 130
    assert events == ["handler", "import"]  # installed before the import
    assert capsys.readouterr().err == "interrupted: stopped, nothing more written\n"
    assert main(["reproduce", "--out", str(tmp_path)]) == 130  # in-process: no handler, one line
    assert events == ["handler", "import", "import"]


@pytest.mark.parametrize("command", ["python -m", "console script"])
def test_ctrl_c_while_the_command_line_imports_jax_is_one_line(tmp_path, command):
    import signal

    if command == "python -m":
        argv = [sys.executable, "-m", "mikota_jax"]
    else:
        argv = [str(Path(sys.executable).parent / "mikota-jax")]
        if not Path(argv[0]).exists():
            pytest.skip("the console script is not installed (pip install -e .)")
    # Python reports each import on stderr as it ends: once a jax module has been reported,
    # jax itself is still importing (the package imports it before anything else runs)
    env = dict(os.environ, MIKOTA_JAX_CACHE="0", OPENBLAS_NUM_THREADS="1",
               PYTHONPROFILEIMPORTTIME="1")
    proc = subprocess.Popen([*argv, "run", "section5_damped", "--out", str(tmp_path / "out")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    for line in proc.stderr:
        if line.split("|")[-1].strip() == "jax._src.config":
            break
    else:
        raise AssertionError("jax was never imported")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    lines = [line for line in err.splitlines() if not line.startswith("import time:")]
    assert proc.returncode == 130 and lines == ["interrupted: stopped, nothing more written"], err


def test_the_scene_size_that_picks_the_compile_level_is_read_past_a_byte_order_mark(tmp_path):
    from mikota_jax.app.cli import _scene_size

    scene = tmp_path / "marked.toml"
    scene.write_bytes("\ufeff".encode() + SCENE.encode())
    assert _scene_size(str(scene)) == 6


@pytest.mark.parametrize("given, expected", [
    ("", "--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false"),
    ("--xla_backend_optimization_level=2",
     "--xla_backend_optimization_level=2 --xla_cpu_use_fusion_emitters=false"),
    ("--xla_cpu_use_fusion_emitters=true",
     "--xla_cpu_use_fusion_emitters=true --xla_backend_optimization_level=0"),
])
def test_run_on_a_small_scene_compiles_fast_unless_the_user_chose_the_flags(
        monkeypatch, given, expected):
    from types import SimpleNamespace

    from mikota_jax.app import cli

    monkeypatch.setattr(cli, "_knows_emitters_flag", lambda: True)
    monkeypatch.setenv("XLA_FLAGS", given)
    cli._compile_level(SimpleNamespace(command="run", scene=SCENE))  # 6 DOFs
    assert os.environ["XLA_FLAGS"] == expected
    large = ('[chain]\ntype = "mikota"\nn = 1001\n'
             + SCENE[SCENE.index("[[damper]]"):].replace("dofs = [2, 5]", "dofs = [2, 500]"))
    assert cli._scene_size(large) == 1001
    monkeypatch.setenv("XLA_FLAGS", given)
    cli._compile_level(SimpleNamespace(command="run", scene=large))
    assert os.environ["XLA_FLAGS"] == given


FULL_ORDER_SCENE = """
[chain]
type = "mikota"
n = 12

[[damper]]
type = "grounded"
position = 4
coefficient = 1.0

[[damper]]
type = "relative"
dofs = [2, 9]
coefficient = 1.0

[initial]
displacement = { 3 = 1.0 }

[time]
end = 20.0
step = 0.1
"""


@pytest.mark.slow  # default-run time (issue: CI under 15 min)
def test_optimise_at_full_order_frees_the_relative_damper_and_takes_the_h2_criterion(
        tmp_path, capsys, close):
    scene = tmp_path / "two.toml"
    scene.write_text(FULL_ORDER_SCENE)
    out = tmp_path / "out"
    assert main(["optimise", str(scene), "--out", str(out), "--search", "viscosities",
                 "--objective", "h2", "--output-dofs", "12", "--input-dofs", "12",
                 "--no-progress"]) == 0
    report = json.loads((out / "placement.json").read_text())
    result = report["result"]
    assert result["converged"] and result["relative_gradient"] < 1e-6
    assert result["pairs"] == [[2, 9]] and (out / report["figure"]).exists()
    assert "relative pairs [[2, 9]]" in capsys.readouterr().out
    # independent: scipy's dense controllability Gramian at the reported coefficients
    grounded, relative = result["coefficients"]
    system = mj.mikota_chain(12, dampers=[mj.GroundedDamper(4, grounded),
                                          mj.RelativeDamper((2, 9), relative)])
    m, d, k = (np.asarray(a) for a in system.dense())
    minv = np.diag(1 / np.diag(m))
    a = np.block([[np.zeros((12, 12)), np.eye(12)], [-minv @ k, -minv @ d]])
    b = np.concatenate([np.zeros(12), minv[:, 11]])[:, None]
    gramian = sl.solve_continuous_lyapunov(a, -b @ b.T)
    close(result["value"], np.sqrt(gramian[11, 11]), rtol=1e-8)
    # and the optimum is one: a step either way in either coefficient is no lower
    for i in range(2):
        for step in (0.98, 1.02):
            moved = np.array(result["coefficients"])
            moved[i] *= step
            system = mj.mikota_chain(12, dampers=[mj.GroundedDamper(4, moved[0]),
                                                  mj.RelativeDamper((2, 9), moved[1])])
            assert float(mj.H2Norm(np.eye(12)[:, 11:], np.eye(12)[11:])(system)) >= (
                result["value"] * (1 - 1e-12))


@pytest.mark.slow  # ~60 s of compiles (two screens, the criterion); the refusal runs by default
def test_optimise_places_moves_the_relative_damper_over_candidate_pairs(tmp_path, capsys,
                                                                         close):
    scene = tmp_path / "two.toml"
    scene.write_text(FULL_ORDER_SCENE)
    out = tmp_path / "out"
    assert main(["optimise", str(scene), "--out", str(out), "--search", "places",
                 "--objective", "average_energy", "--lowest", "5", "--candidates", "4",
                 "--pair-candidates", "2-9,1-12,5-6", "--method", "spg", "--no-progress"]) == 0
    result = json.loads((out / "placement.json").read_text())["result"]
    # every candidate pair with both coefficients optimised: the search returns the best
    best = min((mj.optimise(mj.DamperDesign(mj.mikota_chain(12, dampers=[
        mj.GroundedDamper(4, 1.0), mj.RelativeDamper(pair, 1.0)]), mj.AverageEnergy(5)),
        mj.Coefficients()).value, pair) for pair in [(2, 9), (1, 12), (5, 6)])
    assert sorted(result["pairs"][0]) == sorted(best[1])
    close(result["value"], best[0], rtol=1e-9)
    assert "relative pairs" in capsys.readouterr().out


@pytest.mark.parametrize(("argv", "match"), [
    (["--search", "places", "--pair-candidates", "1-13"], "pairs must be"),
    (["--objective", "h2"], "needs a full-order search"),
    (["--search", "viscosities", "--objective", "output"], "needs output_dofs"),
    (["--search", "places", "--objective", "h2", "--output-dofs", "3"], "needs input_dofs"),
    (["--search", "places", "--objective", "output", "--output-dofs", "13"],
     "output_dofs must be distinct DOFs in 1..12"),
])
def test_full_order_optimise_refuses_missing_or_bad_dofs_in_one_line(tmp_path, capsys, argv,
                                                                      match):
    scene = tmp_path / "two.toml"
    scene.write_text(FULL_ORDER_SCENE)
    assert main(["optimise", str(scene), "--out", str(tmp_path / "out"), *argv]) == 2
    err = capsys.readouterr().err
    assert match in err and len(err.strip().splitlines()) == 1
