"""kfkit grade: real kernels on submissions built from lab 01's solution and lab notebooks.

One module fixture grades a whole folder of honest and adversarial submissions through the CLI
(``--jobs 2``, short timeouts); the tests then read its gradebook and feedback. The expected
grades come from what each submission does, never from the grader's own output.
"""
import base64
import csv
import hashlib
import json
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import nbformat
import numpy as np
import psutil
import pytest

from kfkit.checkpoints import LABS
from kfkit.cli import main
from kfkit.datasets import KIT_ROOT
from kfkit.grading import _kernel_side, core, sandbox, wire

SOLUTION = KIT_ROOT / "solutions" / "01_roll_kf_1d.ipynb"
LAB = KIT_ROOT / "labs" / "01_roll_kf_1d.ipynb"
POINTS = {"01.accel_roll": 1, "01.kf_predict": 1, "01.kf_update": 2, "01.run_kf": 2, "01.kf_beats_sensors": 2}
TIMEOUT = 6  # s per cell / call in these tests (the grader's warm-up has loaded the heavy modules)
KIT_FILE = KIT_ROOT / "kfkit" / "checkpoints" / "lab01.py"
KIT_CANARY = KIT_ROOT / "kfkit" / ".grading-test-canary"


def read(path):
    return nbformat.read(path, as_version=4)


def minimal():
    """Lab 01 reduced to its imports and the cells defining its exercise functions (solved)."""
    cells = [c for c in read(SOLUTION).cells if c.cell_type == "code"]
    keep = [cells[0]] + [c for c in cells if "### BEGIN SOLUTION" in c.source and "def " in c.source]
    return nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c.source) for c in keep])


def edit(nb, old, new):
    hits = [c for c in nb.cells if old in c.source]
    assert hits, f"{old!r} not in the notebook"
    for c in hits:
        c.source = c.source.replace(old, new)
    return nb


def add(nb, source, at=1, **metadata):
    nb.cells.insert(at, nbformat.v4.new_code_cell(source, metadata=metadata))
    return nb


def build(folder: Path, instructor: Path):
    canary = instructor / "canary.txt"
    canary.write_text("instructor's file")
    subs = {
        "correct": read(SOLUTION),
        "correct_again": minimal(),
        "blank": read(LAB),
        "wrong": edit(minimal(), "np.arctan2(-ay, -az)", "np.arctan2(ay, -az)"),
        "loop": add(edit(minimal(), "return np.arctan2(-ay, -az)", "while True:\n        pass"),
                    "print(accel_roll(0.0, -9.8))", at=-1),
        "stubborn": edit(minimal(), "return np.arctan2(-ay, -az)",
                         "while True:\n        try:\n            pass\n        except BaseException:\n            pass"),
        "exits": add(edit(minimal(), "    y = z - x\n", "    import sys\n    sys.exit(1)\n"),
                     "import os\nos._exit(3)"),
        "huge_print": add(minimal(), "print('x' * 30_000_000)\nfor i in range(100_000):\n    print(i)"),
        "renamed": edit(edit(minimal(), "def accel_roll(", "def accel_roll_v2("), "def kf_update(", "def kf_update_old("),
        "syntax": edit(minimal(), "return x + omega * dt, P + q", "return x + omega * dt, P + q)"),
        "tags": minimal(),
        "tamper": add(read(LAB), """
import kfkit, kfkit.checkpoints as C, kfkit.filters as F, kfkit.filters.roll as R
C.run_checkpoint = lambda cp, answer, seed=None: C.CheckResult(cp.name, "passed", 1, 1, cp.points, cp.points, "ok")
C.compare = lambda *a, **k: None
for cp in C.REGISTRY.values():
    object.__setattr__(cp, "judge", lambda case, got: None)
def kf_predict(x, P, omega, dt, q):
    return (0.0, 0.0)
F.roll_kf_predict = R.roll_kf_predict = kf_predict
from kfkit.filters import roll_kf_update as kf_update
print("✅ 01.kf_predict: 12/12 random cases")
""", at=-1),
        "vandal": add(minimal(), f"""
import os, socket
attempts = {{}}
for name, act in {{
    "write instructor": lambda: open({str(instructor / 'planted.txt')!r}, "w").write("x"),
    "delete instructor": lambda: os.remove({str(canary)!r}),
    "write kit": lambda: open({str(KIT_FILE)!r}, "a").write("\\n# vandal"),
    "new kit file": lambda: open({str(KIT_ROOT / 'kfkit' / 'planted.py')!r}, "w").write("x"),
    "delete kit": lambda: os.remove({str(KIT_CANARY)!r}),
    "network": lambda: socket.create_connection(("1.1.1.1", 53), timeout=2),
}}.items():
    try:
        act()
        attempts[name] = "done"
    except Exception as exc:
        attempts[name] = type(exc).__name__
"""),
    }
    tagged = subs["tags"]
    for c in tagged.cells[1:]:
        c.metadata["tags"] = ["skip-execution", "raises-exception"]
    tagged.metadata["kernelspec"] = {"name": "no-such-kernel", "display_name": "nope", "language": "cobol"}
    for name, nb in subs.items():
        nbformat.write(nb, folder / f"{name}.ipynb")
    (folder / "not_json.ipynb").write_text("this is not JSON {")
    (folder / "binary.ipynb").write_bytes(bytes(range(256)) * 10)
    (folder / "not_notebook.ipynb").write_text(json.dumps({"hello": "world"}))


