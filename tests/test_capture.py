"""kfkit.capture without a pty: protocol v1 parsing, board discovery, opening errors, loop:// URLs."""

import errno
import json
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
import serial
import serial.tools.list_ports

import kfkit.capture as C
from kfkit.capture import ports as ports_module


def xor(text: bytes) -> int:
    """Independent NMEA checksum: XOR byte by byte."""
    x = 0
    for c in text:
        x ^= c
    return x


# -- protocol v1 ---------------------------------------------------------------------------------
def test_design_example_sample_parses():
    item = C.parse_line(b"$123456,42,-120,35,16390,12,-8,3*2D\r\n")
    assert isinstance(item, C.Sample)
    assert item.values == (123456, 42, -120, 35, 16390, 12, -8, 3)
    assert (item.t_us, item.seq) == (123456, 42)
    assert xor(b"123456,42,-120,35,16390,12,-8,3") == 0x2D


def test_design_example_header_parses():
    item = C.parse_line(
        b"#KFKIT,1,board=mpu6050,rate_hz=100,fields=t_us|seq|ax|ay|az|gx|gy|gz,accel_fs_g=2,gyro_fs_dps=250\n"
    )
    assert isinstance(item, C.Header)
    assert (item.version, item.board, item.rate_hz) == (1, "mpu6050", 100.0)
    assert item.fields == ("t_us", "seq", "ax", "ay", "az", "gx", "gy", "gz")
    assert item.params["gyro_fs_dps"] == "250"


@pytest.mark.parametrize(
    "line, kind",
    [
        (b"$123456,42,-120,35,16390,12,-8,3*2E", "checksum"),  # wrong checksum
        (b"$123456,42,-120,35,16390,12,-8,4*2D", "checksum"),  # a changed digit
        (b"$123456,42,-120,35,16390,12,-8,3", "malformed"),  # no *HH
        (b"$123456,42,-120,35,16390,12,-8,3*2", "malformed"),  # one hex digit
        (b"$123456,42,-120,35,16390,12,-8,3*ZZ", "malformed"),  # not hex
        (b"123456,42,-120,35*00", "malformed"),  # no $
        (b"\xff\xfe\x00garbage", "malformed"),  # binary noise
        (b"#KFKIT,2,board=x,rate_hz=1,fields=t_us|seq", "version"),  # another protocol version
        (b"#KFKIT,1,board=x,fields=t_us|seq", "malformed"),  # no rate_hz
        (b"#KFKIT,1,board=x,rate_hz=1,fields=seq|t_us", "malformed"),
        (b"#KFKIT,1,board=x,rate_hz=0,fields=t_us|seq", "malformed"),  # a rate the host cannot divide by
        (b"#KFKIT,1,board=x,rate_hz=nan,fields=t_us|seq", "malformed"),
        (b"   \r\n", "empty"),
    ],
)
def test_bad_lines_are_classified(line, kind):
    item = C.parse_line(line)
    assert isinstance(item, C.BadLine) and item.kind == kind, item


def test_non_integer_field_with_valid_checksum_is_malformed():
    body = b"1000,1,12.5,3"
    item = C.parse_line(b"$" + body + b"*%02X" % xor(body))
    assert isinstance(item, C.BadLine) and item.kind == "malformed" and "integer" in item.detail


def test_tagged_message_and_note():
    body = b"ATT,12.50,-3.25"
    item = C.parse_line(b"$" + body + b"*%02X\n" % xor(body))
    assert item == C.Message("ATT", (12.5, -3.25))
    assert C.parse_line(b"#ERROR,ISM330DHCX not found") == C.Note("ERROR,ISM330DHCX not found")


