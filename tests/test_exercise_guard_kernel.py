"""kfkit.exercise_guard in a Jupyter kernel, where a hand-out runs: ipykernel transforms every cell twice (once in
do_execute, again in run_cell), and a student runs a skipped cell again after finishing an exercise. Each note
must give the reason of this moment, and a cell must never be held back by what it itself would have made."""

import nbformat
import pytest
from nbclient import NotebookClient
from waiting import HANG_GUARD_S

STUB = "def {name}(x):\n    # YOUR CODE HERE\n    raise NotImplementedError()\n"
DONE = "def {name}(x):\n    return 2 * x\n"


@pytest.fixture(scope="module")
def run():
    """``run(code)`` executes one cell in one kernel (the guard loaded) and returns what it printed."""
    nb = nbformat.v4.new_notebook()
    client = NotebookClient(
        nb, timeout=HANG_GUARD_S, startup_timeout=HANG_GUARD_S, allow_errors=False, kernel_name="python3"
    )
    with client.setup_kernel():

        def run(code):
            cell = nbformat.v4.new_code_cell(code)
            nb.cells.append(cell)
            client.execute_cell(cell, len(nb.cells) - 1)  # an error raises CellExecutionError
            return "".join(o.get("text", "") for o in cell.outputs)

        run("%load_ext kfkit.exercise_guard")
        yield run


def test_a_cell_that_rebinds_what_it_reads_names_the_exercise_and_runs_once_it_is_done(run):
    """Lab 03's turns cell read ``turns_rec`` and rebound it: skipped, its second transform saw turns_rec missing
    and blamed it, and once the exercise was written the cell was still held back by its own name."""
    run(STUB.format(name="find_turns"))
    run("rec = [1.0, 2.0]")
    cell = "n = len(rec)\nrec = find_turns(rec)\nprint('turned', n, rec)"
    assert "it needs find_turns (not written yet)" in run(cell)
    run(DONE.format(name="find_turns"))
    assert run(cell).strip() == "turned 2 [1.0, 2.0, 1.0, 2.0]"


def test_a_note_names_what_is_still_missing_not_what_was_missing_before(run):
    """A cell skipped for one exercise, then (that one written) for another: the cells that use what it makes
    must name the other one; naming the first, already written, sends the student back to a finished exercise."""
    run(STUB.format(name="calibrate") + "\n" + STUB.format(name="heading"))
    make = "c = calibrate(1.0)\nvalue = heading(c)"
    use = "print(value)"
    run(make)
    assert "made by a cell that needs calibrate (not written yet)" in run(use)
    run(DONE.format(name="calibrate"))
    assert "it needs heading (not written yet)" in run(make)
    note = run(use)
    assert "made by a cell that needs heading (not written yet)" in note and "calibrate" not in note
    run(DONE.format(name="heading"))
    run(make)
    assert run(use).strip() == "4.0"


@pytest.mark.parametrize(
    "reads_it", ["total = total + 1", "total += 1", "for total in sorted(total):\n    pass", "(total := total * 2)"]
)
def test_a_statement_that_reads_a_name_before_rebinding_it_waits_for_it(run, reads_it):
    """An assignment binds its name after its value is evaluated (a loop after its iterable): ``total = total + 1``
    reads the ``total`` a skipped cell never made, and must be skipped, not raise NameError."""
    run(STUB.format(name="count"))
    run("total = count(3)")
    note = run(reads_it)
    assert "it uses total, made by a cell that needs count (not written yet)" in note


def test_a_stub_is_told_from_a_finished_function_by_its_source_in_the_kernel(run):
    """ipykernel keeps each cell's source under a file name of its own: the guard reads the stub there."""
    run("import numpy as np")
    run(
        "def tilt(ay, az):\n    '''Tilt (rad).'''\n    ay = np.asarray(ay)\n"
        "    # YOUR CODE HERE\n    raise NotImplementedError()\n"
    )
    assert "it needs tilt (not written yet)" in run("angle = tilt(1.0, 1.0)\nprint('ran')")
    run(
        "def tilt(ay, az):\n    if np.ndim(ay) > 1:\n        raise NotImplementedError('2-D input')\n"
        "    return np.arctan2(ay, az)\n"
    )
    assert run("angle = tilt(1.0, 1.0)\nprint(round(angle, 4))").strip() == "0.7854"


def test_a_check_of_an_exercise_whose_new_cell_was_skipped_says_stale_and_never_passes(run):
    """The cell that rewrites accel_roll also calls a stub: it is skipped (twice, once per transform), and the check of
    accel_roll must not pass the accel_roll of before; once the stub is done, the new code is what is checked."""
    run("import numpy as np\nfrom kfkit.checkpoints import check")
    run(STUB.format(name="smooth"))
    run("def accel_roll(ay, az):\n    return np.arctan2(-ay, -az)\n")
    assert "✅ 01.accel_roll" in run("check('01.accel_roll', accel_roll);")
    rewrite = "def accel_roll(ay, az):\n    return np.arctan2(ay, az)  # changed since\nsmoothed = smooth(1.0)"
    assert "it needs smooth (not written yet)" in run(rewrite)
    note = run("check('01.accel_roll', accel_roll);")
    assert "✅" not in note and "⏳ 01.accel_roll: stale: the cell that defines accel_roll was skipped" in note
    run(DONE.format(name="smooth"))
    assert "skipped" not in run(rewrite)
    assert "❌ 01.accel_roll" in run("check('01.accel_roll', accel_roll);")


def test_a_name_a_function_binds_with_global_is_there_once_it_ran(run):
    run(STUB.format(name="start_value"))
    run("x0 = start_value(1.0)")  # skipped
    run("def init():\n    global x0\n    x0 = 0.5\ninit()")
    assert run("print(x0)").strip() == "0.5"
