"""The two installs: environment.txt (the labs) holds everything kfkit and the notebooks import, and
requirements-test.txt (environment.txt plus the test tools) is what the README and CI install.

Requirement lines are parsed with ``packaging`` and imports mapped to distributions with
``importlib.metadata.packages_distributions``, independently of kfkit.doctor's own reader.
"""

import ast
import os
import re
import subprocess
import sys
from importlib import metadata

import nbformat
import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

from kfkit.paths import KIT_ROOT

ENVIRONMENT = KIT_ROOT / "environment.txt"
TEST_REQUIREMENTS = KIT_ROOT / "requirements-test.txt"


def requirement_lines(path):
    """(line number, text) of every line of ``path`` that is not blank or a comment."""
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        text = line.split(" #")[0].strip()
        if text and not text.startswith("#"):
            yield number, text


def pins(path):
    """{canonical name: version} of the requirements in ``path`` (not following ``-r``)."""
    found = {}
    for number, text in requirement_lines(path):
        if text.startswith("-"):
            continue
        req = Requirement(text)
        [spec] = req.specifier
        assert spec.operator == "==" and "*" not in spec.version, f"{path.name}:{number}: {text} is no exact pin"
        name = canonicalize_name(req.name)
        assert name not in found, f"{path.name}:{number}: {req.name} pinned twice"
        found[name] = spec.version
    return found


def test_both_files_pin_exactly_and_the_test_file_extends_the_student_file():
    student, test_only = pins(ENVIRONMENT), pins(TEST_REQUIREMENTS)
    assert not student.keys() & test_only.keys(), "a package pinned in both files"
    options = [text for _, text in requirement_lines(ENVIRONMENT) if text.startswith("-")]
    assert options == ["-e ."]
    first_number, first = next(requirement_lines(TEST_REQUIREMENTS))
    assert first == "-r environment.txt", f"requirements-test.txt:{first_number} should start with -r environment.txt"
    assert [text for _, text in requirement_lines(TEST_REQUIREMENTS) if text.startswith("-")] == [first]


def third_party_modules(tree):
    """Top-level names of the absolute imports in ``tree`` (functions' deferred imports included)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            names.add(node.module.split(".")[0])
    return names - set(sys.stdlib_module_names) - {"kfkit", "__future__"}


def distributions(modules, where):
    """{module: canonical distribution name}; fails for a module no installed distribution provides."""
    providers = metadata.packages_distributions()
    missing = sorted(m for m in modules if m not in providers)
    assert not missing, f"{where} imports {missing}, which no installed distribution provides"
    return {m: canonicalize_name(providers[m][0]) for m in modules}


def kfkit_imports():
    modules = set()
    for path in sorted((KIT_ROOT / "kfkit").rglob("*.py")):
        modules |= third_party_modules(ast.parse(path.read_text(encoding="utf-8"), filename=str(path)))
    return distributions(modules, "kfkit/")


def test_kfkit_imports_only_what_the_student_install_pins_and_pyproject_declares():
    import tomllib

    imported = kfkit_imports()
    student = pins(ENVIRONMENT)
    unpinned = {m: d for m, d in imported.items() if d not in student}
    assert not unpinned, f"kfkit imports {unpinned}, not pinned in environment.txt (a student install lacks them)"
    project = tomllib.loads((KIT_ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    declared = {canonicalize_name(Requirement(r).name) for r in project["dependencies"]}
    undeclared = {m: d for m, d in imported.items() if d not in declared}
    assert not undeclared, f"kfkit imports {undeclared}, not in pyproject.toml's dependencies"


def test_test_tools_are_not_what_kfkit_needs():
    """The test-only pins (the packages a student does not get) are never imported by kfkit."""
    assert not set(kfkit_imports().values()) & pins(TEST_REQUIREMENTS).keys()


@pytest.mark.parametrize("notebook", sorted((KIT_ROOT / "solutions").glob("*.ipynb")), ids=lambda p: p.stem)
def test_each_lab_imports_only_what_the_student_install_pins(notebook):
    modules = set()
    for cell in nbformat.read(notebook, as_version=4).cells:
        if cell.cell_type == "code":
            python = re.sub(r"(?m)^\s*[%!].*$", "", cell.source)  # IPython magics and shell lines
            modules |= third_party_modules(ast.parse(python))
    imported = distributions(modules, notebook.name)
    student = pins(ENVIRONMENT)
    assert not {m: d for m, d in imported.items() if d not in student}, (
        f"{notebook.name} needs a package environment.txt lacks"
    )


@pytest.mark.slow
def test_pytest_starts_with_only_the_student_plugins():
    """pyproject.toml's addopts (--nbval-lax…) and tests/conftest.py parse with just environment.txt's pytest
    plugins, so ``python -m pytest NOTEBOOK`` works in a student install, which carries no test runner's
    plugin (pytest-xdist is a test tool: requirements-test.txt)."""
    assert "pytest-xdist" not in pins(ENVIRONMENT)
    student = pins(ENVIRONMENT)
    plugins = [ep.name for ep in metadata.entry_points(group="pytest11") if canonicalize_name(ep.dist.name) in student]
    env = {**os.environ, "PYTEST_DISABLE_PLUGIN_AUTOLOAD": "1"}
    args = [arg for name in plugins for arg in ("-p", name)]
    done = subprocess.run(
        [sys.executable, "-m", "pytest", *args, "--collect-only", "-q", "tests/test_deployment.py"],
        cwd=KIT_ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, f"pytest with only {plugins}:\n{done.stdout[-2000:]}{done.stderr[-2000:]}"


def fenced_commands(section):
    """The lines of the first ```bash block under README heading ``section`` (before the next heading)."""
    readme = (KIT_ROOT / "README.md").read_text(encoding="utf-8")
    match = re.search(
        rf"^## {re.escape(section)}\n(?:(?!#|```)[^\n]*\n)*?```bash\n(.*?)\n```", readme, flags=re.M | re.S
    )
    assert match, f"README.md has no ```bash block under '## {section}'"
    return match[1].splitlines()