def graded_rows(path):
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    out = {}
    for r in rows:
        out.setdefault(Path(r["submission"]).stem, {})[r["checkpoint"]] = r
    return rows, out


def grader_kernels(marker):
    found = []
    for p in psutil.process_iter(["cmdline"]):
        try:
            if any(marker in a for a in (p.info["cmdline"] or [])):
                found.append(p)
        except psutil.Error:
            pass
    return found


@pytest.fixture(scope="module")
def graded(tmp_path_factory):
    instructor = tmp_path_factory.mktemp("instructor")
    subs = instructor / "submissions"
    subs.mkdir()
    empty = instructor / "empty"
    empty.mkdir()
    isolated = sandbox.probe([str(instructor)]).mode != "none"
    KIT_CANARY.write_text("kit file")
    build(subs, instructor)
    if not isolated:  # never run the vandal unprotected: it would really write into the kit
        (subs / "vandal.ipynb").unlink()
    kit_hash = hashlib.sha256(KIT_FILE.read_bytes()).hexdigest()
    out = instructor / "gradebook.csv"
    scratch = Path(tempfile.mkdtemp(prefix="kg-", dir="/tmp"))  # the grader's temporary folders (short: sockets)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tempfile, "tempdir", str(scratch))
        code = main(["grade", "--lab", "01", "--out", str(out), "--jobs", "2", "--timeout", str(TIMEOUT),
                     "--total-timeout", "120", str(subs), str(empty)])
    rows, by_sub = graded_rows(out)
    canary_kept = KIT_CANARY.exists()
    KIT_CANARY.unlink(missing_ok=True)
    yield {"isolated": isolated, "kit_canary_kept": canary_kept, "scratch": scratch, "code": code, "rows": rows,
           "subs": by_sub, "dir": instructor, "out": out, "kit_hash": kit_hash}
    shutil.rmtree(scratch, ignore_errors=True)


def points(graded, sub):
    return {cp: float(r["points"]) for cp, r in graded["subs"][sub].items()}


def message(graded, sub, cp):
    return graded["subs"][sub][cp]["message"]


def test_gradebook_has_one_row_per_checkpoint_and_submission(graded):
    assert graded["code"] == 0
    assert list(graded["rows"][0]) == ["submission", "checkpoint", "points", "max_points", "message"]
    assert len(graded["subs"]) == 16 if graded["isolated"] else 15
    for sub, cps in graded["subs"].items():
        assert {cp: float(r["max_points"]) for cp, r in cps.items()} == POINTS, sub


