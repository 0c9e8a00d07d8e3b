/**
 * @file tilt_kf.h
 * @brief One tilt angle and its gyroscope bias, x = [angle; bias], fused by a Kalman filter.
 *
 * The C twin of kfkit.filters.TiltBiasKF (lab 05). C99, float32, no dynamic allocation, no
 * Arduino dependencies: it compiles on the host (tests/test_tilt_c.py) and on the board.
 *
 *   predict  angle = angle + (gyroRate - bias) * dt         A = [1 -dt; 0 1], B = [dt; 0]
 *            P = A P A' + diag(qAngle, qBias)
 *   update   y = accelAngle - angle, S = P00 + r, K = [P00; P01] / S
 *            x = x + K y, P = (I - K H) P                    H = [1 0]
 *
 * Units: rad, rad/s, s; qAngle rad², qBias (rad/s)², r rad². One TiltKf per axis (roll, pitch).
 * Yaw cannot be estimated this way: gravity does not reveal heading.
 */
#ifndef TILT_KF_H
#define TILT_KF_H

#include <stdbool.h>

#ifdef __cplusplus
extern "C" {
#endif

/** What the filter does with a sample whose accelerometer angle is not trusted (staticOk false). */
typedef enum {
    TiltKfGateNone,    /**< update anyway */
    TiltKfGateSkip,    /**< no update: coast on the gyroscope */
    TiltKfGateInflate, /**< update with r multiplied by inflation */
} TiltKfGate;

/** Tuning, in the units above. */
typedef struct {
    float qAngle;              /**< angle process noise per step, rad² (≈ (gyro noise σ · dt)², then tuned) */
    float qBias;               /**< bias random walk per step, (rad/s)² (much smaller than qAngle) */
    float r;                   /**< accelerometer angle variance, rad² (its variance at rest) */
    TiltKfGate gate;           /**< what to do when staticOk is false */
    float inflation;           /**< r multiplier for TiltKfGateInflate */
    float initialBiasVariance; /**< P11 after TiltKfReset, (rad/s)² */
} TiltKfSettings;

/** Defaults for an MPU6050 at 100 Hz, skip gate, tuned for motion: qAngle, qBias from the gyro's noise (lab 02). */
extern const TiltKfSettings tiltKfDefaultSettings;

/** Filter state. Treat as opaque; read it with the getters. */
typedef struct {
    TiltKfSettings settings;
    float samplePeriod; /**< s */
    float angle;        /**< rad */
    float bias;         /**< rad/s */
    float p00, p01, p11;
    float innovation;          /**< y of the last update, rad (0 when skipped) */
    float innovationVariance;  /**< S of the last update, rad² (0 when skipped) */
    bool updated;              /**< whether the last call made an update */
} TiltKf;

void TiltKfInitialise(TiltKf *const kf, const float samplePeriod, const TiltKfSettings *const settings);
void TiltKfReset(TiltKf *const kf, const float angle, const float bias);
void TiltKfSetCovariance(TiltKf *const kf, const float p00, const float p01, const float p11);
void TiltKfUpdate(TiltKf *const kf, const float gyroRate, const float accelAngle, const bool staticOk);
float TiltKfGetAngle(const TiltKf *const kf);
float TiltKfGetBias(const TiltKf *const kf);

/* Tilt from specific force in the body frame FRD (any unit: only ratios matter), rad:
 * roll = atan2(-fy, -fz), pitch = atan2(fx, sqrt(fy² + fz²)). */
float TiltKfAccelerometerRoll(const float fx, const float fy, const float fz);
float TiltKfAccelerometerPitch(const float fx, const float fy, const float fz);

/** true when | |f| - 1 | < tolerance, with f in units of g (the board is probably not accelerating). */
bool TiltKfAccelerometerStatic(const float fx, const float fy, const float fz, const float tolerance);

#ifdef __cplusplus
}
#endif

#endif
