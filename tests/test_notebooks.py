"""Every notebook in notebooks/ executes end to end at its small size
(``MIKOTA_NOTEBOOK_SIZE=small``) and at its full size, both under ``-m slow`` (the default run
tests what they call, module by module), and is
stored with its outputs stripped; the docs site's executed page (``docs/examples/NAME.md``,
written by ``docs/execute_notebooks.py``) holds the same code, a figure and no traceback."""

import json
import os
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

ROOT = Path(__file__).parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
# the file each notebook writes into MIKOTA_NOTEBOOK_OUT when it has run to the end
OUTPUTS = {"paper_reproduction.ipynb": "reproduce.json", "damper_placement.ipynb": "placement.json",
           "sensitivity_study.ipynb": "sensitivity.json",
           "custom_systems.ipynb": "custom_systems.json", "multi_damper.ipynb": "multi_damper.json",
           "reduced_damper_design.ipynb": "reduced_damper_design.json"}


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_is_stored_without_outputs(path):
    cells = json.loads(path.read_text())["cells"]
    assert all(not cell.get("outputs") for cell in cells if cell["cell_type"] == "code")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_the_docs_copy_is_this_notebook_executed(path):
    # a notebook edited without re-running docs/execute_notebooks.py shows stale outputs
    page = (ROOT / "docs" / "examples" / f"{path.stem}.md").read_text()
    code = [c for c in json.loads(path.read_text())["cells"] if c["cell_type"] == "code"]
    assert all("".join(c["source"]).strip() in page for c in code)
    assert f"]({path.stem}_files/" in page  # a figure
    assert "Traceback (most recent call last)" not in page


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_cells_have_ids(path):
    # nbformat 4.5: a cell without an id is a warning on reading (an error under this suite)
    notebook = json.loads(path.read_text())
    assert (notebook["nbformat"], notebook["nbformat_minor"]) >= (4, 5)
    assert all("id" in cell for cell in notebook["cells"])


# paper_reproduction has one size (the paper's): its one computation, ``mj.app.reproduce``, is what
# tests/test_paper.py runs in the default run, so the notebook runs once, under -m slow (43 s).
# Two small runs go under -m slow beside their full ones, for the 15-minute budget (the default
# run was 919-931 s with them; 885 s without damper_placement's, ~4 % slower on CI), each where
# the default run tests what it calls: damper_placement (139 s: ScreenAndCertify for one and two
# dampers, the split search, the certification's enrichment, Grid full and
# reduced through the CLI: tests/test_optimise.py) and custom_systems (100 s: Matrix
# Market files, branched chains, Rayleigh and modal damping, mj.system: tests/test_io.py,
# test_systems.py, test_scene_systems.py, test_viscosity.py). The other two small runs went the
# same way when the default run grew past 25 min on CI (140-170 s each there): multi_damper
# (CoordinateDescent, Coefficients and the published examples: tests/test_damper_search.py,
# test_viscosity.py) and sensitivity_study (sensitivities, grid, sweep: tests/test_sensitivity.py,
# test_sweep.py, and docs/sensitivities.md's blocks under -m slow).
ONE_SIZE = {"paper_reproduction.ipynb"}
# reduced_damper_design (70 s small) likewise: tests/test_structured_h2.py runs what it calls
SLOW_SMALL = ONE_SIZE | {"damper_placement.ipynb", "custom_systems.ipynb", "multi_damper.ipynb",
                         "sensitivity_study.ipynb", "reduced_damper_design.ipynb"}
RUNS = [pytest.param(path, "small", id=f"{path.name}-small",
                     marks=[pytest.mark.slow] if path.name in SLOW_SMALL else [])
        for path in NOTEBOOKS] + [pytest.param(path, "full", id=f"{path.name}-full",
                                               marks=pytest.mark.slow)
                                  for path in NOTEBOOKS if path.name not in ONE_SIZE]


@pytest.mark.parametrize(("path", "size"), RUNS)
def test_notebook_executes(path, size, tmp_path, monkeypatch):
    # the default run executes every notebook at its small size, -m slow at the size it ships
    # with; the kernel inherits conftest's XLA_FLAGS (no LLVM optimisation passes: at these
    # sizes compiling is most of the wall time)
    monkeypatch.setenv("MIKOTA_NOTEBOOK_OUT", str(tmp_path / "out"))
    monkeypatch.setenv("MIKOTA_NOTEBOOK_SIZE", size)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    notebook = nbformat.read(path, as_version=4)
    NotebookClient(notebook, timeout=600 if size == "small" else 1800, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()
    errors = [o for c in notebook.cells for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors
    assert (tmp_path / "out" / OUTPUTS[path.name]).exists()
    assert os.environ["MIKOTA_NOTEBOOK_OUT"] == str(tmp_path / "out")
