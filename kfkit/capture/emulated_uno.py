"""An emulated Arduino Uno: the kit's real AVR firmware on simavr, with an emulated MPU6050 on its I²C bus.

:class:`EmulatedUno` is a board object for :class:`kfkit.capture.Recorder` (``port="emulated-uno"``, or
``kfkit capture --port emulated-uno``). It builds a sketch of ``firmware/`` for the ATmega328P with avr-gcc and
the Arduino AVR core, as the Arduino IDE does for an Uno (:func:`build_avr_image`), builds the emulator
``firmware/emulator/uno_mpu6050.c`` against simavr (:func:`build_emulator`), runs the image in it with an MPU6050
that plays a recording's counts at the rate the firmware sets, and serves the Uno's serial port as a
pseudo-terminal: the whole chain (firmware, I²C bus, serial line, capture) without a board.

The builds need, on Debian or Ubuntu, ``sudo apt-get install gcc gcc-avr avr-libc arduino-core-avr simavr
libsimavr-dev`` (elsewhere avr-gcc, simavr's headers and library, and the Arduino AVR core named by
``$KFKIT_ARDUINO_AVR``); without them :class:`EmulatorUnavailable` says what to install. They are kept under
``$XDG_CACHE_HOME/kfkit/emulated-uno`` (``~/.cache``), one folder per version of their sources.

The emulator's clock is the AVR's cycle count: it runs as fast as the machine allows (``realtime=True`` holds
it to the wall clock, for watching), and waits when the host reads slowly, so nothing is lost either way.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io import load_recording
from ..paths import KIT_ROOT, data_dir
from .errors import CaptureError

FIRMWARE = KIT_ROOT / "firmware"
EMULATOR_SOURCE = FIRMWARE / "emulator" / "uno_mpu6050.c"
AVR_PACKAGES = "gcc-avr avr-libc arduino-core-avr"
EMULATOR_PACKAGES = "gcc simavr libsimavr-dev"
SIMAVR_INCLUDE = Path("/usr/include/simavr")
#: the sketches it runs, and the kit folders (beside firmware/common) each one compiles with
SKETCHES = {"mpu6050_logger": (), "mpu6050_tilt_kf": ("tilt_kf",)}
DEFAULT_RECORDING = "05_tilt_protocol"  # lab 05's tilt protocol, MPU6050 counts at 100 Hz, played in a loop
UNO_FLASH, UNO_RAM = 32256, 2048  # boards.txt: uno.upload.maximum_size, maximum_data_size (bytes)


class EmulatorUnavailable(CaptureError):
    """A tool or package the emulated Uno needs is missing (the message says which, and how to install it)."""


@dataclass(frozen=True)
class AvrImage:
    """A linked firmware image: ``elf``, ``flash`` (.text + .data, bytes) and ``ram`` (.data + .bss: static RAM,
    the rest of the 2 KB is stack)."""

    elf: Path
    flash: int
    ram: int


def avr_core() -> Path:
    """The Arduino AVR core (cores/, variants/, libraries/): ``$KFKIT_ARDUINO_AVR`` or Debian's arduino-core-avr."""
    return Path(os.environ.get("KFKIT_ARDUINO_AVR", "/usr/share/arduino/hardware/arduino/avr"))


def _run(command, what: str):
    done = subprocess.run([str(c) for c in command], capture_output=True, text=True)
    if done.returncode:
        raise CaptureError(f"{what} failed:\n{done.stderr.strip()}")
    return done


