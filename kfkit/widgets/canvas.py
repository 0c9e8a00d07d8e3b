"""The ipympl canvas every interactive figure of the kit is drawn on.

Each panel gets a canvas of its own, so the rest of a notebook keeps the inline backend (static
PNGs that survive in saved outputs) while the panel's figure redraws in place without flicker.
"""

from __future__ import annotations

import warnings

import matplotlib


def interactive_canvas(fig):
    """Attach an ipympl canvas to ``fig`` without switching the notebook's backend."""
    backend = matplotlib.get_backend()
    from ipympl.backend_nbagg import Canvas, FigureManager  # importing ipympl selects its backend…

    if matplotlib.get_backend() != backend:
        matplotlib.use(backend)  # …so hand the notebook its own back

    canvas = Canvas(fig)
    with warnings.catch_warnings():
        # ipympl's own bug (matplotlib/ipympl#611, #488): Toolbar.__init__ calls DOMWidget.__init__, whose
        # cooperative super() reaches NavigationToolbar2WebAgg.__init__ without its canvas; traitlets catches
        # the TypeError and warns. The toolbar is then built by its explicit second __init__ call and works.
        warnings.filterwarnings(
            "ignore", r"Passing unrecognized arguments to super\(Toolbar\)\.__init__\(\)", DeprecationWarning
        )
        FigureManager(canvas, 0)
    canvas.header_visible = False
    canvas.footer_visible = False
    canvas.toolbar_position = "right"
    return canvas
