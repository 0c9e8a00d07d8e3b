"""The filters' settings dataclasses: each docstring's defaults table against the dataclass, one meaning per
field name across the filters, and the one validation helper (kfkit.filters.contract.check_settings)."""

import ast
import dataclasses
import inspect
import math
import re

import numpy as np
import pytest
from test_filter_contract import CASES

from kfkit.filters.contract import check_settings
from kfkit.filters.mag_gate import MagGate
from kfkit.filters.mekf import MultiplicativeEKFSettings
from kfkit.filters.registry import FILTERS
from kfkit.frames import MAG_FIELD_LONDON


def settings_classes():
    """Every registered filter's settings class, once (the fast and the stepped Euler EKF share one)."""
    return list(dict.fromkeys(type(CASES[name]()["make"]().settings) for name in FILTERS))


SETTINGS = settings_classes()


def classes():
    return [pytest.param(c, id=c.__name__) for c in SETTINGS]


# --- the docstring's defaults table ----------------------------------------------------------------------------

ROW = re.compile(r"([a-z_][a-z0-9_]*) {2,}(.*)")
DEGREES = {"°": 1.0, "°/s": 1.0, "°/s/√Hz": 1.0}  # units a default may be written in: degrees → rad (per s, per √Hz)


def defaults_table(doc):
    """{field: (description, default)} from a docstring's table: a row starts at the margin with the field name and
    two or more spaces, its indented lines continue it, and the default is what follows the last run of two or more
    spaces on its last line. Numbers may carry °, °/s or °/s/√Hz (turned into rad); None, True, False, "text"."""
    rows, name = {}, None
    for line in inspect.cleandoc(doc).splitlines():
        match = ROW.fullmatch(line)
        if match:
            name = match.group(1)
            rows[name] = [match.group(2)]
        elif name and line.startswith(" ") and line.strip():
            rows[name].append(line.strip())
        else:
            name = None
    return {
        name: (" ".join(lines), parse_default(re.split(r" {2,}", lines[-1].strip())[-1]))
        for name, lines in rows.items()
    }


def parse_default(text):
    number = re.fullmatch(r"([-+]?[0-9.]+(?:e[-+]?[0-9]+)?) ?(°(?:/s(?:/√Hz)?)?)?", text)
    if number:
        value = float(number.group(1))
        return math.radians(value) if number.group(2) in DEGREES else value
    try:
        return ast.literal_eval(text)
    except (SyntaxError, ValueError):
        raise ValueError(
            f"the default {text!r} is neither a number (in °, °/s or °/s/√Hz, or none) nor a literal; "
            f"is there one space only before it?"
        ) from None


def test_the_table_parser_reads_rows_units_and_literals_and_sees_a_wrong_default():
    @dataclasses.dataclass(frozen=True)
    class Toy:
        """Toy settings.

        rate      a rate, rad/s, whose description runs on
                  to a second line                                     0.3 °/s
        angle     an angle, rad                                          10°
        mode      a mode                                              "skip"
        gate      a threshold; None = off                               None
        tiny      a small number                                        2e-10

        The text after the table.
        """

        rate: float = math.radians(0.3)
        angle: float = math.radians(10.0)
        mode: str = "skip"
        gate: float | None = None
        tiny: float = 2e-11  # the docstring says 2e-10

    table = defaults_table(Toy.__doc__)
    assert list(table) == ["rate", "angle", "mode", "gate", "tiny"]
    assert table["rate"] == (
        "a rate, rad/s, whose description runs on to a second line                                     0.3 °/s",
        pytest.approx(math.radians(0.3)),
    )
    assert [table[n][1] for n in ("angle", "mode", "gate")] == [pytest.approx(math.radians(10.0)), "skip", None]
    assert mismatches(Toy) == ["tiny: the docstring says 2e-10, the dataclass 2e-11"]


def mismatches(cls):
    """Fields whose docstring default differs from the dataclass's, and rows or fields the other side lacks."""
    table = defaults_table(cls.__doc__)
    problems = [
        f"{name}: in the docstring's table, not a field"
        for name in table
        if name not in {f.name for f in dataclasses.fields(cls)}
    ]
    for f in dataclasses.fields(cls):
        if f.name not in table:
            problems.append(f"{f.name}: a field without a row in the docstring's table")
            continue
        documented = table[f.name][1]
        if isinstance(f.default, float):
            same = isinstance(documented, float) and documented == pytest.approx(f.default, rel=1e-12)
        else:
            same = type(documented) is type(f.default) and documented == f.default
        if not same:
            problems.append(f"{f.name}: the docstring says {documented!r}, the dataclass {f.default!r}")
    return problems


@pytest.mark.parametrize("cls", classes())
def test_each_docstring_table_states_the_dataclass_defaults(cls):
    assert mismatches(cls) == []


# --- one meaning per word --------------------------------------------------------------------------------------

