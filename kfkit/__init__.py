"""kfkit: the helper package of a Jupyter lab kit that teaches Kalman filtering on real sensors.

One module per concern (see README): frames, sensors, sim, filters, metrics, io, datasets,
plots, widgets, checkpoints, authoring, cli. Import what you need, e.g.
``from kfkit import frames, filters``.
"""
__version__ = "0.1.0"
