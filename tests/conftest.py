"""Shared by every test: no figure outlives the test that drew it (a helper's figures piling up across
tests made matplotlib warn about memory); the longest test modules are handed out first.

Scheduling: with ``-n N`` (pytest-xdist, the README's test command), :func:`pytest_cmdline_main` makes the
distribution ``loadscope``, which keeps each module (and each notebook's nbval cells, and each module's
session fixtures: the JupyterLab server, the grading runs) on one worker, and turns off its reordering, so
modules are handed out in collection order. Left to its default, xdist orders them by their number of tests,
so a module of a few long tests (the browser run of every notebook, the grading of every lab) could start
last and leave one worker running it alone for minutes. :func:`pytest_collection_modifyitems` moves the
known long modules to the front, longest first. ``-n`` is not in pyproject's addopts, so pytest starts
without xdist too (a student's ``python -m pytest NOTEBOOK``).
"""

import sys

import pytest


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config):
    """``-n N`` without ``--dist`` means ``--dist loadscope --no-loadscope-reorder`` (runs before xdist's own
    hook, which would otherwise make it ``load``)."""
    if getattr(config.option, "numprocesses", None) and config.option.dist == "no":
        config.option.dist = "loadscope"
        config.option.loadscopereorder = False


#: the longest test modules and notebooks, longest first (CPU time on the 2-core machine; see the README's
#: "Tests" section); everything else keeps pytest's order after them
LONGEST_FIRST = (
    "tests/browser/",
    "tests/test_hub.py",
    "tests/test_grading.py",
    "tests/test_notebooks.py",
    "tests/test_lab04_notebook.py",
    "solutions/04_ekf_attitude.ipynb",
    "tests/test_grading_isolation.py",
    "tests/test_calibration_labs.py",
    "tests/test_firmware_stm32.py",  # the STM32duino core's build, about a minute of CPU
    "tests/test_firmware_emulated_uno.py",
)


def _rank(item) -> int:
    path = item.nodeid.split("::", 1)[0]
    return next((i for i, prefix in enumerate(LONGEST_FIRST) if path.startswith(prefix)), len(LONGEST_FIRST))


def pytest_collection_modifyitems(items):
    """Longest modules first (see above); every notebook's nbval cells are slow (the quick tier, -m 'not slow', runs
    kfkit's own tests and leaves the notebook runs to the full suite)."""
    items.sort(key=_rank)  # stable: each module's own order is kept
    for item in items:
        if item.nodeid.split("::", 1)[0].endswith(".ipynb"):
            item.add_marker(pytest.mark.slow)


@pytest.fixture(autouse=True)
def close_figures():
    yield
    pyplot = sys.modules.get("matplotlib.pyplot")  # only when the test used it: importing it costs ~0.5 s
    if pyplot is not None:
        pyplot.close("all")
