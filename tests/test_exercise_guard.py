"""kfkit.exercise_guard in a real IPython shell: unfinished exercises and what depends on them are skipped with
a note, everything else runs, and finishing an exercise lets the skipped cells run."""

import ast

import nbformat
import pytest
from exercise_variants import exercise_cells, python
from IPython.core.interactiveshell import InteractiveShell

from kfkit.authoring import is_stub
from kfkit.paths import KIT_ROOT

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
    result, out = shell(
        "import contextlib\n"
        "for v in range(2):\n    labels = [w * 2 for w in range(v)]\n    print(len(labels))\n"
        "with contextlib.nullcontext(5) as port:\n    print(port)\n"
    )
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
    result, out = shell(
        "def errors(psi, asked):\n    total = 0\n    for a in asked:\n        total += a\n    return total\n"
        "print(errors(0, [1, 2]))"
    )
    assert result.success and out.strip() == "3"


# --- issue 24 §2: the guard never skips correct code -------------------------------------------------------------


@pytest.mark.parametrize(
    "finished",
    [
        # raises it for an input it does not handle
        "def accel_roll(ay, az):\n    if np.ndim(ay) > 1:\n        raise NotImplementedError('2-D input')\n"
        "    return np.arctan2(ay, az)\n",
        # the very statement make-labs writes, but only for that input
        "def accel_roll(ay, az):\n    if np.ndim(ay) > 1:\n        raise NotImplementedError()\n"
        "    return np.arctan2(ay, az)\n",
        "def accel_roll(ay, az):\n    if np.ndim(ay) <= 1:\n        return np.arctan2(ay, az)\n"
        "    raise NotImplementedError()\n",
        # catches it
        "def accel_roll(ay, az):\n    try:\n        return np.arctan2(ay, az)\n    except NotImplementedError:\n"
        "        return 0.0\n",
        # the stub left below the answer, never reached
        "def accel_roll(ay, az):\n    '''Roll.'''\n    return np.arctan2(ay, az)\n"
        "    # YOUR CODE HERE\n    raise NotImplementedError()\n",
        # a helper in it raises it
        "def accel_roll(ay, az):\n    def two_d():\n        raise NotImplementedError()\n"
        "    return two_d() if np.ndim(ay) > 1 else np.arctan2(ay, az)\n",
    ],
)
def test_a_finished_function_that_mentions_not_implemented_error_is_not_a_stub(shell, finished):
    """A stub is what make-labs wrote (the raise among the function's own statements, nothing before it that can
    return), not "any function that mentions the exception": every cell that uses a finished one runs."""
    shell("import numpy as np")
    shell(STUB.format(name="accel_roll"))
    shell(finished)
    result, out = shell("roll = accel_roll(1.0, 1.0)\nprint(round(roll, 4))")
    assert result.success and out.strip() == "0.7854"
    shell("def run_all(ay, az):\n    return accel_roll(ay, az)\n")  # reached through a function of the notebook
    result, out = shell("print(round(run_all(1.0, 1.0), 4))")
    assert result.success and out.strip() == "0.7854"


def test_a_finished_kf_update_that_catches_not_implemented_error_is_not_a_stub(shell):
    shell(STUB.format(name="kf_update"))
    shell(
        "def kf_update(x, P, z, r):\n    try:\n        K = P / (P + r)\n    except NotImplementedError:\n"
        "        raise\n"
        "    return x + K * (z - x), (1 - K) * P\n"
    )
    result, out = shell("print(kf_update(0.0, 1.0, 2.0, 1.0))")
    assert result.success and out.strip() == "(1.0, 0.5)"