def test_encoders_round_trip_and_header_checksum_is_optional():
    rng = np.random.default_rng(1)
    for _ in range(200):  # the firmware's types: uint32 t_us, uint16 seq, int32 values
        values = (
            int(rng.integers(0, 2**32)),
            int(rng.integers(0, 2**16)),
            *(int(v) for v in rng.integers(-(2**31), 2**31, 9)),
        )
        line = C.encode_sample(values)
        assert line.endswith(b"\n") and int(line[-3:-1], 16) == xor(line[1:-4])
        assert C.parse_line(line).values == values
    header = C.encode_header("nucleo-iks02a1", 104, ("t_us", "seq", "ax"), accel_fs_g=4)
    assert header == b"#KFKIT,1,board=nucleo-iks02a1,rate_hz=104,fields=t_us|seq|ax,accel_fs_g=4\n"
    body = header[1:-1]
    assert isinstance(C.parse_line(b"#" + body + b"*%02X" % xor(body)), C.Header)
    assert C.parse_line(b"#" + body + b"*%02X" % (xor(body) ^ 1)).kind == "checksum"


# The protocol's integer range is the firmware's (kfkit_protocol.h): uint32 t_us, uint16 seq, int32 fields. Every
# value inside it is exact in float64; a value outside it (2^53 + 1 and 1e20 are not) must never reach a file.
IN_RANGE = [(0, 0, -(2**31), 2**31 - 1), (2**32 - 1, 2**16 - 1, 0), (7, 3)]
OUT_OF_RANGE = [
    (2**32, 0, 1),
    (-1, 0, 1),
    (0, 2**16, 1),
    (0, -1, 1),
    (0, 0, 2**31),
    (0, 0, -(2**31) - 1),
    (0, 0, 5, 2**53 + 1),
    (0, 0, 10**20),
    (0, 0, -(10**20)),
    (2**64 + 5, 1, 2),
]


@pytest.mark.parametrize("values", IN_RANGE)
def test_the_protocols_integer_range_is_accepted_exactly(values):
    item = C.parse_line(C.encode_sample(values))
    assert isinstance(item, C.Sample) and item.values == values
    assert [int(float(v)) for v in item.values] == list(values)  # exact in float64 too


@pytest.mark.parametrize("values", OUT_OF_RANGE)
def test_values_outside_the_protocols_range_are_malformed(values):
    item = C.parse_line(C.encode_sample(values))  # the checksum is right: only the range is wrong
    assert isinstance(item, C.BadLine) and item.kind == "malformed", item
    assert "range" in item.detail or "must be in" in item.detail


@pytest.mark.parametrize(
    "body",
    [
        b"1000,1,+5",
        b"1000,1, 5",
        b"1000,1,1_000",
        b"1000,1,--5",
        b"1000,1,-",
        b"1000,,5",
        b"1000,1,5 ",
        "1000,1,\u0663".encode(),
    ],
)
def test_integers_are_an_optional_minus_and_digits_only(body):
    """int() would take '+5', ' 5', '1_000' or an Arabic-Indic digit: the protocol does not."""
    item = C.parse_line(b"$" + body + b"*%02X" % xor(body))
    assert isinstance(item, C.BadLine) and item.kind == "malformed" and "integer" in item.detail, item


def test_every_single_byte_change_of_a_sample_is_rejected():
    line = C.encode_sample((4294960000, 65535, -32768, 32767, 0, 1, -1, 7)).rstrip(b"\n")
    for i in range(len(line)):
        for new in (ord("0"), ord("9"), ord(","), ord("-")):
            if new == line[i]:
                continue
            changed = line[:i] + bytes([new]) + line[i + 1 :]
            assert isinstance(C.parse_line(changed), C.BadLine), changed


# -- discovery ---------------------------------------------------------------------------------------
def port(device, vid=None, pid=None, description="n/a"):
    return SimpleNamespace(device=device, vid=vid, pid=pid, description=description)


@pytest.fixture
def comports(monkeypatch):
    def use(*ports):
        monkeypatch.setattr(serial.tools.list_ports, "comports", lambda include_links=False: list(ports))

    return use


def test_find_boards_names_known_ids_and_skips_builtin_uarts(comports):
    comports(
        port("/dev/ttyS0"),
        port("/dev/ttyUSB0", 0x1234, 0x5678, "Mystery"),
        port("/dev/ttyUSB1", 0x1A86, 0x7523, "USB Serial"),
        port("/dev/ttyACM0", 0x0483, 0x374B, "STM32 STLink"),
    )
    boards = C.find_boards()
    assert [b.port for b in boards] == ["/dev/ttyACM0", "/dev/ttyUSB1", "/dev/ttyUSB0"]
    assert [b.board for b in boards] == ["nucleo-iks02a1", "mpu6050", None]
    assert boards[0].vid_pid == "0483:374B" and "ST-LINK" in boards[0].guess
    assert "unknown USB serial device (Mystery)" in str(boards[2])


