"""The kfkit command: exit codes and messages of make-labs, data regenerate and doctor; options refused at the door."""

import json
import re
import subprocess
import sys
import threading

import nbformat
import pytest

from kfkit import datasets
from kfkit.cli import main
from kfkit.cli_options import number


def test_python_dash_m_kfkit_help():
    out = subprocess.run([sys.executable, "-m", "kfkit", "--help"], capture_output=True, text=True, check=True).stdout
    assert "make-labs" in out and "doctor" in out and "data" in out


def test_make_labs_then_check(tmp_path, capsys):
    sol, labs = tmp_path / "solutions", tmp_path / "labs"
    sol.mkdir()
    nb = nbformat.v4.new_notebook(
        cells=[nbformat.v4.new_code_cell("def f():\n    ### BEGIN SOLUTION\n    return 1\n    ### END SOLUTION")]
    )
    nbformat.write(nb, sol / "01_x.ipynb")
    assert main(["make-labs", "--check", "--solutions", str(sol), "--labs", str(labs)]) == 1
    assert "missing" in capsys.readouterr().out
    assert main(["make-labs", "--solutions", str(sol), "--labs", str(labs)]) == 0
    assert main(["make-labs", "--check", "--solutions", str(sol), "--labs", str(labs)]) == 0
    assert "raise NotImplementedError()" in (labs / "01_x.ipynb").read_text()