@pytest.mark.parametrize(
    "stub",
    [
        STUB.format(name="accel_roll"),
        "def accel_roll(x):\n    '''Roll (rad).'''\n    x = float(x)\n    # YOUR CODE HERE\n"
        "    raise NotImplementedError()\n",
        "def accel_roll(x):\n    if x < 0:\n        raise ValueError('x < 0')\n    # YOUR CODE HERE\n"
        "    raise NotImplementedError()\n",
        "import functools\ndef logged(f):\n    @functools.wraps(f)\n    def wrapper(*a):\n        return f(*a)\n"
        "    return wrapper\n"
        "@logged\n" + STUB.format(name="accel_roll"),
        "def logged(f):\n    def wrapper(*a):\n        return f(*a)\n    return wrapper\n@logged\n"
        + STUB.format(name="accel_roll"),
    ],
)
def test_a_stub_is_recognised_behind_kept_code_and_decorators(shell, stub):
    shell(stub)
    result, out = shell("roll = accel_roll(1.0)\nprint('ran')")
    assert result.success and "ran" not in out and "accel_roll (not written yet)" in out


def test_a_function_made_by_exec_is_judged_by_what_it_calls(shell):
    """exec leaves no source to read: such a function is not taken for a stub, but a stub it calls still is."""
    shell(STUB.format(name="kf_predict"))
    shell("exec('def run_kf(x):\\n    return kf_predict(x)\\n')\nexec('def twice(x):\\n    return 2 * x\\n')")
    result, out = shell("print(run_kf(1))")
    assert "run_kf, which calls kf_predict (not written yet)" in out
    result, out = shell("print(twice(2))")
    assert result.success and out.strip() == "4"


def test_parameters_and_locals_of_nested_scopes_are_not_names_from_the_notebook(shell):
    """A lambda's or an inner function's parameter, a comprehension's variable, an inner function's local, named
    like what a skipped cell would have made (r, roll_acc, x0), is not that name: the cell runs."""
    shell(STUB.format(name="accel_roll"))
    shell("roll_acc = accel_roll(1.0)\nr = 0.1\nx0 = 0.0")  # skipped: roll_acc, r and x0 are missing
    result, out = shell(
        "def helper(z):\n    scale = lambda r: r * 2\n    def inner(roll_acc, *, x0=1):\n"
        "        return roll_acc + x0\n    return inner(scale(z))\nprint(helper(1))"
    )
    assert result.success and out.strip() == "3", out
    result, out = shell("print(helper(2))")  # and from a later cell
    assert result.success and out.strip() == "5"
    result, out = shell(
        "def total(n):\n    def local():\n        x0 = 5\n        return x0\n"
        "    return sum(r for r in range(n)) + local() + [roll_acc for roll_acc in (1,)][0]\n"
        "print(total(3))"
    )
    assert result.success and out.strip() == "9", out
    result, out = shell("print(list(map(lambda r: r + 1, [1, 2])), [x0 for x0 in 'ab'])")
    assert result.success and out.strip() == "[2, 3] ['a', 'b']"


def test_a_nested_scope_still_reads_what_it_does_not_bind(shell):
    """The other way round: an inner function reading the notebook's r (no parameter of that name) needs it."""
    shell(STUB.format(name="accel_roll"))
    shell("r = accel_roll(1.0)")
    result, out = shell("def helper(z):\n    inner = lambda q: q * r\n    return inner(z)\nprint(helper(1))")
    assert result.success and "it uses helper, which calls r, made by a cell that needs accel_roll" in out


def test_an_attribute_named_like_a_stub_is_not_the_stub(shell):
    """``filters.run_kf`` is kfkit's, not the notebook's unwritten run_kf (attribute names are in co_names too)."""
    shell(STUB.format(name="run_kf"))
    shell(
        "import types\nfilters = types.SimpleNamespace(run_kf=lambda q: 2 * q)\n"
        "def kf_roll(q):\n    return filters.run_kf(q)\n"
    )
    result, out = shell("print(kf_roll(2))")
    assert result.success and out.strip() == "4"


