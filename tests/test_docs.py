"""The API reference and the getting-started page: every public name documents itself (shapes,
units, 1-based DOFs, the paper's equation numbers), and the page's three steps and the README's
example run as printed and compute what their comments say."""

import inspect
import re
import types
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import mikota_jax as mj

ROOT = Path(__file__).parent.parent
README = ROOT / "README.md"
GETTING_STARTED = ROOT / "docs" / "index.md"
SUBMODULES = ("analytic", "metrics", "io")  # public submodules: their names count as public
PUBLIC = sorted([n for n in dir(mj)
                 if not n.startswith("_") and not isinstance(getattr(mj, n), types.ModuleType)]
                + [f"{m}.{n}" for m in SUBMODULES for n in getattr(mj, m).__all__])
def public(name: str):
    """The object a public (possibly dotted: ``analytic.mode_shape``) name stands for."""
    obj = mj
    for part in name.split("."):
        obj = getattr(obj, part)
    return obj


CLASSES = [n for n in PUBLIC if inspect.isclass(public(n))]

# The paper's numbered equations (Weber & Zastrau 2018): (2.1)-(2.7), (3.1)-(3.8), (4.1)-(4.4),
# (5.1)-(5.4). A docstring citing any other number cites nothing.
PAPER_EQUATIONS = {f"{s}.{k}" for s, last in ((2, 7), (3, 8), (4, 4), (5, 4))
                   for k in range(1, last + 1)}
# name -> an equation its docstring must cite (a range "eqs. 3.2-3.4" cites 3.3 too)
EQUATIONS = {
    "analytic.eigenfrequencies": "2.4", "analytic.mode_shape": "2.5",
    "analytic.mode_shape_coefficients": "2.5", "analytic.paper_mode_shape": "2.6", "chain": "2.2",
    "mikota_chain": "2.3", "SecondOrderSystem": "3.1",
    "modal_decomposition": "2.4", "GroundedDamper": "5.1", "RelativeDamper": "3.1",
    "solve": "3.1", "Trajectory": "3.2", "Pulse": "4.3", "pulse": "4.3",
    "reduce": "3.4", "ReducedModel": "3.3", "POD": "3.6",
    "metrics.pseudo_energy": "3.7",
    "metrics.phase_error": "5.4", "Energy": "3.1", "AverageEnergy": "3.1",
    "Scene": "4.3", "run_scene": "5.4", "app.reproduce": "5.4",
    "ScreenAndCertify": "3.7", "Grid": "3.4",
}
# names (and methods) that take or return arrays: their docstrings state a shape like (n,) or
# (N, d), in the letters of the package (n DOFs, N times, r rank, m snapshots, ...)
SHAPED = [
    "analytic.eigenfrequencies", "analytic.mode_shape", "analytic.paper_mode_shape", "chain",
    "modal_decomposition",
    "unit_vector", "Pulse", "pulse", "solve", "Trajectory",
    "ReducedModel", "reduce", "POD", "Projection", "ReductionStats",
    "metrics.pseudo_energy", "metrics.phase_error", "metrics.relative_error", "Energy", "Peak",
    "Scene", "DamperDesign", "Solution", "Grid", "ScreenAndCertify",
    "AbstractReduction.basis", "ReducedModel.lift", "ReducedModel.reduce_state",
    "SecondOrderSystem.dense", "SecondOrderSystem.project", "Pulse.project",
]
SHAPE = re.compile(r"\((?:[nNrmkdgPCS]|\d+)(?:, ?(?:[nNrmkdgPCS]|\d+))*,?\)")
ONE_BASED = ["unit_vector", "pulse", "analytic.mode_shape", "GroundedDamper", "RelativeDamper",
             "solve", "Trajectory", "DamperDesign", "Solution", "Grid"]
UNITS = {"analytic.eigenfrequencies": "rad per unit time", "mikota_chain": "force per length",
         "chain": "force per length", "GroundedDamper": "force * time per length",
         "RelativeDamper": "force * time per length", "SecondOrderSystem": "force per length"}


def own_doc(obj) -> str:
    """The object's own docstring: not inherited, not the signature dataclasses write."""
    doc = obj.__doc__ or ""
    name = getattr(obj, "__name__", "")
    return "" if name and doc.startswith(f"{name}(") else inspect.cleandoc(doc)


def doc_of(dotted: str) -> str:
    obj = mj
    for part in dotted.split("."):
        # modules by getattr (their names load on first use), class members statically
        obj = (getattr(obj, part) if isinstance(obj, types.ModuleType)
               else inspect.getattr_static(obj, part))
    return own_doc(obj.fget if isinstance(obj, property) else obj)


def cited(doc: str) -> set[str]:
    """Equation numbers cited as "eq. 2.4", "eq. (2.4)", "eqs. 3.5-3.8" (ranges expanded)."""
    numbers = set()
    for first, last in re.findall(r"\beqs?\. \(?(\d\.\d+)\)?(?:\s*-\s*\(?(\d\.\d+))?", doc):
        numbers.add(first)
        if last:
            section, a, b = first.split(".")[0], int(first.split(".")[1]), int(last.split(".")[1])
            numbers |= {f"{section}.{k}" for k in range(a, b + 1)}
    return numbers


