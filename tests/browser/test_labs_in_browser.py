"""The labs in JupyterLab in Chromium, as a student meets them: what the kernel-side tests cannot see.

Every hand-out (``labs/``, exercises unfilled) that shows a widget, Run All: it runs to its end (the exercise
guard skips the cells that wait for an exercise, with a note), no error or stderr output, no "Error displaying
widget", every ipympl figure shows a drawn canvas. Lab 01's solution, filled in: the same, and moving its tuning
panel's slider changes the figure's pixels and the printed RMSE. (A hand-out without widgets shows the browser
nothing a kernel does not: ``tests/test_notebooks.py`` runs every hand-out to its end with the same checks, and
nbval runs every solution.)
"""

from __future__ import annotations

import io
import json
import time

import numpy as np
import pytest
from PIL import Image
from waiting import HANG_GUARD_MS, HANG_GUARD_S, wait_until

from kfkit.paths import KIT_ROOT

from .conftest import ARTIFACTS

pytestmark = pytest.mark.slow  # the quick tier (-m 'not slow') leaves this module out: see pyproject.toml

WIDGET_VIEW = "application/vnd.jupyter.widget-view+json"


def shows_a_widget(lab) -> bool:
    """Whether the lab's solution, as stored with its outputs, displays an ipywidget (a panel, a slider, a 3-D view)."""
    return WIDGET_VIEW in (KIT_ROOT / "solutions" / lab.name).read_text(encoding="utf-8")


HANDOUTS = sorted(f"labs/{p.name}" for p in (KIT_ROOT / "labs").glob("*.ipynb") if shows_a_widget(p))
SOLVED = "01_roll_kf_1d.ipynb"  # a solution with a tuning panel: the slider's round trip through the browser


@pytest.fixture(autouse=True)
def fresh_kernels(jupyter_lab):
    """After each test its notebook's kernel is shut down: a kernel left running (lab 00's virtual board and
    capture timers) keeps a core busy for the rest of the suite."""
    yield
    jupyter_lab.shutdown_kernels()


def open_notebook(page, lab, name: str):
    page.goto(lab.url(name))
    page.wait_for_selector(".jp-Notebook .jp-Cell", timeout=HANG_GUARD_MS)
    page.wait_for_function(
        "() => window.jupyterapp && window.jupyterapp.shell.currentWidget"
        " && window.jupyterapp.shell.currentWidget.sessionContext"
        " && window.jupyterapp.shell.currentWidget.sessionContext.session"
        " && window.jupyterapp.shell.currentWidget.sessionContext.session.kernel"
        " && window.jupyterapp.shell.currentWidget.sessionContext.session.kernel.status === 'idle'",
        timeout=HANG_GUARD_MS,
    )


def run_all(page):
    """Run every cell through JupyterLab's own command; wait until nothing is queued or running.

    JupyterLab stops a run at the first error, leaving later prompts empty; the caller decides
    whether that is expected (see :func:`unexecuted_cells`).
    """
    page.evaluate("() => window.jupyterapp.commands.execute('notebook:run-all-cells')")
    deadline = time.monotonic() + HANG_GUARD_S
    quiet_since = None
    while time.monotonic() < deadline:
        busy = page.evaluate("""() => {
            const k = window.jupyterapp.shell.currentWidget.sessionContext.session.kernel;
            const running = [...document.querySelectorAll('.jp-CodeCell .jp-InputPrompt')]
                .some(p => p.textContent.includes('*'));
            return k.status !== 'idle' || running;
        }""")
        if busy:
            quiet_since = None
        elif quiet_since is None:
            quiet_since = time.monotonic()
        elif time.monotonic() - quiet_since > 1.5:  # idle and nothing queued for 1.5 s: done, widgets drawn
            return
        page.wait_for_timeout(300)
    pytest.fail(f"the notebook was still running after {HANG_GUARD_S:g} s (a hang guard)")


def unexecuted_cells(page) -> int:
    """Code cells with an empty prompt after a run (JupyterLab left them unrun)."""
    return page.evaluate("""() => [...document.querySelectorAll('.jp-CodeCell .jp-InputPrompt')]
        .filter(p => !/\\[\\d+\\]/.test(p.textContent)).length""")


def error_outputs(page) -> list[str]:
    return page.eval_on_selector_all(
        ".jp-OutputArea-output[data-mime-type='application/vnd.jupyter.stderr']",
        "els => els.map(e => e.innerText.slice(0, 400))",
    )


def canvas_png(element) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(element.screenshot())).convert("L"), dtype=float)


def screenshot(page, name: str, suffix: str):
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / f"{name.replace('/', '-').removesuffix('.ipynb')}{suffix}.png"))


