"""mkdocs hook: the guide pages are the README's sections, cut at build time (one text, no copy).

Each page below is made from the README sections named beside it; links into the repository are
rewritten for the site (``benchmarks/results/`` is ``figures/``, a link to the README's own
"Library use" section goes to the first page).
"""

import re
from pathlib import Path

from mkdocs.structure.files import File

README = Path(__file__).resolve().parent.parent / "README.md"

# page -> (title, README "## " sections in order; "" is the text before the first section)
PAGES = {
    "index.md": ("mikota_jax", ["", "What it computes", "Library use"]),
    "paper.md": ("The paper, reproduced", ["The paper, reproduced"]),
    "placement.md": ("Damper placement", ["Damper placement"]),
    "sensitivities.md": ("Sensitivities and sweeps", ["Sensitivities and sweeps"]),
    "reduced_models.md": ("Reduced models across the design space",
                          ["Reduced models across the design space"]),
    "own_matrices.md": ("Your own matrices and scenes",
                        ["Beyond Mikota: your own matrices, internal damping, branched chains",
                         "Scenes"]),
    "benchmarks.md": ("Benchmarks", ["Speed"]),
    "stability.md": ("Stability on stiff and extreme cases",
                     ["Stability on stiff and extreme cases", "Architecture"]),
}


def sections(text: str) -> dict[str, str]:
    """The README's "## " sections by title ("" for the text before the first)."""
    parts = re.split(r"^## (.+)$", text, flags=re.MULTILINE)
    found = {"": parts[0].split("\n", 1)[1] if parts[0].startswith("# ") else parts[0]}
    for title, body in zip(parts[1::2], parts[2::2]):
        found[title.strip()] = body
    return found


def rewrite(markdown: str) -> str:
    """Repository links as site links."""
    markdown = markdown.replace("](benchmarks/results/", "](figures/")
    markdown = markdown.replace("](#library-use)", "](index.md#library-use)")
    return re.sub(r"\[([^\]]+)\]\(benchmarks/README\.md\)", r"\1 (`benchmarks/README.md`)",
                  markdown)


def page(title: str, names: list[str], found: dict[str, str]) -> str:
    missing = [name for name in names if name not in found]
    if missing:
        raise ValueError(f"docs/hooks.py: README has no section {missing}")
    chunks = []
    for name in names:
        heading = "" if name in ("", title) else f"## {name}\n"
        chunks.append(heading + found[name])
    return rewrite(f"# {title}\n\n" + "\n".join(chunks))


FIGURES = README.parent / "benchmarks" / "results"


def gallery() -> str:
    """Every figure the benchmarks wrote (``benchmarks/results/*.png``), under its script's name."""
    lines = ["", "## Every benchmark figure", "",
             "As the scripts in `benchmarks/` wrote them (`python benchmarks/NAME.py`; the JSON "
             "beside each figure holds its numbers and the machine it ran on).", ""]
    for figure in sorted(FIGURES.glob("*.png")):
        if not figure.stem.endswith("_quick"):
            lines += [f"### {figure.stem}", "", f"![{figure.stem}](figures/{figure.name})", ""]
    return "\n".join(lines)


def on_files(files, config):
    found = sections(README.read_text(encoding="utf-8"))
    for path, (title, names) in PAGES.items():
        content = page(title, names, found)
        if path == "benchmarks.md":
            content += gallery()
        files.append(File.generated(config, path, content=content))
    return files
