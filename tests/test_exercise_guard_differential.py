"""The exercise guard never changes what correct code does (issue 24 §2): every way of writing a lab's exercises in
tests/exercise_variants.py (at least 30 per lab: decorators, closures, classes, comprehensions, walrus, match, try,
generators, magics, star imports, globals, …) runs in a Jupyter kernel with the guard loaded exactly as in one
without it, and exactly as the reference solution does.

Oracles: the kernel without the guard (every cell's outputs, and the names each way leaves, must be the same with
it), and the solution's own exercise cells run without the guard (each way's checks and results must match them).
One pair of kernels per lab (running side by side) runs every way in turn, the lab's first cell (its imports)
before them; a way's cells are its exercise cells, a cell of checks (the lab's random-case checkpoints, on cases
drawn once, with ``answer=`` in every other way) that also calls every exercise, and a cell that calls them through
a function of the notebook, then puts the namespace back.
"""

from __future__ import annotations

import asyncio
import dataclasses
import importlib

import cloudpickle
import nbformat
import numpy as np
import pytest
from exercise_variants import exercise_cells, variants
from nbclient import NotebookClient

from kfkit import checkpoints as cps
from kfkit.paths import KIT_ROOT

SOLUTIONS = sorted((KIT_ROOT / "solutions").glob("*.ipynb"))
SHORT = 100  # rows of a long input array kept for the calls (the checks use their own cases)
GUARD = "%load_ext kfkit.exercise_guard"


def exercise_inputs(prefix: str, exercises: list[str]) -> tuple[dict, list[str], dict]:
    """(arguments to call each exercise with, the exercises only read (their inputs are whole recordings), the
    random-case checkpoints of the lab, name → function): each exercise's inputs are the first case of its first
    random-case checkpoint, else of its first checkpoint, long arrays cut to SHORT rows."""
    for lab in cps.LABS:
        importlib.import_module(f"kfkit.checkpoints.{lab}")
    mine = [cp for name, cp in cps.REGISTRY.items() if name.startswith(prefix + ".") and cp.function in exercises]
    random = {cp.name: cp.function for cp in mine if "random" in cp.what}
    args, read_only = {}, []
    for name in exercises:
        chosen = sorted((cp for cp in mine if cp.function == name), key=lambda cp: "random" not in cp.what)
        case = chosen[0].cases(np.random.default_rng(0))[0].args
        if any(type(v).__module__.startswith("kfkit") and not dataclasses.is_dataclass(v) for v in case.values()):
            read_only.append(name)
        else:
            args[name] = {
                k: v[:SHORT] if isinstance(v, np.ndarray) and v.ndim and len(v) > SHORT else v for k, v in case.items()
            }
    return args, read_only, random


def harness(args_path, args: dict, read_only: list[str], checked: list[str]) -> tuple[str, str]:
    """(the setup cell, the cell that calls every exercise): what it prints is a digest of every result. The setup
    draws the cases of each checkpoint in ``checked`` once (seed 1), and every way's check replays them."""
    calls = "".join(f"        {n!r}: {n}(**ARGS[{n!r}]),\n" for n in args)
    calls += "".join(f"        {n!r}: callable({n}),\n" for n in read_only)
    setup = (
        "import copy, dataclasses, hashlib, pickle, warnings\nimport numpy as np\n"
        "from kfkit import checkpoints\n\n"
        f"for name in {checked!r}:\n    drawn = checkpoints.get(name).cases(np.random.default_rng(1))\n"
        "    checkpoints.REGISTRY[name] = dataclasses.replace(checkpoints.get(name),\n"
        "                                                    cases=lambda rng, drawn=drawn: copy.deepcopy(drawn))\n\n"
        f"with open({str(args_path)!r}, 'rb') as f:\n    ARGS = pickle.load(f)\n\n"
        "def digest(value):\n    return hashlib.sha256(pickle.dumps(value)).hexdigest()[:16]\n\n"
        "def use_all():\n    with warnings.catch_warnings():\n        warnings.simplefilter('ignore')\n"
        f"        return {{\n{calls}    }}\n\nSNAPSHOT = dict(globals())\n"
    )
    use = (
        "with warnings.catch_warnings():\n    warnings.simplefilter('ignore')\n"
        f"    results = {{\n{calls}    }}\nprint(digest(results))\n"
    )
    return setup, use