def run_and_check_rendering(page, jupyter_lab, name):
    open_notebook(page, jupyter_lab, name)
    run_all(page)
    screenshot(page, name, "-end")

    assert error_outputs(page) == [], f"{name}: error or stderr output in the browser"
    assert unexecuted_cells(page) == 0, f"{name}: some code cells did not run"
    broken = page.get_by_text("Error displaying widget").count()
    assert broken == 0, f"{name}: {broken} widget(s) show 'Error displaying widget'"

    figures = page.locator(".jupyter-matplotlib")
    for i in range(figures.count()):
        canvas = figures.nth(i).locator("canvas").first
        canvas.scroll_into_view_if_needed()
        # a busy machine draws late, not never: wait for the drawing (a blank canvas forever is the failure)
        wait_until(
            lambda canvas=canvas: canvas_png(canvas).std() > 5,
            f"{name}: ipympl figure {i} to be drawn (it stays blank)",
            poll_s=500,
            sleep=page.wait_for_timeout,
        )


@pytest.mark.parametrize("name", HANDOUTS)
def test_handout_runs_to_its_end_and_renders_in_jupyterlab(page, jupyter_lab, name):
    run_and_check_rendering(page, jupyter_lab, name)
    notes = page.get_by_text("skipped:")
    assert notes.count() > 0, f"{name}: no cell waits for an exercise? (the guard's notes are missing)"


def test_solved_lab_renders_and_its_slider_moves_the_figure(page, jupyter_lab):
    run_and_check_rendering(page, jupyter_lab, SOLVED)
    assert page.get_by_text("skipped:").count() == 0
    _check_slider_moves_figure(page, SOLVED)


def _check_slider_moves_figure(page, name):
    # the tuning panel: a figure, sliders and an RMSE read-out (lab 04's later 3-D replay has sliders, no RMSE)
    panel = page.locator(".widget-vbox:has(.jupyter-matplotlib):has(.widget-slider)").filter(has_text="RMSE").last
    panel.scroll_into_view_if_needed()
    canvas = panel.locator(".jupyter-matplotlib canvas").first
    readout = panel.get_by_text("RMSE").first
    before_png, before_text = canvas_png(canvas), readout.inner_text()
    screenshot(page, name, "-panel")

    handle = panel.locator(".widget-slider .noUi-handle").first
    value = panel.locator(".widget-slider .widget-readout").first  # the slider's own read-out, drawn by the browser
    before_value = value.inner_text()
    for _ in range(3):  # keys pressed while the page still lays out can miss the handle: press until it moves
        handle.focus()
        for _ in range(8):
            handle.press("ArrowRight")
        page.wait_for_timeout(500)
        if value.inner_text() != before_value:
            break
    assert value.inner_text() != before_value, f"{name}: the slider's handle did not move under the arrow keys"
    page.wait_for_function(
        "([el, old]) => el.innerText !== old", arg=[readout.element_handle(), before_text], timeout=HANG_GUARD_MS
    )
    _wait_for_new_pixels(page, canvas, before_png, f"{name}: moving the slider did not change the figure")
    screenshot(page, name, "-panel-moved")
    assert readout.inner_text() != before_text


BROKEN_NOTEBOOK = {
    "cells": [
        {
            "cell_type": "code",
            "metadata": {},
            "execution_count": None,
            "outputs": [],
            "source": ["def kf_predict(x):\n", "    raise NotImplementedError()\n", "kf_predict(1.0)"],
        }
    ],
    "metadata": {"kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"}},
    "nbformat": 4,
    "nbformat_minor": 5,
}


def test_the_checks_see_errors_a_student_would_see(page, jupyter_lab):
    """The detector above is not blind: a notebook without the guard that calls a stub shows the error."""
    (jupyter_lab.root / "broken.ipynb").write_text(json.dumps(BROKEN_NOTEBOOK))
    open_notebook(page, jupyter_lab, "broken.ipynb")
    run_all(page)
    assert any("NotImplementedError" in text for text in error_outputs(page))


CAPTURE_SECONDS = 120.0  # long enough that a slow redraw never reaches the end
CAPTURE_NOTEBOOK = {
    "cells": [
        {
            "cell_type": "code",
            "metadata": {},
            "execution_count": None,
            "outputs": [],
            "source": [
                "from kfkit import widgets\n",
                "panel = widgets.capture_panel(out_dir='browser_capture')\n",
                "panel.port.value = 'virtual'\n",
                f"panel.seconds.value = {CAPTURE_SECONDS}\n",
                "panel",
            ],
        }
    ],
    "metadata": {"kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"}},
    "nbformat": 4,
    "nbformat_minor": 5,
}


def _progress_and_samples(panel) -> tuple[int, int]:
    """The progress bar's percentage and the sample count of the status line, read in one go."""
    percent, status = panel.evaluate("""el => [el.querySelector('.widget-hprogress').innerText,
                                            el.innerText.match(/(\\d+) samples/)?.[1] ?? '0']""")
    return int(percent.split("%")[0].split()[-1]), int(status)


