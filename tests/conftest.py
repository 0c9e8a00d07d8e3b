"""Shared by every test: no figure outlives the test that drew it (a helper's figures piling up across
tests made matplotlib warn about memory)."""
import sys

import pytest


@pytest.fixture(autouse=True)
def close_figures():
    yield
    pyplot = sys.modules.get("matplotlib.pyplot")  # only when the test used it: importing it costs ~0.5 s
    if pyplot is not None:
        pyplot.close("all")
