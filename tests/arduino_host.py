"""Build and run an Arduino sketch on the host: g++ against small stand-ins for the Arduino core,
Wire, and ST's STM32duino ISM330DHCX / IIS2MDC libraries.

The stand-ins declare only functions the real APIs have, with the real signatures (Arduino core
Print/Stream/HardwareSerial, ``micros``, ``delay``, ``F()``; ``TwoWire``; STM32duino ISM330DHCX and
IIS2MDC 2.0.x as in their ``src/*Sensor.h``), so a sketch calling something the real libraries do
not have, or with the wrong argument types, fails to compile here as it would for the board.
``micros()`` is 32-bit, as on AVR and STM32.

The host program runs ``setup()``, then ``loop()`` every 500 µs of a simulated clock until every
sensor frame has been read. Frames come from stdin, one line of integers per sensor sample:
``ax ay az gx gy gz`` (MPU6050, played as its registers over Wire at address 0x68) or
``ax ay az gx gy gz mx my mz`` (X-NUCLEO-IKS02A1, returned by the ST library stubs; the IIS2MDC
stub raises its data-ready flag at its configured output rate). Serial output goes to stdout;
configuration (register writes, ranges and rates set through the ST API) goes to stderr, one
line each. Options (argv): ``--start-us N`` (the clock's start, e.g. near 2³² to cross the wrap),
``--who-am-i 0xNN`` (what the MPU6050 answers), ``--max-us N`` (stop a sketch stuck in setup),
and ``T:c`` (the host sends character c at T µs after the start).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

FIRMWARE = Path(__file__).resolve().parents[1] / "firmware"

ARDUINO_H = r"""
#pragma once
#include <stdint.h>
#include <stddef.h>
#include <string.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

class __FlashStringHelper;
#define F(text) (reinterpret_cast<const __FlashStringHelper *>(text))

#define DEC 10
#define HEX 16

class Print {
  public:
    virtual ~Print() {}
    virtual size_t write(uint8_t c) { return fwrite(&c, 1, 1, stdout); }
    virtual size_t write(const uint8_t *buffer, size_t size) { return fwrite(buffer, 1, size, stdout); }
    size_t print(const char *text) { return write((const uint8_t *)text, strlen(text)); }
    size_t print(const __FlashStringHelper *text) { return print(reinterpret_cast<const char *>(text)); }
    size_t print(char c) { return write((uint8_t)c); }
    size_t print(unsigned char n, int base = DEC) { return print((unsigned long)n, base); }
    size_t print(int n, int base = DEC) { return print((long)n, base); }
    size_t print(unsigned int n, int base = DEC) { return print((unsigned long)n, base); }
    size_t print(long n, int base = DEC) {
        if (base == DEC && n < 0) return print('-') + print((unsigned long)(-n), DEC);
        return print((unsigned long)n, base);
    }
    size_t print(unsigned long n, int base = DEC) {
        char text[40];
        snprintf(text, sizeof text, base == HEX ? "%lX" : "%lu", n);
        return print(text);
    }
    size_t println() { return print("\r\n"); }
    size_t println(const char *text) { return print(text) + println(); }
    size_t println(const __FlashStringHelper *text) { return print(text) + println(); }
};

class Stream : public Print {
  public:
    virtual int available() = 0;
    virtual int read() = 0;
    virtual int peek() = 0;
};

class HardwareSerial : public Stream {  /* the host's commands arrive when the clock reaches them */
  public:
    void begin(unsigned long baud) { fprintf(stderr, "Serial.begin %lu\n", baud); }
    int available();
    int read();
    int peek();
};
extern HardwareSerial Serial;
uint32_t micros();
uint32_t millis();
void delay(unsigned long ms);
"""

WIRE_H = r"""
#pragma once
#include <stdint.h>
#include <stddef.h>

