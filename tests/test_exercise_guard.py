"""kfkit.exercise_guard in a real IPython shell: unfinished exercises and what depends on them are skipped with
a note, everything else runs, and finishing an exercise lets the skipped cells run."""
import pytest
from IPython.core.interactiveshell import InteractiveShell

STUB = "def {name}(x):\n    # YOUR CODE HERE\n    raise NotImplementedError()\n"


@pytest.fixture()
def shell(capsys):
    ip = InteractiveShell.instance()
    ip.reset(new_session=False)
    ip.run_line_magic("load_ext", "kfkit.exercise_guard")

    def run(code):
        result = ip.run_cell(code)
        return result, capsys.readouterr().out

    yield run
    ip.run_line_magic("unload_ext", "kfkit.exercise_guard")


def test_a_cell_calling_a_stub_is_skipped_with_the_function_named_and_raises_nothing(shell):
    shell(STUB.format(name="kf_predict"))
    result, out = shell("x = kf_predict(1.0)\nprint('ran')")
    assert result.success and "ran" not in out
    assert "skipped" in out and "kf_predict (not written yet)" in out


def test_what_a_skipped_cell_would_have_made_is_missing_downstream_with_the_reason(shell):
    shell(STUB.format(name="accel_roll"))
    shell("roll = accel_roll(2.0)")
    result, out = shell("print(roll * 2)")
    assert result.success and "uses roll" in out and "accel_roll (not written yet)" in out


def test_a_stub_reached_through_your_own_function_is_named(shell):
    shell(STUB.format(name="kf_update"))
    shell("def run_kf(z):\n    return kf_update(z)\n")  # defining it needs nothing yet: it runs
    result, out = shell("print(run_kf(3))")
    assert result.success and "run_kf, which calls kf_update (not written yet)" in out


def test_a_top_level_exercise_cell_is_skipped_and_its_names_are_missing(shell):
    result, out = shell("q = 1e-4\n# YOUR CODE HERE\nraise NotImplementedError()")
    assert result.success and "this cell is an exercise" in out
    result, out = shell("print(q)")
    assert result.success and "uses q" in out and "exercise cell not filled in yet" in out


def test_check_cells_run_so_the_check_can_say_not_attempted(shell):
    shell(STUB.format(name="accel_roll"))
    shell("def check(name, f):\n    print('checked', name)\n")
    result, out = shell("check('01.accel_roll', accel_roll)")
    assert result.success and "checked 01.accel_roll" in out and "skipped" not in out


def test_cells_that_need_no_exercise_run_untouched(shell):
    shell(STUB.format(name="accel_roll"))
    result, out = shell("import math\nvalues = [math.sqrt(v) for v in range(3)]\nprint(len(values))")
    assert result.success and out.strip() == "3"


def test_finishing_the_exercise_lets_the_skipped_cells_run(shell):
    shell(STUB.format(name="accel_roll"))
    shell("roll = accel_roll(2.0)")
    shell("def accel_roll(x):\n    return -x\n")
    result, out = shell("roll = accel_roll(2.0)\nprint(roll)")
    assert result.success and out.strip() == "-2.0"
    result, out = shell("print(roll * 2)")
    assert out.strip() == "-4.0"


def test_real_errors_are_still_errors(shell):
    result, _ = shell("1 / 0")
    assert isinstance(result.error_in_exec, ZeroDivisionError)
    result, _ = shell("def f(:\n    pass")
    assert result.error_before_exec is not None


def test_loading_twice_installs_one_guard(shell):
    InteractiveShell.instance().run_line_magic("load_ext", "kfkit.exercise_guard")
    InteractiveShell.instance().run_line_magic("reload_ext", "kfkit.exercise_guard")
    guards = [t for t in InteractiveShell.instance().input_transformers_post if getattr(t, "is_exercise_guard", False)]
    assert len(guards) == 1


def test_names_a_cell_binds_before_reading_them_are_its_own(shell):
    """A loop target, a with-as name, an assignment earlier in a loop body, a comprehension's variable: not
    "made by a skipped cell" even when a skipped cell also bound them."""
    shell(STUB.format(name="board_time"))
    shell("for v in range(2):\n    labels = board_time(v)\n")  # skipped: v and labels are missing
    result, out = shell("import contextlib\n"
                        "for v in range(2):\n    labels = [w * 2 for w in range(v)]\n    print(len(labels))\n"
                        "with contextlib.nullcontext(5) as port:\n    print(port)\n")
    assert result.success and "skipped" not in out and out.split() == ["0", "1", "5"]


def test_a_function_defined_and_called_in_the_same_cell_is_followed_into(shell):
    """Before the cell runs its function does not exist yet: the guard reads its body instead."""
    shell(STUB.format(name="to_body"))
    result, out = shell("def body_si(x):\n    return to_body(x)\nsi = body_si(3)\nprint('ran')")
    assert result.success and "ran" not in out and "body_si, which calls to_body (not written yet)" in out


def test_a_lambda_handed_on_is_read_as_running_now_and_its_parameters_are_its_own(shell):
    shell(STUB.format(name="run_kf"))
    shell("def tune(f, q):\n    return f(q)\n")
    result, out = shell("panel = tune(lambda q: run_kf(q), 1.0)\nprint('ran')")
    assert result.success and "ran" not in out and "run_kf (not written yet)" in out
    shell("q = 0.5")
    result, out = shell("print(tune(lambda q: q * 2, 3.0))")  # q is the lambda's, not the notebook's
    assert result.success and out.strip() == "6.0"


def test_a_cell_that_redefines_a_stub_and_uses_it_runs(shell):
    """The notebook's stub is the old definition: the cell's own new one is what runs."""
    shell(STUB.format(name="kf_update"))
    result, out = shell("def kf_update(x):\n    return x + 1\nprint(kf_update(1))")
    assert result.success and out.strip() == "2"


def test_a_function_defined_here_is_judged_by_the_names_it_reads_not_its_parameters(shell):
    shell(STUB.format(name="tilt_heading"))
    shell("asked = tilt_heading(1)")  # skipped: 'asked' is missing
    result, out = shell("def errors(psi, asked):\n    total = 0\n    for a in asked:\n        total += a\n    return total\n"
                        "print(errors(0, [1, 2]))")
    assert result.success and out.strip() == "3"
