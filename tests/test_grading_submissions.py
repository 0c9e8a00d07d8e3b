"""Which files ``kfkit grade`` opens. A submissions folder is the students' ground: a link named
``alice.ipynb`` pointing at the kit's solution, a link to another student's folder, a named pipe. The grader
runs with the instructor's permissions outside the sandbox, so it must refuse each of them (a gradebook row
with status ``refused`` and the reason, and a line of the summary: no submission silently disappears) and
never open a path outside the folder being graded, nor a pipe.

The oracle is the file system: what each entry is (``os.lstat``) and where a link points (``os.readlink``);
which files reached the grading is recorded by a stand-in for the per-submission kernel run.
"""

import os
import shutil
import subprocess
import sys
import threading

import nbformat
import pytest
from waiting import HANG_GUARD_S

from kfkit.checkpoints import Status
from kfkit.grading import core, gradebook, sandbox
from kfkit.paths import KIT_ROOT

SOLUTION = KIT_ROOT / "solutions" / "01_roll_kf_1d.ipynb"
CHECKPOINTS = core.lab_checkpoints("01")
BOX = sandbox.Sandbox("root", True, ["/x"])


def notebook(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    nbformat.write(nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell("x = 1")]), path)
    return path


def full_marks(name):
    return core.SubmissionGrade(
        name, 1, [core.Row(cp.name, cp.points, cp.points, Status.PASSED, "ok") for cp in CHECKPOINTS]
    )


@pytest.fixture
def kernels(monkeypatch):
    """Stands in for the kernel run of each submission: → the list of files handed to it."""
    given = []
    monkeypatch.setattr(core, "_grade_one", lambda task: given.append(os.fspath(task[0])) or full_marks(task[1]))
    return given


@pytest.fixture(params=["openat", "lstat"])
def opening(request, monkeypatch):
    """Both ways files are opened: ``openat`` step by step (Linux, macOS), and where it is missing (Windows)
    ``lstat`` of each step and ``fstat`` compared once open."""
    if request.param == "lstat":
        monkeypatch.setattr(os, "supports_dir_fd", set())
    return request.param


@pytest.fixture
def class_folder(tmp_path):
    """A submissions folder with one honest notebook and every kind of entry that must be refused."""
    subs = tmp_path / "subs"
    notebook(subs / "victim" / "lab01.ipynb")
    (subs / "alice.ipynb").symlink_to(SOLUTION)  # the attack: the kit's solution under Alice's name
    (subs / "aaa").symlink_to("victim")  # a link to another student's folder
    (subs / "bbb").mkdir()
    (subs / "bbb" / "lab01.ipynb").symlink_to("../victim/lab01.ipynb")  # a link to another student's notebook
    (subs / "dangling.ipynb").symlink_to(tmp_path / "nowhere.ipynb")
    os.mkfifo(subs / "carol.ipynb")  # size 0: passes a size check; with no writer, reading it blocks forever
    (subs / "notes.txt").symlink_to(SOLUTION)  # not a notebook, not a folder: not a submission at all
    return subs


#: entry → what its refusal must say (from os.readlink / os.lstat, as set up above)
REFUSED = {
    "subs/alice.ipynb": f"a symbolic link (to {SOLUTION}), not followed",
    "subs/aaa": "a symbolic link (to victim), not followed",
    "subs/bbb/lab01.ipynb": "a symbolic link (to ../victim/lab01.ipynb), not followed",
    "subs/carol.ipynb": "a named pipe (FIFO), not opened",
    "subs/dangling.ipynb": "a symbolic link (to ",
}