@pytest.mark.parametrize(
    "binds",
    [
        "def init():\n    global x0\n    x0 = 0.5\ninit()",
        "globals().update(x0=0.5)",
        "globals()['x0'] = 0.5",
        "exec('x0 = 0.5')",
    ],
)
@pytest.mark.parametrize("before", ["", "x0 = 1.0\n"])
def test_a_name_bound_since_by_code_that_ran_is_not_missing(shell, binds, before):
    """A name a skipped cell would have made is missing only until something that runs binds it: a function's
    ``global x0``, ``globals().update``, ``exec`` (whether or not it held an older value)."""
    shell(STUB.format(name="accel_roll"))
    shell(before)
    shell("x0 = accel_roll(1.0)")  # skipped
    result, out = shell(binds)
    assert result.success and "skipped" not in out
    result, out = shell("print(x0)")
    assert result.success and out.strip() == "0.5"


def test_an_older_value_that_nothing_rebound_is_still_missing(shell):
    shell(STUB.format(name="accel_roll"))
    shell("x0 = 1.0")
    shell("x0 = accel_roll(1.0)")  # skipped: 1.0 is not what this notebook means by x0 any more
    result, out = shell("print(x0)")
    assert result.success and "it uses x0, made by a cell that needs accel_roll (not written yet)" in out


def test_what_a_skipped_cell_would_have_bound_through_a_global_statement_is_missing(shell):
    shell(STUB.format(name="accel_roll"))
    shell("def init(v):\n    global x0\n    x0 = accel_roll(v)\n")
    result, out = shell("init(1.0)")
    assert "it needs init, which calls accel_roll (not written yet)" in out
    result, out = shell("print(x0 + 1)")
    assert result.success and "it uses x0, made by a cell that needs init, which calls accel_roll" in out


CORRECT_KF_UPDATE = (
    "def kf_update(x, P, z, r):\n    K = P / (P + r)\n    return x + K * (z - x), (1 - K) * P, z - x, P + r\n"
)


def test_a_skipped_cell_that_redefines_an_exercise_sets_the_old_one_aside(shell):
    """The student rewrites kf_update in a cell that also calls run_kf, a stub: the cell is skipped, and the check of
    kf_update must not pass the kf_update of before; nor may a function that calls it run it."""
    shell("from kfkit.checkpoints import check")
    shell(STUB.format(name="run_kf"))
    shell(CORRECT_KF_UPDATE)
    assert "✅" in shell("check('01.kf_update', kf_update);")[1]
    shell("def filter_one(z):\n    return kf_update(0.0, 1.0, z, 1.0)\n")
    result, out = shell("def kf_update(x, P, z, r):\n    return x, P, 0.0, 1.0  # changed since\nx_kf = run_kf(1)")
    assert "it needs run_kf (not written yet)" in out
    result, out = shell("check('01.kf_update', kf_update);")
    assert (
        result.success
        and "✅" not in out
        and "⏳ 01.kf_update: stale: the cell that defines kf_update was skipped" in out
    )
    result, out = shell("print(filter_one(2.0))")
    assert result.success and "filter_one, which calls kf_update (its cell was skipped)" in out
    shell("def run_kf(q):\n    return q\n")
    result, out = shell("def kf_update(x, P, z, r):\n    return x, P, 0.0, 1.0  # changed since\nx_kf = run_kf(1)")
    assert result.success and "skipped" not in out
    assert "❌ 01.kf_update" in shell("check('01.kf_update', kf_update);")[1]  # the new code is what is checked


def test_a_function_whose_only_cell_was_skipped_is_checked_as_stale_not_a_name_error(shell):
    shell("from kfkit.checkpoints import check")
    shell(STUB.format(name="run_kf"))
    shell(CORRECT_KF_UPDATE + "x_kf = run_kf(1)")  # skipped: kf_update was never defined
    result, out = shell("check('01.kf_update', kf_update);")
    assert result.success and "⏳ 01.kf_update: stale" in out


