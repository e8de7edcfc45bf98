"""Every ```python block of the README and of the guide pages in ``docs/`` runs as printed.

A page's blocks run in order in one namespace (a page is one script a reader follows from the
top); blocks meant as text use another fence (```text, ```toml, ```bash). The pages whose blocks
together take more than about a minute on a 2-core CPU run under ``-m slow``; the checks of what
particular blocks compute (central differences, the paper's numbers) live beside the API they
use (``tests/test_docs.py``, ``tests/test_systems.py``).
"""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
# every page with code; a new guide page must be listed (test_every_page_with_code_is_listed)
PAGES = ["README.md", "docs/index.md", "docs/paper.md", "docs/placement.md",
         "docs/sensitivities.md", "docs/reduced_models.md", "docs/own_matrices.md",
         "docs/numerics.md", "docs/stability.md", "docs/architecture.md"]
# own_matrices.md also runs, with its gradient checked, in test_systems
SLOW = {"docs/placement.md", "docs/sensitivities.md", "docs/reduced_models.md",
        "docs/own_matrices.md"}
# pages whose every block another test runs, checking what it computes: page -> block count
RUN_ELSEWHERE = {"README.md": 1, "docs/index.md": 3}  # tests/test_docs.py


def blocks(page: str) -> list[str]:
    """The ```python blocks of a page, in order."""
    return re.findall(r"^```python\n(.*?)^```", (ROOT / page).read_text(encoding="utf-8"),
                      re.S | re.M)


def run_page(page: str) -> dict:
    namespace = {"__name__": f"guide:{page}"}
    for k, code in enumerate(blocks(page), 1):
        exec(compile(code, f"{page}, python block {k}", "exec"), namespace)
    return namespace


def test_every_page_with_code_is_listed():
    pages = {"README.md"} | {str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md")}
    unlisted = sorted(p for p in pages if p not in PAGES and blocks(p))
    assert not unlisted


def test_the_pages_run_elsewhere_have_only_the_blocks_run_there():
    assert {page: len(blocks(page)) for page in RUN_ELSEWHERE} == RUN_ELSEWHERE


@pytest.mark.parametrize("page", [pytest.param(p, marks=pytest.mark.slow) if p in SLOW else p
                                  for p in PAGES if p not in RUN_ELSEWHERE])
def test_every_python_block_of_the_page_runs(page, capsys):
    if not (ROOT / page).exists():
        pytest.fail(f"{page} is listed but missing")
    run_page(page)


# history (dates, issue and stop numbers) goes to CHANGELOG.md, measurements to the benchmark
# pages generated from benchmarks/results/*.json
HISTORY = re.compile(r"\b20\d\d-\d\d-\d\d\b|\bissues? #?\d+|\bstop #?\d+\b|\bprevious stop\b|"
                     r"\bthis session\b", re.I)


def test_no_history_in_the_readme_the_guides_or_the_docstrings():
    texts = {page: (ROOT / page).read_text(encoding="utf-8") for page in PAGES
             if (ROOT / page).exists()}
    texts |= {str(p.relative_to(ROOT)): p.read_text(encoding="utf-8")
              for p in (ROOT / "mikota_jax").rglob("*.py")}
    # the notes that froze answered investigations: their figures, no calendar
    texts |= {str(p.relative_to(ROOT)): p.read_text(encoding="utf-8")
              for p in (ROOT / "docs" / "notes").glob("*.md")}
    # the benchmarks' docstrings are their sections of the generated benchmark page
    texts |= {str(p.relative_to(ROOT)): ast.get_docstring(ast.parse(p.read_text("utf-8"))) or ""
              for p in (ROOT / "benchmarks").glob("*.py")}
    found = {name: HISTORY.findall(text) for name, text in texts.items() if HISTORY.search(text)}
    assert not found
