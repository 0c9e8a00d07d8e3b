"""Capture: a board on a serial port or a phone running phyphox, recorded into the kit's format.

- :mod:`.protocol`       ``parse_line`` and the line encoders (protocol v1, docs/design.md)
- :mod:`.errors`         the capture errors (``CaptureError`` and its family, a phone's ``PhoneError`` ones)
- :mod:`.ports`          ``find_boards`` (USB VID:PID), ``check_port`` (the forms a port takes, ``NAMED_PORTS``) and
                         ``open_port`` (a serial port, or ``phyphox://``)
- :mod:`.phyphox_http`   ``PhyphoxPort``: a phone's phyphox remote interface (REST), read like a port
- :mod:`.timeline`       the board-time unwrap and drop bookkeeping of a stream
- :mod:`.recorder`       ``Recorder`` (reader thread, statistics, streamed file) and ``capture``
- :mod:`.virtual`        ``VirtualBoard``: the IMU simulator streaming to a pseudo-terminal
- :mod:`.emulated_uno`   ``EmulatedUno``: the real Uno firmware on simavr with an emulated MPU6050, on a pseudo-terminal
- :mod:`.virtual_phone`  ``VirtualPhone``: the phone simulator behind phyphox's remote interface
- :mod:`.guided`         guided protocols (stationary, six faces, tilt, magnetometer rotations, axis turns, headings)

It builds on the sensors, simulators and filters below it, never on datasets, plots or widgets.
"""

from .errors import (
    BoardDisconnectedError,
    CaptureError,
    NoDataError,
    PortAddressError,
    PortBusyError,
    PortNotFoundError,
    PortPermissionError,
    ProtocolVersionError,
    WrongBaudError,
)
from .guided import PROTOCOLS, dataset_name, protocol_motion, protocol_steps, record_protocol, sphere_coverage
from .ports import KNOWN_USB_IDS, NAMED_PORTS, BoardPort, check_port, find_boards, open_port, resolve_auto
from .protocol import (
    BadLine,
    Header,
    Message,
    Note,
    Sample,
    board_time,
    checksum,
    encode_header,
    encode_message,
    encode_sample,
    parse_line,
)
from .recorder import DEFAULT_BAUD, CaptureStats, Recorder, capture, header_metadata
from .virtual import FAULT_KINDS, VirtualBoard

__all__ = [
    "PROTOCOLS",
    "dataset_name",
    "protocol_motion",
    "protocol_steps",
    "record_protocol",
    "sphere_coverage",
    "KNOWN_USB_IDS",
    "NAMED_PORTS",
    "BoardDisconnectedError",
    "BoardPort",
    "CaptureError",
    "NoDataError",
    "PortAddressError",
    "PortBusyError",
    "PortNotFoundError",
    "PortPermissionError",
    "ProtocolVersionError",
    "WrongBaudError",
    "check_port",
    "find_boards",
    "open_port",
    "resolve_auto",
    "BadLine",
    "Header",
    "Message",
    "Note",
    "Sample",
    "board_time",
    "checksum",
    "encode_header",
    "encode_message",
    "encode_sample",
    "parse_line",
    "DEFAULT_BAUD",
    "CaptureStats",
    "Recorder",
    "capture",
    "header_metadata",
    "FAULT_KINDS",
    "VirtualBoard",
]
