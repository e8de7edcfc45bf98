"""The paper reproduced end to end: ``python -m mikota_jax reproduce`` as a user runs it.

One run (about 30 s) serves every assertion: its exit code, its figures and the numbers in
``reproduce.json``, each checked against the value Weber & Zastrau (2018) print.
"""

import json
import os
import subprocess
import sys

import pytest


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    cache = tmp_path_factory.mktemp("xla_cache")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", MIKOTA_JAX_CACHE="1",
               MIKOTA_JAX_CACHE_DIR=str(cache))
    done = subprocess.run([sys.executable, "-m", "mikota_jax", "reproduce", "--out", str(out)],
                          capture_output=True, text=True, env=env, timeout=600)
    data = json.loads((out / "reproduce.json").read_text())
    rows = {row["quantity"]: row for row in data["rows"]}
    return done, out, data, rows, cache


def row(rows, start):
    (match,) = [r for q, r in rows.items() if q.startswith(start)]
    return match


def test_reproduce_exits_zero_and_prints_the_table(report):
    done, _, data, _, _ = report
    assert done.returncode == 0, done.stderr[-2000:]
    assert data["missed"] == 0 and "sigma_77 / sigma_max" in done.stdout


def test_reproduce_writes_figures_2_to_9(report):
    _, out, _, _, _ = report
    names = sorted(p.name for p in out.glob("fig*.png"))
    assert [name.split("_")[0] for name in names] == [f"fig{k}" for k in range(2, 10)]
    assert all((out / name).read_bytes()[:4] == b"\x89PNG" for name in names)


def test_eigenfrequencies_and_mode_shapes_are_exact(report):
    rows = report[3]
    assert row(rows, "Omega_l = l*Omega, l = 1..300")["value"] < 1e-10
    for l in (1, 2, 3):
        assert row(rows, f"mode shape u_{l}")["value"] < 1e-12
    assert row(rows, "U^T U tridiagonal")["value"] < 1e-13


def test_first_mode_excitation_has_one_singular_value_and_pom_1_is_mode_1(report):
    rows = report[3]
    assert row(rows, "sigma_k>1 / sigma_1")["value"] < 1e-14
    assert row(rows, "POM 1 = mode shape 1")["value"] < 1e-12


def test_impulse_zero_instants_hold_at_the_pulse_centre_and_in_the_dirac_limit(report):
    rows = report[3]
    assert row(rows, "x_i = 0 for all i, at t = j*pi + delta_f/2")["value"] < 1e-12
    assert row(rows, "x_i = 0 for all i, at t = j*pi, as printed")["value"] > 0.05
    assert row(rows, "Dirac limit: x = 0")["value"] < 1e-12
    assert row(rows, "Dirac limit: v = v(0)")["value"] < 1e-12


def test_section_5_ranks_and_singular_value_ratios_match_the_paper(report):
    rows = report[3]
    assert row(rows, "n_red at 99.00% pseudo-energy")["value"] == 76
    assert row(rows, "n_red at 99.99% pseudo-energy")["value"] == 98
    assert row(rows, "n_red at 99.00%, sum of squares")["value"] == 54
    assert round(row(rows, "sigma_77 / sigma_max")["value"], 4) == 0.0184
    assert round(row(rows, "sigma_99 / sigma_max")["value"], 5) == 0.00024
    total = row(rows, "E_pseudo printed as 977.5528^2")
    assert total["status"] == "not reproduced" and abs(total["value"] / 977.5528 - 1) < 1e-4


def test_section_5_reduced_models_follow_the_full_one_as_in_figs_8_and_9(report):
    rows = report[3]
    assert row(rows, "Fig. 8")["value"] < 0.1
    assert row(rows, "Fig. 9")["value"] < 0.005
    for rank in (76, 98):
        phase = row(rows, f"Delta E_phase, n_red = {rank}")
        assert phase["status"] == "not reproduced" and "closest" in phase["reading"]
    assert row(rows, "Delta E_phase, n_red = 98")["value"] < row(rows, "Delta E_phase, n_red = 76")[
        "value"]


def test_reproduce_stores_its_compiled_solves_in_the_persistent_cache(report):
    # an executable holding a host callback (a raising check inside jit) is never stored
    _, _, _, _, cache = report
    entries = list(cache.iterdir())
    assert len(entries) > 20, entries