GLOSSARY = {  # field name: (the unit its docstring row names, what it means) — one meaning each, in every filter
    "q_angle": ("rad²", "angle process noise per step"),
    "q_bias": ("(rad/s)²", "gyro-bias random walk per step"),
    "r": ("rad²", "variance of the accelerometer angle"),
    "q_beta": ("rad²/s", "process noise density on β̇"),
    "q_r": ("rad²/s³", "process noise density on the yaw acceleration"),
    "q_bias_ay": ("(m/s²)²/s", "random-walk density of the lateral-accelerometer bias"),
    "gyro_noise": ("rad/s", "σ of a gyro sample"),
    "gyro_density": ("rad/s/√Hz", "gyro white-noise density"),
    "gyro_bias_rw": ("rad/s/√s", "gyro-bias random-walk density (σ)"),
    "accel_noise": ("m/s²", "σ of an accelerometer sample"),
    "mag_noise": ("µT", "σ of a magnetometer sample"),
    "accel_density": ("m/s²/√Hz", "accelerometer white-noise density"),
    "mag_density": ("µT/√Hz", "magnetometer white-noise density"),
    "accel_dynamic": ("m/s²", "linear acceleration at which the accelerometer's variance doubles"),
    "rest_gyro": ("rad/s", "rest detection's threshold on the gyro"),
    "rest_accel": ("m/s²", "rest detection's threshold on the accelerometer"),
    "rest_time": ("s", "time within the thresholds before the IMU counts as at rest"),
    "rest_tau": ("s", "time constant of the rest detector's low-passes"),
    "rest_margin": ("s", "age of the gyro sample a zero-rate update uses"),
    "accel_gate": ("m/s²", "threshold on |‖f‖ − g| above which the accelerometer is gated"),
    "accel_gating": (None, "what a gated accelerometer sample does: skip, inflate, none"),
    "accel_inflation": (None, "variance multiplier of a gated accelerometer sample"),
    "accel_tau": ("s", "time constant of the accelerometer low-pass"),
    "mag_norm_gate": (None, "threshold on the field norm, a fraction of the reference's"),
    "mag_dip_gate": ("rad", "threshold on the dip angle"),
    "mag_nis_gate": ("χ²", "threshold on the heading innovation's NIS"),
    "mag_recovery": ("s", "time a field must pass the gates before it is used again"),
    "mag_ref_tau": ("s", "time constant of the gates' reference field"),
    "v_min": ("m/s", "speed below which the kinematic sideslip is used"),
    "beta_low_std": ("rad", "σ of that kinematic sideslip"),
    "bias_ay": (None, "whether there is a lateral-accelerometer bias state"),
    "bias_ay_std": ("m/s²", "initial σ of that bias"),
    "vx_step": ("m/s", "width of the speed bins of the model cache"),
    "stiffness_std": (None, "relative σ of an axle's tyre force"),
}


@pytest.mark.parametrize("cls", classes())
def test_each_field_name_has_one_meaning_across_the_filters(cls):
    """Every field is in the glossary and its docstring row names the glossary's unit, so one word cannot carry two
    units (the tilt filter's q_bias in (rad/s)², the sideslip filter's in (m/s²)²/s); a *_gate is a threshold
    (a number or None), never a mode."""
    table = defaults_table(cls.__doc__)
    for f in dataclasses.fields(cls):
        assert f.name in GLOSSARY, f"{cls.__name__}.{f.name} is not in the glossary: does another name mean it already?"
        unit = GLOSSARY[f.name][0]
        assert unit is None or unit in table[f.name][0], f"{cls.__name__}.{f.name}: its row does not say {unit}"
        if f.name.endswith("gate"):
            assert f.default is None or isinstance(f.default, (int, float)), (
                f"{cls.__name__}.{f.name} is not a threshold"
            )


# --- the one validation helper ---------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Checked:
    size: float = 1.0
    offset: float = 0.0
    limit: float | None = None
    enabled: bool = False
    mode: str = "skip"

    def __post_init__(self):
        check_settings(
            self,
            positive=("size", "limit"),
            non_negative=("offset",),
            optional=("limit",),
            flags=("enabled",),
            choices={"mode": ("skip", "inflate")},
        )


@pytest.mark.parametrize(
    "change, message",
    [
        ({"size": 0.0}, "Checked: size must be a positive number, got 0.0"),
        ({"size": np.nan}, "Checked: size must be a positive number, got nan"),
        ({"size": "1"}, "Checked: size must be a positive number, got '1'"),
        ({"size": True}, "Checked: size must be a positive number, got True"),
        ({"offset": -1e-9}, "Checked: offset must be a number ≥ 0, got -1e-09"),
        ({"limit": -1.0}, "Checked: limit must be a positive number or None, got -1.0"),
        ({"enabled": 1}, "Checked: enabled must be True or False, got 1"),
        ({"mode": "sometimes"}, "Checked: mode must be one of skip, inflate, got 'sometimes'"),
    ],
)
def test_check_settings_names_the_class_field_expectation_and_value(change, message):
    assert Checked(limit=2.0, offset=0.0, enabled=True, mode="inflate").limit == 2.0
    with pytest.raises(ValueError, match=re.escape(message)):
        Checked(**change)


def test_check_settings_wants_every_field_in_one_group():
    @dataclasses.dataclass(frozen=True)
    class Forgotten:
        a: float = 1.0
        b: float = 1.0

        def __post_init__(self):
            check_settings(self, positive=("a",))

    with pytest.raises(TypeError, match="each field in one group; wrong for b"):
        Forgotten()


def test_mag_gate_takes_the_mekf_settings():
    """MagGate(field_n, settings) reads its gates and times from MultiplicativeEKFSettings (not positional copies)."""
    settings = MultiplicativeEKFSettings(mag_norm_gate=0.2, mag_recovery=2.0)
    gate = MagGate(np.array(MAG_FIELD_LONDON), settings)
    assert (gate.norm_gate, gate.recovery) == (0.2, 2.0)