# the issue's table: ST-LINK (Nucleo), Arduino, and the USB-serial chips of clones, by what they are
ISSUE_IDS = {
    "0483:374B": "ST-LINK/V2-1",
    "0483:3752": "ST-LINK/V2-1",
    "0483:374E": "STLINK-V3",
    "0483:374F": "STLINK-V3",
    "0483:3753": "STLINK-V3",
    "0483:3754": "STLINK-V3",
    "2341:0043": "Arduino Uno",
    "2341:0001": "Arduino Uno",
    "2341:0243": "Genuino Uno",
    "2A03:0043": "Arduino Uno",
    "1A86:7523": "CH340",
    "1A86:55D4": "CH9102",
    "10C4:EA60": "CP210x",
    "0403:6001": "FTDI FT232R",
    "0403:6015": "FTDI FT-X",
}


@pytest.mark.parametrize("vid_pid", ISSUE_IDS)
def test_issue_vid_pid_table_is_recognised(comports, vid_pid):
    vid, pid = (int(x, 16) for x in vid_pid.split(":"))
    comports(port("/dev/ttyX", vid, pid))
    (b,) = C.find_boards()
    assert b.known and b.vid_pid == vid_pid and ISSUE_IDS[vid_pid] in b.guess
    assert b.board == ("nucleo-iks02a1" if vid == 0x0483 else "mpu6050")  # ST-LINK: a Nucleo; the rest: Arduinos
    assert str(b) == f"/dev/ttyX [{vid_pid}] {b.guess} → probably {b.board}"


def test_kfkit_boards_lists_what_it_finds(comports, capsys):
    from kfkit.cli import main

    comports(port("/dev/ttyACM0", 0x0483, 0x374B, "STM32 STLink"), port("/dev/ttyUSB0", 0x1234, 0x5678, "Mystery"))
    assert main(["boards"]) == 0
    assert capsys.readouterr().out.splitlines() == [
        "/dev/ttyACM0 [0483:374B] ST-LINK/V2-1 (STM32 Nucleo-64 such as the Nucleo-F411RE) → probably nucleo-iks02a1",
        "/dev/ttyUSB0 [1234:5678] unknown USB serial device (Mystery)",
    ]
    comports()
    assert main(["boards"]) == 0
    assert "no USB serial boards found" in capsys.readouterr().out


def test_auto_picks_the_single_board_or_explains(comports):
    comports(port("/dev/ttyS0"), port("/dev/ttyACM0", 0x0483, 0x374B))
    found, why = C.resolve_auto()
    assert found.port == "/dev/ttyACM0" and "only known board" in why
    comports(port("/dev/ttyACM0", 0x0483, 0x374B), port("/dev/ttyUSB0", 0x2341, 0x0043))
    with pytest.raises(C.PortNotFoundError, match="found 2 boards.*ttyACM0.*ttyUSB0"):
        C.resolve_auto()
    comports(port("/dev/ttyS0"))
    with pytest.raises(C.PortNotFoundError, match="no board.*port='virtual'"):
        C.resolve_auto()
    comports(port("/dev/ttyUSB3", 0x1234, 0x5678))
    assert C.resolve_auto()[0].port == "/dev/ttyUSB3"


# -- opening errors ----------------------------------------------------------------------------------------
def test_missing_port_lists_what_exists(comports):
    comports(port("/dev/ttyACM0", 0x0483, 0x374B, "STM32 STLink"))
    with pytest.raises(C.PortNotFoundError, match=r"/dev/ttyNOPE not found; ports found: /dev/ttyACM0 \[0483:374B\]"):
        C.Recorder("/dev/ttyNOPE").start()


def test_hwgrep_without_match_is_port_not_found(comports):
    comports()
    with pytest.raises(C.PortNotFoundError, match="hwgrep://FFFF:FFFF not found; no USB serial ports"):
        C.open_port("hwgrep://FFFF:FFFF")