def build_avr_image(
    sketch: Path, work: Path, include=(), sources=(), libraries=("Wire",), mcu="atmega328p", variant="standard"
) -> AvrImage:
    """Compile and link ``sketch`` (an .ino) for an Arduino Uno with avr-gcc, the Arduino AVR core and
    ``libraries``, with the flags of the core's platform.txt for ``arduino:avr:uno`` (without -flto, which
    Debian's avr-gcc 5.4 links without). The kit's own code (the sketch, firmware/common, ``sources``, more
    folders in ``include``) is compiled with ``-Wall -Wextra -Werror``; the core with its own warnings off."""
    gxx, gcc, size = (shutil.which(tool) for tool in ("avr-g++", "avr-gcc", "avr-size"))
    core_dir = avr_core()
    if not (gxx and gcc and size and (core_dir / "cores" / "arduino" / "Arduino.h").exists()):
        raise EmulatorUnavailable(
            f"building for the Uno needs avr-gcc and the Arduino AVR core ({core_dir} has none): "
            f"sudo apt-get install {AVR_PACKAGES} (or point KFKIT_ARDUINO_AVR at "
            f"arduino-cli's packages/arduino/hardware/avr/<version>)"
        )
    work = Path(work)
    core, lib_dirs = core_dir / "cores" / "arduino", [core_dir / "libraries" / name / "src" for name in libraries]
    includes = [f"-I{core}", f"-I{core_dir / 'variants' / variant}", f"-I{FIRMWARE / 'common'}"]
    includes += [f"-I{d}" for d in lib_dirs] + [f"-I{d / 'utility'}" for d in lib_dirs if (d / "utility").exists()]
    includes += [f"-I{folder}" for folder in include]
    defines = [f"-mmcu={mcu}", "-DF_CPU=16000000L", "-DARDUINO=10807", "-DARDUINO_AVR_UNO", "-DARDUINO_ARCH_AVR"]
    c_flags = ["-c", "-Os", "-std=gnu11", "-ffunction-sections", "-fdata-sections", *defines, *includes]
    cpp_flags = [
        "-c",
        "-Os",
        "-std=gnu++11",
        "-fpermissive",
        "-fno-exceptions",
        "-ffunction-sections",
        "-fdata-sections",
        "-fno-threadsafe-statics",
        *defines,
        *includes,
    ]
    core_sources = sorted(core.glob("*.c")) + sorted(core.glob("*.cpp")) + sorted(core.glob("*.S"))
    for d in lib_dirs:
        core_sources += sorted(d.rglob("*.c")) + sorted(d.rglob("*.cpp"))

    def compile_one(source: Path, kit=False):
        obj = work / f"{source.name}.o"
        if source.suffix == ".ino":  # the sketch: C++, as the IDE compiles it
            command = [gxx, *cpp_flags, "-x", "c++", source]
        elif source.suffix == ".cpp":  # DECIMAL_DIG: Debian's avr-gcc 5 leaves it out of <float.h> for WString.cpp
            command = [gxx, *cpp_flags, "-DDECIMAL_DIG=17", source]
        else:
            command = [gcc, *c_flags, "-x", "assembler-with-cpp" if source.suffix == ".S" else "c", source]
        warnings = ["-Wall", "-Wextra", "-Werror"] if kit else ["-w"]
        _run([*command[:1], *warnings, *command[1:], "-o", obj], f"compiling {source.name} for the {mcu}")
        return obj

    with ThreadPoolExecutor(max_workers=2) as pool:
        objects = list(pool.map(compile_one, core_sources))
    objects += [compile_one(Path(source), kit=True) for source in (sketch, *sources)]
    elf = work / f"{Path(sketch).stem}.elf"
    _run([gcc, f"-mmcu={mcu}", "-Os", "-Wl,--gc-sections", "-o", elf, *objects, "-lm"], f"linking {Path(sketch).name}")
    sizes = _run([size, "-A", elf], "avr-size").stdout
    section = {m.group(1): int(m.group(2)) for m in re.finditer(r"^\.(\w+)\s+(\d+)", sizes, re.M)}
    return AvrImage(
        elf, section.get("text", 0) + section.get("data", 0), section.get("data", 0) + section.get("bss", 0)
    )