def test_correct_solution_full_marks_on_fresh_random_cases(graded):
    for sub in ("correct", "correct_again"):
        assert points(graded, sub) == POINTS
    seeds = [(graded["dir"] / "gradebook_feedback" / f"submissions_{s}.md").read_text().split("seed ")[1].split(" ")[0]
             for s in ("correct", "correct_again")]
    assert seeds[0] != seeds[1]


def test_blank_lab_scores_zero_not_attempted(graded):
    assert set(points(graded, "blank").values()) == {0}
    assert all("not attempted" in r["message"] for r in graded["subs"]["blank"].values())


def test_wrong_answer_loses_only_its_points_with_expected_vs_got(graded):
    assert points(graded, "wrong") == {**POINTS, "01.accel_roll": 0}
    assert "expected 1.571, got -1.571" in message(graded, "wrong", "01.accel_roll") or "sign is flipped" in message(graded, "wrong", "01.accel_roll")


def test_infinite_loop_scores_zero_timed_out_and_the_rest_is_graded(graded):
    assert points(graded, "loop") == {**POINTS, "01.accel_roll": 0}
    assert "timed out" in message(graded, "loop", "01.accel_roll")
    feedback = (graded["dir"] / "gradebook_feedback" / "submissions_loop.md").read_text()
    assert f"timed out after {TIMEOUT} s (interrupted)" in feedback  # the student's own looping cell


def test_loop_ignoring_interrupts_restarts_the_kernel_and_grading_goes_on(graded):
    assert points(graded, "stubborn") == {**POINTS, "01.accel_roll": 0}
    assert "timed out" in message(graded, "stubborn", "01.accel_roll")


def test_killed_kernel_and_sys_exit(graded):
    assert points(graded, "exits") == {**POINTS, "01.kf_update": 0, "01.run_kf": 0, "01.kf_beats_sensors": 0}
    assert "raised SystemExit" in message(graded, "exits", "01.kf_update")
    feedback = (graded["dir"] / "gradebook_feedback" / "submissions_exits.md").read_text()
    assert "kernel died" in feedback and "restarted" in feedback


def test_huge_print_is_dropped_and_noted(graded):
    assert points(graded, "huge_print") == POINTS
    assert "MB of output (discarded)" in (graded["dir"] / "gradebook_feedback" / "submissions_huge_print.md").read_text()


def test_tampering_with_kfkit_in_the_kernel_gains_nothing(graded):
    assert set(points(graded, "tamper").values()) == {0}
    assert "kfkit's own kfkit.filters.roll.roll_kf_update" in message(graded, "tamper", "01.kf_update")
    assert "expected" in message(graded, "tamper", "01.kf_predict")


def test_renamed_or_deleted_function_gets_a_clear_message(graded):
    assert points(graded, "renamed")["01.accel_roll"] == 0
    assert "no function named accel_roll" in message(graded, "renamed", "01.accel_roll")
    assert "no function named kf_update" in message(graded, "renamed", "01.kf_update")
    assert points(graded, "renamed")["01.kf_predict"] == 1


def test_syntax_error_names_the_failing_cell(graded):
    p = points(graded, "syntax")
    assert p["01.kf_predict"] == 0 and p["01.kf_update"] == 0 and p["01.accel_roll"] == 1
    assert "SyntaxError" in message(graded, "syntax", "01.kf_predict")


def test_files_that_are_not_notebooks(graded):
    for sub, why in (("not_json", "not valid JSON"), ("binary", "not text"), ("not_notebook", "not a Jupyter notebook")):
        assert set(points(graded, sub).values()) == {0}
        assert why in message(graded, sub, "01.accel_roll"), sub


def test_cell_tags_and_kernelspec_cannot_change_execution(graded):
    assert points(graded, "tags") == POINTS


