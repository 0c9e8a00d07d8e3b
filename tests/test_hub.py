"""A class on a real JupyterHub, end to end (issue 19): hand-outs by nbgitpuller, a lab in JupyterLab through the
hub, a fix pushed mid-term, collection and grading, and what one student can reach of the others.

The hub, its users and the single-user environment (the kit without solutions/) are set up by tests/hub.py:
see its docstring. Three students: the first works in a real browser (Chromium, as in tests/browser/), the
other two through the REST API with their own tokens. Skips with the reason where no hub can run here.
"""

from __future__ import annotations

import csv
import json
import re
import shutil
import subprocess
import sys
import urllib.parse

import hub as hubkit
import pytest
from browser.conftest import browser  # noqa: F401 (a fixture)
from waiting import HANG_GUARD_MS, wait_until

from kfkit.paths import KIT_ROOT

pytestmark = pytest.mark.slow  # the quick tier (-m 'not slow') leaves this module out: see pyproject.toml

LAB = "01_roll_kf_1d.ipynb"
FIX_01 = "\n\n*Corrected in week 3: the recording's rate is 104 Hz.*"
FIX_02 = "\n\n*Corrected in week 3: see the note on the gyro's rounding.*"


@pytest.fixture(scope="module")
def hub():
    reason = hubkit.why_no_hub()
    if reason:
        pytest.skip(reason)
    with hubkit.Hub(students=3) as h:
        yield h


def test_requirements_test_pins_what_a_hub_image_installs():
    """requirements-test.txt repeats requirements-hub.txt's pins (it may only -r environment.txt): the same versions."""
    from test_environment import pins

    hub_pins = pins(KIT_ROOT / "requirements-hub.txt")
    assert set(hub_pins) == {"jupyterhub", "nbgitpuller"}
    assert {k: v for k, v in pins(KIT_ROOT / "requirements-test.txt").items() if k in hub_pins} == hub_pins


def source(cell) -> str:
    return cell["source"] if isinstance(cell["source"], str) else "".join(cell["source"])


def answers(wrong_roll=False) -> dict[int, str]:
    """Hand-out cell index → the code a student fills in: the solution's function bodies (the nbgrader markers
    dropped), matched by the functions each stub cell defines; with ``wrong_roll`` accel_roll swaps atan2's
    arguments."""

    def defines(text):
        return tuple(re.findall(r"^def (\w+)\(", text, re.M))

    solution = json.loads((KIT_ROOT / "solutions" / LAB).read_text(encoding="utf-8"))
    by_functions = {defines(source(c)): source(c) for c in solution["cells"] if c["cell_type"] == "code"}
    handout = json.loads((KIT_ROOT / "labs" / LAB).read_text(encoding="utf-8"))
    filled = {}
    for i, cell in enumerate(handout["cells"]):
        text = source(cell)
        if cell["cell_type"] == "code" and "raise NotImplementedError" in text:
            code = re.sub(r"^\s*### (BEGIN|END) SOLUTION\n", "", by_functions[defines(text)], flags=re.M)
            if wrong_roll and "def accel_roll(" in code:
                code = re.sub(r"np\.arctan2\((.+?), (.+?)\)$", r"np.arctan2(\2, \1)", code, flags=re.M)
            filled[i] = code
    assert filled and all("NotImplementedError" not in c for c in filled.values())
    return filled


def append_to_first_markdown(text):
    def edit(nb):
        cell = next(c for c in nb["cells"] if c["cell_type"] == "markdown")
        cell["source"] = source(cell) + text

    return edit


