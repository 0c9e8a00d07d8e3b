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
// kfkit_protocol.h and kfkit_mpu6050.h from firmware/common (arduino-cli --library ../common, or copy them here).

#include <Arduino.h>
#include <Wire.h>

#define KFKIT_BOARD "mpu6050"
#define KFKIT_RATE_HZ "100"
#define KFKIT_FIELDS "t_us|seq|ax|ay|az|gx|gy|gz"
#define KFKIT_HEADER_EXTRA "accel_fs_g=2,gyro_fs_dps=250"
#include <kfkit_protocol.h>
#include <kfkit_mpu6050.h>

// --- settings -------------------------------------------------------------------------------------
static const uint32_t BAUD = 115200;
static const uint32_t SAMPLE_PERIOD_US = 10000;  // 100 Hz

static uint32_t nextSampleUs;
static uint16_t seq;
static bool streaming = true;

void setup() {
    Serial.begin(BAUD);
    mpu6050Begin(Serial);  // reports a missing or wrong chip once a second instead of streaming
    kfkitSendHeader(Serial);
    nextSampleUs = micros();
}

void loop() {
    if (kfkitHandleCommands(Serial, &streaming)) nextSampleUs = micros();  // 'h' header, 's' stop/start
    // Signed difference: correct across the 32-bit micros() wrap (every 71.6 minutes).
    if (!streaming || (int32_t)(micros() - nextSampleUs) < 0) return;
    // A stall (an I2C transfer that hung until its timeout) can pass whole periods: those samples were not taken.
    // Their slots are skipped and counted in seq, so kfkit counts them as dropped and t_us stays on the grid.
    while ((int32_t)(micros() - nextSampleUs) >= (int32_t)SAMPLE_PERIOD_US) {
        nextSampleUs += SAMPLE_PERIOD_US;
        seq++;
    }
    const uint32_t tUs = nextSampleUs;
    nextSampleUs += SAMPLE_PERIOD_US;

    int16_t counts[6];  // ax ay az gx gy gz
    if (!mpu6050ReadOrReport(counts, Serial)) {  // says why on Serial; a reset sensor is configured again
        seq++;  // the host sees a seq gap: a dropped sample
        return;
    }
    const int32_t sample[8] = {(int32_t)tUs, seq++, counts[0], counts[1], counts[2], counts[3], counts[4], counts[5]};
    kfkitSendSample(Serial, sample, 8);
}
