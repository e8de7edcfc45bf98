"""mkdocs hook: the benchmark pages, generated from ``benchmarks/results/*.json`` at build time.

The guides are files in ``docs/``; measurements live only in the benchmarks' JSON. For every
script ``benchmarks/NAME.py`` this writes a section of ``benchmarks.md`` (the suite's maintained
scripts first, in the suite's order): the question the script answers (its module docstring),
how it is run, and for each of its result files (``NAME.json``, ``NAME_gpu.json``, ...) the
machine it ran on, its summary and rows as tables, and its figure. Then a list of the notes in
``docs/notes/`` (investigations answered once, their scripts removed), each with its question.
"""

import ast
import json
import math
import re
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = ROOT / "benchmarks"
RESULTS = SCRIPTS / "results"
NOTES = ROOT / "docs" / "notes"
MAX_ROWS, MAX_COLUMNS = 40, 12

INTRO = """# Benchmarks

Every figure and table on this page is generated from the JSON files the benchmark scripts wrote
(`benchmarks/results/NAME.json`, with the machine, versions and date of the run), so a rerun
updates the page. The maintained benchmarks run as one suite, each script in its own process,
from the repository root:

```bash
OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/suite.py --quick   # smoke runs (in CI)
OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/suite.py           # full runs, a quiet machine
OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/NAME.py [--quick]  # one script
OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/NAME.py --replot  # its figure from the JSON
```

Conventions (`benchmarks/_common.py`): correctness is checked before any timing; compilation is
timed apart from running; a run time is the median of repeats, each ended by
`jax.block_until_ready`; every comparison runs in the same process. Timings on a small shared
machine vary by tens of per cent between runs: compare rows of one file, not across files.
"""


def docstring(script: Path) -> str:
    """The script's module docstring as markdown (``code`` -> `code`)."""
    text = ast.get_docstring(ast.parse(script.read_text(encoding="utf-8"))) or ""
    return re.sub(r"``([^`]+)``", r"`\1`", text)


def number(value) -> str:
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value) or math.isinf(value):
            return str(value)
        return f"{value:.4g}"
    text = str(value).replace("|", "/").replace("\n", " ")
    return text if len(text) <= 60 else text[:57] + "..."


def flat(record: dict, prefix: str = "") -> dict:
    """Nested dicts of scalars as one dict with dotted keys; lists of scalars joined."""
    out = {}
    for key, value in record.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out |= flat(value, name + ".")
        elif isinstance(value, list):
            if all(not isinstance(v, dict | list) for v in value) and len(value) <= 6:
                out[name] = ", ".join(number(v) for v in value)
        else:
            out[name] = number(value)
    return out


def table(rows: list[dict]) -> list[str]:
    rows = [flat(row) for row in rows[:MAX_ROWS]]
    columns = []
    for row in rows:
        columns += [c for c in row if c not in columns]
    columns = columns[:MAX_COLUMNS]
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(row.get(c, "") for c in columns) + " |" for row in rows]
    return lines


def machine(data: dict) -> str:
    meta = data.get("metadata") or data.get("meta") or {}
    if not meta:
        return "Machine not recorded in the file."
    device = meta.get("device", "?")
    cpus = meta.get("cpu_count")
    return (f"Measured {meta.get('date', '?')[:10]} on {meta.get('backend', '?')} ({device}"
            f"{f', {cpus} CPUs' if cpus else ''}), mikota_jax {meta.get('mikota_jax', '?')}, "
            f"jax {meta.get('jax', '?')}{', quick run' if data.get('quick') else ''}.")


def result_section(path: Path) -> list[str]:
    data = json.loads(path.read_text(encoding="utf-8"))
    lines = [f"#### `{path.name}`", "", machine(data), ""]
    summary = data.get("summary")
    if isinstance(summary, dict) and flat(summary):
        lines += ["Summary:", ""] + table([{"quantity": k, "value": v}
                                           for k, v in flat(summary).items()]) + [""]
    elif isinstance(summary, list) and summary and all(isinstance(r, dict) for r in summary):
        lines += ["Summary:", ""] + table(summary) + [""]
    rows = data.get("rows")
    if isinstance(rows, list) and rows and all(isinstance(r, dict) for r in rows):
        more = f" (the first {MAX_ROWS} of {len(rows)})" if len(rows) > MAX_ROWS else ""
        lines += [f"Rows{more}:", ""] + table(rows) + [""]
    figure = path.with_suffix(".png")
    if figure.exists():
        lines += [f"![{path.stem}](figures/{figure.name})", ""]
    return lines


def suite() -> list[str]:
    """The maintained scripts, in the suite's order (the keys of ``SUITE`` in ``suite.py``)."""
    tree = ast.parse((SCRIPTS / "suite.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "SUITE"
                                                for t in node.targets):
            return [key.value for key in node.value.keys]
    raise ValueError("benchmarks/suite.py defines no SUITE")


def notes() -> list[str]:
    """One line per note in ``docs/notes/``: a link (its title) and its question."""
    lines = []
    for note in sorted(NOTES.glob("*.md")):
        text = note.read_text(encoding="utf-8")
        title = re.search(r"^# (.+)$", text, re.M).group(1)
        question = re.search(r"\*\*Question\.\*\* (.+?)\n\n", text, re.S)
        lines.append(f"- [{title}](notes/{note.name})"
                     + (f": {' '.join(question.group(1).split())}" if question else ""))
    return lines


def benchmarks_page() -> str:
    lines = [INTRO]
    maintained = suite()
    others = sorted(s.stem for s in SCRIPTS.glob("[!_]*.py")
                    if s.stem not in maintained and s.stem != "suite")
    for name in maintained + others:
        script = SCRIPTS / f"{name}.py"
        if name == maintained[0]:
            lines += ["## The maintained benchmarks (`benchmarks/suite.py`)", ""]
        elif name == (others or [None])[0]:
            lines += ["## Other scripts", ""]
        results = sorted(p for p in RESULTS.glob(f"{name}*.json")
                         if not p.stem.endswith("_quick")
                         and re.fullmatch(rf"{name}(_[a-z0-9]+)?", p.stem)
                         and not any(p.stem.startswith(other.stem) and other.stem != name
                                     and len(other.stem) > len(name)
                                     for other in SCRIPTS.glob(f"{name}_*.py")))
        lines += [f"### {name}", "", docstring(script), "",
                  f"Source: `benchmarks/{script.name}`.", ""]
        if not results:
            lines += ["No committed results.", ""]
        for path in results:
            lines += result_section(path)
    lines += ["## Notes", "", "Investigations that answered one question once: the question, how "
              "it was measured, the figures and the conclusion, frozen (the scripts that measured "
              "them are in the repository's history).", ""] + notes() + [""]
    return "\n".join(lines)


def on_files(files, config):
    files.append(File.generated(config, "benchmarks.md", content=benchmarks_page()))
    changelog = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    files.append(File.generated(config, "changelog.md", content=changelog))
