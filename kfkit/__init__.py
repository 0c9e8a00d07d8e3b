"""kfkit: the helper package of a Jupyter lab kit that teaches Kalman filtering on real sensors.

Layers, bottom to top (a module imports only from its own layer or below; README has the full table):

0. ``paths`` (where data and calibrations live), ``frames`` (g, the reference field, every rotation)
1. ``sensors`` (boards incl. the phone, the sensor vocabulary), ``metrics``
2. ``unit_errors`` (each board's simulated unit), ``clocks`` (one time base, sample counters),
   ``motions``, ``attitude_motions``, ``calibration_motions`` (truth motions), ``sim`` (simulate_imu),
   ``phone_sim`` (a phone's sensors, simulated)
3. ``io`` (the kit's recording format), ``vehicle`` (bicycle models, drives, the vehicle format)
4. ``readers`` (foreign formats: phyphox export, BROAD, your vehicle CSV; ``load_any``)
5. ``calibration``, ``filters``
6. ``datasets`` (the bundled recordings)
7. ``capture`` (boards and phones, recorded into the kit's format)
8. ``plots``, ``widgets``, ``demo``
9. ``checkpoints``, ``grading``, ``authoring``, ``doctor``, ``cli``

Import what you need, e.g. ``from kfkit import frames, filters``.
"""

__version__ = "0.1.0"
