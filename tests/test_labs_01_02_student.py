"""Labs 01 and 02 as a student meets them (issue 18).

(Run All on each hand-out with every exercise unfilled: ``tests/test_notebooks.py``, for every lab.) The text
leaves room to think: one Questions section at the end whose questions name their section (every figure explained
in the very next cell: ``tests/test_solutions_layout.py``, for every lab), and a prompt to predict before the key
figure (lab 01's consistency, lab 02's Allan curve).
"""

import re

import nbformat
import pytest

from kfkit.paths import KIT_ROOT

LABS = {
    "01_roll_kf_1d": {"key_figure": "plots.consistency("},
    "02_bias_and_noise": {"key_figure": "plots.allan(axes[0], taus, adev_g", "computed": "02.q_from_datasheet"},
}


def read(folder, name):
    return nbformat.read(KIT_ROOT / folder / f"{name}.ipynb", as_version=4)


@pytest.mark.parametrize("name", LABS)
def test_the_solution_loads_the_exercise_guard_right_after_matplotlib(name):
    first = next(c for c in read("solutions", name).cells if c.cell_type == "code")
    lines = first.source.splitlines()
    assert lines[:2] == ["%matplotlib inline", "%load_ext kfkit.exercise_guard"]
    assert lines[2].startswith("#") and "skipped" in lines[2]  # says what it does, for the student


@pytest.mark.parametrize("name", LABS)
def test_the_questions_are_one_section_at_the_end_each_naming_its_section(name):
    """The last section is the Questions: each names the section it builds on, each has a model answer, and a
    question to compute has its function and check in the section (issue 26 §2)."""
    cells = read("solutions", name).cells
    start = max(i for i, c in enumerate(cells) if c.cell_type == "markdown" and re.match(r"#+ ", c.source))
    assert re.match(r"## \d+\. Questions\n", cells[start].source), "the lab's last section is its Questions"
    assert not any("Questions" in c.source for c in cells[:start] if c.cell_type == "markdown"), "one Questions section"
    text = "\n".join(c.source for c in cells[start:] if c.cell_type == "markdown")
    asked, answers = text.split("### BEGIN SOLUTION")
    questions = re.findall(r"^\d+\. (.*)", asked, flags=re.M)
    assert len(questions) >= 4 and all(q.startswith("*Section") for q in questions), questions
    assert len(re.findall(r"^\d+\. ", answers, flags=re.M)) == len(questions), "one model answer per question"
    computed = LABS[name].get("computed")
    if computed:
        assert any(f'check("{computed}"' in c.source for c in cells[start:] if c.cell_type == "code"), computed


@pytest.mark.parametrize("name", LABS)
def test_the_key_figure_comes_after_a_prompt_to_predict_it(name):
    cells = read("solutions", name).cells
    index = next(i for i, c in enumerate(cells) if c.cell_type == "code" and LABS[name]["key_figure"] in c.source)
    assert any("image/png" in o.get("data", {}) for o in cells[index].outputs)
    before = cells[index - 1]
    assert before.cell_type == "markdown" and before.source.startswith("**Predict before you run:**")
    assert "?" in before.source
