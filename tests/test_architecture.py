"""The package's shape (issue 16): imports only point down, modules stay small and uniquely named.

An import graph of kfkit from its source (``ast``), counting imports inside functions too (a deferred
import that dodges a cycle is still a cycle), checked against the rules in docs/design.md:
no import cycle, no module over MAX_LINES lines (600 formatted), no two modules with one name, the capture layer
depends on nothing above it, and the leaves (``paths``, ``frames``) import nothing from kfkit. The walker is
tested on a small package of its own first, so a rule that cannot fail would show.
"""

import ast
from collections import Counter
from pathlib import Path

import pytest

KFKIT = Path(__file__).resolve().parents[1] / "kfkit"
#: lines of a module as ruff formats it (../shared/tools/import_cycles.py counts the same 600); a module that grows past
#: it is split by concern
MAX_LINES = 600
LEAVES = ("paths", "frames")
ABOVE_CAPTURE = ("datasets", "plots", "widgets", "demo", "checkpoints", "grading", "authoring", "doctor", "cli")


def modules(root: Path) -> dict:
    """{dotted name: path} of every .py file under ``root`` (a package's __init__ named for the package)."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(root.parent).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def import_graph(mods: dict) -> dict:
    """{module: set of package modules it imports}, every ``import``/``from … import`` anywhere in the file
    (functions included), relative imports resolved; ``from pkg import name`` counts pkg.name when that is a module."""
    graph = {}
    for name, path in mods.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                found = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                    module = ".".join(base + ([node.module] if node.module else []))
                else:
                    module = node.module or ""
                found = [module] + [f"{module}.{alias.name}" for alias in node.names]
            else:
                continue
            for target in found:
                while target and target not in mods:  # kfkit.frames.wrap_angle → kfkit.frames
                    target = target.rpartition(".")[0]
                if (
                    target and target != name and not name.startswith(target + ".")
                ):  # a package's own parents: not edges
                    targets.add(target)
        graph[name] = targets
    return graph


def cycles(graph: dict) -> list:
    """Strongly connected components with more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def reachable(graph: dict, start: str) -> dict:
    """{module reachable from ``start``: the chain of imports that reaches it}."""
    chains, todo = {start: [start]}, [start]
    while todo:
        v = todo.pop()
        for w in sorted(graph.get(v, ())):
            if w not in chains:
                chains[w] = chains[v] + [w]
                todo.append(w)
    return chains


def oversized(mods: dict) -> list:
    return sorted(
        (name, n)
        for name, path in mods.items()
        if (n := len(path.read_text(encoding="utf-8").splitlines())) > MAX_LINES
    )


#: a lab's support and its checkpoints share the lab's name by design (docs/design.md: kfkit.labs.labNN,
#: kfkit.checkpoints.labNN)
PAIRED_BY_LAB = ("labs", "checkpoints")


def duplicate_names(mods: dict) -> list:
    """Module file names (not packages' __init__) used by more than one module, apart from a lab's pair."""

    def lab_pair(name):
        package, _, base = name.rpartition(".")
        return package.rpartition(".")[2] in PAIRED_BY_LAB and base.startswith("lab")

    counts = Counter(
        name.rpartition(".")[2] for name, path in mods.items() if path.name != "__init__.py" and not lab_pair(name)
    )
    return sorted(base for base, n in counts.items() if n > 1)


# --- the walker on a package of its own -----------------------------------------------------------------------


@pytest.fixture
def toy(tmp_path):
    pkg = tmp_path / "toy"
    (pkg / "sub").mkdir(parents=True)
    files = {
        "__init__.py": "from .b import f\n",
        "a.py": "import numpy\nfrom toy.b import f\n",
        "b.py": "def f():\n    from . import c  # deferred: still an edge\n    return c\n",
        "c.py": "def g():\n    from .sub.d import h\n",
        "sub/__init__.py": "",
        "sub/d.py": "from ..a import *\nfrom .. import leaf\n",
        "sub/a.py": "x = 1\n" * (MAX_LINES + 1),
        "leaf.py": "import math\n",
    }
    for name, text in files.items():
        (pkg / name).write_text(text, encoding="utf-8")
    return modules(pkg)