class TwoWire {  /* one MPU6050 at 0x68 (a register file: WHO_AM_I, and 14 data bytes from 0x3B) */
  public:
    TwoWire() {}
    TwoWire(uint32_t sda, uint32_t scl) { (void)sda; (void)scl; }
    void begin() {}
    void setClock(uint32_t frequency) { (void)frequency; }
    void beginTransmission(uint8_t address);
    size_t write(uint8_t value);
    uint8_t endTransmission(bool sendStop = true);
    uint8_t requestFrom(uint8_t address, uint8_t count);
    int available() { return position < length; }
    int read() { return position < length ? buffer[position++] : -1; }
  private:
    uint8_t address = 0, reg = 0, sent = 0, buffer[32] = {0}, length = 0, position = 0, pending[8] = {0};
};
extern TwoWire Wire;
"""

ISM330DHCX_H = r"""
#pragma once
#include "Wire.h"
#define ISM330DHCX_I2C_ADD_L 0xD5U
#define ISM330DHCX_I2C_ADD_H 0xD7U
typedef enum { ISM330DHCX_OK = 0, ISM330DHCX_ERROR = -1 } ISM330DHCXStatusTypeDef;

class ISM330DHCXSensor {  /* STM32duino ISM330DHCX 2.0.x: the calls a logger can make, real signatures */
  public:
    ISM330DHCXSensor(TwoWire *i2c, uint8_t address = ISM330DHCX_I2C_ADD_H);
    ISM330DHCXStatusTypeDef begin();
    ISM330DHCXStatusTypeDef end();
    ISM330DHCXStatusTypeDef ReadID(uint8_t *Id);
    ISM330DHCXStatusTypeDef ACC_Enable();
    ISM330DHCXStatusTypeDef ACC_Disable();
    ISM330DHCXStatusTypeDef ACC_GetSensitivity(float *Sensitivity);
    ISM330DHCXStatusTypeDef ACC_GetOutputDataRate(float *Odr);
    ISM330DHCXStatusTypeDef ACC_SetOutputDataRate(float Odr);
    ISM330DHCXStatusTypeDef ACC_GetFullScale(int32_t *FullScale);
    ISM330DHCXStatusTypeDef ACC_SetFullScale(int32_t FullScale);
    ISM330DHCXStatusTypeDef ACC_GetAxesRaw(int16_t *Value);
    ISM330DHCXStatusTypeDef ACC_GetAxes(int32_t *Acceleration);
    ISM330DHCXStatusTypeDef ACC_Get_DRDY_Status(uint8_t *Status);
    ISM330DHCXStatusTypeDef GYRO_Enable();
    ISM330DHCXStatusTypeDef GYRO_Disable();
    ISM330DHCXStatusTypeDef GYRO_GetSensitivity(float *Sensitivity);
    ISM330DHCXStatusTypeDef GYRO_GetOutputDataRate(float *Odr);
    ISM330DHCXStatusTypeDef GYRO_SetOutputDataRate(float Odr);
    ISM330DHCXStatusTypeDef GYRO_GetFullScale(int32_t *FullScale);
    ISM330DHCXStatusTypeDef GYRO_SetFullScale(int32_t FullScale);
    ISM330DHCXStatusTypeDef GYRO_GetAxesRaw(int16_t *Value);
    ISM330DHCXStatusTypeDef GYRO_GetAxes(int32_t *AngularRate);
    ISM330DHCXStatusTypeDef GYRO_Get_DRDY_Status(uint8_t *Status);
  private:
    uint8_t address, started = 0, accOn = 0, gyroOn = 0;
    float accOdr = 104.0f, gyroOdr = 104.0f;
    int32_t accFs = 2, gyroFs = 2000;  /* begin() leaves ±2 g, ±2000 °/s */
    void report();
};
"""

IIS2MDC_H = r"""
#pragma once
#include "Wire.h"
typedef enum { IIS2MDC_OK = 0, IIS2MDC_ERROR = -1 } IIS2MDCStatusTypeDef;