def test_a_stale_check_still_says_stale_after_the_guard_is_reloaded(shell):
    """%reload_ext makes a new StaleDefinition class; check knows a set-aside function by its mark, not its class."""
    shell("from kfkit.checkpoints import check")
    shell(STUB.format(name="run_kf"))
    shell(CORRECT_KF_UPDATE + "x_kf = run_kf(1)")
    InteractiveShell.instance().run_line_magic("reload_ext", "kfkit.exercise_guard")
    result, out = shell("check('01.kf_update', kf_update);")
    assert result.success and "⏳ 01.kf_update: stale" in out


@pytest.mark.parametrize(
    "call",
    [
        "check('01.run_kf', answer=by_hand);",
        "check('01.run_kf', by_hand);",
        "check('01.run_kf', lambda **kw: run_kf(**kw));",
        "import functools\ncheck('01.run_kf', functools.partial(run_kf));",
    ],
)
def test_check_cells_always_run(shell, call):
    """However the answer is handed to check (by keyword, a lambda, a partial), the check says 'not attempted'."""
    shell("from kfkit.checkpoints import check")
    shell("def kf_update(x, P, z, r):\n    # YOUR CODE HERE\n    raise NotImplementedError()\n")
    shell("def run_kf(gyro_rate, roll_acc, dt, q, r, x0, P0):\n    return kf_update(x0, P0, roll_acc[0], r)\n")
    shell("def by_hand(**kw):\n    return run_kf(**kw)\n")
    result, out = shell(call)
    assert result.success and "skipped" not in out and "⏳ 01.run_kf: not attempted yet" in out


LAB_NAMES = sorted(p.name for p in (KIT_ROOT / "labs").glob("*.ipynb"))


def _functions(nb):
    return [
        node
        for cell in nb.cells
        if cell.cell_type == "code"
        for node in ast.walk(ast.parse(python(cell.source)))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
    ]


@pytest.mark.parametrize("name", LAB_NAMES)
def test_every_stub_of_a_hand_out_is_one_and_no_function_of_its_solution_is(name, shell):
    """The oracle is the solution's markers: a hand-out's function is a stub exactly when make-labs replaced a
    solution block in its body; read from the source (authoring.is_stub) and by the guard from the functions a
    notebook defines."""
    solution = nbformat.read(KIT_ROOT / "solutions" / name, as_version=4)
    lab = nbformat.read(KIT_ROOT / "labs" / name, as_version=4)
    exercises = {n for _, names in exercise_cells(solution) for n in names}
    assert exercises
    assert {f.name for f in _functions(lab) if is_stub(f.body)} == exercises
    assert [f.name for f in _functions(solution) if is_stub(f.body)] == []
    ids = {c.id for c in solution.cells if c.cell_type == "code" and "### BEGIN SOLUTION" in c.source}
    guard = next(
        t for t in InteractiveShell.instance().input_transformers_post if getattr(t, "is_exercise_guard", False)
    )
    assert shell(python(next(c.source for c in lab.cells if c.cell_type == "code")))[0].success  # the imports
    for nb, stubs in ((lab, exercises), (solution, set())):
        for cell in nb.cells:
            if cell.id in ids:
                assert shell(cell.source)[0].success
        assert {n for n in exercises if guard.unfinished(n) == f"{n} (not written yet)"} == stubs
        assert all(guard.unfinished(n) is None for n in exercises - stubs)


def test_a_check_of_a_name_that_does_not_exist_at_all_is_skipped_not_a_name_error(shell):
    """check(…) reports a stub itself, but cannot be handed a name a skipped cell never made."""
    shell("from kfkit.checkpoints import check")
    shell(STUB.format(name="make_update"))
    shell("kf_update = make_update(1)")  # skipped: kf_update never existed
    result, out = shell("check('01.kf_update', kf_update);")
    assert result.success and "it uses kf_update, made by a cell that needs make_update (not written yet)" in out