def test_student_code_cannot_touch_instructor_files_or_the_kit(graded):
    if not graded["isolated"]:
        pytest.skip("no sandbox on this machine (see test_no_isolation_is_announced_loudly)")
    assert points(graded, "vandal") == POINTS  # the attempts failed quietly and grading went on
    assert (graded["dir"] / "canary.txt").read_text() == "instructor's file"
    assert not (graded["dir"] / "planted.txt").exists()
    assert not (KIT_ROOT / "kfkit" / "planted.py").exists()
    assert hashlib.sha256(KIT_FILE.read_bytes()).hexdigest() == graded["kit_hash"]
    assert graded["kit_canary_kept"]


def test_no_kernel_or_temporary_folder_outlives_grading(graded):
    assert grader_kernels(str(graded["scratch"])) == []
    assert list(graded["scratch"].iterdir()) == []


def test_sandbox_blocks_writes_to_the_kit_and_the_network(tmp_path):
    box = sandbox.probe([str(tmp_path)])
    if box.mode == "none":
        pytest.skip(f"no isolation possible here: {box.warning}")
    code = ("import os, socket\n"
            f"for p in ({str(KIT_ROOT / 'kfkit')!r}, {str(tmp_path)!r}, {sys.prefix!r}):\n"
            "    try:\n        open(os.path.join(p, 'x.txt'), 'w').close(); print('wrote', p)\n"
            "    except OSError as e:\n        print('refused', e.errno)\n"
            "try:\n    socket.create_connection(('1.1.1.1', 53), timeout=2); print('net')\n"
            "except OSError:\n    print('no net')\n")
    done = sandbox.run_in_sandbox(box, [sys.executable, "-c", code], [str(tmp_path)])
    assert done.returncode == 0, done.stderr
    assert "wrote" not in done.stdout and done.stdout.count("refused") == 3
    assert "no net" in done.stdout and box.network_blocked
    assert not (tmp_path / "x.txt").exists() and not (KIT_ROOT / "kfkit" / "x.txt").exists()


def test_no_isolation_is_announced_loudly(tmp_path):
    box = sandbox.probe([str(tmp_path)], modes=[])
    assert box.mode == "none"
    text = core.summary([], core.lab_checkpoints("01"), box)
    assert text.startswith("!!!") and "NOT ISOLATED" in text


def test_empty_folder_alone_is_an_error(tmp_path, capsys):
    assert main(["grade", "--lab", "01", "--out", str(tmp_path / "g.csv"), str(tmp_path)]) == 1
    assert "holds no .ipynb" in capsys.readouterr().err
    assert not (tmp_path / "g.csv").exists()


def test_unknown_lab_is_named(tmp_path, capsys):
    assert main(["grade", "--lab", "99", "--out", str(tmp_path / "g.csv"), str(tmp_path)]) == 2
    assert "lab01" in capsys.readouterr().err


def test_update_regrades_one_student_and_keeps_the_others(graded, tmp_path, capsys):
    out = tmp_path / "gradebook.csv"
    out.write_bytes(graded["out"].read_bytes())
    student = graded["dir"] / "submissions" / "renamed.ipynb"
    nbformat.write(minimal(), student)  # the student fixed the names
    assert main(["grade", "--lab", "1", "--out", str(out), "--update", "--seed", "7", str(student)]) == 0
    rows, subs = graded_rows(out)
    assert len(rows) == len(graded["rows"])
    assert {cp: float(r["points"]) for cp, r in subs["renamed"].items()} == POINTS
    assert subs["correct"] == graded["subs"]["correct"]
    assert "01.kf_update" in capsys.readouterr().out


def test_summary_reports_pass_rates(graded, capsys):
    grades = [core.SubmissionGrade("a", 1, [core.Row("01.accel_roll", 1, 1, "passed", "")] +
                                   [core.Row(n, 0, p, "failed", "") for n, p in POINTS.items() if n != "01.accel_roll"]),
              core.SubmissionGrade("b", 2, [core.Row(n, 0, p, "failed", "") for n, p in POINTS.items()])]
    text = core.summary(grades, core.lab_checkpoints("01"), sandbox.Sandbox("root", True, ["/x"]))
    line = next(s for s in text.splitlines() if s.startswith("01.accel_roll"))
    assert "1/2" in line and "50 %" in line


