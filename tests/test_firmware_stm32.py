"""The Nucleo logger built as a student's Arduino IDE builds it, and the host stand-ins held to ST's real headers.

The build: ``arduino-builder`` (the IDE's builder) with what the IDE's Boards and Library Managers install for a
NUCLEO-F411RE, the STM32duino core 2.12.0, CMSIS-Core 6 and ST's STM32duino ISM330DHCX 2.2.0 and IIS2MDC 2.0.2
(``../shared/vendor/stm32duino`` beside the kit, or ``$KFKIT_STM32DUINO``), compiled by Debian's gcc-arm-none-eabi
with the IDE's "all warnings" (-Wall -Wextra). The image must fit the board; the sketch's own files (the .ino and
firmware/common) must compile without one warning. Skips, naming what is missing, without the vendor folder or
the packages (gcc-arm-none-eabi libnewlib-arm-none-eabi libstdc++-arm-none-eabi-newlib arduino-builder
arduino-ctags).

The stand-ins: tests/arduino_host.py builds the sketch for the host against stand-ins of ST's two libraries, to run
it on simulated data (test_firmware_protocol.py). Here g++ compiles ST's real headers and checks that every method
and constructor the stand-ins declare exists there with the same return and parameter types.

What is not done: running it. No emulator on these machines models the STM32F411's I²C peripheral with an
ISM330DHCX and an IIS2MDC on it, so the Nucleo logger is proven by this real build and by the protocol tests on the
host, not by running (the Uno's sketches do run: test_firmware_emulated_uno.py).
"""

import os
import re
import shutil
import subprocess
from pathlib import Path

import arduino_host
import pytest

from kfkit.paths import KIT_ROOT

SKETCH = arduino_host.FIRMWARE / "nucleo_iks02a1_logger" / "nucleo_iks02a1_logger.ino"
STM32DUINO = Path(os.environ.get("KFKIT_STM32DUINO") or KIT_ROOT.parent / "shared" / "vendor" / "stm32duino")
ST_LIBRARIES = {"ISM330DHCXSensor": "STM32duino_ISM330DHCX", "IIS2MDCSensor": "STM32duino_IIS2MDC"}
FQBN = "STMicroelectronics:stm32:Nucleo_64:pnum=NUCLEO_F411RE"
PACKAGES = "gcc-arm-none-eabi libnewlib-arm-none-eabi libstdc++-arm-none-eabi-newlib arduino-builder arduino-ctags"


def vendor_or_skip() -> Path:
    if not (STM32DUINO / "hardware" / "STMicroelectronics" / "stm32" / "boards.txt").exists():
        pytest.skip(f"no STM32duino vendor folder at {STM32DUINO} (set KFKIT_STM32DUINO to one)")
    return STM32DUINO


def arduino_builder_command(vendor: Path, libraries: Path, build: Path, sketch: Path) -> list:
    """The vendor README's command line: Debian's arm-none-eabi-gcc and the vendored CMSIS stand in for the
    toolchain and CMSIS that platform.txt names (the IDE's xPack gcc 14.2, CMSIS 6.2); 'all' warnings."""
    return [
        "arduino-builder",
        "-compile",
        "-hardware",
        "/usr/share/arduino-builder",
        "-hardware",
        vendor / "hardware",
        "-tools",
        "/usr/share/arduino-builder",
        "-tools",
        "/usr/bin",
        "-libraries",
        vendor / "libraries",
        "-libraries",
        libraries,
        "-fqbn",
        FQBN,
        "-prefs",
        "runtime.tools.xpack-arm-none-eabi-gcc-14.2.1-1.1.path=/usr",
        "-prefs",
        f"runtime.tools.CMSIS-6.2.0.path={vendor / 'tools' / 'CMSIS-6'}",
        "-prefs",
        "runtime.tools.STM32Tools.path=/nonexistent",
        "-prefs",
        "runtime.tools.ctags.path=/usr/bin",
        "-warnings",
        "all",
        "-verbose",
        "-build-path",
        build,
        sketch,
    ]


def kit_warnings(output: str) -> list[str]:
    """The compiler's warnings about the kit's own files (anything under firmware/, however the path was reached)."""
    found = []
    for match in re.finditer(r"^(\S[^:\n]*):\d+:\d+: warning: .*$", output, re.M):
        path = Path(match.group(1)).resolve()
        if path.is_relative_to(arduino_host.FIRMWARE.resolve()):
            found.append(match.group(0))
    return found