def test_links_and_pipes_become_refused_rows_named_in_the_summary(class_folder, kernels, monkeypatch):
    monkeypatch.chdir(class_folder.parent)
    grades, text = core.grade([class_folder], "01", class_folder.parent / "g.csv", progress=False, sandbox=BOX)
    assert kernels == [str(class_folder.resolve() / "victim" / "lab01.ipynb")]  # nothing else reached a kernel
    rows = {g.submission: g.rows for g in gradebook.read_gradebook(class_folder.parent / "g.csv")}
    assert sorted(rows) == sorted([*REFUSED, "subs/victim/lab01.ipynb"])  # none dropped, none added
    for name, why in REFUSED.items():
        assert [r.status for r in rows[name]] == [Status.REFUSED] * len(CHECKPOINTS), name
        assert {r.points for r in rows[name]} == {0} and why in rows[name][0].message, rows[name][0].message
        assert f"warning: {name}: refused: it is {why}" in text
    assert {r.status for r in rows["subs/victim/lab01.ipynb"]} == {Status.PASSED}
    assert "REFUSED 5 " in text and "1 submission(s) graded" in text
    feedback = (class_folder.parent / "g_feedback" / "subs" / "alice.md").read_text()
    assert "symbolic link" in feedback and f"Score: 0 / {sum(cp.points for cp in CHECKPOINTS)}" in feedback


def test_a_link_is_never_read(tmp_path, opening):
    """Reading the submission itself: a link to the solution is refused, its target never opened."""
    (tmp_path / "alice.ipynb").symlink_to(SOLUTION)
    with pytest.raises(core.NotANotebook) as refused:
        core.read_notebook(tmp_path / "alice.ipynb")
    assert refused.value.status == Status.REFUSED and "symbolic link" in str(refused.value)
    assert opening == "lstat" or f"symbolic link (to {SOLUTION})" in str(refused.value)


def test_a_pipe_without_a_writer_is_refused_without_blocking(tmp_path, opening):
    os.mkfifo(tmp_path / "carol.ipynb")
    outcome = []

    def read():
        try:
            core.read_notebook(tmp_path / "carol.ipynb")
            outcome.append("read")
        except core.NotANotebook as exc:
            outcome.append(exc)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(HANG_GUARD_S)
    if reader.is_alive():  # the old grader: blocked in open(); a writer that closes at once lets it go
        with open(tmp_path / "carol.ipynb", "w"):
            pass
        pytest.fail("reading a named pipe blocked the grader")
    assert isinstance(outcome[0], core.NotANotebook) and outcome[0].status == Status.REFUSED
    assert "named pipe (FIFO)" in str(outcome[0])


def test_a_file_or_folder_swapped_for_a_link_after_the_walk_is_refused(tmp_path, opening):
    """Between finding a submission and opening it, a student who can still write there swaps it."""
    notebook(tmp_path / "subs" / "x" / "lab01.ipynb")
    (tmp_path / "elsewhere").mkdir()
    shutil.copy(SOLUTION, tmp_path / "elsewhere" / "lab01.ipynb")
    [found], _ = core.find_submissions([tmp_path / "subs"])
    assert found.refused == "" and core.read_code_cells(found) == ["x = 1"]
    os.rename(tmp_path / "subs" / "x", tmp_path / "x_before")
    (tmp_path / "subs" / "x").symlink_to(tmp_path / "elsewhere")  # the folder is now a link to the solution
    with pytest.raises(core.NotANotebook) as refused:
        core.read_notebook(found)
    assert refused.value.status == Status.REFUSED and "x is a symbolic link" in str(refused.value)
    (tmp_path / "subs" / "x").unlink()
    os.rename(tmp_path / "x_before", tmp_path / "subs" / "x")
    (tmp_path / "subs" / "x" / "lab01.ipynb").unlink()
    (tmp_path / "subs" / "x" / "lab01.ipynb").symlink_to(SOLUTION)  # and now the file itself
    with pytest.raises(core.NotANotebook) as refused:
        core.read_notebook(found)
    assert refused.value.status == Status.REFUSED and "symbolic link" in str(refused.value)


