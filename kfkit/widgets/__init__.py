"""ipywidgets UIs, one module each, every figure on its own ipympl canvas (:mod:`.canvas`):

- :mod:`.tuning`         ``tune`` / ``TuningPanel``: a filter's tuning values on log-scale sliders (labs 01, 04)
- :mod:`.attitude_view`  ``attitude_view`` / ``AttitudeView``: the board in 3-D, replayed or live
                         (``AttitudeView.live`` + ``LiveAttitude``) (lab 04)
- :mod:`.capture_panel`  ``capture_panel`` / ``CapturePanel`` / ``LiveSignals``: record from a board, a phone
                         or the virtual board (lab 00)

``from kfkit import widgets; widgets.tune(...)`` reaches all of them.
"""

from .attitude_view import AttitudeView, LiveAttitude, attitude_view
from .canvas import interactive_canvas
from .capture_panel import CapturePanel, LiveSignals, capture_panel
from .tuning import TuningPanel, tune

__all__ = [
    "AttitudeView",
    "CapturePanel",
    "LiveAttitude",
    "LiveSignals",
    "TuningPanel",
    "attitude_view",
    "capture_panel",
    "interactive_canvas",
    "tune",
]
