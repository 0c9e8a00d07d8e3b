from types import SimpleNamespace

import pytest
import serial.tools.list_ports

import kfkit.doctor as doctor

EXTENSIONS = ("@jupyter-widgets/jupyterlab-manager", "jupyter-matplotlib")


def install_extensions(base, names):
    for name in names:
        (base / name).mkdir(parents=True)
        (base / name / "package.json").write_text("{}")


@pytest.fixture
def healthy(monkeypatch, tmp_path):
    """An environment with both labextensions, one board, dialout membership and bundled data."""
    ext_dir = tmp_path / "share" / "jupyter" / "labextensions"
    install_extensions(ext_dir, EXTENSIONS)
    monkeypatch.setattr(doctor, "labextension_search_path", lambda: [tmp_path / "nowhere", ext_dir])
    board = SimpleNamespace(device="/dev/ttyACM0", description="STM32 STLink", vid=0x0483, pid=0x374B)
    monkeypatch.setattr(serial.tools.list_ports, "comports", lambda: [board])
    monkeypatch.setattr(doctor, "needs_dialout", lambda: False)
    data = tmp_path / "data"
    data.mkdir()
    (data / "imu.csv").write_text("t,ax\n")
    (data / "gps.csv").write_text("t,lat\n")
    monkeypatch.setenv("KFKIT_DATA", str(data))
    return tmp_path


def test_healthy_environment_is_ok(healthy):
    text, ok = doctor.doctor_report()
    lines = text.splitlines()
    assert ok
    assert all(line.startswith(("✅", "⚠️")) for line in lines)
    assert "✅ serial port /dev/ttyACM0: STM32 STLink [0483:374B]" in lines
    assert f"✅ bundled data: 2 CSV files in {healthy / 'data'}" in lines
    assert any(line.split()[1:2] == ["numpy"] for line in lines)  # ✅, or ⚠️ when not the pinned version


def test_find_labextension(tmp_path):
    first, second = tmp_path / "a", tmp_path / "b"
    install_extensions(second, ["jupyter-matplotlib"])
    (first / "@jupyter-widgets" / "jupyterlab-manager").mkdir(parents=True)  # no package.json: broken
    assert doctor.find_labextension("jupyter-matplotlib", [first, second]) == second / "jupyter-matplotlib"
    assert doctor.find_labextension("@jupyter-widgets/jupyterlab-manager", [first, second]) is None


def test_missing_labextension_fails(healthy, monkeypatch):
    ext_dir = healthy / "other"
    install_extensions(ext_dir, ["@jupyter-widgets/jupyterlab-manager"])
    monkeypatch.setattr(doctor, "labextension_search_path", lambda: [ext_dir])
    text, ok = doctor.doctor_report()
    assert not ok
    [failure] = [line for line in text.splitlines() if line.startswith("❌")]
    assert "jupyter-matplotlib" in failure and "reinstall ipympl" in failure and "restart JupyterLab" in failure
    assert "✅ JupyterLab extension @jupyter-widgets/jupyterlab-manager" in text


def test_missing_package_fails(healthy, monkeypatch):
    real_version = doctor.metadata.version

    def version(name):
        if name == "filterpy":
            raise doctor.metadata.PackageNotFoundError(name)
        return real_version(name)

    monkeypatch.setattr(doctor.metadata, "version", version)
    text, ok = doctor.doctor_report()
    assert not ok
    assert "❌ filterpy is not installed; run: python -m pip install -r environment.txt" in text.splitlines()


def test_read_pins_skips_comments_and_the_editable_kit(tmp_path):
    env = tmp_path / "environment.txt"
    env.write_text("# the labs\n\njupyter_client==8.10.0\nipympl==0.10.0  # widgets\n-e .\npyserial==3.5\n")
    assert doctor.read_pins(env) == {"jupyter_client": "8.10.0", "ipympl": "0.10.0", "pyserial": "3.5"}


@pytest.mark.parametrize("line", ["numpy>=2", "numpy", "-r other.txt", "numpy == 2.4.6 extra"])
def test_a_line_that_is_no_exact_pin_names_file_and_line(healthy, monkeypatch, line):
    env = healthy / "environment.txt"
    env.write_text(f"# pins\nscipy==1.17.1\n{line}\n")
    with pytest.raises(ValueError, match=r"environment.txt, line 3: expected an exact pin 'name==version'"):
        doctor.read_pins(env)
    monkeypatch.setattr(doctor, "ENVIRONMENT", env)
    text, ok = doctor.doctor_report()
    assert not ok
    assert (
        f"❌ cannot read the package list: {env}, line 3: expected an exact pin 'name==version' or '-e .', got {line!r}"
        in text
    )