class IIS2MDCSensor {  /* STM32duino IIS2MDC 2.0.x: the calls a logger can make, real signatures */
  public:
    IIS2MDCSensor(TwoWire *i2c);
    IIS2MDCStatusTypeDef begin();
    IIS2MDCStatusTypeDef end();
    IIS2MDCStatusTypeDef ReadID(uint8_t *Id);
    IIS2MDCStatusTypeDef Enable();
    IIS2MDCStatusTypeDef Disable();
    IIS2MDCStatusTypeDef GetSensitivity(float *sensitivity);
    IIS2MDCStatusTypeDef GetOutputDataRate(float *odr);
    IIS2MDCStatusTypeDef SetOutputDataRate(float odr);
    IIS2MDCStatusTypeDef GetFullScale(int32_t *fullscale);
    IIS2MDCStatusTypeDef SetFullScale(int32_t fullscale);
    IIS2MDCStatusTypeDef GetAxes(int32_t *magnetic_field);
    IIS2MDCStatusTypeDef GetAxesRaw(int16_t *value);
    IIS2MDCStatusTypeDef GetDRDYStatus(uint8_t *status);
  private:
    uint8_t started = 0, on = 0;
    float odr = 100.0f;  /* begin() leaves 100 Hz */
    uint32_t lastTick = 0xFFFFFFFFu;
    void report();
};
"""

HOST_MAIN = r"""
#include "Arduino.h"
#include "Wire.h"
#include "ISM330DHCXSensor.h"
#include "IIS2MDCSensor.h"

HardwareSerial Serial;
TwoWire Wire;
static uint32_t start = 0, now = 0, maxUs = 10000000u;
static int whoAmI = 0x68;
static uint8_t mpuRegisters[128];  /* what the sketch wrote (PWR_MGMT_1 powers on asleep: 0x40, set in main) */
static long frames[40000][9];
static long frameCount = 0, used = 0, current = -1;
static struct { uint32_t at; int c; } commands[16];
static int commandCount = 0, nextCommand = 0;

uint32_t micros() { return now; }
uint32_t millis() { return now / 1000u; }
void delay(unsigned long ms) {
    now += 1000u * (uint32_t)ms;
    if (now - start > maxUs) { fflush(stdout); exit(0); }  /* a sketch stuck in setup(): stop */
}
static bool commandDue() { return nextCommand < commandCount && (int32_t)(now - commands[nextCommand].at) >= 0; }
int HardwareSerial::available() { return commandDue() ? 1 : 0; }
int HardwareSerial::read() { return commandDue() ? commands[nextCommand++].c : -1; }
int HardwareSerial::peek() { return commandDue() ? commands[nextCommand].c : -1; }
static bool nextFrame() {
    if (used >= frameCount) return false;
    current = used++;
    return true;
}

/* --- Wire: the MPU6050 --- */
void TwoWire::beginTransmission(uint8_t a) { address = a; sent = 0; }
size_t TwoWire::write(uint8_t value) { if (sent < sizeof pending) pending[sent] = value; sent++; return 1; }
uint8_t TwoWire::endTransmission(bool) {
    if (address != 0x68) return 2;  /* NACK on the address */
    reg = pending[0];
    if (sent == 2) {
        fprintf(stderr, "MPU6050 write 0x%02X = 0x%02X\n", reg, pending[1]);
        mpuRegisters[reg & 0x7F] = pending[1];
    }
    return 0;
}
uint8_t TwoWire::requestFrom(uint8_t a, uint8_t count) {
    position = length = 0;
    if (a != 0x68 || count > sizeof buffer) return 0;
    if (reg == 0x75) { buffer[0] = (uint8_t)whoAmI; length = count; return count; }
    if (reg == 0x6B && count == 1) { buffer[0] = mpuRegisters[0x6B]; length = count; return count; }  /* PWR_MGMT_1 */
    if (reg == 0x3B && count == 14) {
        if (!nextFrame()) return 0;
        const long *f = frames[current];
        const long regs[7] = {f[0], f[1], f[2], 0, f[3], f[4], f[5]};  /* ax ay az temperature gx gy gz */
        for (int i = 0; i < 7; i++) { buffer[2 * i] = (uint8_t)(((uint16_t)regs[i]) >> 8); buffer[2 * i + 1] = (uint8_t)(regs[i] & 0xFF); }
        length = count;
        return count;
    }
    return 0;
}

