"""Execute every notebook in notebooks/ at the size it ships with and store it, rendered with its
outputs, as docs/examples/NAME.md plus its figures in docs/examples/NAME_files/ (what the docs
site shows; no notebook with outputs is committed, and the docs build executes nothing).

``tests/test_notebooks.py`` checks that each page holds every code cell of its notebook verbatim,
a figure and no traceback, so a notebook changed without re-running this script fails the tests.

Run: ``OPENBLAS_NUM_THREADS=1 python docs/execute_notebooks.py [NAME.ipynb ...]`` (about 10
minutes for all five on a 2-core CPU). Needs the ``notebooks`` extra.
"""

import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient
from nbconvert import MarkdownExporter

ROOT = Path(__file__).resolve().parent.parent
SOURCE, TARGET = ROOT / "notebooks", ROOT / "docs" / "examples"


def execute(path: Path) -> Path:
    """``path`` executed in a scratch folder (its files go there); the copy's path."""
    notebook = nbformat.read(path, as_version=4)
    with tempfile.TemporaryDirectory() as scratch:
        os.environ["MIKOTA_NOTEBOOK_OUT"] = str(Path(scratch) / "out")
        os.environ.pop("MIKOTA_NOTEBOOK_SIZE", None)  # the size it ships with
        NotebookClient(notebook, timeout=3600, kernel_name="python3",
                       resources={"metadata": {"path": scratch}}).execute()
    errors = [o for c in notebook.cells for o in c.get("outputs", []) if o.output_type == "error"]
    if errors:
        raise SystemExit(f"{path.name}: a cell failed: {errors[0].get('ename')}")
    files = f"{path.stem}_files"
    body, resources = MarkdownExporter().from_notebook_node(
        notebook, resources={"output_files_dir": files})
    shutil.rmtree(TARGET / files, ignore_errors=True)
    for name, data in resources.get("outputs", {}).items():
        (TARGET / name).parent.mkdir(parents=True, exist_ok=True)
        (TARGET / name).write_bytes(data)
    target = TARGET / f"{path.stem}.md"
    target.write_text(body)
    return target


def main(names: list[str]) -> None:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    TARGET.mkdir(exist_ok=True)
    paths = [SOURCE / n for n in names] if names else sorted(SOURCE.glob("*.ipynb"))
    for path in paths:
        start = time.perf_counter()
        target = execute(path)
        print(f"{path.name}: {time.perf_counter() - start:.0f} s -> {target.relative_to(ROOT)}",
              flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
