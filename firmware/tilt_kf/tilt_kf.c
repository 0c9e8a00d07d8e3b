/**
 * @file tilt_kf.c
 * @brief [angle; gyro bias] Kalman filter for one tilt axis. See tilt_kf.h.
 */
#include "tilt_kf.h"

#include <math.h>

/* Tuned for motion (the board is used while it moves: kfkit demo tilt): qAngle and qBias are the MPU6050's own gyro
 * noise, N^2 dt and K^2 dt from lab 02's calibration (Van Loan), not lab 05's tuning on the holds (qAngle 2e-6, which
 * follows every push of the hand through the gate). See kfkit.filters.TiltBiasKFSettings and tilt_kf/README.md. */
const TiltKfSettings tiltKfDefaultSettings = {
    .qAngle = 8.0e-11f,
    .qBias = 6.0e-11f,
    .r = 1.6e-5f,
    .gate = TiltKfGateSkip,
    .inflation = 100.0f,
    .initialBiasVariance = 0.01f,
};

void TiltKfInitialise(TiltKf *const kf, const float samplePeriod, const TiltKfSettings *const settings) {
    kf->settings = *settings;
    kf->samplePeriod = samplePeriod;
    TiltKfReset(kf, 0.0f, 0.0f);
}

/** Angle and bias as given; P = diag(r, initialBiasVariance). */
void TiltKfReset(TiltKf *const kf, const float angle, const float bias) {
    kf->angle = angle;
    kf->bias = bias;
    TiltKfSetCovariance(kf, kf->settings.r, 0.0f, kf->settings.initialBiasVariance);
    kf->innovation = 0.0f;
    kf->innovationVariance = 0.0f;
    kf->updated = false;
}

void TiltKfSetCovariance(TiltKf *const kf, const float p00, const float p01, const float p11) {
    kf->p00 = p00;
    kf->p01 = p01;
    kf->p11 = p11;
}

void TiltKfUpdate(TiltKf *const kf, const float gyroRate, const float accelAngle, const bool staticOk) {
    const float dt = kf->samplePeriod;
    const TiltKfSettings *const s = &kf->settings;

    /* Predict: angle += (rate - bias) dt; P = A P A' + Q written out for the symmetric P. */
    kf->angle += (gyroRate - kf->bias) * dt;
    kf->p00 += dt * (dt * kf->p11 - 2.0f * kf->p01) + s->qAngle;
    kf->p01 -= dt * kf->p11;
    kf->p11 += s->qBias;

    kf->updated = false;
    kf->innovation = 0.0f;
    kf->innovationVariance = 0.0f;
    if (isnan(accelAngle) || (!staticOk && s->gate == TiltKfGateSkip)) {
        return;
    }

    /* Update with the accelerometer angle: H = [1 0]. */
    const float r = (!staticOk && s->gate == TiltKfGateInflate) ? s->r * s->inflation : s->r;
    const float y = accelAngle - kf->angle;
    const float S = kf->p00 + r;
    const float k0 = kf->p00 / S;
    const float k1 = kf->p01 / S;
    kf->angle += k0 * y;
    kf->bias += k1 * y;
    kf->p11 -= k1 * kf->p01; /* uses the prior p01: update it before p01 */
    kf->p01 -= k0 * kf->p01;
    kf->p00 -= k0 * kf->p00;
    kf->innovation = y;
    kf->innovationVariance = S;
    kf->updated = true;
}

float TiltKfGetAngle(const TiltKf *const kf) {
    return kf->angle;
}

float TiltKfGetBias(const TiltKf *const kf) {
    return kf->bias;
}

float TiltKfAccelerometerRoll(const float fx, const float fy, const float fz) {
    (void) fx;
    return atan2f(-fy, -fz);
}

float TiltKfAccelerometerPitch(const float fx, const float fy, const float fz) {
    return atan2f(fx, sqrtf(fy * fy + fz * fz));
}

bool TiltKfAccelerometerStatic(const float fx, const float fy, const float fz, const float tolerance) {
    return fabsf(sqrtf(fx * fx + fy * fy + fz * fz) - 1.0f) < tolerance;
}