@pytest.mark.parametrize(
    "code, error, words",
    [
        (errno.EACCES, C.PortPermissionError, "group 'dialout' and you are not in it: sudo usermod -aG dialout"),
        (errno.EBUSY, C.PortBusyError, "busy: another program"),
        (errno.EAGAIN, C.PortBusyError, "busy: another program"),  # pyserial's exclusive lock (flock) is taken
    ],
)
def test_open_errors_say_what_to_do(monkeypatch, code, error, words):
    def refuse(*args, **kwargs):
        raise serial.SerialException(code, f"could not open port /dev/ttyACM0: [Errno {code}]")

    monkeypatch.setattr(serial, "serial_for_url", refuse)
    monkeypatch.setattr(ports_module.sys, "platform", "linux")
    monkeypatch.setattr(ports_module.os, "getgroups", lambda: [])  # not in any group (the port is absent: dialout)
    with pytest.raises(error, match=words):
        C.open_port("/dev/ttyACM0")


@pytest.mark.parametrize(
    "text, error",
    [
        (
            "could not open port 'COM7': FileNotFoundError(2, 'The system cannot find the file specified.', None, 2)",
            C.PortNotFoundError,
        ),
        ("could not open port 'COM3': PermissionError(13, 'Access is denied.', None, 5)", C.PortBusyError),
    ],
)
def test_windows_open_errors(monkeypatch, comports, text, error):
    """pyserial on Windows gives no errno: 'Access is denied' is a port another program holds."""

    def refuse(*args, **kwargs):
        raise serial.SerialException(text)

    comports()
    monkeypatch.setattr(serial, "serial_for_url", refuse)
    monkeypatch.setattr(ports_module.sys, "platform", "win32")
    with pytest.raises(error):
        C.open_port("COM3")


# -- a pyserial URL: loop:// echoes what is written into it -------------------------------------------------
HEADER = C.encode_header(
    "mpu6050", 100, ("t_us", "seq", "ax", "ay", "az", "gx", "gy", "gz"), accel_fs_g=2, gyro_fs_dps=250
)


def loop_capture(payload: bytes, settle_s=0.05, **options):
    """Record ``payload`` through pyserial's loop:// URL; keep reading ``settle_s`` after it arrived (the reader
    parses every whole line of what it read before it looks at the clock again, so the counts are complete)."""
    rec = C.Recorder("loop://", **options).start()
    try:
        rec._serial.write(b"\n" + payload)  # the newline ends the echoed 'h' request
        deadline = time.monotonic() + 60  # a safety net only
        while rec.stats.bytes < len(payload) + 2 and not rec.done.is_set() and time.monotonic() < deadline:
            time.sleep(0.01)
        rec.done.wait(settle_s)
    finally:
        rec.stop(raise_error=False)
    return rec


def test_loop_url_records_counts_and_converts_to_si():
    lines = b"".join(C.encode_sample((10_000 * k + 7, k, 0, 0, 16384, 131, 0, -131)) for k in range(20))
    rec = loop_capture(HEADER + lines)
    assert rec.error is None and rec.stats.samples == 20 and rec.stats.bad_lines == 0
    r = rec.recording()
    np.testing.assert_allclose(r.t, np.arange(20) * 0.01)
    np.testing.assert_allclose(r.body("acc")[0], [0.0, 0.0, -9.80665])  # +1 g on z up → −g on z down
    np.testing.assert_allclose(r.body("gyr")[0], np.radians([1.0, 0.0, 1.0]))  # 131 LSB per °/s, y and z flipped
    assert r.meta["board"] == "mpu6050" and r.meta["protocol"]["header"] == HEADER.decode().strip()


def test_unknown_protocol_version_is_an_error():
    rec = loop_capture(b"#KFKIT,2,board=mpu6050,rate_hz=100,fields=t_us|seq\n")
    assert isinstance(rec.error, C.ProtocolVersionError)
    assert "unknown protocol" in str(rec.error) and "version 1" in str(rec.error)