def public_members():
    """(Class.name, function) of every public method and property a public class defines."""
    for name in CLASSES:
        for key, value in vars(public(name)).items():
            if not key.startswith("_") and isinstance(value, property | types.FunctionType):
                yield f"{name}.{key}", value.fget if isinstance(value, property) else value


def test_every_public_name_has_a_docstring_of_at_least_one_sentence():
    missing = [n for n in PUBLIC if len(own_doc(public(n)).split("\n")[0].split()) < 3]
    assert not missing


def test_every_public_method_and_property_of_a_public_class_has_a_docstring():
    missing = [name for name, fn in public_members() if len(own_doc(fn).split()) < 2]
    assert not missing


def test_docstrings_cite_the_papers_equations():
    missing = {n: eq for n, eq in EQUATIONS.items() if eq not in cited(doc_of(n))}
    assert not missing


def test_docstrings_cite_only_equations_the_paper_has():
    docs = {n: own_doc(public(n)) for n in PUBLIC}
    docs |= {name: own_doc(fn) for name, fn in public_members()}
    wrong = {n: sorted(cited(d) - PAPER_EQUATIONS) for n, d in docs.items()
             if cited(d) - PAPER_EQUATIONS}
    assert not wrong


def test_docstrings_of_array_functions_state_shapes():
    missing = [n for n in SHAPED if not SHAPE.search(doc_of(n))]
    assert not missing


def test_docstrings_state_the_one_based_dof_convention_and_units():
    assert not [n for n in ONE_BASED if "1-based" not in doc_of(n)]
    assert not {n: u for n, u in UNITS.items() if u not in doc_of(n)}


def three_steps() -> list[str]:
    """The ```python blocks of the getting-started page's "## The paper's model in three steps"."""
    text = GETTING_STARTED.read_text()
    section = text.split("\n## The paper's model in three steps\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, re.S)


def test_readme_is_a_front_page_that_links_the_guides():
    text = README.read_text()
    assert len(text.encode()) <= 10_000
    for page in ("docs/index.md", "docs/placement.md", "docs/reduced_models.md", "CHANGELOG.md"):
        assert f"]({page})" in text


def test_readme_example_gradient_agrees_with_central_differences(capsys, close):
    (code,) = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    namespace = {}
    exec(compile(code, "README.md, example", "exec"), namespace)
    assert namespace["response"].displacement.shape == (2001, 1)
    # J carries ~1e-11 relative rounding (see below). The coefficient: a central difference,
    # h = 1e-4. The position: at an integer DOF J has a kink (the damper's split changes
    # sides) and jax.grad is the right-sided derivative: a second-order one-sided difference
    # (4 J(p + h) - J(p + 2h) - 3 J(p)) / 2h, h = 1e-3 (truncation ~1e-6, rounding ~1e-8)
    energy = lambda p, c: namespace["gradient"](p, c)[0]  # noqa: E731 (the compiled program)
    h = 1e-4
    central = (float(energy(7.0, 1.0 + h)) - float(energy(7.0, 1.0 - h))) / (2 * h)
    close(namespace["d_coefficient"], central, rtol=1e-5, what="d_coefficient")
    h = 1e-3
    right = (4 * float(energy(7.0 + h, 1.0)) - float(energy(7.0 + 2 * h, 1.0))
             - 3 * float(energy(7.0, 1.0))) / (2 * h)
    close(namespace["d_position"], right, rtol=1e-5, what="d_position")
    assert capsys.readouterr().out.startswith(f"J = {float(namespace['value']):.6f}")


def test_the_three_steps_run_in_sequence_and_compute_what_they_say(capsys, close):
    snippets = three_steps()
    assert len(snippets) == 3
    namespace = {}
    for k, code in enumerate(snippets, 1):
        exec(compile(code, f"docs/index.md, step {k}", "exec"), namespace)
    printed = capsys.readouterr().out.splitlines()
    assert len(printed) == 4
    # 1: what the default runs there; Dopri8 at rtol 1e-8 against the exact solution, DOF 150
    fast, full = namespace["fast"], namespace["full"]
    assert float(jnp.max(jnp.abs(fast.displacement[:, 0] - full.displacement[:, 149]))) < 1e-5
    # 2: the paper's n_red = 76 (99 %) and our phase error (ratio of sums, README table)
    assert printed[0] == "Spectral()"
    assert namespace["r"] == 76 and printed[2].startswith("76 0.071")
    close(namespace["error"], 0.0712, rtol=1e-3)
    # 3: the gradient agrees with central differences. The exact energy carries ~1e-11 relative
    # rounding (Van Loan step and doublings), so the step is 1e-4 x scale, not sqrt(eps) x scale:
    # measured, it agrees to 6e-7 (position) and 1e-7 (coefficient), 6e-5 at 1e-7 x scale.
    energy = lambda p, c: namespace["gradient"](p, c)[0]  # noqa: E731 (the compiled program)
    for which, point in (("d_position", 7.5), ("d_coefficient", 1.0)):
        h = 1e-4 * point
        plus, minus = ((7.5 + s * h, 1.0) if which == "d_position" else (7.5, 1.0 + s * h)
                       for s in (1.0, -1.0))
        central = (float(energy(*plus)) - float(energy(*minus))) / (2 * h)
        assert np.isfinite(float(namespace[which]))
        close(namespace[which], central, rtol=1e-5, what=which)
