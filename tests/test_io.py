"""kfkit.io: recording round trip, validation messages (file + line), Recording helpers."""

import json
import math
import re

import numpy as np
import pytest

from kfkit.io import Recording, RecordingError, load_recording, recording_text, save_recording
from kfkit.motions import sine_roll, stationary
from kfkit.sim import simulate_imu

IDENTITY = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
#: what a recording with ax and mx columns must carry: each sensor's sensitivity and mounting
SENSOR_META = {
    "sensors": {"acc": {"sensitivity": 0.001}, "mag": {"sensitivity": 0.15}},
    "mount": {"acc": IDENTITY, "mag": IDENTITY},
}
HEADER = "# kfkit-recording v1 " + json.dumps({"rate_hz": 100.0, **SENSOR_META}) + "\n"
COLUMNS = "t,seq,ax,mx,true_roll\n"
ROWS = ["0.00,0,10,5,0.1\n", "0.01,1,-3,,0.2\n", "0.02,2,7,6,0.3\n"]
GOOD = HEADER + COLUMNS + "".join(ROWS)


def write(tmp_path, content, name="rec.csv"):
    path = tmp_path / name
    (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
    return path


def load_error(path, line):
    """Load ``path``, expecting a RecordingError at ``line`` whose message names file and line."""
    with pytest.raises(RecordingError) as err:
        load_recording(path)
    msg = str(err.value)
    assert str(path) in msg
    assert err.value.line == line
    if line is not None:
        assert f"line {line}:" in msg
    return msg


def small_recording():
    meta = {
        "board": "test",
        "rate_hz": 100.0,
        "description": "roll 30° ±, µT",
        "nested": {"a": [1, 2.5, None]},
        **SENSOR_META,
    }
    data = {
        "t": np.arange(5) / 100.0,
        "seq": np.arange(5, dtype=np.int64),
        "ax": np.array([0, -32768, 32767, 5, -1], dtype=np.int64),
        "mx": np.array([3.0, np.nan, -4.0, np.nan, 0.0]),
        "true_roll": np.array([0.0, 1e-9, -np.pi, 0.123456789012, 7.0]),
    }
    return Recording(meta, data)


# --- round trip ---------------------------------------------------------------------------


def test_round_trip_preserves_meta_columns_dtypes_and_values(tmp_path):
    rec = small_recording()
    path = save_recording(rec, tmp_path / "r.csv")
    back = load_recording(path)
    assert back.meta == rec.meta
    assert back.columns == rec.columns
    assert back.path == path
    for c in ("seq", "ax"):
        assert back[c].dtype == np.int64
        np.testing.assert_array_equal(back[c], rec[c])
    assert back["mx"].dtype == float
    np.testing.assert_array_equal(np.isnan(back["mx"]), np.isnan(rec["mx"]))
    np.testing.assert_array_equal(back["mx"][~np.isnan(rec["mx"])], [3.0, -4.0, 0.0])
    np.testing.assert_allclose(back.t, rec.t, atol=5e-7)
    np.testing.assert_allclose(back["true_roll"], rec["true_roll"], rtol=1e-8)


def test_round_trip_of_a_simulation_is_textually_stable(tmp_path):
    rec = simulate_imu(sine_roll(duration=3.0), seed=5)
    back = load_recording(save_recording(rec, tmp_path / "sim.csv"))
    assert back.meta == rec.meta
    for c in rec.columns:
        assert back[c].dtype == rec[c].dtype, c
    np.testing.assert_array_equal(back["ax"], rec["ax"])
    np.testing.assert_array_equal(back["mx"], rec["mx"])  # NaNs in the same places
    assert recording_text(back) == recording_text(rec)


def test_saved_file_layout(tmp_path):
    text = save_recording(small_recording(), tmp_path / "r.csv").read_text(encoding="utf-8")
    lines = text.split("\n")
    assert lines[0].startswith("# kfkit-recording v1 {")
    assert lines[1] == "t,seq,ax,mx,true_roll"
    assert lines[3].split(",")[3] == ""  # NaN magnetometer cell is empty
    assert text.endswith("\n") and "\r" not in text


def test_loads_hand_written_file_and_crlf(tmp_path):
    for name, text in (("lf.csv", GOOD), ("crlf.csv", GOOD.replace("\n", "\r\n"))):
        rec = load_recording(write(tmp_path, text.encode(), name))
        assert rec.rate_hz == 100.0 and len(rec) == 3
        np.testing.assert_array_equal(rec["ax"], [10, -3, 7])
        assert math.isnan(rec["mx"][1]) and rec["mx"][2] == 6


# --- bad input: header and column line ----------------------------------------------------


@pytest.mark.parametrize(
    "text, line, expect",
    [
        ("", 1, ["empty"]),
        ("t,seq,ax\n0,0,1\n", 1, ["header", "kfkit recording"]),
        ('# kfkit-recording v2 {"rate_hz": 100}\n' + COLUMNS + ROWS[0], 1, ["'v2'", "v1"]),
        ('# kfkit-recording v1 {"rate_hz": }\n' + COLUMNS + ROWS[0], 1, ["not valid JSON"]),
        ('# kfkit-recording v1 {"board": "x"}\n' + COLUMNS + ROWS[0], 1, ["rate_hz"]),
        ("# kfkit-recording v1 [1, 2]\n" + COLUMNS + ROWS[0], 1, ["JSON object", "rate_hz"]),
        (HEADER, 2, ["column line", "t, seq"]),
        (HEADER + "t,ax,ay\n0,1,2\n", 2, ["t, seq", "'t,ax,ay'"]),
        (HEADER + "time,seq\n0,1\n", 2, ["t, seq"]),
        (HEADER + "t,seq,ax,ax\n0,0,1,1\n", 2, ["duplicate", "ax"]),
    ],
    ids=[
        "empty",
        "not-a-recording",
        "version",
        "json",
        "no-rate",
        "not-object",
        "header-only-no-columns",
        "no-seq",
        "no-t",
        "duplicate",
    ],
)
def test_bad_header_or_columns(tmp_path, text, line, expect):
    msg = load_error(write(tmp_path, text), line)
    for word in expect:
        assert word in msg


def test_header_only_has_no_samples(tmp_path):
    assert "no samples" in load_error(write(tmp_path, HEADER + COLUMNS), 3)


def test_not_utf8(tmp_path):
    path = write(tmp_path, HEADER.encode() + COLUMNS.encode() + b"0.0,0,\xff\xfe,1,0\n")
    assert "not a text file" in load_error(path, None)


def test_missing_file(tmp_path):
    path = tmp_path / "nowhere" / "rec.csv"
    with pytest.raises(FileNotFoundError, match=re.escape(str(path))):
        load_recording(path)


# --- bad input: rows ----------------------------------------------------------------------


def with_row(index, row):
    """GOOD with data row ``index`` (0-based; file line index + 3) replaced."""
    rows = list(ROWS)
    rows[index] = row
    return HEADER + COLUMNS + "".join(rows)


@pytest.mark.parametrize(
    "row_index, row, expect",
    [
        (1, "0.01,1,-3,0.2\n", ["expected 5 fields", "got 4"]),
        (2, "0.02,2,7,6,0.3,9\n", ["expected 5 fields", "got 6"]),
        (1, "0.01,1,1.5,,0.2\n", ["'ax'", "'1.5'", "not an integer"]),
        (0, "0.00,zero,10,5,0.1\n", ["'seq'", "not an integer"]),
        (2, "0.02,2,7,6.5,0.3\n", ["'mx'", "not an integer"]),
        (1, "0.01,1,-3,,abc\n", ["'true_roll'", "'abc'", "not a number"]),
        (1, "0.01,1,nan,,0.2\n", ["'ax'", "'nan'"]),
        (1, "nan,1,-3,,0.2\n", ["'t'", "not a finite number"]),
        (2, "inf,2,7,6,0.3\n", ["'t'", "not a finite number"]),
        (0, "0.00,0,10,5,-inf\n", ["'true_roll'", "not a finite number"]),
        (2, "0.005,2,7,6,0.3\n", ["time does not increase", "0.005", "0.01"]),
        (2, "0.01,2,7,6,0.3\n", ["time does not increase"]),
    ],
    ids=[
        "too-few",
        "too-many",
        "float-in-int",
        "text-in-seq",
        "float-in-mag",
        "text-in-float",
        "nan-in-ax",
        "nan-t",
        "inf-t",
        "inf-float",
        "t-backwards",
        "t-repeated",
    ],
)
def test_bad_rows(tmp_path, row_index, row, expect):
    msg = load_error(write(tmp_path, with_row(row_index, row)), row_index + 3)
    for word in expect:
        assert word in msg


def test_truncated_last_line(tmp_path):
    cut = GOOD[: GOOD.rindex("\n", 0, len(GOOD) - 1) + 1] + "0.02,2,7"  # last row cut mid-line
    msg = load_error(write(tmp_path, cut), 5)
    assert "cut short" in msg and "interrupted" in msg
    assert "the 2 rows before it are complete" in msg and "delete this line" in msg


def test_short_row_with_newline_is_not_called_truncated(tmp_path):
    msg = load_error(write(tmp_path, GOOD + "0.03,3,7\n"), 6)
    assert "expected 5 fields" in msg and "cut short" not in msg


def test_last_line_without_newline_is_rejected_even_with_all_fields(tmp_path):
    # "8075" cut to "80" keeps the field count: only the missing newline shows the cut.
    with pytest.raises(RecordingError, match=r"line 5: the last line is cut short"):
        load_recording(write(tmp_path, GOOD.rstrip("\n")))


def test_blank_lines_at_the_end_are_ignored(tmp_path):
    assert len(load_recording(write(tmp_path, GOOD + "\n\n"))) == 3


# --- Recording helpers --------------------------------------------------------------------


def test_truth_missing_raises_clear_keyerror():
    rec = Recording({"rate_hz": 100.0}, {"t": np.arange(3) / 100.0, "seq": np.arange(3)})
    with pytest.raises(KeyError, match="truth columns.*simulated"):
        rec.truth()


def test_truth_returns_n_by_3():
    rec = simulate_imu(sine_roll(duration=1.0), seed=0)
    truth = rec.truth()
    assert truth.shape == (len(rec), 3)
    np.testing.assert_array_equal(truth[:, 0], rec["true_roll"])


def test_unknown_column_lists_columns():
    with pytest.raises(KeyError, match="'nope'.*t, seq, ax, mx, true_roll"):
        small_recording()["nope"]


def test_head_keeps_the_first_seconds():
    rec = small_recording()
    first = rec.head(0.025)
    assert len(first) == 3 and first.columns == rec.columns and first.meta == rec.meta
    assert first.t.max() < 0.025
    np.testing.assert_array_equal(first["ax"], rec["ax"][:3])
    assert len(rec.head(10.0)) == len(rec)


def test_counts_sensor_si_and_body():
    n = 4
    data = {
        "t": np.arange(n) / 10.0,
        "seq": np.arange(n),
        "ax": np.array([1, 2, 3, 4]),
        "ay": np.array([10, 20, 30, 40]),
        "az": np.array([-5, 0, 5, 100]),
    }
    meta = {
        "rate_hz": 10.0,
        "sensors": {"acc": {"sensitivity": 0.5}},
        "mount": {"acc": [[0, -1, 0], [1, 0, 0], [0, 0, 1]]},
    }  # 90° about z: not symmetric
    rec = Recording(meta, data)
    counts = np.column_stack([data["ax"], data["ay"], data["az"]])
    np.testing.assert_array_equal(rec.counts("acc"), counts)
    np.testing.assert_allclose(rec.sensor_si("acc"), 0.5 * counts)
    x_s = 0.5 * counts
    np.testing.assert_allclose(rec.body("acc"), np.column_stack([-x_s[:, 1], x_s[:, 0], x_s[:, 2]]))  # x_b = M_bs x_s


def test_phase_windows_select_samples_and_survive_a_round_trip(tmp_path):
    motion = stationary(3.0, 10.0)
    motion.phases = [(0.0, 1.0, "still"), (2.0, 3.0, "still"), (1.0, 2.0, "turn")]
    rec = load_recording(save_recording(simulate_imu(motion, seed=1), tmp_path / "p.csv"))
    assert rec.phase("still").sum() == 20 and rec.phase("turn").sum() == 10
    assert not (rec.phase("still") & rec.phase("turn")).any()
    with pytest.raises(KeyError, match="no phase 'six'.*still, turn"):
        rec.phase("six")


# --- counts are exact integers; numbers are plain ASCII decimal ------------------------------------


@pytest.mark.parametrize(
    "col, cell, expect",
    [
        (2, "1e20", "'ax': '1e20' is not an integer count"),
        (2, str(2**53 + 1), "'ax': 9007199254740993 is out of range for a count"),  # int64 holds it, float64 would not
        (2, str(2**70), "'ax': 1180591620717411303424 is out of range"),  # beyond int64: was a raw OverflowError
        (3, str(-(2**53) - 1), "'mx': -9007199254740993 is out of range"),  # the NaN-able column is float64
        (3, "1e20", "'mx': '1e20' is not an integer count"),
        (2, "1_000", "'ax': '1_000' is not an integer count"),  # int() takes it
        (2, "\u0661\u0662", "is not an integer count"),  # Arabic-Indic "12": int() takes it too
        (4, "1_0.5", "'true_roll': '1_0.5' is not a number"),  # float() takes it
        (4, "1e999", "'true_roll': '1e999' is not a finite number"),  # float() makes it inf
        (1, "1.0", "'seq': '1.0' is not an integer count"),
    ],
    ids=[
        "1e20",
        "2^53+1",
        "2^70",
        "mag-2^53+1",
        "mag-1e20",
        "underscore",
        "unicode-digits",
        "float-underscore",
        "overflow",
        "seq",
    ],
)
def test_counts_never_pass_through_float_and_numbers_are_plain_decimal(tmp_path, col, cell, expect):
    cells = ROWS[1].rstrip("\n").split(",")
    cells[col] = cell
    msg = load_error(write(tmp_path, with_row(1, ",".join(cells) + "\n")), 4)
    assert expect in msg


def test_the_largest_exact_count_loads_exactly(tmp_path):
    edge = f"0.01,1,{-(2**53)},{2**53},0.2\n"
    rec = load_recording(write(tmp_path, with_row(1, edge)))
    assert rec["ax"].dtype == np.int64 and int(rec["ax"][1]) == -(2**53)
    assert rec["mx"][1] == float(2**53) and int(rec["mx"][1]) == 2**53


def test_the_writer_refuses_a_count_it_would_have_to_round(tmp_path):
    rec = small_recording()
    for bad in (12.7, np.nan, float(2**60)):
        rec.data["ax"] = np.array([0, 1, bad, 3, 4], dtype=float)
        with pytest.raises(ValueError, match=r"column 'ax': .* (not an integer count|out of range)"):
            save_recording(rec, tmp_path / "r.csv")
    rec.data["ax"] = np.array([0, 1, 2, 3, 4], dtype=float)  # whole floats are counts: written as integers
    assert load_recording(save_recording(rec, tmp_path / "r.csv"))["ax"].tolist() == [0, 1, 2, 3, 4]


# --- metadata ------------------------------------------------------------------------------------


def with_meta(changes):
    """GOOD with its metadata changed: {"a.b": value} sets meta["a"]["b"]; a value of ... removes it."""
    meta = {"rate_hz": 100.0, **json.loads(json.dumps(SENSOR_META))}
    for key, value in changes.items():
        *parents, leaf = key.split(".")
        node = meta
        for k in parents:
            node = node[k]
        if value is ...:
            del node[leaf]
        else:
            node[leaf] = value
    return "# kfkit-recording v1 " + json.dumps(meta) + "\n" + COLUMNS + "".join(ROWS)


@pytest.mark.parametrize(
    "changes, expect",
    [
        ({"rate_hz": -104.0}, "'rate_hz' must be a positive finite number (Hz), got -104.0"),
        ({"rate_hz": 0}, "'rate_hz' must be a positive finite number"),
        ({"rate_hz": float("nan")}, "'rate_hz' must be a positive finite number (Hz), got nan"),
        ({"rate_hz": "104"}, "got '104'"),
        ({"rate_hz": True}, "got True"),
        ({"rate_hz": None}, "got None"),
        ({"sensors": ...}, "no 'sensors' object, but the file has columns of acc, mag"),
        ({"mount": ...}, "no 'mount' object"),
        (
            {"sensors.mag": ...},
            "sensors.mag.sensitivity must be a positive finite number (SI units per count), got None",
        ),
        ({"sensors.acc": {"sensitivity": -0.001}}, "sensors.acc.sensitivity must be a positive finite number"),
        ({"sensors.acc": {"sensitivity": 0}}, "sensors.acc.sensitivity"),
        ({"sensors.acc": {"sensitivity": "0.001"}}, "sensors.acc.sensitivity"),
        ({"mount.acc": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}, "mount.acc must be a 3×3 rotation matrix M_bs"),
        (
            {"mount.mag": "flat"},
            "mount.mag must be a 3×3 rotation matrix M_bs (body ← sensor; orthonormal, det +1), got 'flat'",
        ),
        ({"phases": [{"label": "rest", "start": 1.0}]}, "phases[0] must be"),
        ({"phases": [{"label": "rest", "start": 2.0, "end": 1.0}]}, "with start < end"),
        ({"phases": "rest"}, "'phases' must be a list"),
    ],
    ids=[
        "rate-negative",
        "rate-zero",
        "rate-nan",
        "rate-text",
        "rate-bool",
        "rate-null",
        "no-sensors",
        "no-mount",
        "no-mag-sensor",
        "sensitivity-negative",
        "sensitivity-zero",
        "sensitivity-text",
        "mount-reflection",
        "mount-name",
        "phase-no-end",
        "phase-backwards",
        "phases-not-list",
    ],
)
def test_metadata_the_helpers_read_is_checked_on_loading(tmp_path, changes, expect):
    assert expect in load_error(write(tmp_path, with_meta(changes)), 1)


def test_a_recording_without_sensor_columns_needs_no_sensor_metadata(tmp_path):
    rec = load_recording(
        write(tmp_path, '# kfkit-recording v1 {"rate_hz": 50}\nt,seq,true_roll\n0,0,0.5\n0.02,1,0.6\n')
    )
    assert rec.columns == ["t", "seq", "true_roll"] and rec.rate_hz == 50.0


def test_a_column_without_a_name_is_an_error(tmp_path):
    assert "column 3 has no name" in load_error(write(tmp_path, HEADER + "t,seq,,ax\n0,0,1,2\n"), 2)


def test_a_byte_order_mark_is_accepted_by_load_recording_and_load_any(tmp_path):
    from kfkit.readers import load_any

    path = write(tmp_path, b"\xef\xbb\xbf" + GOOD.encode())  # Excel's "CSV UTF-8"
    ref = load_recording(write(tmp_path, GOOD, "plain.csv"))
    for rec in (load_recording(path), load_any(path)):
        assert rec.meta == ref.meta
        for c in ref.columns:
            np.testing.assert_array_equal(rec[c], ref[c])


# --- fuzz: a truncated or garbled file loads the same numbers or raises the loader's own error ---------


def fuzz_variants(data: bytes, seed=0, n_garbled=150):
    """(label, bytes): the file cut at every byte of its last 300 and at random offsets, and copies with one
    byte replaced by a character that cannot complete a different number (so a garble is never undetectable)."""
    rng = np.random.default_rng(seed)
    cuts = sorted(set(range(max(0, len(data) - 300), len(data))) | set(rng.integers(0, len(data), 60).tolist()))
    for k in cuts:
        yield f"cut at {k}", data[:k]
    for k in rng.integers(0, len(data), n_garbled):
        yield f"byte {k} → x", data[:k] + b"x" + data[k + 1 :]
        yield f"byte {k} → NUL", data[:k] + b"\x00" + data[k + 1 :]


def check_fuzzed(path, load, good: bytes, error, same, names=None, garble=True):
    """Every variant of ``good``, written to ``path``, either makes ``load(path)`` raise ``error`` naming the
    file (or ``names``: the export folder it is part of) or loads so that ``same(loaded)`` holds; returns
    how many of each. ``garble=False``: cuts only (for formats without a checksum over binary numbers)."""
    outcome = {"loaded": 0, "rejected": 0}
    for label, data in fuzz_variants(good, n_garbled=150 if garble else 0):
        path.write_bytes(data)
        try:
            got = load(path)
        except error as e:
            assert str(names or path) in str(e), f"{label}: the message does not name the file: {e}"
            outcome["rejected"] += 1
            continue
        except Exception as e:  # noqa: BLE001 — the point: nothing else may escape
            raise AssertionError(f"{label}: {type(e).__name__} escaped the loader: {e}") from None
        assert same(got), f"{label}: loaded different numbers"
        outcome["loaded"] += 1
    return outcome


def same_rows(ref):
    """True when ``rec`` holds the first rows of ``ref`` exactly, in every column they share."""

    def check(rec):
        n = len(rec)
        return 0 < n <= len(ref) and all(
            np.array_equal(rec[c], ref[c][:n], equal_nan=True) for c in rec.columns if c in ref.data
        )

    return check


@pytest.mark.slow
def test_fuzzed_recordings_load_the_same_numbers_or_name_the_file(tmp_path):
    from kfkit.readers import load_any

    rec = simulate_imu(sine_roll(duration=2.0, rate_hz=50.0), seed=4)
    good = recording_text(rec).encode()
    ref = load_recording(write(tmp_path, good, "ref.csv"))
    for load in (load_recording, load_any):
        outcome = check_fuzzed(tmp_path / "fuzzed.csv", load, good, RecordingError, same_rows(ref))
        assert outcome["rejected"] > 100 and outcome["loaded"] > 0  # both paths exercised


# --- seq is a 16-bit counter; a number longer than any writer's is refused, shown short ------------------------------


@pytest.mark.parametrize("seq", ["-1", "-65536", "65536", "100000"])
def test_a_seq_outside_the_16_bit_counter_names_file_line_and_field(tmp_path, seq):
    """A negative seq used to load silently; every writer (boards, simulations, readers) counts 0 … 65535."""
    msg = load_error(write(tmp_path, with_row(1, f"0.01,{seq},-3,,0.2\n")), 4)
    assert f"column 'seq': {seq} is not a sample counter" in msg and "0 … 65535" in msg


def test_the_writer_refuses_a_seq_the_loader_would_refuse(tmp_path):
    rec = small_recording()
    for bad in (-1, 65536):
        rec.data["seq"] = np.array([0, 1, bad, 3, 4])
        with pytest.raises(ValueError, match=f"column 'seq': {bad} is not a 16-bit sample counter"):
            save_recording(rec, tmp_path / "r.csv")
    rec.data["seq"] = np.array([65533, 65534, 65535, 0, 1])  # a wrap is a counter's life
    assert load_recording(save_recording(rec, tmp_path / "r.csv"))["seq"].tolist() == [65533, 65534, 65535, 0, 1]


@pytest.mark.parametrize(
    "col, cell, expect",
    [
        (
            4,
            "0." + "0" * 1_000_000 + "1",
            r"'true_roll': '0.0000000000000000000000'… \(1,000,003 characters\) is longer",
        ),
        (2, "1" * 65, r"'ax': '111111111111111111111111'… \(65 characters\) is longer"),
        (0, "x" * 50, r"'t': 'xxxxxxxxxxxxxxxxxxxxxxxx'… \(50 characters\) is not a number"),
    ],
    ids=["1 MB of digits", "65 digits", "50 letters"],
)
def test_a_number_longer_than_any_writer_makes_is_refused_and_shown_short(tmp_path, col, cell, expect):
    """A megabyte of digits used to load as 0.0; every message shows a value cut to 24 characters."""
    cells = ROWS[1].rstrip("\n").split(",")
    cells[col] = cell
    msg = load_error(write(tmp_path, with_row(1, ",".join(cells) + "\n")), 4)
    assert re.search(expect, msg) and len(msg) < 300, msg[:300]


def test_both_kit_formats_check_their_kind_and_version(tmp_path):
    """One header reader for the recording and the vehicle formats: another version or the other kind is named."""
    from kfkit.io import load_vehicle

    future = tmp_path / "future.csv"
    future.write_text('# kfkit-vehicle v2 {"rate_hz": 100}\nt,delta,yaw_rate,ay,vx\n0,0,0,0,10\n')
    with pytest.raises(
        RecordingError, match=r"future\.csv, line 1: unsupported vehicle version 'v2'; this kfkit reads v1"
    ):
        load_vehicle(future)
    imu = tmp_path / "imu.csv"
    imu.write_text('# kfkit-recording v1 {"rate_hz": 100}\nt,seq\n0,0\n')
    with pytest.raises(
        RecordingError, match=r"imu\.csv, line 1: expected the header '# kfkit-vehicle v1 .*load_vehicle_csv"
    ):
        load_vehicle(imu)
    with pytest.raises(RecordingError, match=r"future\.csv, line 1: expected the header '# kfkit-recording v1"):
        load_recording(future)
