// mpu6050_tilt_kf: roll and pitch of an MPU6050 (GY-521) from two [angle, gyro bias] Kalman
// filters (firmware/tilt_kf), at a fixed 100 Hz, streamed as kfkit serial protocol v1.
//
// Every 10 ms: read the MPU6050, send the raw sample line, run both filters, send
//   $ATT,<roll_deg>,<pitch_deg>*HH
// The first 2 s after start measure the gyro bias: keep the board still and flat. See README.md.
//
// Wiring (GY-521): VCC 5 V (or 3.3 V), GND, SDA → A4, SCL → A5 on an Uno/Nano (SDA/SCL pins elsewhere).
// Libraries: Wire (built in); firmware/tilt_kf and firmware/common (kfkit_protocol.h, kfkit_mpu6050.h), passed to
// arduino-cli with --library (see README.md).

#include <Arduino.h>
#include <Wire.h>
#include <math.h>

// The header this sketch sends (kfkit_protocol.h builds it from these macros).
#define KFKIT_BOARD "mpu6050"
#define KFKIT_RATE_HZ "100"
#define KFKIT_FIELDS "t_us|seq|ax|ay|az|gx|gy|gz"
#define KFKIT_HEADER_EXTRA "accel_fs_g=2,gyro_fs_dps=250,messages=ATT,filter=tilt_kf"
#include <kfkit_protocol.h>
#include <kfkit_mpu6050.h>
#include <tilt_kf.h>

// --- settings ---------------------------------------------------------------------------------
static const uint32_t BAUD = 115200;
static const uint32_t SAMPLE_PERIOD_US = 10000;  // 100 Hz
static const float SAMPLE_PERIOD_S = SAMPLE_PERIOD_US * 1e-6f;
static const uint16_t BIAS_SAMPLES = 200;        // 2 s still at the start
static const float STATIC_TOLERANCE_G = 0.05f;   // | |f| - 1 g | below this: trust the accelerometer
static const float ROLL_MIN_G = 0.5f;            // no roll update while sqrt(fy² + fz²) < 0.5 g (pitch beyond ±60°)

// Six-face correction from lab 02 (body frame, g): f = (f_raw - ACCEL_BIAS_G) / ACCEL_SCALE.
static const float ACCEL_BIAS_G[3] = {0.0f, 0.0f, 0.0f};
static const float ACCEL_SCALE[3] = {1.0f, 1.0f, 1.0f};

// --- MPU6050 counts (kfkit_mpu6050.h sets ±2 g and ±250 °/s) ----------------------------------------
static const float ACCEL_LSB_PER_G = 16384.0f;  // ±2 g
static const float GYRO_LSB_PER_DPS = 131.0f;   // ±250 °/s
static const float DEG_PER_RAD = 57.29577951f;

static TiltKf rollKf, pitchKf;
static uint32_t nextSampleUs;
static uint16_t seq;
static uint16_t biasCount;
static float gyroSum[2];
static bool streaming = true;
static bool filtersRunning = false;

static void startFilters() {
    biasCount = 0;
    gyroSum[0] = gyroSum[1] = 0.0f;
    filtersRunning = false;
    Serial.println(F("#NOTE,measuring gyro bias: keep the board still for 2 s"));
}

void setup() {
    Serial.begin(BAUD);
    mpu6050Begin(Serial);  // reports a missing or wrong chip once a second instead of streaming

    TiltKfInitialise(&rollKf, SAMPLE_PERIOD_S, &tiltKfDefaultSettings);
    TiltKfInitialise(&pitchKf, SAMPLE_PERIOD_S, &tiltKfDefaultSettings);
    kfkitSendHeader(Serial);
    startFilters();
    nextSampleUs = micros();
}

void loop() {
    // 'h' header, 's' stop/start; the board may have moved while stopped, so a restart measures the bias again
    if (kfkitHandleCommands(Serial, &streaming) && streaming) {
        startFilters();
        nextSampleUs = micros();
    }
    if (!streaming || (int32_t) (micros() - nextSampleUs) < 0) return;
    // A stall (an I2C transfer that hung until its timeout) can pass whole periods: those samples were not taken.
    // Their slots are skipped and counted in seq, so kfkit counts them as dropped and t_us stays on the grid.
    while ((int32_t) (micros() - nextSampleUs) >= (int32_t) SAMPLE_PERIOD_US) {
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
    const int32_t sample[8] = {(int32_t) tUs, seq++, counts[0], counts[1], counts[2], counts[3], counts[4], counts[5]};
    kfkitSendSample(Serial, sample, 8);

    // Body frame FRD: the sensor's z points up when the board lies flat, so y and z flip (M_bs = diag(1, -1, -1)).
    float f[3] = {counts[0] / ACCEL_LSB_PER_G, -counts[1] / ACCEL_LSB_PER_G, -counts[2] / ACCEL_LSB_PER_G};
    for (uint8_t i = 0; i < 3; i++) f[i] = (f[i] - ACCEL_BIAS_G[i]) / ACCEL_SCALE[i];
    const float p = counts[3] / GYRO_LSB_PER_DPS / DEG_PER_RAD;   // roll rate, rad/s
    const float q = -counts[4] / GYRO_LSB_PER_DPS / DEG_PER_RAD;  // pitch rate, rad/s
    const float roll = TiltKfAccelerometerRoll(f[0], f[1], f[2]);
    const float pitch = TiltKfAccelerometerPitch(f[0], f[1], f[2]);

    if (!filtersRunning) {  // stationary start: the mean rate is the gyro bias
        gyroSum[0] += p;
        gyroSum[1] += q;
        if (++biasCount < BIAS_SAMPLES) return;
        TiltKfReset(&rollKf, roll, gyroSum[0] / BIAS_SAMPLES);
        TiltKfReset(&pitchKf, pitch, gyroSum[1] / BIAS_SAMPLES);
        filtersRunning = true;
    } else {
        const bool staticOk = TiltKfAccelerometerStatic(f[0], f[1], f[2], STATIC_TOLERANCE_G);
        const bool rollOk = staticOk && sqrtf(f[1] * f[1] + f[2] * f[2]) >= ROLL_MIN_G;
        TiltKfUpdate(&rollKf, p, roll, rollOk);
        TiltKfUpdate(&pitchKf, q, pitch, staticOk);
    }
    const float attitude[2] = {TiltKfGetAngle(&rollKf) * DEG_PER_RAD, TiltKfGetAngle(&pitchKf) * DEG_PER_RAD};
    kfkitSendMessage(Serial, "ATT", attitude, 2);
}