def test_the_walker_sees_deferred_and_relative_imports_cycles_sizes_and_names(toy):
    graph = import_graph(toy)
    assert graph["toy.a"] == {"toy.b"} and graph["toy.b"] == {"toy.c"} and graph["toy.c"] == {"toy.sub.d"}
    assert graph["toy.sub.d"] == {"toy.a", "toy.leaf"} and graph["toy"] == {"toy.b"} and graph["toy.leaf"] == set()
    assert cycles(graph) == [["toy.a", "toy.b", "toy.c", "toy.sub.d"]]
    assert reachable(graph, "toy.a")["toy.leaf"] == ["toy.a", "toy.b", "toy.c", "toy.sub.d", "toy.leaf"]
    assert oversized(toy) == [("toy.sub.a", MAX_LINES + 1)]
    assert duplicate_names(toy) == ["a"]


# --- kfkit's rules --------------------------------------------------------------------------------------------

MODS = modules(KFKIT)
GRAPH = import_graph(MODS)


def test_no_import_cycle_counting_imports_inside_functions():
    found = cycles(GRAPH)
    assert not found, "import cycles: " + " | ".join(" <-> ".join(c) for c in found)


def test_no_module_over_max_lines():
    big = oversized(MODS)
    assert not big, f"modules over {MAX_LINES} lines: {big}"


def test_no_two_modules_share_a_name():
    twice = duplicate_names(MODS)
    assert not twice, f"module names used twice: {twice}"


@pytest.mark.parametrize("module", sorted(m for m in MODS if m == "kfkit.capture" or m.startswith("kfkit.capture.")))
def test_the_capture_layer_depends_on_nothing_above_it(module):
    above = {f"kfkit.{name}" for name in ABOVE_CAPTURE}
    bad = {m: chain for m, chain in reachable(GRAPH, module).items() if m in above or m.rpartition(".")[0] in above}
    assert not bad, "; ".join(" → ".join(chain) for chain in bad.values())


@pytest.mark.parametrize("leaf", LEAVES)
def test_the_leaves_import_nothing_from_kfkit(leaf):
    assert f"kfkit.{leaf}" in MODS, f"kfkit.{leaf} is missing"
    assert GRAPH[f"kfkit.{leaf}"] == set(), f"kfkit.{leaf} imports {sorted(GRAPH[f'kfkit.{leaf}'])}"


# --- rotations live in frames only (issue 27) --------------------------------------------------------------------
ROTATION_HOME = "frames.py"


def _terms(node):
    """The terms of a sum/difference: a + b − c → [a, b, c] (signs dropped)."""
    if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Add, ast.Sub)):
        return _terms(node.left) + _terms(node.right)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        return _terms(node.operand)
    return [node]


def _is_product(node):
    return isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mult)


def _mentions_pi(node):
    return any(
        isinstance(n, ast.Name) and n.id in ("pi", "TWO_PI") or isinstance(n, ast.Attribute) and n.attr == "pi"
        for n in ast.walk(node)
    )


def _is_number(node, *values):
    return isinstance(node, ast.Constant) and node.value in values


def rotation_maths(source: str) -> list[str]:
    """Rotation maths a module writes out itself, which belongs in kfkit.frames: scipy's Rotation or Slerp; a
    Hamilton product (a function with four or more sums of exactly four products, as w1·w2 − x1·x2 − y1·y2 − z1·z2);
    a quaternion → matrix expansion (1 − 2(a² + b²)); an angle wrap (… % 2π)."""
    tree, found = ast.parse(source), []
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.ImportFrom)
            and (node.module or "").startswith("scipy.spatial.transform")
            or isinstance(node, ast.Attribute)
            and node.attr in ("Rotation", "Slerp")
        ):
            found.append(f"line {node.lineno}: scipy's Rotation/Slerp")
        elif isinstance(node, (ast.FunctionDef, ast.Lambda)):
            sums = [
                n
                for n in ast.walk(node)
                if isinstance(n, ast.BinOp) and len(t := _terms(n)) == 4 and all(_is_product(x) for x in t)
            ]
            if len(sums) >= 4:
                found.append(
                    f"line {node.lineno}: a quaternion product written out ({len(sums)} sums of four products)"
                )
        elif (
            isinstance(node, ast.BinOp)
            and isinstance(node.op, ast.Sub)
            and _is_number(node.left, 1, 1.0)
            and _is_product(node.right)
            and _is_number(node.right.left, 2, 2.0)
            and len(_terms(node.right.right)) == 2
            and all(_is_product(x) for x in _terms(node.right.right))
        ):
            found.append(f"line {node.lineno}: a quaternion → matrix expansion (1 − 2(a² + b²))")
        elif isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mod) and _mentions_pi(node.right):
            found.append(f"line {node.lineno}: an angle wrap written out (% 2π)")
    return found


