"""Finding boards (USB VID:PID) and opening a port, with errors that say what to do."""
from __future__ import annotations

import errno
import sys
from dataclasses import dataclass

from ..doctor import needs_dialout

DIALOUT_FIX = "sudo usermod -aG dialout $USER   (then log out and in again)"
SKETCHES = "firmware/nucleo_iks02a1_logger or firmware/mpu6050_logger"


class CaptureError(RuntimeError):
    """A capture problem the user can fix; the message says what happened and what to do."""


class PortNotFoundError(CaptureError):
    pass


class PortBusyError(CaptureError):
    pass


class PortPermissionError(CaptureError):
    pass


class WrongBaudError(CaptureError):
    pass


class NoDataError(CaptureError):
    pass


class ProtocolVersionError(CaptureError):
    pass


class BoardDisconnectedError(CaptureError):
    pass


#: USB VID:PID → (what it is, the kfkit board it most likely carries)
KNOWN_USB_IDS = {
    (0x0483, 0x374B): ("ST-LINK/V2-1 (STM32 Nucleo-64, e.g. Nucleo-F411RE)", "nucleo-iks02a1"),
    (0x0483, 0x3752): ("ST-LINK/V2-1 without mass storage (STM32 Nucleo)", "nucleo-iks02a1"),
    (0x0483, 0x374E): ("ST-LINK/V3 (STM32 Nucleo)", "nucleo-iks02a1"),
    (0x0483, 0x374F): ("ST-LINK/V3 (STM32 Nucleo)", "nucleo-iks02a1"),
    (0x0483, 0x3753): ("ST-LINK/V3 dual VCP (STM32 Nucleo)", "nucleo-iks02a1"),
    (0x0483, 0x3754): ("ST-LINK/V3 without mass storage (STM32 Nucleo)", "nucleo-iks02a1"),
    (0x2341, 0x0043): ("Arduino Uno R3", "mpu6050"),
    (0x2341, 0x0001): ("Arduino Uno", "mpu6050"),
    (0x2341, 0x0243): ("Genuino Uno", "mpu6050"),
    (0x2A03, 0x0043): ("Arduino Uno (arduino.org)", "mpu6050"),
    (0x1A86, 0x7523): ("CH340 USB-serial (Arduino Uno/Nano clone)", "mpu6050"),
    (0x1A86, 0x55D4): ("CH9102 USB-serial (Arduino clone)", "mpu6050"),
    (0x10C4, 0xEA60): ("CP210x USB-serial (Arduino clone or adapter)", "mpu6050"),
    (0x0403, 0x6001): ("FTDI FT232R (Arduino Nano / adapter)", "mpu6050"),
    (0x0403, 0x6015): ("FTDI FT-X (Arduino clone / adapter)", "mpu6050"),
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
        what = f"{self.guess} → probably {self.board}" if self.known else f"unknown USB serial device ({self.description})"
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
    raise PortNotFoundError(f"port='auto' found no board ({_list_text(boards)}). Plug the board in with a data "
                            "USB cable, or use port='virtual' to practise with the virtual board")


def open_port(port: str, baud: int = 115200, timeout: float = 0.05):
    """Open a device path or a pyserial URL (``loop://``, ``socket://host:port``, ``hwgrep://VID:PID``)."""
    import serial

    is_url = "://" in port
    try:
        return serial.serial_for_url(port, baudrate=baud, timeout=timeout, exclusive=None if is_url else True)
    except serial.SerialException as e:
        code = e.errno
        if code == errno.ENOENT or (is_url and "no ports found" in str(e)):
            raise PortNotFoundError(f"port {port} not found; {_list_text(find_boards())}") from None
        if code in (errno.EBUSY, errno.EAGAIN):
            raise PortBusyError(f"port {port} is busy: another program has it open (a serial monitor, "
                                "another notebook or kfkit capture?); close it and try again") from None
        if code == errno.EACCES:
            fix = ""
            if needs_dialout():
                fix = f"; you are not in the 'dialout' group that owns serial ports: {DIALOUT_FIX}"
            elif sys.platform.startswith("linux"):
                fix = f"; check the port's group with `ls -l {port}` and that you are in it (usually: {DIALOUT_FIX})"
            raise PortPermissionError(f"permission denied opening {port}{fix}") from None
        raise CaptureError(f"cannot open {port}: {e}") from None