def test_data_check_reports_stale_file(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("KFKIT_DATA", str(tmp_path))
    monkeypatch.setattr(
        datasets, "BUNDLED", {"01_roll_sine": datasets.BUNDLED["01_roll_sine"]}
    )  # one file: the messages
    assert main(["data", "regenerate"]) == 0
    assert main(["data", "regenerate", "--check"]) == 0
    f = next(tmp_path.glob("*.csv"))
    f.write_text(f.read_text().replace("\n0.009615,1,", "\n0.009615,2,", 1))
    assert main(["data", "regenerate", "--check"]) == 1
    assert "line 4" in capsys.readouterr().out


def test_doctor_prints_a_report(capsys):
    code = main(["doctor"])
    out = capsys.readouterr().out
    assert code in (0, 1) and "numpy" in out and ("✅" in out or "❌" in out)


# --- kfkit capture always answers: options checked at the door, one JSON object with --json ---------------------


def run_main(capsys, argv):
    """``kfkit.cli.main(argv)`` on a thread, waited for by an event: (exit code, captured output). The wait's
    limit is a safety net (a capture that never ends fails here instead of hanging the suite); every case below
    ends at the door, long before it."""
    done, result = threading.Event(), {}

    def call():
        try:
            result["code"] = main(argv)
        except BaseException as e:  # noqa: BLE001 — reported by the assertion below
            result["escaped"] = e
        finally:
            done.set()

    threading.Thread(target=call, daemon=True).start()
    assert done.wait(120), f"kfkit {' '.join(argv)} did not return"
    assert "escaped" not in result, f"kfkit {' '.join(argv)} raised {result.get('escaped')!r}"
    return result["code"], capsys.readouterr()


BAD_OPTIONS = {  # id: (options, words the one-line message must hold)
    "baud -5": (["--baud", "-5"], "--baud"),
    "baud text": (["--baud", "fast"], "--baud"),
    "baud too high": (["--baud", "99999999999"], "--baud"),
    "seconds -1": (["--port", "virtual", "--seconds", "-1"], "--seconds"),
    "seconds 0": (["--port", "virtual", "--seconds", "0"], "--seconds"),
    "seconds nan": (["--port", "virtual", "--seconds", "nan"], "--seconds"),
    "seconds inf": (["--port", "virtual", "--seconds", "inf"], "--seconds"),
    "seconds 1e999": (["--port", "virtual", "--seconds", "1e999"], "--seconds"),
    "rate 0": (["--port", "virtual", "--rate", "0"], "--rate"),
    "rate -100": (["--port", "virtual", "--rate", "-100"], "--rate"),
    "rate nan": (["--port", "virtual", "--rate", "nan"], "--rate"),
    "rate 1e9": (["--port", "virtual", "--rate", "1e9"], "--rate"),
    "rate of a real board": (["--port", "/dev/ttyACM0", "--rate", "100"], "--rate"),
    "rate with a protocol": (["--port", "virtual", "--protocol", "tilt", "--rate", "100"], "--rate"),
    "fast on a real board": (["--port", "/dev/ttyACM0", "--fast"], "--fast"),
    "quick without a protocol": (["--port", "virtual", "--quick"], "--quick"),
    "board of a real port": (["--port", "/dev/ttyACM0", "--board", "mpu6050"], "--board"),
    "phone without host": (["--port", "phyphox://::::"], "phyphox://::::"),
    "phone port out of range": (["--port", "phyphox://10.0.0.2:99999"], "1 … 65535"),
    "phone poll -1": (["--port", "phyphox://10.0.0.2?poll=-1"], "poll"),
    "phone unknown option": (["--port", "phyphox://10.0.0.2?pol=1"], "'pol'"),
    "unknown scheme": (["--port", "bogus://x"], "'bogus://x'.*socket://HOST:PORT"),
    "socket without port": (["--port", "socket://localhost"], "socket://.*HOST:PORT"),
    "empty port": (["--port", ""], "--port"),
    "unknown option": (["--bogus"], "--bogus"),
    "out is a folder": (["--port", "virtual", "--out", "."], "--out"),
}


@pytest.mark.parametrize("as_json", [True, False], ids=["json", "human"])
@pytest.mark.parametrize("case", BAD_OPTIONS)
def test_a_bad_capture_option_is_refused_at_the_door_naming_it(tmp_path, capsys, monkeypatch, case, as_json):
    """Nothing is opened or written; with --json exactly one JSON object with the error, else the message on
    stderr; never a traceback, never exit 0 (`--seconds -1` used to record and exit 0 with error null, `--seconds
    nan` to record forever, `--rate 0` to be ignored, `--rate -100` to kill the virtual board's thread)."""
    monkeypatch.chdir(tmp_path)
    options, words = BAD_OPTIONS[case]
    argv = ["capture", "--out", "x.csv", *options] + (["--json"] if as_json else [])
    code, printed = run_main(capsys, argv)
    assert code == 2 and not (tmp_path / "x.csv").exists() and "Traceback" not in printed.err + printed.out
    if as_json:
        (line,) = printed.out.splitlines()
        result = json.loads(line)
        assert result["error"] and re.search(words, result["error"]), result["error"]
        assert (result["samples"], result["out"], result["board"]) == (0, None, None)
    else:
        assert re.search(words, printed.err.splitlines()[-1]), printed.err
        assert "nothing saved" in printed.out or printed.out == ""


def test_argparse_errors_answer_in_json_too(tmp_path, capsys):
    code, printed = run_main(capsys, ["capture", "--json", "--port", "virtual"])  # no --out
    assert code == 2 and "--out" in json.loads(printed.out)["error"] and printed.err == ""
    code, printed = run_main(capsys, ["capture", "--js", "--seconds", "nan", "--out", str(tmp_path / "x.csv")])
    assert code == 2 and "--seconds" in json.loads(printed.out)["error"]  # argparse takes --js for --json


@pytest.mark.parametrize(
    "raised, code, error_type, words",
    [
        (RuntimeError("a bug"), 1, "UnexpectedError", "unexpected error \\(RuntimeError: a bug\\)"),
        (KeyboardInterrupt(), 130, "KeyboardInterrupt", "stopped by Ctrl-C"),
    ],
)
@pytest.mark.parametrize("as_json", [True, False], ids=["json", "human"])
def test_an_unexpected_exception_or_ctrl_c_still_gives_one_answer(
    tmp_path, capsys, monkeypatch, raised, code, error_type, words, as_json
):
    from kfkit.capture import recorder

    def run(self, progress=None):
        raise raised

    monkeypatch.setattr(recorder.Recorder, "run", run)
    argv = ["capture", "--port", "virtual", "--seconds", "1", "--out", str(tmp_path / "x.csv")]
    got, printed = run_main(capsys, argv + (["--json"] if as_json else []))
    assert got == code and "Traceback" not in printed.err
    if as_json:
        result = json.loads(printed.out)
        assert result["error_type"] == error_type and re.search(words, result["error"]) and result["out"] is None
    else:
        assert re.search(words, printed.err) or (code == 130 and "stopped before any sample arrived" in printed.err)


@pytest.mark.parametrize(
    "argv, words",
    [
        (["capture", "--port", "bogus://x", "--out", "x.csv", "--json"], "no port has the scheme 'bogus://'"),
        (["capture", "--port", "virtual", "--rate", "-100", "--out", "x.csv", "--json"], "--rate"),
        (["capture", "--port", "phyphox://::::", "--out", "x.csv", "--json"], "no host"),
    ],
)
def test_the_installed_command_answers_in_json(tmp_path, argv, words):
    """The real entry point (python -m kfkit): one JSON object on stdout, nothing on stderr (these printed a
    traceback and nothing on stdout, or a thread's traceback)."""
    run = subprocess.run(
        [sys.executable, "-m", "kfkit", *argv], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 2 and run.stderr == "", run.stderr
    (line,) = run.stdout.splitlines()
    assert words in json.loads(line)["error"]


@pytest.mark.parametrize(
    "argv, words",
    [
        (["grade", "--lab", "01", "--timeout", "nan", "x.ipynb"], "--timeout"),
        (["grade", "--lab", "01", "--jobs", "0", "x.ipynb"], "--jobs"),
        (["grade", "--lab", "01", "--max-memory", "-4", "x.ipynb"], "--max-memory"),
        (["grade", "--lab", "01", "--seed", "-1", "x.ipynb"], "--seed"),
        (["demo", "tilt", "--seconds", "-1"], "--seconds"),
        (["demo", "tilt", "--baud", "0"], "--baud"),
        (["demo", "tilt", "--port", "bogus://x"], "--port"),
    ],
)
def test_every_subcommands_numbers_and_ports_are_checked_at_the_door(capsys, argv, words):
    code, printed = run_main(capsys, argv)
    assert code == 2 and words in printed.err.splitlines()[-1]


def test_option_types_name_what_they_take():
    import argparse

    seconds = number(float, 0.0, unit="s")
    assert seconds("2.5") == 2.5 and number(int, 0, include_low=True)("0") == 0
    for text in ("0", "-1", "nan", "inf", "-inf", "1e999", "x", ""):
        with pytest.raises(argparse.ArgumentTypeError, match="is not a finite number > 0 \\(s\\)"):
            seconds(text)
    with pytest.raises(argparse.ArgumentTypeError, match="'1.5' is not a whole number > 0 and ≤ 10"):
        number(int, 0, 10)("1.5")
    with pytest.raises(argparse.ArgumentTypeError, match=r"'111111111111111111111111'… \(1,000 characters\) is not"):
        seconds("1" * 1000)
