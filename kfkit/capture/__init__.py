"""Serial capture: protocol v1, board discovery, the recorder, and a virtual board.

- :mod:`.protocol`  ``parse_line`` and the line encoders (protocol v1, DESIGN.md)
- :mod:`.ports`     ``find_boards`` (USB VID:PID), ``open_port`` and the capture errors
- :mod:`.virtual`   ``VirtualBoard``: the IMU simulator streaming to a pseudo-terminal
- :mod:`.recorder`  ``Recorder`` (reader thread, statistics, streamed file) and ``capture``
- :mod:`.guided`    guided protocols (stationary, six faces, tilt, magnetometer rotations, axis turns, headings)
"""
from .guided import PROTOCOLS, dataset_name, protocol_motion, protocol_steps, record_protocol, sphere_coverage
from .ports import (KNOWN_USB_IDS, BoardDisconnectedError, BoardPort, CaptureError, NoDataError, PortBusyError,
                    PortNotFoundError, PortPermissionError, ProtocolVersionError, WrongBaudError, find_boards,
                    open_port, resolve_auto)
from .protocol import (BadLine, Header, Message, Note, Sample, board_time, checksum, encode_header, encode_message,
                       encode_sample, parse_line)
from .recorder import DEFAULT_BAUD, CaptureStats, Recorder, capture, header_metadata
from .virtual import FAULT_KINDS, VirtualBoard

__all__ = [
    "PROTOCOLS", "dataset_name", "protocol_motion", "protocol_steps", "record_protocol", "sphere_coverage",
    "KNOWN_USB_IDS", "BoardDisconnectedError", "BoardPort", "CaptureError", "NoDataError", "PortBusyError",
    "PortNotFoundError", "PortPermissionError", "ProtocolVersionError", "WrongBaudError", "find_boards",
    "open_port", "resolve_auto",
    "BadLine", "Header", "Message", "Note", "Sample", "board_time", "checksum", "encode_header", "encode_message",
    "encode_sample", "parse_line",
    "DEFAULT_BAUD", "CaptureStats", "Recorder", "capture", "header_metadata",
    "FAULT_KINDS", "VirtualBoard",
]