def test_wrong_field_count_duplicate_time_and_samples_before_header():
    early = C.encode_sample((5, 0, 1, 2, 3, 4, 5, 6))
    good = [C.encode_sample((1000 * k, k, 1, 2, 3, 4, 5, 6)) for k in range(1, 5)]
    rec = loop_capture(early + HEADER + good[0] + C.encode_sample((2000, 2, 1, 2)) + good[1] + good[1] + good[2])
    s = rec.stats
    assert (s.before_header, s.samples, s.malformed, s.dropped) == (1, 3, 2, 0)


def test_samples_without_a_header_say_which_sketch():
    lines = b"".join(C.encode_sample((10_000 * k, k, 0, 0, 0, 0, 0, 0)) for k in range(20))
    rec = loop_capture(lines, settle_s=60.0, no_data_s=0.3)  # ends when the recorder gives up (after 0.3 s)
    assert isinstance(rec.error, C.CaptureError) and "no #KFKIT header" in str(rec.error)
    assert "firmware/nucleo_iks02a1_logger or firmware/mpu6050_logger" in str(rec.error)


def test_header_but_no_samples_says_the_board_is_stopped():
    rec = loop_capture(HEADER + b"#ERROR,MPU6050 read failed\n", settle_s=60.0, no_data_s=0.3)
    assert isinstance(rec.error, C.NoDataError)
    assert "header but no samples" in str(rec.error) and "the board said: ERROR,MPU6050 read failed" in str(rec.error)


def test_noise_without_newlines_is_counted_once_and_capture_goes_on():
    noise = bytes(np.random.default_rng(2).integers(0x20, 0x7F, 5000, dtype=np.uint8))  # no b"\n" in it
    good = b"".join(C.encode_sample((10_000 * k, k, 0, 0, 16384, 0, 0, 0)) for k in range(10))
    rec = loop_capture(HEADER + noise + b"\n" + good)
    s = rec.stats
    assert (s.samples, s.malformed, s.bad_checksum, s.dropped) == (10, 1, 0, 0)


def test_socket_url():
    import socket

    server = socket.create_server(("127.0.0.1", 0))
    host, port_number = server.getsockname()

    def serve():
        conn, _ = server.accept()
        with conn:
            conn.recv(1)  # the 'h' request
            conn.sendall(HEADER + b"".join(C.encode_sample((10_000 * k, k, 0, 0, 0, 0, 0, 0)) for k in range(20)))
            while conn.recv(4096):  # keep the connection until the recorder closes it (however slow it is)
                pass

    thread = threading.Thread(target=serve)
    thread.start()
    try:
        r = C.capture(f"socket://{host}:{port_number}", seconds=0.1)
    finally:
        thread.join()
        server.close()
    assert len(r) == 10 and r.meta["board"] == "mpu6050"


def test_stats_as_json():
    s = C.CaptureStats(samples=3, bad_checksum=1, malformed=2)
    d = json.loads(json.dumps(s.as_dict()))
    assert d["bad_lines"] == 3 and d["jitter_us"] is None


def test_board_time_reference_against_a_float_clock():
    rng = np.random.default_rng(5)
    true_t = np.cumsum(rng.uniform(0.009, 0.011, 500))  # s, a clock that never wraps
    start = 2**32 - 2_000_000  # 2 s before micros() wraps
    t_us = (start + np.round(true_t * 1e6).astype(np.int64)) % 2**32
    np.testing.assert_allclose(
        C.board_time(t_us), np.round(true_t * 1e6) / 1e6 - np.round(true_t[0] * 1e6) / 1e6, atol=1e-9
    )


# -- options checked where they are taken: the Recorder, the virtual board, a port's address ------------------------
@pytest.mark.parametrize(
    "options, words",
    [
        ({"seconds": float("nan")}, "seconds"),
        ({"seconds": -1.0}, "seconds"),
        ({"seconds": 0}, "seconds"),
        ({"seconds": float("inf")}, "seconds"),
        ({"baud": -5}, "baud"),
        ({"baud": 0}, "baud"),
        ({"baud": 115200.5}, "baud"),
        ({"no_data_s": float("nan")}, "no_data_s"),
        ({"flush_s": 0.0}, "flush_s"),
    ],
)
def test_the_recorder_refuses_options_it_cannot_honour(options, words):
    """A NaN duration used to record forever (no board time is ≥ NaN)."""
    with pytest.raises(ValueError, match=f"Recorder: {words} must be"):
        C.Recorder("loop://", **options)