RESTORE = (
    "print(digest(use_all()))\n"
    "left = sorted(n for n in globals() if n not in SNAPSHOT and n != 'SNAPSHOT' and not n.startswith('_'))\n"
    "print(left)\nfor name in left:\n    del globals()[name]\n"
    "globals().update({n: v for n, v in SNAPSHOT.items() if not n.startswith('_')})\n"
)


def outputs(cell) -> list:
    """A cell's outputs as comparable values: streams by name (however the kernel chunked them), results and displays
    as text, errors by name."""
    seen = []
    for o in cell.outputs:
        if o.output_type == "stream" and seen and seen[-1][0] == o.name:
            seen[-1] = (o.name, seen[-1][1] + o.text)
        elif o.output_type == "stream":
            seen.append((o.name, o.text))
        elif o.output_type in ("execute_result", "display_data"):
            seen.append((o.output_type, o.data.get("text/plain", "")))
        else:
            seen.append((o.output_type, o.get("ename", "")))
    return seen


def run_all(*runs: list[str]) -> list[list[list]]:
    """Run each list of cells in a fresh kernel of its own, in order, the kernels side by side (an error fails the
    test, naming the cell); the outputs of each cell of each."""
    notebooks = [nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c) for c in cells]) for cells in runs]

    async def execute_all():
        await asyncio.gather(
            *(
                NotebookClient(
                    nb,
                    timeout=600,
                    allow_errors=False,
                    kernel_name="python3",
                    resources={"metadata": {"path": str(KIT_ROOT / "labs")}},
                ).async_execute()
                for nb in notebooks
            )
        )

    asyncio.run(execute_all())
    return [[outputs(c) for c in nb.cells] for nb in notebooks]


@pytest.mark.parametrize("path", SOLUTIONS, ids=[p.stem for p in SOLUTIONS])
def test_every_way_of_writing_the_exercises_runs_as_without_the_guard(path, tmp_path):
    solution = nbformat.read(path, as_version=4)
    exercises = [name for _, names in exercise_cells(solution) for name in names]
    ways = variants(solution)
    assert len(ways) >= 30 and ways[0].name == "as_written"
    args, read_only, random = exercise_inputs(path.stem.split("_")[0], exercises)
    assert len(args) >= len(exercises) - 1, "call the exercises, not only read them"
    with open(tmp_path / "args.pickle", "wb") as f:
        cloudpickle.dump(args, f)  # a checkpoint's input may be a function (lab 04's numerical_jacobian)
    setup, use = harness(tmp_path / "args.pickle", args, read_only, list(random))
    first = next(c.source for c in solution.cells if c.cell_type == "code")
    assert GUARD in first
    plan, where = [setup], {}  # where: (way, part) → index of the cell in the plan
    for k, way in enumerate(ways):
        answer = "answer=" if k % 2 else ""  # check(…, answer=f) in every other way
        checks = "".join(f"check({name!r}, {answer}{function})\n" for name, function in random.items())
        parts = {
            **{f"exercise cell {i}": c for i, c in enumerate(way.cells)},
            "checks and calls": checks + use,
            "calls through a function, names left": RESTORE,
        }
        for part, source in parts.items():
            where[way.name, part] = len(plan) + 1
            plan.append(source)
    guarded, plain = run_all([first] + plan, [first.replace(GUARD, "")] + plan)

    skipped = [(way, part) for (way, part), i in where.items() if "skipped" in str(guarded[i])]
    assert skipped == [], f"the guard skipped correct code: {skipped}"
    for (way, part), i in where.items():
        assert guarded[i] == plain[i], f"{way}, {part}: with the guard {guarded[i]}, without {plain[i]}"
    reference = plain[where["as_written", "checks and calls"]]
    assert reference[0][1].count("✅") == len(random) and "❌" not in str(reference) and "⏳" not in str(reference)
    for way in ways:
        mine = plain[where[way.name, "checks and calls"]]
        assert mine == reference, f"{way.name}: not as the solution"
        digests = plain[where[way.name, "calls through a function, names left"]][0][1].split("\n")[0]
        assert digests == reference[0][1].strip().split("\n")[-1], f"{way.name}: not as the solution through a function"