def build_emulator(work: Path) -> Path:
    """Compile ``firmware/emulator/uno_mpu6050.c`` against simavr (``-Wall -Wextra -Werror``); returns the program."""
    gcc = shutil.which("gcc")
    if gcc is None or not (SIMAVR_INCLUDE / "sim_avr.h").exists():
        raise EmulatorUnavailable(
            f"the Uno emulator needs gcc and simavr's headers and library ({SIMAVR_INCLUDE} "
            f"has none): sudo apt-get install {EMULATOR_PACKAGES}"
        )
    program = Path(work) / "uno_mpu6050"
    _run(
        [
            gcc,
            "-std=c99",
            "-O2",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-isystem",
            SIMAVR_INCLUDE,
            EMULATOR_SOURCE,
            "-o",
            program,
            "-lsimavr",
        ],
        "building the Uno emulator",
    )
    return program


def cache_dir() -> Path:
    """Where built images and the emulator are kept: ``$XDG_CACHE_HOME/kfkit/emulated-uno`` (``~/.cache``)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "kfkit" / "emulated-uno"


def _cached(name: str, inputs, build) -> Path:
    """The folder holding ``build(folder)``'s output for these input files, built once per version of them.
    Concurrent builders each build in a folder of their own; the first to finish is kept."""
    digest = hashlib.sha256(str(avr_core()).encode())
    for path in sorted(set(map(Path, inputs))):
        digest.update(str(path).encode() + b"\0" + path.read_bytes())
    folder = cache_dir() / f"{name}-{digest.hexdigest()[:16]}"
    if not (folder / "done").exists():
        folder.parent.mkdir(parents=True, exist_ok=True)
        scratch = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=folder.parent))
        try:
            build(scratch)
            (scratch / "done").touch()
            os.replace(scratch, folder)
        except OSError:  # another process got there first (the folder exists): use theirs
            if not (folder / "done").exists():
                raise
        finally:
            shutil.rmtree(scratch, ignore_errors=True)
    return folder


def sketch_image(sketch: str) -> AvrImage:
    """The firmware image of ``sketch`` (a key of :data:`SKETCHES`), built once per version of its sources."""
    folders = [FIRMWARE / sketch, FIRMWARE / "common", *(FIRMWARE / name for name in SKETCHES[sketch])]
    inputs = [p for folder in folders for p in folder.iterdir() if p.suffix in (".ino", ".h", ".c", ".cpp")]

    def build(work: Path):
        extra = [FIRMWARE / name for name in SKETCHES[sketch]]
        image = build_avr_image(
            FIRMWARE / sketch / f"{sketch}.ino",
            work,
            include=extra,
            sources=[p for d in extra for p in sorted(d.glob("*.c"))],
        )
        (work / "image.json").write_text(json.dumps({"elf": image.elf.name, "flash": image.flash, "ram": image.ram}))
        for obj in work.glob("*.o"):  # keep the image only
            obj.unlink()

    folder = _cached(sketch, inputs, build)
    info = json.loads((folder / "image.json").read_text())
    return AvrImage(folder / info["elf"], info["flash"], info["ram"])


def emulator_program() -> Path:
    """The emulator, built once per version of its source."""
    return _cached("uno_mpu6050", [EMULATOR_SOURCE], build_emulator) / "uno_mpu6050"


def recording_frames(rec) -> np.ndarray:
    """An MPU6050 recording's raw counts as the emulator plays them, (N, 6) ints: ax ay az gx gy gz."""
    board, rate = rec.meta.get("board"), rec.rate_hz
    if board != "mpu6050" or abs(rate - 100.0) > 0.5:
        raise ValueError(
            f"the emulated Uno's MPU6050 plays MPU6050 counts at the 100 Hz its sketches set; "
            f"{rec.path or 'this recording'} is {board} at {rate:g} Hz"
        )
    return np.column_stack([rec.counts("acc"), rec.counts("gyr")]).astype(np.int64)


