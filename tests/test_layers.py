"""The core library never imports its application layer (``mikota_jax.app``), and ``import
mikota_jax`` stays light: the app's names are there (``dir``, attribute access) but load on use."""

import ast
import json
import os
import subprocess
import sys
import types
from pathlib import Path

import pytest

import mikota_jax as mj
import mikota_jax.app as app

PACKAGE = Path(mj.__file__).parent
CORE = sorted(p for p in PACKAGE.glob("*.py") if p.name != "__main__.py")
APP_NAMES = ("load_scene", "reproduce", "optimise_scene", "problem_from_scene")


def imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports, absolute (``from . import app`` -> ``mikota_jax.app``)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative to the package mikota_jax (core modules are top level)
                base = ".".join(["mikota_jax", *([base] if base else [])])
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


def test_import_mikota_jax_loads_neither_matplotlib_nor_toml_nor_the_app_layer():
    code = ("import sys, mikota_jax\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('matplotlib', 'tomllib', 'tqdm') or m.startswith('mikota_jax.app')))")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                          timeout=300, check=True)
    assert done.stdout.strip() == "[]"


def test_the_app_layers_names_are_listed_and_resolve_to_the_app():
    listed = dir(mj)
    for name in APP_NAMES:
        assert name in listed
        assert getattr(mj, name) is getattr(app, name)
    assert "Scene" in listed and "run_scene" in listed and "SceneResult" in listed
    assert not isinstance(mj.load_scene, types.ModuleType)
    from mikota_jax import load_scene

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
