"""Finding boards (USB VID:PID) and opening a port, with errors that say what to do (:mod:`.errors`)."""

from __future__ import annotations

import errno
import importlib.util
import os
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass
from urllib.parse import urlsplit

from .errors import CaptureError, PortAddressError, PortBusyError, PortNotFoundError, PortPermissionError
from .phyphox_http import SCHEME, URL_FORM, PhyphoxPort, parse_url

SKETCHES = "firmware/nucleo_iks02a1_logger or firmware/mpu6050_logger"


@dataclass(frozen=True)
class NamedPort:
    """A port kfkit makes itself: ``make(**options)`` returns a board object the
    :class:`~kfkit.capture.Recorder` starts and reads (see :mod:`kfkit.capture.recorder`)."""

    description: str
    make: Callable


def _virtual_board(**options):
    from .virtual import VirtualBoard

    return VirtualBoard(**options)


def _emulated_uno(**options):
    from .emulated_uno import EmulatedUno

    return EmulatedUno(**options)


#: Ports by name, each a board kfkit simulates or emulates: the one place to add one. :func:`check_port` accepts
#: these names and the Recorder makes ``NAMED_PORTS[name].make(**virtual)`` (its ``virtual`` options) for them.
NAMED_PORTS = {
    "virtual": NamedPort("the virtual board: the IMU simulator on a pseudo-terminal", _virtual_board),
    "emulated-uno": NamedPort("the Uno's real firmware on simavr with an emulated MPU6050", _emulated_uno),
}
AUTO = "auto"
_SCHEME = re.compile(r"[a-z][a-z0-9_]*")
_HOST_PORT_SCHEMES = ("socket", "rfc2217")  # pyserial's network ports: HOST:PORT


def port_forms() -> str:
    """The forms a port takes, for messages."""
    named = "; ".join(f"'{name}' ({p.description})" for name, p in NAMED_PORTS.items())
    return (
        f"'{AUTO}' (the one board plugged in); {named}; a device path (/dev/ttyACM0, /dev/ttyUSB0, COM3); "
        f"{URL_FORM} (a phone running phyphox); or a pyserial URL: socket://HOST:PORT, rfc2217://HOST:PORT, "
        f"hwgrep://VID:PID, loop://"
    )


def check_port(port) -> str:
    """``port`` if it has a form kfkit opens: 'auto', a name of :data:`NAMED_PORTS`, a device path,
    ``phyphox://HOST[:PORT]`` (:func:`~kfkit.capture.phyphox_http.parse_url`) or a URL whose scheme pyserial knows
    (``socket://`` and ``rfc2217://`` with HOST:PORT). Otherwise :class:`PortAddressError` naming the port and listing
    the forms. Whether a device exists is for :func:`open_port` to find (:class:`PortNotFoundError`)."""

    def bad(why):
        return PortAddressError(f"port {port!r}: {why}. A port is {port_forms()}")

    if not isinstance(port, str) or not port.strip() or "\0" in port:
        raise bad("not a port name" if isinstance(port, str) else f"a port is text, not {type(port).__name__}")
    scheme, sep, rest = port.partition("://")
    if not sep or port == AUTO or port in NAMED_PORTS:
        return port
    if port.startswith(SCHEME):
        parse_url(port)  # its error names the address and gives a phone's form
        return port
    scheme = scheme.lower()
    if not _SCHEME.fullmatch(scheme) or not _pyserial_knows(scheme):
        raise bad(f"no port has the scheme {scheme + '://'!r}")
    if scheme in _HOST_PORT_SCHEMES:
        parts = urlsplit("x://" + rest)
        try:
            number = parts.port
        except ValueError:
            number = None
        if not parts.hostname or not number:
            raise bad(f"{scheme}:// needs HOST:PORT, the port a whole number 1 … 65535")
    return port


def _pyserial_knows(scheme: str) -> bool:
    """True if pyserial's ``serial_for_url`` has a handler for ``scheme://`` (how it finds one: a module
    ``protocol_<scheme>`` in one of ``serial.protocol_handler_packages``)."""
    import serial

    for package in serial.protocol_handler_packages:
        try:
            if importlib.util.find_spec(f"{package}.protocol_{scheme}") is not None:
                return True
        except ImportError:
            continue
    return False


#: USB VID:PID → (what it is, the kfkit board it most likely carries). ST-LINK product IDs as in
#: OpenOCD's and stlink's tables; Arduino's from its boards.txt; the rest are the USB-serial chips of clones.
KNOWN_USB_IDS = {
    (0x0483, 0x374B): ("ST-LINK/V2-1 (STM32 Nucleo-64 such as the Nucleo-F411RE)", "nucleo-iks02a1"),
    (0x0483, 0x3752): ("ST-LINK/V2-1 without mass storage (STM32 Nucleo-64)", "nucleo-iks02a1"),
    (0x0483, 0x374E): ("STLINK-V3E (on newer STM32 Nucleo boards)", "nucleo-iks02a1"),
    (0x0483, 0x374F): ("STLINK-V3SET probe (an STM32 board wired to it)", "nucleo-iks02a1"),
    (0x0483, 0x3753): ("STLINK-V3 with two virtual COM ports (STM32 Nucleo)", "nucleo-iks02a1"),
    (0x0483, 0x3754): ("STLINK-V3 without mass storage (STM32 Nucleo)", "nucleo-iks02a1"),
    (0x2341, 0x0043): ("Arduino Uno R3", "mpu6050"),
    (0x2341, 0x0001): ("Arduino Uno (first revision)", "mpu6050"),
    (0x2341, 0x0243): ("Genuino Uno", "mpu6050"),
    (0x2A03, 0x0043): ("Arduino Uno (arduino.org)", "mpu6050"),
    (0x1A86, 0x7523): ("CH340 USB-serial (Arduino Uno/Nano clone)", "mpu6050"),
    (0x1A86, 0x55D4): ("CH9102 USB-serial (Arduino clone)", "mpu6050"),
    (0x10C4, 0xEA60): ("CP210x USB-serial (Arduino clone or adapter)", "mpu6050"),
    (0x0403, 0x6001): ("FTDI FT232R (Arduino Nano, older Arduinos, adapters)", "mpu6050"),
    (0x0403, 0x6015): ("FTDI FT-X (Arduino clone or adapter)", "mpu6050"),
}


