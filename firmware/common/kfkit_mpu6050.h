/*
 * kfkit_mpu6050.h: the MPU6050 (GY-521) as the kit's sketches use it, over Wire (Arduino C++).
 *
 *   mpu6050Begin(Serial);            // WHO_AM_I check, then 100 Hz, DLPF 44/42 Hz, ±2 g, ±250 °/s
 *   int16_t counts[6];               // ax ay az gx gy gz, raw int16 in the sensor frame
 *   if (mpu6050ReadOrReport(counts, Serial)) ...  // false (and a #ERROR line) when the read failed or the
 *                                                 // chip was reset (then it is configured again)
 *
 * Registers from RM-MPU-6000A-00 rev 4.2. Counts: 16384 LSB/g (±2 g), 131 LSB/(°/s) (±250 °/s);
 * kfkit converts them (kfkit.sensors). Used by mpu6050_logger and mpu6050_tilt_kf; host-tested
 * through both sketches (tests/arduino_host.py), and run in their Uno images on simavr with an emulated
 * MPU6050 (firmware/emulator), missing, stuck and reset included (tests/test_firmware_emulated_uno.py).
 */
#ifndef KFKIT_MPU6050_H
#define KFKIT_MPU6050_H

#include <Arduino.h>
#include <Wire.h>

static const uint8_t MPU6050_ADDRESS = 0x68;  // AD0 low (0x69 with AD0 high)
static const uint8_t MPU6050_REG_SMPLRT_DIV = 0x19, MPU6050_REG_CONFIG = 0x1A, MPU6050_REG_GYRO_CONFIG = 0x1B;
static const uint8_t MPU6050_REG_ACCEL_CONFIG = 0x1C, MPU6050_REG_ACCEL_XOUT_H = 0x3B, MPU6050_REG_PWR_MGMT_1 = 0x6B;
static const uint8_t MPU6050_REG_WHO_AM_I = 0x75;
static const uint8_t MPU6050_AWAKE = 0x01;  // PWR_MGMT_1: not asleep, clock from the x gyro PLL (power-on value 0x40: asleep)

inline void mpu6050WriteRegister(uint8_t reg, uint8_t value) {
    Wire.beginTransmission(MPU6050_ADDRESS);
    Wire.write(reg);
    Wire.write(value);
    Wire.endTransmission();
}

inline bool mpu6050ReadRegisters(uint8_t reg, uint8_t *buffer, uint8_t count) {
    Wire.beginTransmission(MPU6050_ADDRESS);
    Wire.write(reg);
    if (Wire.endTransmission(false) != 0) return false;
    if (Wire.requestFrom(MPU6050_ADDRESS, count) != count) return false;
    for (uint8_t i = 0; i < count; i++) buffer[i] = Wire.read();
    return true;
}

/* Nothing to stream: say why on ``out``, once a second, for ever (kfkit shows '#' notes in its errors). */
inline void mpu6050ReportMissing(Print &out, bool answered, uint8_t who) {
    for (;;) {
        if (answered) {
            out.print(F("#ERROR,the chip at 0x68 has WHO_AM_I 0x"));
            out.print(who, HEX);
            out.println(F(", not 0x68: not an MPU6050 (MPU6500/9250 clones read 0x70-0x73)"));
        } else {
            out.println(F("#ERROR,no MPU6050 answers at 0x68: check VCC, GND, SDA (A4), SCL (A5) and that AD0 is low"));
        }
        delay(1000);
    }
}

/* 100 Hz, DLPF 44/42 Hz, ±2 g, ±250 °/s: at start, and again after the chip was reset. */
inline void mpu6050Configure() {
    mpu6050WriteRegister(MPU6050_REG_PWR_MGMT_1, MPU6050_AWAKE);  // wake up, clock from the x gyro PLL
    mpu6050WriteRegister(MPU6050_REG_CONFIG, 0x03);        // DLPF 44 Hz accel / 42 Hz gyro: below Nyquist at 100 Hz
    mpu6050WriteRegister(MPU6050_REG_SMPLRT_DIV, 9);       // 1 kHz / (1 + 9) = 100 Hz internal sample rate
    mpu6050WriteRegister(MPU6050_REG_GYRO_CONFIG, 0x00);   // ±250 °/s
    mpu6050WriteRegister(MPU6050_REG_ACCEL_CONFIG, 0x00);  // ±2 g
}

/* Start I2C at 400 kHz (the 14-byte read takes ~0.4 ms), check the chip, configure it. */
inline void mpu6050Begin(Print &errors) {
    Wire.begin();
    Wire.setClock(400000);
#if defined(ARDUINO_ARCH_AVR)
    // A transfer that never ends (a stuck bus: SDA held low) gives up after 25 ms and resets the TWI, instead of
    // hanging the sketch for ever (Arduino AVR Boards >= 1.8.3).
    Wire.setWireTimeout(25000, true);
#endif
    uint8_t who = 0;
    const bool answered = mpu6050ReadRegisters(MPU6050_REG_WHO_AM_I, &who, 1);
    if (!answered || who != 0x68) mpu6050ReportMissing(errors, answered, who);
    mpu6050Configure();
}

enum Mpu6050Result { MPU6050_OK, MPU6050_BUS_ERROR, MPU6050_WAS_RESET };

/* One sample into counts = {ax, ay, az, gx, gy, gz} (the temperature between them is skipped). PWR_MGMT_1 is read
 * back after it: a chip that lost its power since mpu6050Configure() starts asleep (0x40) and reads zeros, so
 * that sample is not one (MPU6050_WAS_RESET). */
inline Mpu6050Result mpu6050Read(int16_t counts[6]) {
    uint8_t raw[14], power = 0;  // ax ay az temperature gx gy gz, big-endian registers
    if (!mpu6050ReadRegisters(MPU6050_REG_ACCEL_XOUT_H, raw, sizeof raw)) return MPU6050_BUS_ERROR;
    if (!mpu6050ReadRegisters(MPU6050_REG_PWR_MGMT_1, &power, 1)) return MPU6050_BUS_ERROR;
    if (power != MPU6050_AWAKE) return MPU6050_WAS_RESET;
    for (uint8_t i = 0, k = 0; i < 7; i++) {
        if (i == 3) continue;
        counts[k++] = (int16_t)((raw[2 * i] << 8) | raw[2 * i + 1]);
    }
    return MPU6050_OK;
}

/* mpu6050Read, saying on ``out`` why there is no sample: a failed transfer, or a reset chip (configured again).
 * false: no sample this time (the sketches then skip a seq number, which kfkit counts as a dropped sample). */
inline bool mpu6050ReadOrReport(int16_t counts[6], Print &out) {
    switch (mpu6050Read(counts)) {
    case MPU6050_OK:
        return true;
    case MPU6050_WAS_RESET:
        out.println(F("#ERROR,MPU6050 was reset (power glitch or loose VCC?): configured again"));
        mpu6050Configure();
        return false;
    default:
        out.println(F("#ERROR,MPU6050 read failed"));
        return false;
    }
}

#endif /* KFKIT_MPU6050_H */