class EmulatedUno:
    """An Arduino Uno running a kit sketch in simavr, its MPU6050 playing ``frames``; its serial port is ``port``.

    sketch    a key of :data:`SKETCHES` ("mpu6050_logger" or "mpu6050_tilt_kf")
    frames    (N, 6) int counts ax ay az gx gy gz, or an MPU6050 recording (:func:`recording_frames`);
              default: the bundled 05_tilt_protocol
    loop      play the frames again from the start at their end (default: when ``frames`` is the default);
              otherwise the sensor holds the last one
    realtime  hold the emulation to the wall clock (for watching); by default it runs as fast as it can
    faults    the emulator's ``--fault`` specs: "nack@S[+D]" (the sensor does not answer), "stuck@S+D" (the bus
              hangs), "reset@S" (the sensor resets); S and D in seconds of AVR time from power-on
    watch     [(address, length)] of AVR RAM to log with every sensor read (for tests)
    log       file for the emulator's event log (sensor reads, register writes, faults; firmware/emulator/README.md)

    Like an Uno, it powers on when the host opens the port and sends its first byte (``kfkit capture`` sends
    'h'). ``start()`` builds what it needs (cached) and raises :class:`EmulatorUnavailable` naming the packages
    to install.
    """

    source = "capture (emulated Uno: simavr)"  # the recording's metadata "source"

    def __init__(
        self, sketch="mpu6050_logger", frames=None, *, loop=None, realtime=False, faults=(), watch=(), log=None
    ):
        if sketch not in SKETCHES:
            raise ValueError(f"EmulatedUno runs one of {', '.join(SKETCHES)}, not {sketch!r}")
        self.sketch, self.realtime, self.faults, self.watch = sketch, realtime, list(faults), list(watch)
        self.loop = frames is None if loop is None else bool(loop)
        if frames is None:
            frames = load_recording(data_dir() / f"{DEFAULT_RECORDING}.csv")
        self.playing = getattr(frames, "path", None) or "given counts"
        self.frames = recording_frames(frames) if hasattr(frames, "counts") else np.asarray(frames)
        if self.frames.ndim != 2 or self.frames.shape[1] != 6 or not len(self.frames):
            raise ValueError(
                f"EmulatedUno: frames must be (N, 6) counts ax ay az gx gy gz, got shape {self.frames.shape}"
            )
        if np.any((self.frames < -32768) | (self.frames > 32767)):
            raise ValueError("EmulatedUno: frames hold int16 counts (−32768 … 32767)")
        self.log = Path(log) if log is not None else None
        self.image: AvrImage | None = None
        self.port = None
        self.process = None
        self._work = None

    def start(self) -> EmulatedUno:
        program = emulator_program()
        self.image = sketch_image(self.sketch)
        self._work = tempfile.TemporaryDirectory(prefix="kfkit-emulated-uno-")
        work = Path(self._work.name)
        np.savetxt(work / "frames.txt", self.frames, fmt="%d")
        command = [
            program,
            self.image.elf,
            work / "frames.txt",
            *(["--loop"] if self.loop else []),
            *(["--realtime"] if self.realtime else []),
            *(["--log", self.log] if self.log else []),
        ]
        for address, length in self.watch:
            command += ["--watch", f"{address:x}:{length}"]
        for fault in self.faults:
            command += ["--fault", fault]
        with open(work / "stderr", "w") as errors:
            self.process = subprocess.Popen(
                [str(c) for c in command], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=errors
            )
        line = self.process.stdout.readline().decode(errors="replace")
        if not line.startswith("pty "):
            self.process.wait()
            why = (work / "stderr").read_text().strip() or line
            self.close()
            raise CaptureError(f"the Uno emulator did not start: {why}")
        self.port = line.split(None, 1)[1].strip()
        return self

    def close(self):
        """End the emulator (it ends when its stdin closes) and remove its files (idempotent)."""
        if self.process is not None:
            self.process.stdin.close()
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
            self.process.stdout.close()
        if self._work is not None:
            self._work.cleanup()
            self._work = None

    def __enter__(self):
        return self.start() if self.process is None else self

    def __exit__(self, *exc):
        self.close()

    @property
    def description(self) -> str:
        return f"emulated Arduino Uno ({self.sketch} on simavr, its MPU6050 playing {self.playing}) on {self.port}"

    @property
    def phases(self) -> list:
        return []  # the frames the sketch reads first depend on its start-up time: no labelled windows