@pytest.fixture(scope="module")
def nucleo_build(tmp_path_factory):
    """Build the sketch once: (arduino-builder's output, sizes {flash, flash_max, ram, ram_max})."""
    vendor = vendor_or_skip()
    missing = [tool for tool in ("arduino-builder", "arduino-ctags", "arm-none-eabi-g++") if shutil.which(tool) is None]
    if missing:
        pytest.skip(f"{', '.join(missing)} not installed: apt-get install {PACKAGES}")
    work = tmp_path_factory.mktemp("nucleo")
    libraries = work / "libraries"  # the kit's own library, as arduino-cli's --library ../common gives it
    libraries.mkdir()
    (libraries / "kfkit_common").symlink_to(arduino_host.FIRMWARE / "common", target_is_directory=True)
    (work / "build").mkdir()
    done = subprocess.run(
        [str(c) for c in arduino_builder_command(vendor, libraries, work / "build", SKETCH)],
        capture_output=True,
        text=True,
    )
    output = done.stdout + done.stderr
    assert done.returncode == 0, f"arduino-builder failed:\n{output[-6000:]}"
    flash = re.search(r"Sketch uses (\d+) bytes .* Maximum is (\d+) bytes", output)
    ram = re.search(r"Global variables use (\d+) bytes .* Maximum is (\d+) bytes", output)
    sizes = {
        "flash": int(flash.group(1)),
        "flash_max": int(flash.group(2)),
        "ram": int(ram.group(1)),
        "ram_max": int(ram.group(2)),
    }
    return output, sizes


@pytest.mark.slow
def test_nucleo_logger_builds_for_the_nucleo_f411re_and_fits(nucleo_build):
    output, sizes = nucleo_build
    print(
        f"nucleo_iks02a1_logger on the NUCLEO-F411RE: {sizes['flash']} of {sizes['flash_max']} bytes of flash, "
        f"{sizes['ram']} of {sizes['ram_max']} bytes of RAM"
    )
    assert (sizes["flash_max"], sizes["ram_max"]) == (524288, 131072)  # boards.txt: the F411RE's 512 KB and 128 KB
    assert 20_000 < sizes["flash"] < sizes["flash_max"] // 4 and 0 < sizes["ram"] < sizes["ram_max"] // 16
    # what it was built with: ST's libraries and the core from the vendor folder, not something else on the machine
    for library in ST_LIBRARIES.values():
        assert f"Using library {library} at version" in output or f'Compiling library "{library}"' in output


@pytest.mark.slow
def test_nucleo_logger_compiles_without_a_warning_under_wall_wextra(nucleo_build):
    output, _ = nucleo_build
    sketch_compile = next(
        line for line in output.splitlines() if "nucleo_iks02a1_logger.ino.cpp.o" in line and " -c " in line
    )
    assert "-Wall -Wextra" in sketch_compile  # the IDE's "All" compiler warnings reached the sketch
    assert kit_warnings(output) == []


def test_kit_warnings_are_the_kit_files_only():
    """The filter the build test relies on: a warning in the sketch or firmware/common counts, the core's do not."""
    common = arduino_host.FIRMWARE / "common" / "kfkit_protocol.h"
    output = (
        f"{SKETCH}:53:9: warning: unused variable 'x' [-Wunused-variable]\n"
        f"{common}:70:5: warning: comparison of integer expressions of different signedness\n"
        "/vendor/stm32/cores/arduino/Print.cpp:12:3: warning: unused parameter 'b' [-Wunused-parameter]\n"
        f"{SKETCH}: In function 'void setup()':\n"
    )
    assert [w.split(":")[0] for w in kit_warnings(output)] == [str(SKETCH), str(common)]


# --- the host stand-ins of ST's libraries against the real headers ---------------------------------------------
SPI_H = r"""
#pragma once
#include <stdint.h>
#define MSBFIRST 1
#define SPI_MODE3 3
#define LOW 0
#define HIGH 1
inline void digitalWrite(uint32_t, uint32_t) {}
class SPISettings { public: SPISettings(uint32_t, uint8_t, uint8_t) {} };
class SPIClass { public: void beginTransaction(SPISettings) {} uint8_t transfer(uint8_t v) { return v; } void endTransaction() {} };
"""  # noqa: E501  (C++ as C++) what ST's headers use of the SPI library (their paths are not the kit's, but their inline code must compile)