def test_another_version_is_advice_and_a_missing_one_must_be_fixed(healthy, monkeypatch):
    env = healthy / "environment.txt"
    installed = doctor.metadata.version("numpy")
    env.write_text(f"numpy=={installed}\nscipy==0.1\nno-such-package-kfkit==1.0\n-e .\n")
    monkeypatch.setattr(doctor, "ENVIRONMENT", env)
    text, ok = doctor.doctor_report()
    lines = text.splitlines()
    assert not ok
    assert f"✅ numpy {installed}" in lines
    [scipy] = [line for line in lines if "scipy" in line]
    assert scipy.startswith("⚠️") and "is installed, the labs are tested with 0.1 (environment.txt)" in scipy
    assert "❌ no-such-package-kfkit is not installed; run: python -m pip install -r environment.txt" in lines
    env.write_text(f"numpy=={installed}\nscipy==0.1\n")
    assert doctor.doctor_report()[1]  # a version other than the pin is only advice


def test_kit_without_environment_file_warns(healthy, monkeypatch):
    monkeypatch.setattr(doctor, "ENVIRONMENT", healthy / "missing" / "environment.txt")
    text, ok = doctor.doctor_report()
    assert ok
    assert any(line.startswith("⚠️") and "package versions not checked" in line for line in text.splitlines())


def test_no_serial_ports_is_only_a_warning(healthy, monkeypatch):
    monkeypatch.setattr(serial.tools.list_ports, "comports", lambda: [])
    text, ok = doctor.doctor_report()
    assert ok
    assert "⚠️ no serial ports found (that is fine: the labs run on bundled data)" in text.splitlines()


def test_port_without_usb_ids_and_pyserial_port_info():
    from serial.tools.list_ports_common import ListPortInfo

    port = ListPortInfo("/dev/ttyUSB0", skip_link_detection=True)
    port.description, port.vid, port.pid = "CP2102 USB to UART", 0x10C4, 0xEA60
    assert doctor.describe_port(port) == "/dev/ttyUSB0: CP2102 USB to UART [10C4:EA60]"
    legacy = SimpleNamespace(device="/dev/ttyS0", description="n/a", vid=None, pid=None)
    assert doctor.describe_port(legacy) == "/dev/ttyS0: n/a"


def test_dialout_advice(healthy, monkeypatch):
    monkeypatch.setattr(doctor, "needs_dialout", lambda: True)
    text, ok = doctor.doctor_report()
    assert ok
    assert any(line.startswith("⚠️") and "sudo usermod -aG dialout $USER" in line for line in text.splitlines())


@pytest.mark.skipif(not hasattr(__import__("os"), "geteuid"), reason="POSIX only")
def test_needs_dialout(monkeypatch):
    import grp

    monkeypatch.setattr(doctor.sys, "platform", "linux")
    monkeypatch.setattr(grp, "getgrnam", lambda name: SimpleNamespace(gr_gid=20))
    monkeypatch.setattr(doctor.os, "geteuid", lambda: 1000)
    monkeypatch.setattr(doctor.os, "getgroups", lambda: [1000, 27])
    assert doctor.needs_dialout()
    monkeypatch.setattr(doctor.os, "getgroups", lambda: [1000, 20])
    assert not doctor.needs_dialout()
    monkeypatch.setattr(doctor.os, "getgroups", lambda: [1000])
    monkeypatch.setattr(doctor.os, "geteuid", lambda: 0)
    assert not doctor.needs_dialout()
    monkeypatch.setattr(doctor.sys, "platform", "darwin")
    monkeypatch.setattr(doctor.os, "geteuid", lambda: 1000)
    assert not doctor.needs_dialout()


def test_missing_data_dir_fails(healthy, monkeypatch, tmp_path):
    missing = tmp_path / "no-such-data"
    monkeypatch.setenv("KFKIT_DATA", str(missing))
    text, ok = doctor.doctor_report()
    assert not ok
    assert f"❌ bundled data not found at {missing}" in text


def test_default_data_dir_is_repo_data(monkeypatch):
    monkeypatch.delenv("KFKIT_DATA", raising=False)
    repo_data = doctor.Path(doctor.__file__).resolve().parents[1] / "data"
    assert str(repo_data) in doctor.data_line()