def _wait_for_new_pixels(page, canvas, before, message):
    """The canvas once it differs from ``before`` (> 0.1 % of its pixels): a busy machine redraws late, not never."""

    def new_pixels():
        now = canvas_png(canvas)
        return now if now.shape == before.shape and np.mean(np.abs(now - before) > 10) > 0.001 else None

    return wait_until(new_pixels, message, poll_s=500, sleep=page.wait_for_timeout)


def test_capture_panel_records_from_the_virtual_board(page, jupyter_lab):
    """Press record, watch the live plot move and the progress bar advance, stop, find the file."""
    from kfkit.io import load_recording

    (jupyter_lab.root / "capture_panel.ipynb").write_text(json.dumps(CAPTURE_NOTEBOOK))
    open_notebook(page, jupyter_lab, "capture_panel.ipynb")
    run_all(page)
    panel = page.locator(".widget-vbox:has(.jupyter-matplotlib):has(.widget-hprogress)").last
    panel.scroll_into_view_if_needed()
    assert page.get_by_text("Error displaying widget").count() == 0
    canvas = panel.locator(".jupyter-matplotlib canvas").first
    idle = canvas_png(canvas)

    panel.locator("button", has_text="record").click()
    page.wait_for_function(
        "el => /recording from|samples/.test(el.innerText)", arg=panel.element_handle(), timeout=HANG_GUARD_MS
    )
    first = _wait_for_new_pixels(page, canvas, idle, "the live plot to draw the incoming samples")
    _wait_for_new_pixels(page, canvas, first, "the live plot to move on while recording (it froze)")
    # progress is judged by the board's samples, not by a clock: each reading's percentage must be what its own
    # sample count implies (checked below against the saved file's rate), and both must advance
    readings = [_progress_and_samples(panel)]
    readings.append(
        wait_until(
            lambda: now if (now := _progress_and_samples(panel))[0] > readings[0][0] else None,
            "the progress bar to advance",
            poll_s=500,
            sleep=page.wait_for_timeout,
        )
    )
    screenshot(page, "capture_panel", "-recording")
    panel.locator("button", has_text="stop").click()
    page.wait_for_function("el => el.innerText.includes('saved')", arg=panel.element_handle(), timeout=HANG_GUARD_MS)
    screenshot(page, "capture_panel", "-saved")
    saved = jupyter_lab.root / "browser_capture" / "capture.csv"
    assert saved.exists(), f"the panel says it saved, but {saved} is missing"
    rec = load_recording(saved)
    assert rec.meta["board"] and len(rec) > 100  # ≥ 1 s at the virtual board's rate
    for percent, samples in readings:  # the board's time is its samples over its rate (± rounding and one tick)
        assert abs(percent - 100 * samples / (rec.meta["rate_hz"] * CAPTURE_SECONDS)) <= 1.5, (percent, samples)
    assert readings[0][1] < readings[1][1] and readings[0][0] < readings[1][0] < 100, readings
    assert f"saved {len(rec)} samples" in panel.inner_text()


def test_a_folded_explanation_opens_on_a_click(page, jupyter_lab):
    """make-labs folds a prediction's explanation (``jupyter.source_hidden``): JupyterLab shows a bar, not the text,
    until the student clicks it; the answer cell for the prediction is there and editable."""
    import nbformat

    from kfkit.authoring import strip_solutions

    md = nbformat.v4.new_markdown_cell
    solution = nbformat.v4.new_notebook(metadata=BROKEN_NOTEBOOK["metadata"])
    solution.cells = [
        md("**Predict before you run.** Does the error fall?", metadata={"tags": ["predict"]}),
        nbformat.v4.new_code_cell("print(0.33)"),
        md(
            "It falls: see <!-- run: the RMSE printed above -->0.33°<!-- /run -->. EXPLAINED-HERE",
            metadata={"tags": ["reveal"]},
        ),
    ]
    nbformat.write(strip_solutions(solution), str(jupyter_lab.root / "folded.ipynb"))
    open_notebook(page, jupyter_lab, "folded.ipynb")
    assert page.locator(".jp-RenderedMarkdown", has_text="My prediction:").count() == 1
    explained = page.locator(".jp-RenderedMarkdown", has_text="EXPLAINED-HERE")
    assert explained.count() == 0 or not explained.first.is_visible(), "the explanation is not folded"
    screenshot(page, "folded", "-closed")
    placeholder = page.locator(".jp-MarkdownCell .jp-InputPlaceholder, .jp-MarkdownCell .jp-Placeholder").first
    placeholder.wait_for(timeout=HANG_GUARD_MS)
    assert "Explanation" in placeholder.inner_text() and "EXPLAINED-HERE" not in placeholder.inner_text()
    placeholder.click()
    explained.first.wait_for(state="visible", timeout=HANG_GUARD_MS)
    screenshot(page, "folded", "-opened")
    assert "the RMSE printed above" in explained.first.inner_text()