def declarations(stand_in: str, cls: str):
    """(constructor parameter lists, [(return type, name, parameter types)]) of the public part of a stand-in class."""
    public = stand_in.split("public:", 1)[1].split("private:", 1)[0]

    def types(params: str) -> list[str]:  # "TwoWire *i2c, uint8_t address = X" → ["TwoWire *", "uint8_t"]
        return [re.sub(r"\s*\b\w+\s*(=.*)?$", "", p.strip()) for p in params.split(",") if p.strip()]

    def required(params: str) -> list[str]:
        return types(",".join(p for p in params.split(",") if "=" not in p))

    constructors = [(types(p), required(p)) for p in re.findall(rf"^\s*{cls}\(([^)]*)\);", public, re.M)]
    methods = [(ret, name, types(p)) for ret, name, p in re.findall(r"^\s*(\w+)\s+(\w+)\(([^)]*)\);", public, re.M)]
    return constructors, methods


def check_program(cls: str, constructors, methods) -> str:
    """C++ that compiles only if the real ``cls`` has each declaration (a cast picks an overload or fails)."""
    lines = [f'#include "{cls}.h"', "#include <type_traits>"]
    for full, required in constructors:
        for params in (full, required):
            lines.append(
                f"static_assert(std::is_constructible<{cls}, {', '.join(params)}>::value, "
                f'"{cls}({", ".join(params)})");'
            )
    for i, (ret, name, params) in enumerate(methods):
        lines.append(f"using check{i} = decltype(static_cast<{ret} ({cls}::*)({', '.join(params)})>(&{cls}::{name}));")
    return "\n".join(lines) + "\n"


def compile_against_st(tmp_path, program: str, library: str):
    vendor = vendor_or_skip()
    gxx = shutil.which("g++")
    if gxx is None:
        pytest.skip("g++ is not installed")
    for name, text in {
        "Arduino.h": arduino_host.ARDUINO_H,
        "Wire.h": arduino_host.WIRE_H,
        "SPI.h": SPI_H,
        "check.cpp": program,
    }.items():
        (tmp_path / name).write_text(text)
    return subprocess.run(
        [
            gxx,
            "-std=c++11",
            "-fsyntax-only",
            "-Wall",
            "-Wno-unused-local-typedefs",
            f"-I{tmp_path}",
            f"-I{vendor / 'libraries' / library / 'src'}",
            str(tmp_path / "check.cpp"),
        ],
        capture_output=True,
        text=True,
    )


@pytest.mark.parametrize("cls", ST_LIBRARIES)
def test_stand_ins_declare_the_real_st_api(cls, tmp_path):
    """Every constructor and method of the stand-in (arduino_host.ISM330DHCX_H / IIS2MDC_H) exists in ST's header
    with the same types, and the constants the sketch relies on have the same values."""
    stand_in = {"ISM330DHCXSensor": arduino_host.ISM330DHCX_H, "IIS2MDCSensor": arduino_host.IIS2MDC_H}[cls]
    constructors, methods = declarations(stand_in, cls)
    assert constructors and len(methods) >= 12  # the parser found them (ISM330DHCX: 22 methods, IIS2MDC: 13)
    program = check_program(cls, constructors, methods)
    prefix = cls.removesuffix("Sensor")
    program += f'static_assert({prefix}_OK == 0 && {prefix}_ERROR == -1, "status values");\n'
    for name, value in re.findall(r"#define (\w+) (0x\w+)", stand_in):
        program += f'static_assert({name} == {value}, "{name}");\n'
    done = compile_against_st(tmp_path, program, ST_LIBRARIES[cls])
    assert done.returncode == 0, f"the stand-in of {cls} differs from ST's header:\n{done.stderr[-3000:]}"


def test_the_stand_in_check_catches_a_wrong_type(tmp_path):
    """The check above can fail: a stand-in reading raw axes into int32_t (ST's 1.x used a struct) does not compile."""
    program = check_program("ISM330DHCXSensor", [], [("ISM330DHCXStatusTypeDef", "ACC_GetAxesRaw", ["int32_t *"])])
    done = compile_against_st(tmp_path, program, ST_LIBRARIES["ISM330DHCXSensor"])
    assert done.returncode != 0 and "ACC_GetAxesRaw" in done.stderr
