"""The authoring rule every lab keeps (issue 18): each figure is explained in the very next cell, so a student reads
what a figure shows right under it, not after another code cell's printout.

Read from the solutions' stored outputs (they are what nbval validates and what the hand-outs are made from).
"""
import nbformat
import pytest

from kfkit.paths import KIT_ROOT

SOLUTIONS = sorted((KIT_ROOT / "solutions").glob("[0-9][0-9]_*.ipynb"))


def draws_a_figure(cell):
    return cell.cell_type == "code" and any("image/png" in o.get("data", {}) for o in cell.outputs)


def unexplained_figures(cells):
    """Indices of the cells whose figure is not followed by a markdown cell of text (a heading starts a new topic)."""
    return [i for i, cell in enumerate(cells) if draws_a_figure(cell) and not (
        i + 1 < len(cells) and cells[i + 1].cell_type == "markdown" and not cells[i + 1].source.startswith("#"))]


@pytest.mark.parametrize("path", SOLUTIONS, ids=lambda p: p.stem)
def test_every_figure_is_explained_in_the_very_next_cell(path):
    cells = nbformat.read(path, as_version=4).cells
    assert any(map(draws_a_figure, cells)), "a solution stored without its figures: re-run it"
    assert unexplained_figures(cells) == [], f"{path.name}: these cells' figures are not explained right below them"


def test_a_figure_followed_by_a_printout_a_heading_or_nothing_is_unexplained():
    figure = nbformat.v4.new_code_cell("plot()", outputs=[nbformat.v4.new_output("display_data", {"image/png": "iVBOR"})])
    printout, heading, text = (nbformat.v4.new_code_cell("print(1)"), nbformat.v4.new_markdown_cell("## 2. Next"),
                               nbformat.v4.new_markdown_cell("The curve falls because …"))
    assert unexplained_figures([figure, text, figure, printout, text, figure, heading, figure]) == [2, 5, 7]