def test_a_class_on_a_real_hub(hub, browser):  # noqa: F811  (the browser fixture imported from browser/conftest.py)
    """The whole term in one run; each step's assertion says which step failed."""
    from browser.test_labs_in_browser import (
        _check_slider_moves_figure,
        canvas_png,
        error_outputs,
        run_all,
        unexecuted_cells,
    )

    alice, bob, carol = hub.students
    home = {s: hub.homes / s / "kfkit-labs" for s in hub.students}
    # --- bob and carol: their servers through the REST API; alice's starts when she follows the link
    for s in (bob, carol):
        hub.spawn(s)
    tokens = {s: hub.user_token(s) for s in hub.students}

    # --- alice: logs in and follows the nbgitpuller link to lab 01, in a real browser
    page = browser.new_context(viewport={"width": 1400, "height": 1000}).new_page()
    link = hub.pull_link(LAB)
    page.goto(f"{hub.url}/hub/login?next={urllib.parse.quote(link.removeprefix(hub.url))}")
    page.fill("#username_input", alice)
    page.fill("#password_input", hubkit.PASSWORD)
    page.click("#login_submit")
    page.wait_for_url(re.compile(rf"/user/{alice}/lab/tree/kfkit-labs/{LAB}"), timeout=hubkit.START_TIMEOUT * 1000)
    _wait_for_kernel(page)

    for s in (bob, carol):  # their links, through nbgitpuller's API
        hub.wait_ready(s)
        assert "Cloning into" in hub.pull(s, tokens[s])
    assert all((home[s] / LAB).is_file() for s in hub.students), "nbgitpuller did not bring lab 01 into every home"
    assert not (hub.kit / "solutions").exists()

    # --- alice fills in the exercises in JupyterLab, runs everything, moves a slider, saves
    mine = answers()
    for i, code in mine.items():
        page.evaluate(
            "([i, code]) => window.jupyterapp.shell.currentWidget.content.widgets[i].model.sharedModel.setSource(code)",
            [i, code],
        )
    run_all(page)
    assert error_outputs(page) == [], "alice's lab 01 shows an error or stderr output"
    assert unexecuted_cells(page) == 0 and page.get_by_text("skipped:").count() == 0
    assert page.get_by_text("Error displaying widget").count() == 0
    figures = page.locator(".jupyter-matplotlib canvas")
    assert figures.count() > 0 and all(canvas_png(figures.nth(i)).std() > 5 for i in range(figures.count()))
    _check_slider_moves_figure(page, f"hub-{LAB}")
    page.evaluate("() => window.jupyterapp.commands.execute('docmanager:save')")
    saved = _wait_for(lambda: _code_cells_hold(home[alice] / LAB, mine), "alice's saved notebook")

    # --- bob fills them in through the contents API, with the classic swapped atan2; carol does nothing
    path = f"/contents/kfkit-labs/{LAB}"
    model = hub.server_api(bob, "GET", path, token=tokens[bob])
    for i, code in answers(wrong_roll=True).items():
        model["content"]["cells"][i]["source"] = code
    hub.server_api(bob, "PUT", path, {"type": "notebook", "format": "json", "content": model["content"]}, tokens[bob])

    # --- the instructor fixes lab 01's and lab 02's first text cells and pushes; students follow their links again
    lab02 = "02_bias_and_noise.ipynb"
    hub.push_fix(LAB, append_to_first_markdown(FIX_01))
    hub.push_fix(lab02, append_to_first_markdown(FIX_02))
    page.goto(link)
    page.wait_for_url(re.compile(rf"/user/{alice}/lab"), timeout=HANG_GUARD_MS)
    for s in (bob, carol):
        hub.pull(s, tokens[s])
    for s in hub.students:
        assert FIX_02 in _first_markdown(home[s] / lab02), f"{s}: the fix to an untouched hand-out did not arrive"
        assert FIX_01 in _first_markdown(home[s] / LAB), f"{s}: the fix to lab 01's text did not merge"
    after = _code_cells_hold(home[alice] / LAB, mine)
    assert after is not None and [c.replace(FIX_01, "") for c in after] == saved, "the pull changed alice's cells"
    assert _code_cells_hold(home[bob] / LAB, answers(wrong_roll=True)), "the pull changed bob's answers"

    # --- the instructor collects the three notebooks from the homes and grades them
    subs = hub.instructor / "submissions"
    subs.mkdir()
    for s in hub.students:
        shutil.copy(home[s] / LAB, subs / f"{s}.ipynb")
    gradebook = hub.instructor / "gradebook.csv"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "kfkit",
            "grade",
            "--lab",
            "01",
            "--out",
            str(gradebook),
            "--jobs",
            "2",
            "--report",
            str(subs),
        ],
        cwd=hub.instructor,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    with open(gradebook, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    score = {
        s: sum(float(r["points"]) for r in rows if r["submission"] == f"submissions/{s}.ipynb") for s in hub.students
    }
    assert score == {alice: 12, bob: 11, carol: 0}, score
    assert (
        next(r for r in rows if r["submission"] == f"submissions/{bob}.ipynb" and r["checkpoint"] == "01.accel_roll")[
            "message"
        ].count("swapped")
        == 1
    )
    assert all(
        r["message"].startswith("not attempted") for r in rows if r["submission"] == f"submissions/{carol}.ipynb"
    )
    report = (hub.instructor / "gradebook_report.html").read_text(encoding="utf-8")
    assert report.count('<tr class="student">') == 3

    # --- what bob's own kernel can reach: his notebook and the kit, not alice's home, solutions/ or the gradebook
    probes = {
        "own notebook": home[bob] / LAB,
        "the kit's data": hub.kit / "data",
        "alice's home": hub.homes / alice,
        "alice's notebook": home[alice] / LAB,
        "solutions/": KIT_ROOT / "solutions",
        "a solution": KIT_ROOT / "solutions" / LAB,
        "the gradebook": gradebook,
        "the submissions": subs,
    }
    code = (
        "import json, os\nout = {}\n"
        f"for name, path in {json.dumps({k: str(v) for k, v in probes.items()})}.items():\n"
        "    try:\n"
        "        os.listdir(path) if os.path.isdir(path) else open(path, 'rb').read(1)\n"
        "        out[name] = 'read'\n"
        "    except OSError as exc:\n"
        "        out[name] = type(exc).__name__\n"
        "print(json.dumps(out))"
    )
    seen = json.loads(hub.run_code(bob, tokens[bob], code))
    assert seen == {
        "own notebook": "read",
        "the kit's data": "read",
        "alice's home": "PermissionError",
        "alice's notebook": "PermissionError",
        "solutions/": "FileNotFoundError",
        "a solution": "FileNotFoundError",
        "the gradebook": "PermissionError",
        "the submissions": "PermissionError",
    }, seen
    assert (KIT_ROOT / "solutions" / LAB).is_file()  # the control: there, for the instructor


def _wait_for_kernel(page):
    page.wait_for_selector(".jp-Notebook .jp-Cell", timeout=HANG_GUARD_MS)
    page.wait_for_function(
        "() => window.jupyterapp && window.jupyterapp.shell.currentWidget"
        " && window.jupyterapp.shell.currentWidget.sessionContext?.session?.kernel?.status === 'idle'",
        timeout=HANG_GUARD_MS,
    )


def _first_markdown(path) -> str:
    nb = json.loads(path.read_text(encoding="utf-8"))
    return source(next(c for c in nb["cells"] if c["cell_type"] == "markdown"))


def _code_cells_hold(path, filled) -> list[str] | None:
    """The notebook's cell sources if every filled cell holds its code (whitespace at the ends aside), else None."""
    try:
        cells = [source(c) for c in json.loads(path.read_text(encoding="utf-8"))["cells"]]
    except (OSError, ValueError):
        return None
    ok = all(i < len(cells) and cells[i].strip() == code.strip() for i, code in filled.items())
    return cells if ok else None


def _wait_for(get, what):
    return wait_until(get, what, poll_s=0.5)
