"""What a lab notebook calls beyond the library: one module per lab (``kfkit.labs.lab01`` …).

A lab's data preparation (which recording, which window, which calibration), its truth helpers (errors against
motion capture, phase masks) and the few plotting recipes only that lab draws live here, so a notebook's cells stay
short and show the idea, not the plumbing (ThinkDSP's split between chapters and ``thinkdsp.py``). The checkpoints
(:mod:`kfkit.checkpoints`) import the same helpers to build their cases; a notebook imports nothing from the
checkpoints but ``check``. What more than one lab uses belongs in the library (``metrics``, ``plots``, ``datasets``).
"""