def test_nbgrader_layout_refuses_links_between_students(tmp_path, kernels, monkeypatch):
    """nbgrader's submitted/<student>/<assignment>/: Mallory's assignment folder is a link to Alice's,
    Bob's notebook a link to the solution."""
    submitted = tmp_path / "submitted"
    notebook(submitted / "alice" / "lab01" / "01_roll_kf_1d.ipynb")
    (submitted / "mallory").mkdir()
    (submitted / "mallory" / "lab01").symlink_to("../alice/lab01")
    (submitted / "bob" / "lab01").mkdir(parents=True)
    (submitted / "bob" / "lab01" / "01_roll_kf_1d.ipynb").symlink_to(SOLUTION)
    monkeypatch.chdir(tmp_path)
    core.grade([submitted], "01", tmp_path / "g.csv", progress=False, sandbox=BOX)
    assert kernels == [str(submitted.resolve() / "alice" / "lab01" / "01_roll_kf_1d.ipynb")]
    status = {g.submission: {r.status for r in g.rows} for g in gradebook.read_gradebook(tmp_path / "g.csv")}
    assert status == {
        "submitted/alice/lab01/01_roll_kf_1d.ipynb": {Status.PASSED},
        "submitted/mallory/lab01": {Status.REFUSED},
        "submitted/bob/lab01/01_roll_kf_1d.ipynb": {Status.REFUSED},
    }


def test_update_refuses_a_link_it_is_given(tmp_path, kernels, monkeypatch):
    """--update submissions/alice.ipynb, where Alice has since replaced her notebook by a link."""
    notebook(tmp_path / "subs" / "alice.ipynb")
    notebook(tmp_path / "subs" / "bob.ipynb")
    monkeypatch.chdir(tmp_path)
    core.grade([tmp_path / "subs"], "01", tmp_path / "g.csv", progress=False, sandbox=BOX)
    (tmp_path / "subs" / "alice.ipynb").unlink()
    (tmp_path / "subs" / "alice.ipynb").symlink_to(SOLUTION)
    kernels.clear()
    core.grade([tmp_path / "subs" / "alice.ipynb"], "01", tmp_path / "g.csv", progress=False, sandbox=BOX, update=True)
    assert kernels == []
    status = {g.submission: {r.status for r in g.rows} for g in gradebook.read_gradebook(tmp_path / "g.csv")}
    assert status == {"subs/alice.ipynb": {Status.REFUSED}, "subs/bob.ipynb": {Status.PASSED}}


@pytest.mark.slow
def test_kfkit_grade_refuses_a_link_to_the_solution_and_a_pipe(tmp_path):
    """The command an instructor runs, on a folder holding only what must be refused: it ends (no pipe is
    read), exits 1, and the gradebook and the summary name both; nothing is graded, so no kernel starts."""
    subs = tmp_path / "subs"
    subs.mkdir()
    (subs / "alice.ipynb").symlink_to(SOLUTION)
    os.mkfifo(subs / "carol.ipynb")
    done = subprocess.run(
        [sys.executable, "-m", "kfkit", "grade", "--lab", "01", "--out", "g.csv", "subs"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
    )
    assert done.returncode == 1, done.stderr
    assert "subs/alice.ipynb: refused: it is a symbolic link" in done.stdout
    assert "subs/carol.ipynb: refused: it is a named pipe (FIFO)" in done.stdout
    rows = gradebook.read_gradebook(tmp_path / "g.csv")
    assert {g.submission: {r.status for r in g.rows} for g in rows} == {
        "subs/alice.ipynb": {Status.REFUSED},
        "subs/carol.ipynb": {Status.REFUSED},
    }
    assert sum(g.points for g in rows) == 0


def test_a_folder_that_cannot_be_read_is_named(tmp_path, kernels, monkeypatch):
    notebook(tmp_path / "subs" / "alice.ipynb")
    notebook(tmp_path / "subs" / "locked" / "bob.ipynb")

    def walk_without_locked(top, onerror=None, followlinks=False):  # os.walk meeting a folder it may not list
        # (simulated: root, as the grader often runs, may list any folder whatever its mode)
        for folder, dirs, files in real_walk(top, followlinks=followlinks):
            if "locked" in dirs:
                onerror(PermissionError(13, "Permission denied", os.path.join(folder, "locked")))
                dirs.remove("locked")
            yield folder, dirs, files

    real_walk = os.walk
    monkeypatch.setattr(os, "walk", walk_without_locked)
    found, warnings = core.find_submissions([tmp_path / "subs"])
    assert [s.name for s in found] == ["subs/alice.ipynb"]
    assert warnings == [
        f"{tmp_path.resolve() / 'subs' / 'locked'}: folder cannot be read (Permission denied): "
        "what it holds is not graded"
    ]
