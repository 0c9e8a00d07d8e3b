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
import sys
from pathlib import Path

from .paths import KIT_ROOT


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


def _capture(args) -> int:
    from .capture import CaptureError, Recorder
    from .capture.guided import protocol_capture_options, step_at

    options, steps = {}, None
    seconds = args.seconds
    try:
        if args.protocol:
            length, steps, options = protocol_capture_options(args.protocol, args.port, args.board, quick=args.quick,
                                                              fast=args.fast)
            seconds = seconds or length
        elif args.port == "virtual":
            options["virtual"] = {"board": args.board or "nucleo-iks02a1", "rate_hz": args.rate, "realtime": not args.fast}
        elif args.port == "emulated-uno":
            options["virtual"] = {"realtime": not args.fast}
    except ValueError as e:
        return _capture_report(args, None, e, 2)
    seconds = seconds or 10.0
    started = []

    def progress(fraction, rec):
        if args.json:
            return
        if not started:
            started.append(True)
            print(f"recording {seconds:g} s from {rec.description} (Ctrl-C stops early and keeps what arrived)",
                  file=sys.stderr)
        step = step_at(steps, rec.elapsed) if steps and args.port != "virtual" else None
        if step is not None and step is not started[-1]:  # a guided protocol's next instruction, on its own line
            started.append(step)
            print(f"\r{'':100}\r{step[0]:6.1f} s  ▶ {step[3]}", file=sys.stderr)
        s = rec.stats
        bar = "#" * int(30 * fraction)
        print(f"\r[{bar:<30}] {rec.elapsed:6.1f}/{seconds:.1f} s  samples {s.samples}  bad {s.bad_lines}  "
              f"dropped {s.dropped}", end="", file=sys.stderr, flush=True)

    rec = Recorder(args.port, args.baud, args.out, seconds=seconds, **options)
    try:
        rec.run(progress)
    except CaptureError as e:
        return _capture_report(args, rec, e, 2, newline=bool(started))
    except KeyboardInterrupt:  # the recorder has closed the port and written the file by now
        return _capture_report(args, rec, "stopped by Ctrl-C", 130, newline=True)
    return _capture_report(args, rec, None, 0, newline=bool(started))


def _capture_report(args, rec, error, code, newline=False) -> int:
    """What a capture ends with, success or not: one JSON object (--json) or the statistics and where the data is.

    JSON: the statistics (:meth:`CaptureStats.as_dict`), ``out`` (the file, null if nothing was saved), ``port``,
    ``board`` (from the header, null if none came), ``clock_rate_hz`` (the file's ``rate_hz``: the board clock's,
    :meth:`Recorder.clock_rate_hz`) and ``error`` (null, or the message; ``error_type`` its class)."""
    import json

    from .capture import CaptureStats

    stats = rec.stats if rec is not None else CaptureStats()
    saved = rec is not None and stats.samples > 0 and rec.out is not None and rec.out.exists()
    clock = rec.clock_rate_hz() if rec is not None else float("nan")
    if args.json:
        print(json.dumps({**stats.as_dict(), "out": str(rec.out) if saved else None,
                          "port": str(rec.device) if rec is not None else args.port,
                          "board": rec.header.board if rec is not None and rec.header else None,
                          "clock_rate_hz": clock if clock > 0 else None,
                          "error": None if error is None else str(error),
                          "error_type": None if error is None else type(error).__name__}))
        return code
    if newline:
        print(file=sys.stderr)  # end the progress line
    if code == 130:
        print(f"stopped: what arrived is saved in {args.out}" if saved else "stopped before any sample arrived",
              file=sys.stderr)
    elif error is not None:
        print(f"capture failed: {error}", file=sys.stderr)
    if rec is not None and rec.opened:
        print(stats)
    print(f"saved {stats.samples} samples to {args.out}" if saved else f"nothing saved: no samples arrived, {args.out} "
          f"was not written")
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
        run_tilt_demo(port, seconds=args.seconds, headless=args.headless, baud=args.baud, fast=args.fast)
    except (CaptureError, DemoError, ValueError, OSError) as e:
        print(f"demo failed: {e}", file=sys.stderr)
        return 2
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="kfkit", description="Kalman filter lab kit tools.")
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
    p.add_argument("--source", type=Path, default=None,
                   help="folder holding broad/ and racetrack/ (default: $KFKIT_SHARED_DATA or ../shared/data beside the kit)")
    p.set_defaults(run=_data_real)

    p = sub.add_parser("doctor", help="check versions, Jupyter extensions, serial ports and data")
    p.set_defaults(run=_doctor)

    p = sub.add_parser("boards", help="list boards plugged in over USB (VID:PID) and what they probably are")
    p.set_defaults(run=_boards)

    p = sub.add_parser("capture", help="record from a board (protocol v1) into a recording file")
    p.add_argument("--port", default="auto", help="device path, pyserial URL (loop://, socket://, hwgrep://), "
                   "'auto', 'virtual', 'emulated-uno' (the Uno firmware on simavr), or phyphox://HOST:PORT for a phone "
                   "running phyphox with remote access "
                   "(default: %(default)s)")
    p.add_argument("--seconds", type=float, default=None, help="board time to record, s (default: 10, or the protocol's)")
    p.add_argument("--out", type=Path, required=True, help="recording file to write (CSV, kit format)")
    p.add_argument("--baud", type=int, default=115200, help="default: %(default)s")
    p.add_argument("--json", action="store_true", help="print the statistics as one JSON object, no progress bar")
    p.add_argument("--protocol", choices=["stationary", "six-faces", "tilt", "mag-rotations", "axis-turns", "headings"],
                   help="guided protocol: prompts, phase labels; with --port virtual the board plays it")
    p.add_argument("--quick", action="store_true", help="short protocol durations (tests, demonstrations)")
    p.add_argument("--board", choices=["nucleo-iks02a1", "mpu6050"], help="virtual board type")
    p.add_argument("--fast", action="store_true", help="the virtual board (or emulated Uno) runs faster than real time")
    p.add_argument("--rate", type=float, default=None, help="virtual board rate, Hz (free recording)")
    p.set_defaults(run=_capture)

    p = sub.add_parser("demo", help="small demos to drive with a board")
    demo_sub = p.add_subparsers(dest="demo", required=True)
    p = demo_sub.add_parser("tilt", help="steer a car by tilting the board (firmware/mpu6050_tilt_kf, $ATT lines)")
    p.add_argument("--port", default="auto", help="device path, pyserial URL, 'auto' or 'virtual' (default: %(default)s)")
    p.add_argument("--baud", type=int, default=115200, help="default: %(default)s")
    p.add_argument("--seconds", type=float, default=None, help="stop after this long (default: when the window closes)")
    p.add_argument("--headless", action="store_true", help="no window: play --seconds of board time and print a summary")
    p.add_argument("--fast", action="store_true", help="the virtual board runs faster than real time (with --headless)")
    p.set_defaults(run=_demo)

    from .grading import add_parser as add_grade_parser, add_report_parser

    add_grade_parser(sub)
    add_report_parser(sub)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
