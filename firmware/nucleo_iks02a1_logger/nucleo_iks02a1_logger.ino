// nucleo_iks02a1_logger: STM32 Nucleo (e.g. F411RE) + X-NUCLEO-IKS02A1, raw counts as kfkit protocol v1.
//
//   #KFKIT,1,board=nucleo-iks02a1,rate_hz=104,fields=t_us|seq|ax|ay|az|gx|gy|gz|mx|my|mz|mag_new,accel_fs_g=4,gyro_fs_dps=500,mag_rate_hz=50
//   $1523456,0,-15,40,8190,3,-2,1,-132,-18,301,1*24
//
// ISM330DHCX accelerometer ±4 g and gyroscope ±500 °/s at 104 Hz; IIS2MDC magnetometer at 50 Hz.
// The magnetometer is slower than the sample rate, so every line repeats its last reading and the
// last field, mag_new, says whether mx,my,mz is a new reading (1) or the previous one again (0).
// kfkit turns mag_new = 0 rows into empty magnetometer cells (NaN): "no new sample".
// Samples are scheduled on micros() every 1e6/104 µs (fractional period kept in a phase
// accumulator, so the mean rate is exactly 104 Hz). Host commands: 'h' header, 's' stop/start.
//
// Board: STM32duino core (STMicroelectronics:stm32), Nucleo-64, part number Nucleo F411RE.
// Libraries: STM32duino ISM330DHCX 2.x and STM32duino IIS2MDC 2.x (the API with begin(); 1.x differs),
// kfkit_protocol.h from firmware/common.

#include <Arduino.h>
#include <Wire.h>
#include <ISM330DHCXSensor.h>
#include <IIS2MDCSensor.h>

#define KFKIT_BOARD "nucleo-iks02a1"
#define KFKIT_RATE_HZ "104"
#define KFKIT_FIELDS "t_us|seq|ax|ay|az|gx|gy|gz|mx|my|mz|mag_new"
#define KFKIT_HEADER_EXTRA "accel_fs_g=4,gyro_fs_dps=500,mag_rate_hz=50"
#include <kfkit_protocol.h>

// --- settings -------------------------------------------------------------------------------------------
static const uint32_t BAUD = 115200;
static const uint32_t RATE_HZ = 104;
static const float ACCEL_ODR_HZ = 104.0f, GYRO_ODR_HZ = 104.0f, MAG_ODR_HZ = 50.0f;
static const int32_t ACCEL_FS_G = 4, GYRO_FS_DPS = 500;

// The X-NUCLEO-IKS02A1 sits on the Arduino header, whose I2C (D14 SDA, D15 SCL; PB9, PB8 on the
// F411RE) is STM32duino's default Wire on Nucleo-64 boards, as in ST's X-NUCLEO-IKS02A1 examples.
static ISM330DHCXSensor accGyr(&Wire);  // default address ISM330DHCX_I2C_ADD_H (SA0 high), as the shield wires it
static IIS2MDCSensor mag(&Wire);

static uint32_t nextSampleUs, phase;  // phase: remainder of 1e6 / RATE_HZ, in 1/RATE_HZ µs
static uint16_t seq;
static bool streaming = true;
static int16_t lastMag[3];

static void fail(const __FlashStringHelper *why) {
    for (;;) {  // nothing to stream: say why once a second (kfkit shows '#' notes in its errors)
        Serial.print(F("#ERROR,"));
        Serial.println(why);
        delay(1000);
    }
}

void setup() {
    Serial.begin(BAUD);
    Wire.begin();
    Wire.setClock(400000);
    if (accGyr.begin() != ISM330DHCX_OK || accGyr.ACC_Enable() != ISM330DHCX_OK || accGyr.GYRO_Enable() != ISM330DHCX_OK)
        fail(F("ISM330DHCX not found: is the X-NUCLEO-IKS02A1 seated on the Arduino header?"));
    accGyr.ACC_SetOutputDataRate(ACCEL_ODR_HZ);
    accGyr.ACC_SetFullScale(ACCEL_FS_G);
    accGyr.GYRO_SetOutputDataRate(GYRO_ODR_HZ);
    accGyr.GYRO_SetFullScale(GYRO_FS_DPS);
    if (mag.begin() != IIS2MDC_OK || mag.Enable() != IIS2MDC_OK) fail(F("IIS2MDC not found"));
    mag.SetOutputDataRate(MAG_ODR_HZ);
    kfkitSendHeader(Serial);
    nextSampleUs = micros();
}

static void advanceSchedule() {  // next += 1e6/104 µs = 9615 µs + 40/104 µs, exactly on average
    nextSampleUs += 1000000u / RATE_HZ;
    phase += 1000000u % RATE_HZ;
    if (phase >= RATE_HZ) {
        phase -= RATE_HZ;
        nextSampleUs += 1;
    }
}

void loop() {
    if (kfkitHandleCommands(Serial, &streaming)) nextSampleUs = micros();  // 'h' header, 's' stop/start
    // Signed difference: correct across the 32-bit micros() wrap (every 71.6 minutes).
    if (!streaming || (int32_t)(micros() - nextSampleUs) < 0) return;
    // A stall (an I2C transfer that hung until its timeout) can pass whole periods: those samples were not taken.
    // Their slots are skipped and counted in seq, so kfkit counts them as dropped and t_us stays on the grid.
    while ((int32_t)(micros() - nextSampleUs) >= (int32_t)(1000000u / RATE_HZ)) {
        advanceSchedule();
        seq++;
    }
    const uint32_t tUs = nextSampleUs;
    advanceSchedule();

    int16_t acc[3], gyr[3];
    if (accGyr.ACC_GetAxesRaw(acc) != ISM330DHCX_OK || accGyr.GYRO_GetAxesRaw(gyr) != ISM330DHCX_OK) {
        Serial.println(F("#ERROR,ISM330DHCX read failed"));
        seq++;  // the host sees a seq gap: a dropped sample
        return;
    }
    uint8_t magReady = 0;
    if (mag.GetDRDYStatus(&magReady) == IIS2MDC_OK && magReady) {
        int16_t m[3];
        if (mag.GetAxesRaw(m) == IIS2MDC_OK) {
            lastMag[0] = m[0], lastMag[1] = m[1], lastMag[2] = m[2];
        } else {
            magReady = 0;
        }
    }
    const int32_t sample[12] = {(int32_t)tUs, seq++, acc[0], acc[1], acc[2], gyr[0], gyr[1], gyr[2],
                                lastMag[0], lastMag[1], lastMag[2], magReady ? 1 : 0};
    kfkitSendSample(Serial, sample, 12);
}