def test_readme_quick_start_is_what_a_newcomer_types_in_order():
    """Get the kit, go into it, make and activate a virtual environment, install the student file from the kit's
    root (environment.txt ends in ``-e .``), start JupyterLab on the hand-outs."""
    quick = fenced_commands("Quick start (students)")
    steps = [
        "git clone ",
        "cd kfkit",
        "python -m venv .venv",
        "source .venv/bin/activate",
        "python -m pip install -r environment.txt && jupyter lab labs/",
    ]
    at = [next((i for i, line in enumerate(quick) if line.startswith(step)), None) for step in steps]
    assert None not in at and at == sorted(at), f"the Quick start's commands are not {steps} in this order: {quick}"
    assert pins(ENVIRONMENT) and ENVIRONMENT.read_text(encoding="utf-8").rstrip().endswith("-e .")


def test_readme_test_command_installs_the_test_file_and_runs_on_two_workers():
    [tests] = fenced_commands("Tests")
    assert tests == "python -m pip install -r requirements-test.txt && python -m pytest -n 2"


def test_ci_runs_exactly_the_readme_test_command():
    [tests] = fenced_commands("Tests")
    ci = (KIT_ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    assert tests in ci, f".ci/run does not run the README's test command {tests!r}"


def test_no_comment_says_the_kernels_results_are_pickled():
    """The grader pickles the cases' inputs into the kernel and parses only JSON back (kfkit/grading/wire.py; the
    grader-side modules never load a pickle: test_grading.py). environment.txt said "results pickled back": every
    comment, docstring and document of the kit must say what the code does."""
    claim = re.compile(r"\b(results?|outputs?|returns?|answers?)\b[^.;:]*\bpickled\b|\bpickled back\b", re.IGNORECASE)
    files = [
        *KIT_ROOT.glob("*.txt"),
        KIT_ROOT / "README.md",
        *(KIT_ROOT / "kfkit").rglob("*.py"),
        *(KIT_ROOT / "solutions").glob("*.ipynb"),
    ]
    said = [
        f"{path.relative_to(KIT_ROOT)}:{number}: {line.strip()}"
        for path in files
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1)
        if claim.search(line)
    ]
    assert said == [], said