/* --- ISM330DHCX 2.0.x (ranges and rates rounded up to what the chip has, as the library does) --- */
ISM330DHCXSensor::ISM330DHCXSensor(TwoWire *, uint8_t a) : address(a) {}
void ISM330DHCXSensor::report() {
    fprintf(stderr, "ISM330DHCX address=0x%02X acc on=%d fs=%d odr=%g gyro on=%d fs=%d odr=%g\n", address, accOn,
            (int)accFs, accOdr, gyroOn, (int)gyroFs, gyroOdr);
}
ISM330DHCXStatusTypeDef ISM330DHCXSensor::begin() { started = 1; accOn = gyroOn = 0; accFs = 2; gyroFs = 2000; return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::end() { accOn = gyroOn = 0; return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::ReadID(uint8_t *Id) { *Id = 0x6B; return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::ACC_Enable() { if (!started) return ISM330DHCX_ERROR; accOn = 1; report(); return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::ACC_Disable() { accOn = 0; return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::ACC_GetSensitivity(float *s) { *s = 0.061f * (float)(accFs / 2); return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::ACC_GetOutputDataRate(float *o) { *o = accOdr; return ISM330DHCX_OK; }
static float roundOdr(float o) {
    static const float rates[] = {12.5f, 26.0f, 52.0f, 104.0f, 208.0f, 417.0f, 833.0f, 1667.0f, 3333.0f};
    for (float r : rates) if (o <= r) return r;
    return 6667.0f;
}
ISM330DHCXStatusTypeDef ISM330DHCXSensor::ACC_SetOutputDataRate(float o) { accOdr = roundOdr(o); report(); return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::ACC_GetFullScale(int32_t *f) { *f = accFs; return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::ACC_SetFullScale(int32_t f) {
    accFs = f <= 2 ? 2 : f <= 4 ? 4 : f <= 8 ? 8 : 16;
    report();
    return ISM330DHCX_OK;
}
ISM330DHCXStatusTypeDef ISM330DHCXSensor::ACC_GetAxesRaw(int16_t *v) {
    if (!accOn || !nextFrame()) return ISM330DHCX_ERROR;  /* one accelerometer read per sample */
    for (int i = 0; i < 3; i++) v[i] = (int16_t)frames[current][i];
    return ISM330DHCX_OK;
}
ISM330DHCXStatusTypeDef ISM330DHCXSensor::ACC_GetAxes(int32_t *) { return ISM330DHCX_ERROR; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::ACC_Get_DRDY_Status(uint8_t *s) { *s = 1; return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::GYRO_Enable() { if (!started) return ISM330DHCX_ERROR; gyroOn = 1; report(); return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::GYRO_Disable() { gyroOn = 0; return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::GYRO_GetSensitivity(float *s) { *s = 4.375f * (float)gyroFs / 125.0f; return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::GYRO_GetOutputDataRate(float *o) { *o = gyroOdr; return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::GYRO_SetOutputDataRate(float o) { gyroOdr = roundOdr(o); report(); return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::GYRO_GetFullScale(int32_t *f) { *f = gyroFs; return ISM330DHCX_OK; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::GYRO_SetFullScale(int32_t f) {
    gyroFs = f <= 125 ? 125 : f <= 250 ? 250 : f <= 500 ? 500 : f <= 1000 ? 1000 : f <= 2000 ? 2000 : 4000;
    report();
    return ISM330DHCX_OK;
}
ISM330DHCXStatusTypeDef ISM330DHCXSensor::GYRO_GetAxesRaw(int16_t *v) {
    if (!gyroOn || current < 0) return ISM330DHCX_ERROR;  /* the same sample as the accelerometer's */
    for (int i = 0; i < 3; i++) v[i] = (int16_t)frames[current][3 + i];
    return ISM330DHCX_OK;
}
ISM330DHCXStatusTypeDef ISM330DHCXSensor::GYRO_GetAxes(int32_t *) { return ISM330DHCX_ERROR; }
ISM330DHCXStatusTypeDef ISM330DHCXSensor::GYRO_Get_DRDY_Status(uint8_t *s) { *s = 1; return ISM330DHCX_OK; }

/* --- IIS2MDC 2.0.x --- */
IIS2MDCSensor::IIS2MDCSensor(TwoWire *) {}
void IIS2MDCSensor::report() { fprintf(stderr, "IIS2MDC on=%d odr=%g\n", on, odr); }
IIS2MDCStatusTypeDef IIS2MDCSensor::begin() { started = 1; on = 0; odr = 100.0f; return IIS2MDC_OK; }
IIS2MDCStatusTypeDef IIS2MDCSensor::end() { on = 0; return IIS2MDC_OK; }
IIS2MDCStatusTypeDef IIS2MDCSensor::ReadID(uint8_t *Id) { *Id = 0x40; return IIS2MDC_OK; }
IIS2MDCStatusTypeDef IIS2MDCSensor::Enable() { if (!started) return IIS2MDC_ERROR; on = 1; report(); return IIS2MDC_OK; }
IIS2MDCStatusTypeDef IIS2MDCSensor::Disable() { on = 0; return IIS2MDC_OK; }
IIS2MDCStatusTypeDef IIS2MDCSensor::GetSensitivity(float *s) { *s = 1.5f; return IIS2MDC_OK; }
IIS2MDCStatusTypeDef IIS2MDCSensor::GetOutputDataRate(float *o) { *o = odr; return IIS2MDC_OK; }
IIS2MDCStatusTypeDef IIS2MDCSensor::SetOutputDataRate(float o) {
    odr = o <= 10.0f ? 10.0f : o <= 20.0f ? 20.0f : o <= 50.0f ? 50.0f : 100.0f;
    report();
    return IIS2MDC_OK;
}
IIS2MDCStatusTypeDef IIS2MDCSensor::GetFullScale(int32_t *f) { *f = 50; return IIS2MDC_OK; }
IIS2MDCStatusTypeDef IIS2MDCSensor::SetFullScale(int32_t) { return IIS2MDC_OK; }
IIS2MDCStatusTypeDef IIS2MDCSensor::GetAxes(int32_t *) { return IIS2MDC_ERROR; }
IIS2MDCStatusTypeDef IIS2MDCSensor::GetAxesRaw(int16_t *v) {
    if (!on || current < 0) return IIS2MDC_ERROR;
    for (int i = 0; i < 3; i++) v[i] = (int16_t)frames[current][6 + i];
    lastTick = (uint32_t)((uint64_t)(now - start) * (uint64_t)odr / 1000000u);  /* the reading is consumed */
    return IIS2MDC_OK;
}
IIS2MDCStatusTypeDef IIS2MDCSensor::GetDRDYStatus(uint8_t *s) {  /* a new reading every 1/odr s */
    const uint32_t tick = (uint32_t)((uint64_t)(now - start) * (uint64_t)odr / 1000000u);
    *s = on && tick != lastTick;
    return IIS2MDC_OK;
}

void setup();
void loop();
int main(int argc, char **argv) {
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--start-us") && i + 1 < argc) start = (uint32_t)strtoul(argv[++i], NULL, 0);
        else if (!strcmp(argv[i], "--who-am-i") && i + 1 < argc) whoAmI = (int)strtol(argv[++i], NULL, 0);
        else if (!strcmp(argv[i], "--max-us") && i + 1 < argc) maxUs = (uint32_t)strtoul(argv[++i], NULL, 0);
        else if (strchr(argv[i], ':') && commandCount < 16) {
            commands[commandCount].at = (uint32_t)strtoul(argv[i], NULL, 0);
            commands[commandCount++].c = strchr(argv[i], ':')[1];
        }
    }
    char line[256];
    while (frameCount < 40000 && fgets(line, sizeof line, stdin)) {
        char *p = line, *end;
        for (int k = 0; k < 9; k++, p = end) frames[frameCount][k] = strtol(p, &end, 10);
        frameCount++;
    }
    for (int i = 0; i < commandCount; i++) commands[i].at += start;
    mpuRegisters[0x6B] = 0x40;
    now = start;
    setup();
    while (used < frameCount && now - start <= maxUs) { loop(); now += 500u; }
    return 0;
}
"""  # noqa: E501  (C++ source laid out as C++: the one-line stand-in methods stay whole)

HEADERS = {"Arduino.h": ARDUINO_H, "Wire.h": WIRE_H, "ISM330DHCXSensor.h": ISM330DHCX_H, "IIS2MDCSensor.h": IIS2MDC_H}


def build_sketch(sketch: Path, work: Path, include=(), sources=()) -> Path:
    """Compile ``sketch`` (an .ino) with the stand-ins into ``work``; returns the executable.

    ``include``: more include folders (``firmware/common`` is always one); ``sources``: more C/C++ files.
    Skips the test when g++ is not installed.
    """
    gxx = shutil.which("g++")
    if gxx is None:
        pytest.skip("g++ is not installed: the sketch's host build needs it")
    for name, text in HEADERS.items():
        (work / name).write_text(text)
    (work / "host_main.cpp").write_text(HOST_MAIN)
    exe = work / sketch.stem
    includes = [f"-I{work}", f"-I{FIRMWARE / 'common'}", *(f"-I{folder}" for folder in include)]
    extra = []
    for source in sources:
        if Path(source).suffix == ".c":  # C99 on its own: g++'s -std=c++11 is an error for C under -Werror
            obj = work / f"{Path(source).stem}.o"
            subprocess.run(
                [
                    shutil.which("gcc") or "gcc",
                    "-std=c99",
                    "-O1",
                    "-Wall",
                    "-Wextra",
                    "-Werror",
                    *includes,
                    "-c",
                    str(source),
                    "-o",
                    str(obj),
                ],
                check=True,
                capture_output=True,
                text=True,
            )
            extra += ["-x", "none", str(obj)]
        else:
            extra += ["-x", "c++", str(source)]
    command = [
        gxx,
        "-std=c++11",
        "-O1",
        "-Wall",
        "-Wextra",
        "-Werror",
        "-Wno-unused-parameter",
        "-DARDUINO=10819",
        *includes,
        "-x",
        "c++",
        str(sketch),
        "-x",
        "c++",
        str(work / "host_main.cpp"),
        *extra,
        "-o",
        str(exe),
        "-lm",
    ]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode:
        raise AssertionError(f"{sketch.name} does not compile against the Arduino/ST API stand-ins:\n{result.stderr}")
    return exe


def run_sketch(exe: Path, frames, *args, timeout=60):
    """Run a host-built sketch on ``frames`` (rows of ints); returns (stdout lines as bytes, stderr text)."""
    feed = "".join(" ".join(str(int(v)) for v in row) + "\n" for row in frames)
    run = subprocess.run(
        [str(exe), *map(str, args)], input=feed.encode(), capture_output=True, timeout=timeout, check=True
    )
    return run.stdout.splitlines(keepends=True), run.stderr.decode()


def uno_image(sketch: str):
    """The Arduino Uno image of ``firmware/<sketch>`` (a :class:`kfkit.capture.emulated_uno.AvrImage`): avr-gcc with
    the real Arduino AVR core and Wire (Debian's arduino-core-avr, or ``$KFKIT_ARDUINO_AVR``), the kit's code with
    every warning an error, linked as for ``arduino:avr:uno``. kfkit builds it once per version of its sources (its
    cache, shared by the test modules and ``--port emulated-uno``). Skips, naming the packages, without the
    toolchain."""
    from kfkit.capture.emulated_uno import EmulatorUnavailable, sketch_image

    try:
        return sketch_image(sketch)
    except EmulatorUnavailable as e:
        pytest.skip(str(e))


def avr_symbol(elf: Path, name: str) -> tuple[int, int]:
    """(SRAM address, size in bytes) of the variable ``name`` in an AVR image (avr-nm; C++ names demangled, so a
    sketch's ``static TiltKf rollKf`` is "rollKf"). avr-gcc places RAM at 0x800000 in the ELF's address space."""
    listing = subprocess.run(
        [shutil.which("avr-nm") or "avr-nm", "-S", "-C", str(elf)], capture_output=True, text=True, check=True
    ).stdout
    for line in listing.splitlines():
        fields = line.split()
        if len(fields) == 4 and fields[3] == name and fields[2].lower() in "bd":
            return int(fields[0], 16) - 0x800000, int(fields[1], 16)
    raise AssertionError(f"{elf.name} has no variable {name!r} in RAM")
