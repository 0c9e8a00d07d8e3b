"""The ``kfkit`` command (also ``python -m kfkit``).

kfkit make-labs [--check]          solutions/ → labs/ (instructors)
kfkit data regenerate [--check]    rebuild data/ from seeded simulations
kfkit data real [--check] [--source DIR]   convert the real excerpts (BROAD, race track) from their originals
kfkit doctor                       check this environment and say what to fix
kfkit boards                       list the boards plugged in over USB
kfkit capture --port P --seconds S --out FILE   record from a board (or --port virtual, emulated-uno, phyphox://HOST:PORT)
kfkit demo tilt --port P|virtual   steer a car by tilting the board (mpu6050_tilt_kf's $ATT lines)
kfkit grade --lab NN --out gradebook.csv SUBMISSION…   grade notebooks in isolated kernels
kfkit report gradebook.csv         the class report: one self-contained HTML page
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .cli_options import number
from .paths import KIT_ROOT

SECONDS = number(float, 0.0, unit="s")
MAX_BAUD = 12_000_000  # the fastest USB-serial bridges (FTDI FT232H: 12 Mbaud)
BAUD = number(int, 0, MAX_BAUD)


def _make_labs(args) -> int:
    from .authoring import make_labs

    report = make_labs(args.solutions, args.labs, check=args.check)
    if args.check:
        for line in report:
            print(line)
        print("labs/ is up to date" if not report else f"{len(report)} problem(s): run 'kfkit make-labs'")
        return 1 if report else 0
    for line in report:
        print(f"updated {line}")
    print(f"{len(report)} lab notebook(s) written or removed" if report else "labs/ was already up to date")
    return 0


def _data(args) -> int:
    from .datasets import regenerate

    report = regenerate(check=args.check)
    if args.check:
        for line in report:
            print(line)
        print("data/ matches its simulations" if not report else "data/ is stale: run 'kfkit data regenerate'")
        return 1 if report else 0
    for line in report:
        print(f"wrote {line}")
    return 0


def _data_real(args) -> int:
    from .datasets import convert_real

    report, skipped = convert_real(check=args.check, source=args.source)
    for line in skipped:
        print(f"skipped {line}")
    if args.check:
        for line in report:
            print(line)
        if skipped and not report:
            print("the real files found match their originals; the others could not be checked")
        else:
            print("data/'s real files match their originals" if not report else "data/ is stale: run 'kfkit data real'")
        return 1 if report else 0
    for line in report:
        print(f"wrote {line}")
    return 0


def _doctor(args) -> int:
    from .doctor import doctor_report

    text, ok = doctor_report()
    print(text)
    return 0 if ok else 1


def _boards(args) -> int:
    from .capture import find_boards

    boards = find_boards()
    for b in boards:
        print(b)
    if not boards:
        print("no USB serial boards found; `kfkit capture --port virtual` records from the virtual board")
    return 0


DEFAULT_SECONDS = 10.0  # kfkit capture without --seconds (and without a protocol, which has its own length)


class UnexpectedError(Exception):
    """A bug met while capturing, reported like any failure (one line, or one JSON object), not as a traceback."""

    def __init__(self, cause: BaseException):
        super().__init__(
            f"an unexpected error ({type(cause).__name__}: {cause}); please report it with the command you ran"
        )


def _capture(args) -> int:
    """``kfkit capture``: every ending, a bad option, a port that does not open, a failure mid-capture, Ctrl-C or a
    bug, is answered by :func:`_capture_report` (one JSON object with ``--json``) with a non-zero exit code."""
    state = {"rec": None, "started": []}  # the recorder once made; the progress line once begun
    try:
        return _record(args, state)
    except KeyboardInterrupt:  # the recorder, if any, has closed the port and written the file by now
        return _capture_report(args, state["rec"], KeyboardInterrupt("stopped by Ctrl-C"), 130, newline=True)
    except Exception as e:  # noqa: BLE001 — one answer whatever happened
        return _capture_report(args, state["rec"], UnexpectedError(e), 1, newline=bool(state["started"]))


def _check_capture_options(args):
    """Options that only mean something together: ValueError naming the option that does not apply."""
    virtual = args.port == "virtual"
    if args.rate is not None and (not virtual or args.protocol):
        raise ValueError(
            f"--rate sets the rate of the virtual board in a free recording (--port virtual, no "
            f"--protocol); got --port {args.port}{' --protocol ' + args.protocol if args.protocol else ''}: "
            f"a board samples at its sketch's rate, a protocol at the board's"
        )
    if args.fast and args.port not in ("virtual", "emulated-uno"):
        raise ValueError(
            f"--fast is for --port virtual or emulated-uno (a board sends in real time), got --port {args.port}"
        )
    if args.board and not (virtual or args.protocol):
        raise ValueError(
            f"--board chooses the virtual board (--port virtual) or the board a --protocol is recorded "
            f"with; got --port {args.port} without --protocol"
        )
    if args.quick and not args.protocol:
        raise ValueError("--quick shortens a --protocol; without one, give --seconds")
    if args.out.is_dir():
        raise ValueError(f"--out {args.out} is a folder: give a file name, e.g. {args.out / 'capture.csv'}")


def _record(args, state) -> int:
    from .capture import CaptureError, Recorder
    from .capture.guided import protocol_capture_options, step_at

    options, steps = {}, None
    seconds = args.seconds
    try:
        _check_capture_options(args)
        if args.protocol:
            length, steps, options = protocol_capture_options(
                args.protocol, args.port, args.board, quick=args.quick, fast=args.fast
            )
            seconds = length if seconds is None else seconds
        elif args.port == "virtual":
            options["virtual"] = {
                "board": args.board or "nucleo-iks02a1",
                "rate_hz": args.rate,
                "realtime": not args.fast,
            }
        elif args.port == "emulated-uno":
            options["virtual"] = {"realtime": not args.fast}
    except ValueError as e:
        return _capture_report(args, None, e, 2)
    seconds = DEFAULT_SECONDS if seconds is None else seconds
    started = state["started"]

    def progress(fraction, rec):
        if args.json:
            return
        if not started:
            started.append(True)
            print(
                f"recording {seconds:g} s from {rec.description} (Ctrl-C stops early and keeps what arrived)",
                file=sys.stderr,
            )
        step = step_at(steps, rec.elapsed) if steps and args.port != "virtual" else None
        if step is not None and step is not started[-1]:  # a guided protocol's next instruction, on its own line
            started.append(step)
            print(f"\r{'':100}\r{step[0]:6.1f} s  ▶ {step[3]}", file=sys.stderr)
        s = rec.stats
        bar = "#" * int(30 * fraction)
        print(
            f"\r[{bar:<30}] {rec.elapsed:6.1f}/{seconds:.1f} s  samples {s.samples}  bad {s.bad_lines}  "
            f"dropped {s.dropped}",
            end="",
            file=sys.stderr,
            flush=True,
        )

    rec = state["rec"] = Recorder(args.port, args.baud, args.out, seconds=seconds, **options)
    try:
        rec.run(progress)
    except CaptureError as e:
        return _capture_report(args, rec, e, 2, newline=bool(started))
    return _capture_report(args, rec, None, 0, newline=bool(started))


def _capture_fields(rec, port, error) -> dict:
    """The JSON object ``kfkit capture --json`` prints: the statistics (:meth:`CaptureStats.as_dict`), ``out`` (the
    file, null if nothing was saved), ``port``, ``board`` (from the header, null if none came), ``clock_rate_hz`` (the
    file's ``rate_hz``: the board clock's, :meth:`Recorder.clock_rate_hz`) and ``error`` (null, or the message;
    ``error_type`` its class). Without a recorder (an option refused at the door) the statistics are zeros."""
    from .capture import CaptureStats

    stats = rec.stats if rec is not None else CaptureStats()
    saved = rec is not None and stats.samples > 0 and rec.out is not None and rec.out.exists()
    clock = rec.clock_rate_hz() if rec is not None else float("nan")
    return {
        **stats.as_dict(),
        "out": str(rec.out) if saved else None,
        "port": str(rec.device) if rec is not None else port,
        "board": rec.header.board if rec is not None and rec.header else None,
        "clock_rate_hz": clock if clock > 0 else None,
        "error": None if error is None else str(error),
        "error_type": None if error is None else type(error).__name__,
    }


def _capture_report(args, rec, error, code, newline=False) -> int:
    """What a capture ends with, success or not: one JSON object (--json, :func:`_capture_fields`) or the
    statistics and where the data is; returns ``code``."""
    fields = _capture_fields(rec, args.port, error)
    if args.json:
        print(json.dumps(fields))
        return code
    saved = fields["out"] is not None
    if newline:
        print(file=sys.stderr)  # end the progress line
    if code == 130:
        print(
            f"stopped: what arrived is saved in {args.out}" if saved else "stopped before any sample arrived",
            file=sys.stderr,
        )
    elif error is not None:
        print(f"capture failed: {error}", file=sys.stderr)
    if rec is not None and rec.opened:
        print(rec.stats)
    print(
        f"saved {fields['samples']} samples to {args.out}"
        if saved
        else f"nothing saved: no samples arrived, {args.out} was not written"
    )
    return code


def _demo(args) -> int:
    from .capture import CaptureError
    from .demo import DemoError, run_tilt_demo

    port = args.port
    try:
        if port == "auto":
            from .capture import resolve_auto

            board, why = resolve_auto()
            port = board.port
            print(why, file=sys.stderr)
        if args.fast and port != "virtual":
            raise ValueError(f"--fast is for --port virtual (a board sends in real time), got --port {port}")
        if port.startswith("phyphox://"):
            raise ValueError(
                f"the tilt demo steers with a board's $ATT lines (firmware/mpu6050_tilt_kf); a phone "
                f"sends none: --port {port}"
            )
        run_tilt_demo(port, seconds=args.seconds, headless=args.headless, baud=args.baud, fast=args.fast)
    except (CaptureError, DemoError, ValueError, OSError) as e:
        print(f"demo failed: {e}", file=sys.stderr)
        return 2
    return 0


class UsageError(Exception):
    """A command line the parser refused; ``parser`` is the (sub)command whose usage to show."""

    def __init__(self, parser: argparse.ArgumentParser, message: str):
        super().__init__(message)
        self.parser = parser


class _Parser(argparse.ArgumentParser):
    """argparse raising :class:`UsageError` instead of exiting, so that ``--json`` answers in JSON (subcommands'
    parsers are of this class too: argparse makes them with the parent's)."""

    def error(self, message):
        raise UsageError(self, message)


def _port(text: str) -> str:
    """The ``--port`` type: a port of a form kfkit opens (:func:`kfkit.capture.ports.check_port`)."""
    from .capture.errors import PortAddressError
    from .capture.ports import check_port

    try:
        return check_port(text)
    except PortAddressError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _virtual_rate(text: str) -> float:
    """The ``--rate`` type: 0 < Hz ≤ the virtual board's :data:`~kfkit.capture.virtual.MAX_RATE_HZ`."""
    from .capture.virtual import MAX_RATE_HZ

    return number(float, 0.0, MAX_RATE_HZ, unit="Hz")(text)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="kfkit", description="Kalman filter lab kit tools.")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("make-labs", help="generate labs/ from solutions/ (strip solutions and outputs)")
    p.add_argument("--check", action="store_true", help="write nothing; fail if labs/ is stale")
    p.add_argument("--solutions", type=Path, default=KIT_ROOT / "solutions", help="default: %(default)s")
    p.add_argument("--labs", type=Path, default=KIT_ROOT / "labs", help="default: %(default)s")
    p.set_defaults(run=_make_labs)

    p = sub.add_parser("data", help="bundled recordings")
    data_sub = p.add_subparsers(dest="data_command", required=True)
    p = data_sub.add_parser("regenerate", help="rebuild data/ from seeded simulations")
    p.add_argument("--check", action="store_true", help="write nothing; fail if a shipped file differs")
    p.set_defaults(run=_data)
    p = data_sub.add_parser("real", help="convert data/'s real excerpts (BROAD, race track) from their originals")
    p.add_argument("--check", action="store_true", help="write nothing; fail if a shipped file differs")
    p.add_argument(
        "--source",
        type=Path,
        default=None,
        help="folder holding broad/ and racetrack/ (default: $KFKIT_SHARED_DATA or ../shared/data beside the kit)",
    )
    p.set_defaults(run=_data_real)

    p = sub.add_parser("doctor", help="check versions, Jupyter extensions, serial ports and data")
    p.set_defaults(run=_doctor)

    p = sub.add_parser("boards", help="list boards plugged in over USB (VID:PID) and what they probably are")
    p.set_defaults(run=_boards)

    p = sub.add_parser("capture", help="record from a board (protocol v1) into a recording file")
    p.add_argument(
        "--port",
        type=_port,
        default="auto",
        help="device path, pyserial URL (loop://, socket://, "
        "hwgrep://), 'auto', 'virtual', 'emulated-uno' (the Uno firmware on simavr), or phyphox://HOST:PORT "
        "for a phone running phyphox with remote access "
        "(default: %(default)s)",
    )
    p.add_argument(
        "--seconds",
        type=SECONDS,
        default=None,
        help=f"board time to record, s (default: {DEFAULT_SECONDS:g}, or the protocol's length)",
    )
    p.add_argument("--out", type=Path, required=True, help="recording file to write (CSV, kit format)")
    p.add_argument("--baud", type=BAUD, default=115200, help="default: %(default)s")
    p.add_argument("--json", action="store_true", help="print the statistics as one JSON object, no progress bar")
    p.add_argument(
        "--protocol",
        choices=["stationary", "six-faces", "tilt", "mag-rotations", "axis-turns", "headings"],
        help="guided protocol: prompts, phase labels; with --port virtual the board plays it",
    )
    p.add_argument("--quick", action="store_true", help="short protocol durations (tests, demonstrations)")
    p.add_argument("--board", choices=["nucleo-iks02a1", "mpu6050"], help="virtual board type")
    p.add_argument("--fast", action="store_true", help="the virtual board (or emulated Uno) runs faster than real time")
    p.add_argument(
        "--rate", type=_virtual_rate, default=None, help="virtual board rate, Hz (free recording; default: the board's)"
    )
    p.set_defaults(run=_capture)

    p = sub.add_parser("demo", help="small demos to drive with a board")
    demo_sub = p.add_subparsers(dest="demo", required=True)
    p = demo_sub.add_parser("tilt", help="steer a car by tilting the board (firmware/mpu6050_tilt_kf, $ATT lines)")
    p.add_argument(
        "--port",
        type=_port,
        default="auto",
        help="device path, pyserial URL, 'auto' or 'virtual' (default: %(default)s)",
    )
    p.add_argument("--baud", type=BAUD, default=115200, help="default: %(default)s")
    p.add_argument(
        "--seconds", type=SECONDS, default=None, help="stop after this long, s (default: when the window closes)"
    )
    p.add_argument(
        "--headless", action="store_true", help="no window: play --seconds of board time and print a summary"
    )
    p.add_argument("--fast", action="store_true", help="the virtual board runs faster than real time (with --headless)")
    p.set_defaults(run=_demo)

    from .grading import add_parser as add_grade_parser
    from .grading import add_report_parser

    add_grade_parser(sub)
    add_report_parser(sub)
    return parser


def _wants_json(argv) -> bool:
    """``--json`` (or an abbreviation argparse would take for it) among the options."""
    options = argv[: argv.index("--")] if "--" in argv else argv
    return any(len(a) > 2 and "--json".startswith(a) for a in options)


def main(argv=None) -> int:
    """Run the command ``argv`` (default: the process's); returns its exit code. A command line the parser refuses
    exits 2 with argparse's usage and message, or with ``--json`` one JSON object whose ``error`` says why."""
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        args = build_parser().parse_args(argv)
    except UsageError as e:
        if _wants_json(argv):
            command = next((a for a in argv if not a.startswith("-")), None)
            fields = (
                _capture_fields(None, None, e)
                if command == "capture"
                else {"error": str(e), "error_type": "UsageError"}
            )
            print(json.dumps(fields))
        else:
            e.parser.print_usage(sys.stderr)
            print(f"{e.parser.prog}: error: {e}", file=sys.stderr)
        return 2
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