@pytest.mark.parametrize("rate", [0, -100.0, float("nan"), float("inf"), 1e9, True])
def test_the_virtual_board_refuses_a_rate_it_cannot_play(rate):
    """Rate 0 used to fall back to the board's silently; −100 killed the board's thread with a traceback."""
    with pytest.raises(ValueError, match="VirtualBoard: rate_hz must be a number > 0 and ≤ 10000 Hz"):
        C.VirtualBoard(rate_hz=rate)


@pytest.mark.parametrize(
    "port, words",
    [
        ("bogus://x", "no port has the scheme 'bogus://'"),
        ("BOGUS://x", "no port has the scheme 'bogus://'"),
        ("a.b://x", "no port has the scheme 'a.b://'"),
        ("socket://localhost", "socket:// needs HOST:PORT"),
        ("socket://localhost:0", "socket:// needs HOST:PORT"),
        ("rfc2217://:4000", "rfc2217:// needs HOST:PORT"),
        ("", "not a port name"),
        ("  ", "not a port name"),
        ("/dev/tty\0", "not a port name"),
    ],
)
def test_a_port_of_no_known_form_names_it_and_lists_the_forms(port, words):
    for check in (ports_module.check_port, C.open_port):
        with pytest.raises(C.PortAddressError) as e:
            check(port)
        assert words in str(e.value) and repr(port) in str(e.value)
        for form in ("'auto'", "'virtual'", "/dev/ttyACM0", "phyphox://HOST[:PORT]", "socket://HOST:PORT", "loop://"):
            assert form in str(e.value)


@pytest.mark.parametrize(
    "url, words",
    [
        ("phyphox://", "no host"),
        ("phyphox://::::", "no host"),
        ("phyphox://:8080", "no host"),
        ("phyphox://phone:abc", "whole number 1 … 65535"),
        ("phyphox://phone:99999", "whole number 1 … 65535"),
        ("phyphox://phone:0", "whole number 1 … 65535"),
        ("phyphox://pho ne:80", "not a host name"),
        ("phyphox://phone/get", "nothing may follow the port"),
        ("phyphox://phone?poll=nan", "poll='nan'"),
        ("phyphox://phone?timeout=-3", "timeout='-3'"),
        ("phyphox://phone?poll=", "poll=''"),
        ("phyphox://phone?mount=sideways", "unknown phone mounting 'sideways'"),
        ("phyphox://phone?moutn=flat", "'moutn'"),
    ],
)
def test_a_bad_phone_address_says_what_is_wrong_and_the_form(url, words):
    with pytest.raises(C.PortAddressError) as e:
        ports_module.check_port(url)
    assert words in str(e.value) and repr(url) in str(e.value) and "phyphox://HOST[:PORT][?mount=NAME" in str(e.value)


def test_good_ports_pass_the_check_unchanged():
    from kfkit.capture.phyphox_http import parse_url

    for port in (
        "auto",
        "virtual",
        "/dev/ttyACM0",
        "COM3",
        "loop://",
        "socket://127.0.0.1:4000",
        "hwgrep://0483:374B",
        "rfc2217://host:2217",
        "phyphox://192.168.0.42:8080",
        "phyphox://[fe80::1]:80?mount=upright&poll=0.2",
    ):
        assert ports_module.check_port(port) == port
    assert parse_url("phyphox://[fe80::1]?mount=upright&poll=0.2&timeout=5") == (
        "fe80::1",
        8080,
        {"mount": "upright", "poll": 0.2, "timeout": 5.0},
    )


def test_a_name_that_is_no_device_path_lists_the_forms_when_not_found(comports):
    comports()
    with pytest.raises(
        C.PortNotFoundError, match="port virtaul not found; no USB serial ports are connected. A port is 'auto'"
    ):
        C.open_port("virtaul")