def test_the_rotation_detector_sees_each_kind():
    toy = """
from scipy.spatial.transform import Rotation
import math
def product(p, q):
    a, b, c, d = p
    e, f, g, h = q
    return (a * e - b * f - c * g - d * h, a * f + b * e + c * h - d * g,
            a * g - b * h + c * e + d * f, a * h + b * g - c * f + d * e)
def matrix(w, x, y, z):
    return 1 - 2 * (y * y + z * z)
def wrap(a):
    return math.pi - (math.pi - a) % (2 * math.pi)
"""
    kinds = " ".join(rotation_maths(toy))
    for words in ("Rotation", "quaternion product", "matrix expansion", "angle wrap"):
        assert words in kinds
    assert rotation_maths("import numpy as np\ndef f(a, b):\n    return a * b + 2 * np.sin(a) % 3\n") == []


@pytest.mark.parametrize(
    "path", sorted(p for p in KFKIT.rglob("*.py") if p.name != ROTATION_HOME), ids=lambda p: str(p.relative_to(KFKIT))
)
def test_rotations_live_in_frames_only(path):
    found = rotation_maths(path.read_text(encoding="utf-8"))
    assert not found, f"{path.relative_to(KFKIT.parent)} does rotation maths of its own (use kfkit.frames): {found}"


# --- the layers docs/design.md states hold in the code (issue 27) --------------------------------------------------
DESIGN = KFKIT.parent / "docs" / "design.md"


def stated_layers(text: str) -> dict:
    """{top-level name under kfkit: layer} from the package table's rows ``| n | `a`, `b` | … |``."""
    layers = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.split("|")]
        if len(cells) > 3 and cells[1].isdigit():
            for name in cells[2].replace("`", "").split(","):
                layers[name.strip()] = int(cells[1])
    return layers


def layer_violations(graph: dict, layers: dict, package="kfkit") -> list[str]:
    """Imports that point up (to a higher layer); a module not in the table is reported too."""

    def top(module):
        parts = module.split(".")
        return parts[1] if len(parts) > 1 else None

    bad = []
    for module, targets in graph.items():
        if top(module) is None:
            continue
        if top(module) not in layers:
            bad.append(f"{module}: not in docs/design.md's package table")
            continue
        for target in targets:
            if top(target) is not None and top(target) in layers and layers[top(target)] > layers[top(module)]:
                bad.append(f"{module} (layer {layers[top(module)]}) imports {target} (layer {layers[top(target)]})")
    return sorted(bad)


def test_the_layer_rule_sees_an_import_that_points_up():
    layers = stated_layers("| 0 | `low` | … |\n| 2 | `high`, `other` | … |")
    assert layers == {"low": 0, "high": 2, "other": 2}
    graph = {"kfkit.low": {"kfkit.high.sub"}, "kfkit.high.sub": {"kfkit.low"}, "kfkit.new": set()}
    assert layer_violations(graph, layers) == [
        "kfkit.low (layer 0) imports kfkit.high.sub (layer 2)",
        "kfkit.new: not in docs/design.md's package table",
    ]


def test_every_import_points_to_its_own_layer_or_below_as_docs_design_states():
    layers = stated_layers(DESIGN.read_text(encoding="utf-8"))
    assert layer_violations(import_graph(modules(KFKIT)), layers) == []
