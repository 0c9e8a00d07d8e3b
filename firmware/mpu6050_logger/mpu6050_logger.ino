// mpu6050_logger: raw MPU6050 (GY-521) samples at 100 Hz as kfkit serial protocol v1.
//
//   #KFKIT,1,board=mpu6050,rate_hz=100,fields=t_us|seq|ax|ay|az|gx|gy|gz,accel_fs_g=2,gyro_fs_dps=250
//   $1523456,0,-120,35,16390,12,-8,3*2E
//
// Samples are scheduled on micros() (every 10 000 µs, not "delay(10)" after the work), so the
// rate does not drift with the time the I2C read and the serial write take. Counts are raw int16:
// ±2 g (16384 LSB/g) and ±250 °/s (131 LSB/(°/s)); kfkit converts them (kfkit.sensors).
// Host commands: 'h' sends the header again, 's' stops/starts streaming. See README.md.
//
// Wiring (GY-521): VCC 5 V, GND, SDA → A4, SCL → A5 (Uno/Nano). Library: Wire (built in), and
// kfkit_protocol.h from firmware/common (arduino-cli --library ../common, or copy it here).

#include <Arduino.h>
#include <Wire.h>

#define KFKIT_BOARD "mpu6050"
#define KFKIT_RATE_HZ "100"
#define KFKIT_FIELDS "t_us|seq|ax|ay|az|gx|gy|gz"
#define KFKIT_HEADER_EXTRA "accel_fs_g=2,gyro_fs_dps=250"
#include <kfkit_protocol.h>

// --- settings -------------------------------------------------------------------------------------
static const uint32_t BAUD = 115200;
static const uint32_t SAMPLE_PERIOD_US = 10000;  // 100 Hz

// --- MPU6050 registers (RM-MPU-6000A-00 rev 4.2) --------------------------------------------------------
static const uint8_t MPU_ADDRESS = 0x68;  // AD0 low (0x69 with AD0 high)
static const uint8_t REG_SMPLRT_DIV = 0x19, REG_CONFIG = 0x1A, REG_GYRO_CONFIG = 0x1B, REG_ACCEL_CONFIG = 0x1C;
static const uint8_t REG_ACCEL_XOUT_H = 0x3B, REG_PWR_MGMT_1 = 0x6B, REG_WHO_AM_I = 0x75;

static uint32_t nextSampleUs;
static uint16_t seq;
static bool streaming = true;

static void writeRegister(uint8_t reg, uint8_t value) {
    Wire.beginTransmission(MPU_ADDRESS);
    Wire.write(reg);
    Wire.write(value);
    Wire.endTransmission();
}

static bool readRegisters(uint8_t reg, uint8_t *buffer, uint8_t count) {
    Wire.beginTransmission(MPU_ADDRESS);
    Wire.write(reg);
    if (Wire.endTransmission(false) != 0) return false;
    if (Wire.requestFrom(MPU_ADDRESS, count) != count) return false;
    for (uint8_t i = 0; i < count; i++) buffer[i] = Wire.read();
    return true;
}

// Nothing to stream: say why, once a second (kfkit shows '#' notes in its errors).
static void failNoSensor(bool answered, uint8_t who) {
    for (;;) {
        if (answered) {
            Serial.print(F("#ERROR,the chip at 0x68 has WHO_AM_I 0x"));
            Serial.print(who, HEX);
            Serial.println(F(", not 0x68: not an MPU6050 (MPU6500/9250 clones read 0x70-0x73)"));
        } else {
            Serial.println(F("#ERROR,no MPU6050 answers at 0x68: check VCC, GND, SDA (A4), SCL (A5) and that AD0 is low"));
        }
        delay(1000);
    }
}

void setup() {
    Serial.begin(BAUD);
    Wire.begin();
    Wire.setClock(400000);  // 400 kHz I2C: the 14-byte read takes ~0.4 ms
    uint8_t who = 0;
    const bool answered = readRegisters(REG_WHO_AM_I, &who, 1);
    if (!answered || who != 0x68) failNoSensor(answered, who);
    writeRegister(REG_PWR_MGMT_1, 0x01);    // wake up, clock from the x gyro PLL
    writeRegister(REG_CONFIG, 0x03);        // DLPF 44 Hz accel / 42 Hz gyro: below Nyquist at 100 Hz
    writeRegister(REG_SMPLRT_DIV, 9);       // 1 kHz / (1 + 9) = 100 Hz internal sample rate
    writeRegister(REG_GYRO_CONFIG, 0x00);   // ±250 °/s
    writeRegister(REG_ACCEL_CONFIG, 0x00);  // ±2 g
    kfkitSendHeader(Serial);
    nextSampleUs = micros();
}

void loop() {
    if (kfkitHandleCommands(Serial, &streaming)) nextSampleUs = micros();  // 'h' header, 's' stop/start
    // Signed difference: correct across the 32-bit micros() wrap (every 71.6 minutes).
    if (!streaming || (int32_t)(micros() - nextSampleUs) < 0) return;
    const uint32_t tUs = nextSampleUs;
    nextSampleUs += SAMPLE_PERIOD_US;
    if ((int32_t)(micros() - nextSampleUs) > 0) nextSampleUs = micros() + SAMPLE_PERIOD_US;  // fell behind: skip

    uint8_t raw[14];
    if (!readRegisters(REG_ACCEL_XOUT_H, raw, sizeof raw)) {
        Serial.println(F("#ERROR,MPU6050 read failed"));
        seq++;  // the host sees a seq gap: a dropped sample
        return;
    }
    int16_t counts[7];  // ax ay az temperature gx gy gz, big-endian registers
    for (uint8_t i = 0; i < 7; i++) counts[i] = (int16_t)((raw[2 * i] << 8) | raw[2 * i + 1]);
    const int32_t sample[8] = {(int32_t)tUs, seq++, counts[0], counts[1], counts[2], counts[4], counts[5], counts[6]};
    kfkitSendSample(Serial, sample, 8);
}