# ------------------------------------------------------------------ the wire format (no kernel)
def roundtrip(value):
    text = json.dumps(_kernel_side.encode(value, [wire.MAX_NUMBERS]))
    return wire.decode(json.loads(text))


def test_wire_roundtrip_keeps_numbers_shapes_and_containers():
    a = np.arange(6.0).reshape(2, 3)
    got = roundtrip((a, np.int32(3), [1.5, float("nan")], {"k": np.array([True, False])}, "s", None))
    assert isinstance(got, tuple) and got[0].shape == (2, 3) and np.array_equal(got[0], a)
    assert got[1] == 3 and np.isnan(got[2][1]) and got[3]["k"].dtype == bool and got[4:] == ("s", None)
    assert repr(roundtrip(object())) == "<builtins.object object>"


def test_wire_limits_sizes_and_rejects_malformed_data():
    with pytest.raises(_kernel_side.TooLarge):
        _kernel_side.encode(np.zeros(100), [10])
    for bad in ({"__ndarray__": [1, 2], "dtype": "f", "shape": [3]}, {"__ndarray__": ["a"], "dtype": "f", "shape": [1]},
                {"__ndarray__": [1], "dtype": "V", "shape": [1]}, {"__object__": "X", "fields": {"not id": 1}},
                {"__tuple__": 5}, {"what": 1}):
        with pytest.raises(wire.WireError):
            wire.decode(bad)
    with pytest.raises(wire.WireError):
        wire.extract("no result here", "KFKITabc")
    with pytest.raises(wire.WireError):
        wire.extract("KFKITabc[[[" + "KFKITabc", "KFKITabc")


def test_python_dash_m_kfkit_grade_help():
    out = subprocess.run([sys.executable, "-m", "kfkit", "grade", "--help"], capture_output=True, text=True, check=True).stdout
    assert "--jobs" in out and "--timeout" in out and "--update" in out


@pytest.mark.parametrize("lab", [name[3:] for name in LABS])
def test_every_registered_lab_sends_its_cases_to_a_kernel(lab):
    """Every checkpoint's inputs cross the wire (lambdas included) and arrive complete."""
    for i, cp in enumerate(core.lab_checkpoints(lab)):
        cases = cp.cases(np.random.default_rng([i, 1]))
        code = wire.call_code(cp.function, [c.args for c in cases], "KFKITx")
        blob = code.split(f"{cp.function!r}, '", 1)[1].split("'", 1)[0]
        sent = pickle.loads(base64.b64decode(blob))
        assert len(sent) == len(cases) and sent[0].keys() == cases[0].args.keys(), cp.name


def test_killing_the_grader_kills_its_kernels(tmp_path):
    """A grader that dies (SIGKILL, OOM) takes its kernels with it: none is left running."""
    import time

    scratch = Path(tempfile.mkdtemp(prefix="kg-", dir="/tmp"))
    nbformat.write(add(minimal(), "while True:\n    pass", at=-1), tmp_path / "loop.ipynb")
    grader = subprocess.Popen([sys.executable, "-m", "kfkit", "grade", "--lab", "01", "--jobs", "1", "--timeout", "60",
                               "--out", str(tmp_path / "g.csv"), str(tmp_path / "loop.ipynb")],
                              env={**os.environ, "TMPDIR": str(scratch)}, stdout=subprocess.DEVNULL,
                              stderr=open(tmp_path / "grader.log", "w"))
    try:
        for _ in range(360):
            if any("ipykernel_launcher" in " ".join(p.cmdline()) for p in grader_kernels(str(scratch))):
                break
            time.sleep(0.5)
        else:
            pytest.fail("no kernel started: " + (tmp_path / "grader.log").read_text()[-2000:])
    finally:
        grader.kill()
        grader.wait()
    for _ in range(20):
        if not grader_kernels(str(scratch)):
            break
        time.sleep(0.5)
    assert grader_kernels(str(scratch)) == []
    shutil.rmtree(scratch, ignore_errors=True)