@dataclass(frozen=True)
class BoardPort:
    """A USB serial port: ``port`` (device path), ``vid_pid`` ("0483:374B"), what it is."""

    port: str
    vid_pid: str
    description: str
    guess: str  # what kfkit thinks it is, e.g. "ST-LINK/V2-1 (STM32 Nucleo-64, …)"
    board: str | None  # the kfkit board name it probably carries, None if unknown

    @property
    def known(self) -> bool:
        return self.board is not None

    def __str__(self):
        what = (
            f"{self.guess} → probably {self.board}" if self.known else f"unknown USB serial device ({self.description})"
        )
        return f"{self.port} [{self.vid_pid}] {what}"


def _comports():
    from serial.tools import list_ports

    return list_ports.comports()


def find_boards() -> list[BoardPort]:
    """USB serial ports, known boards first. Built-in UARTs (no USB VID:PID, e.g. /dev/ttyS0) are left out."""
    found = []
    for p in _comports():
        if p.vid is None or p.pid is None:
            continue
        guess, name = KNOWN_USB_IDS.get((p.vid, p.pid), ("", None))
        found.append(BoardPort(p.device, f"{p.vid:04X}:{p.pid:04X}", p.description or "", guess, name))
    return sorted(found, key=lambda b: (not b.known, b.port))


def _list_text(boards) -> str:
    if not boards:
        return "no USB serial ports are connected"
    return "ports found: " + "; ".join(str(b) for b in boards)


def resolve_auto() -> tuple[BoardPort, str]:
    """The port ``port="auto"`` means, and why; raises :class:`PortNotFoundError` explaining otherwise."""
    boards = find_boards()
    known = [b for b in boards if b.known]
    if len(known) == 1:
        return known[0], f"auto: the only known board is {known[0]}"
    if len(known) > 1:
        raise PortNotFoundError(f"port='auto' found {len(known)} boards; pass one of them as port: {_list_text(known)}")
    if len(boards) == 1:
        return boards[0], f"auto: no known board, using the only USB serial port {boards[0]}"
    raise PortNotFoundError(
        f"port='auto' found no board ({_list_text(boards)}). Plug the board in with a data "
        "USB cable, or use port='virtual' to practise with the virtual board"
    )


def open_port(port: str, baud: int = 115200, timeout: float = 0.05):
    """Open a device path or a pyserial URL (``loop://``, ``socket://host:port``, ``hwgrep://VID:PID``).

    Device paths are opened exclusively (a second capture of the same port fails as busy).
    Raises :class:`PortNotFoundError` (listing the ports that exist), :class:`PortBusyError`,
    :class:`PortPermissionError` (naming the group to join) or :class:`CaptureError`.
    ``phyphox://HOST:PORT`` opens a phone running phyphox (:class:`kfkit.capture.phyphox_http.PhyphoxPort`).
    A port of no form kfkit opens raises :class:`PortAddressError` (:func:`check_port`).
    """
    check_port(port)
    if port.startswith(SCHEME):
        return PhyphoxPort(port, read_timeout=timeout)
    import serial

    is_url = "://" in port
    try:
        return serial.serial_for_url(port, baudrate=baud, timeout=timeout, exclusive=None if is_url else True)
    except serial.SerialException as e:
        code, text = e.errno, str(e)
        windows = sys.platform == "win32"  # pyserial's Windows errors carry no errno, only the WinError text
        if code == errno.ENOENT or (is_url and "no ports found" in text) or (windows and "FileNotFoundError" in text):
            forms = "" if _looks_like_a_device(port) else f". A port is {port_forms()}"
            raise PortNotFoundError(f"port {port} not found; {_list_text(find_boards())}{forms}") from None
        if code in (errno.EBUSY, errno.EAGAIN) or (windows and "PermissionError" in text):
            raise PortBusyError(
                f"port {port} is busy: another program has it open (a serial monitor, the Arduino "
                "IDE, another notebook or kfkit capture?); close it and try again"
            ) from None
        if code == errno.EACCES:
            raise PortPermissionError(f"permission denied opening {port}{_permission_hint(port)}") from None
        raise CaptureError(f"cannot open {port}: {e}") from None


def _looks_like_a_device(port: str) -> bool:
    return "/" in port or "\\" in port or re.fullmatch(r"COM[0-9]+", port, re.IGNORECASE) is not None


def _permission_hint(port: str) -> str:
    """Linux: the group that owns ``port`` (dialout on most distributions, uucp on Arch) and how to join it."""
    if not sys.platform.startswith("linux"):
        return ""
    import grp

    try:
        gid = os.stat(port).st_gid
        group = grp.getgrgid(gid).gr_name
    except (OSError, KeyError):
        gid, group = None, "dialout"
    if gid is not None and gid in os.getgroups():
        return (
            f"; you are in its group '{group}', so check its mode with `ls -l {port}` (or log out and in "
            "again if you joined the group recently)"
        )
    return (
        f"; serial ports belong to the group '{group}' and you are not in it: "
        f"sudo usermod -aG {group} $USER   (then log out and in again)"
    )
