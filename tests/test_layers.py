"""The core library never imports its application layer (``mikota_jax.app``), and ``import
mikota_jax`` stays light: the app's names are there (``dir``, attribute access) but load on use."""

import ast
import json
import os
import re
import subprocess
import sys
import types
from pathlib import Path

import pytest

import mikota_jax as mj
import mikota_jax.app as app

PACKAGE = Path(mj.__file__).parent
CORE = sorted(p for p in PACKAGE.rglob("*.py")
              if "app" not in p.relative_to(PACKAGE).parts and p.name != "__main__.py")
APP_NAMES = ("load_scene", "reproduce", "optimise_scene", "problem_from_scene")


def imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports, absolute (``from . import app`` -> ``mikota_jax.app``)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative to the module's own package
                package = path.parent.relative_to(PACKAGE.parent).parts
                package = package[: len(package) - (node.level - 1)]
                base = ".".join([*package, *([base] if base else [])])
            found.add(base)
            found |= {f"{base}.{alias.name}" for alias in node.names}
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "import_module":
            if node.args and isinstance(node.args[0], ast.Constant | ast.JoinedStr):
                found.add("dynamic:" + ast.unparse(node.args[0]))
    return found


def test_no_core_module_imports_the_application_layer():
    assert len(CORE) > 20 and all(p.exists() for p in CORE)
    offenders = {p.name: sorted(m for m in imported_modules(p)
                                if m == "mikota_jax.app" or m.startswith("mikota_jax.app."))
                 for p in CORE if p.name != "__init__.py"}
    assert not {name: mods for name, mods in offenders.items() if mods}


def test_the_package_face_reaches_the_app_layer_only_lazily():
    # __init__.py names the app modules only inside its module-level __getattr__
    tree = ast.parse((PACKAGE / "__init__.py").read_text())
    top = [node for node in tree.body if isinstance(node, ast.Import | ast.ImportFrom)]
    assert not [ast.unparse(n) for n in top if "app" in ast.unparse(n).split()]


def test_import_mikota_jax_loads_neither_jax_nor_matplotlib_nor_toml_nor_the_app_layer():
    # every name loads its module on first use; x64 is on for JAX imported afterwards
    code = ("import sys, mikota_jax\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('jax', 'diffrax', 'matplotlib', 'tomllib', 'tqdm') "
            "or m.startswith('mikota_jax.app')))")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                          timeout=300, check=True)
    assert done.stdout.strip() == "[]"


@pytest.mark.parametrize("code", [
    "import mikota_jax\nimport jax.numpy as jnp\nprint(jnp.ones(1).dtype)",
    "import jax\njax.config.update('jax_enable_x64', False)\nimport mikota_jax as mj\n"
    "mj.chain\nimport jax.numpy as jnp\nprint(jnp.ones(1).dtype)"])
def test_importing_the_package_turns_on_float64_before_or_after_jax(code):
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    env.pop("JAX_ENABLE_X64", None)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                          timeout=300, check=True)
    assert done.stdout.strip() == "float64"


def test_the_app_layers_names_live_in_mj_app_only():
    listed = dir(mj)
    assert "app" in listed and "Scene" in listed and "run_scene" in listed
    for name in APP_NAMES:
        assert name not in listed
        with pytest.raises(AttributeError, match=name):
            getattr(mj, name)
        assert not isinstance(getattr(mj.app, name), types.ModuleType)
    from mikota_jax.app import load_scene

    assert load_scene is app.load_scene
    with pytest.raises(AttributeError, match="no_such_name"):
        mj.no_such_name  # noqa: B018


def private_imports(code: str, where: str) -> list[str]:
    """The ``mikota_jax._private`` modules ``code`` imports."""
    found = []
    for node in ast.walk(ast.parse(code, where)):
        names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                 [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
        found += [n for n in names if n.startswith("mikota_jax._")]
    return found


def test_benchmarks_and_notebooks_use_only_public_names():
    root = PACKAGE.parent
    offenders = {}
    for path in sorted((root / "benchmarks").glob("*.py")):
        offenders[path.name] = private_imports(path.read_text(), str(path))
    for path in sorted((root / "notebooks").glob("*.ipynb")):
        cells = json.loads(path.read_text())["cells"]
        code = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
        code = "\n".join(line for line in code.splitlines()  # no IPython magics
                         if not line.lstrip().startswith(("%", "!")))
        offenders[path.name] = private_imports(code, str(path))
    assert len(offenders) > 8
    assert not {name: found for name, found in offenders.items() if found}


ARCHITECTURE = PACKAGE.parent / "docs" / "architecture.md"
MODULE_COLUMN = 24  # where a module's name starts on a line of the page's diagram


def loaded_imports(path: Path) -> set[Path]:
    """The files of the package that ``path`` imports when it is loaded (not inside functions):
    ``from . import _x`` and ``from ._x import y`` -> ``_x.py``; a name taken from a package
    (``from .. import solve``) -> its ``__init__.py``."""
    package = path.parent
    found = set()

    def file_of(dotted: str) -> Path | None:
        if dotted != "mikota_jax" and not dotted.startswith("mikota_jax."):
            return None
        target = PACKAGE.joinpath(*dotted.split(".")[1:])
        return target / "__init__.py" if target.is_dir() else target.with_suffix(".py")

    def visit(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
                continue
            if isinstance(child, ast.Import):
                found.update(file_of(alias.name) for alias in child.names)
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = package
                    for _ in range(child.level - 1):
                        base = base.parent
                    parts = base.relative_to(PACKAGE.parent).parts
                    dotted = ".".join([*parts, *([child.module] if child.module else [])])
                else:
                    dotted = child.module or ""
                target = file_of(dotted)
                if target is not None and target.name == "__init__.py":  # names or submodules
                    for alias in child.names:
                        sub = target.parent / f"{alias.name}.py"
                        found.add(sub if sub.exists() else target)
                else:
                    found.add(target)
            visit(child)

    visit(ast.parse(path.read_text(), str(path)))
    return {p for p in found if p is not None and p != path}


def architecture_listing() -> list[Path]:
    """The modules of docs/architecture.md's diagram, top to bottom, as files."""
    text = ARCHITECTURE.read_text(encoding="utf-8")
    diagram = next(block for block in re.findall(r"^```text\n(.*?)^```", text, re.S | re.M)
                   if block.startswith("application layer"))
    listed, folder, core = [], PACKAGE / "app", False
    for line in diagram.splitlines():
        if line.startswith("core:"):
            folder, core = PACKAGE, True
        elif len(line) > MODULE_COLUMN and line[MODULE_COLUMN - 1] == " " \
                and line[MODULE_COLUMN] != " ":
            label = line[:MODULE_COLUMN].strip()
            if core and label:  # "_solver/spectral/": a subpackage; any other label: the root
                folder = PACKAGE.joinpath(*label.strip("/").split("/")) if label.endswith("/") \
                    else PACKAGE
            name = line[MODULE_COLUMN:].split()[0]
            listed.append(PACKAGE / "__main__.py" if name == "__main__" else folder / f"{name}.py")
    return listed


def test_the_architecture_page_lists_every_module_once_above_what_it_imports():
    listed = architecture_listing()
    files = sorted(PACKAGE.rglob("*.py"))
    assert sorted(listed) == files, "docs/architecture.md must list every module exactly once"
    below = {path: set(listed[k + 1:]) for k, path in enumerate(listed)}
    upward = {str(path.relative_to(PACKAGE)): sorted(str(p.relative_to(PACKAGE))
                                                      for p in loaded_imports(path) - below[path])
              for path in listed}
    assert not {name: found for name, found in upward.items() if found}
