"""The kfkit command: exit codes and messages of make-labs, data regenerate and doctor."""
import subprocess
import sys

import nbformat

from kfkit import datasets
from kfkit.cli import main


def test_python_dash_m_kfkit_help():
    out = subprocess.run([sys.executable, "-m", "kfkit", "--help"], capture_output=True, text=True, check=True).stdout
    assert "make-labs" in out and "doctor" in out and "data" in out


def test_make_labs_then_check(tmp_path, capsys):
    sol, labs = tmp_path / "solutions", tmp_path / "labs"
    sol.mkdir()
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(
        "def f():\n    ### BEGIN SOLUTION\n    return 1\n    ### END SOLUTION")])
    nbformat.write(nb, sol / "01_x.ipynb")
    assert main(["make-labs", "--check", "--solutions", str(sol), "--labs", str(labs)]) == 1
    assert "missing" in capsys.readouterr().out
    assert main(["make-labs", "--solutions", str(sol), "--labs", str(labs)]) == 0
    assert main(["make-labs", "--check", "--solutions", str(sol), "--labs", str(labs)]) == 0
    assert "raise NotImplementedError()" in (labs / "01_x.ipynb").read_text()


def test_data_check_reports_stale_file(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("KFKIT_DATA", str(tmp_path))
    monkeypatch.setattr(datasets, "BUNDLED", {"01_roll_sine": datasets.BUNDLED["01_roll_sine"]})  # one file: the messages
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
