"""The ``kfkit`` command (also ``python -m kfkit``).

    kfkit make-labs [--check]          solutions/ → labs/ (instructors)
    kfkit data regenerate [--check]    rebuild data/ from seeded simulations
    kfkit doctor                       check this environment and say what to fix
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .datasets import KIT_ROOT


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


def _doctor(args) -> int:
    from .doctor import doctor_report

    text, ok = doctor_report()
    print(text)
    return 0 if ok else 1


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

    p = sub.add_parser("doctor", help="check versions, Jupyter extensions, serial ports and data")
    p.set_defaults(run=_doctor)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
