/*
 * uno_mpu6050.c: an Arduino Uno (ATmega328P at 16 MHz, simulated by simavr) with an MPU6050 on its I2C bus
 * and its serial port on a pseudo-terminal, to run the kit's real AVR images without a board.
 *
 *   uno_mpu6050 FIRMWARE.elf FRAMES [--loop] [--realtime] [--log FILE] [--watch ADDR:LEN]... [--fault KIND@S[+D]]...
 *
 * FRAMES      one sensor sample per line, "ax ay az gx gy gz" (int16 counts in the sensor frame), played at
 *             the rate the firmware configures (1 or 8 kHz / (1 + SMPLRT_DIV)); --loop starts again at the end,
 *             otherwise the last frame is held
 * --realtime  hold the AVR's time to the wall clock (for watching); by default it runs as fast as it can
 * --log       one line per event, times in AVR cycles (16 per µs): "boot", "write CYCLE REG VALUE",
 *             "rate CYCLE HZ", "read CYCLE FRAME ax ay az gx gy gz [WATCH…]" (FRAME -1: the sensor was asleep),
 *             "nack CYCLE", "fault CYCLE KIND", "end CYCLE"
 * --watch     with every "read", the LEN bytes of AVR RAM at ADDR (data space, hex) as they were before the
 *             read (e.g. a sketch's filter state, its address from avr-nm)
 * --fault     nack@S[+D]   the sensor does not acknowledge its address from S s (after power-on) for D s
 *                          (for ever without +D): nack@0 is a sensor that is not there
 *             stuck@S+D    the bus hangs from S s for D s: a transfer started then never completes
 *             reset@S      the sensor resets at S s: registers back to their power-on values, asleep
 *
 * stdout: "pty /dev/pts/N" once the port exists. The AVR powers on when the host sends its first byte (as an
 * Uno resets when its port opens; kfkit sends 'h'); the emulator ends when its stdin closes.
 *
 * Time is the AVR's cycle count, never the wall clock: the simulation runs as fast as the machine allows, and
 * when the host reads slowly and the pty is full it waits (the AVR stands still), so no byte is ever dropped.
 * See README.md for what is modelled and what is not.
 */
#define _DEFAULT_SOURCE /* cfmakeraw */
#define _XOPEN_SOURCE 600 /* posix_openpt, grantpt, unlockpt, ptsname */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <avr_twi.h>
#include <avr_uart.h>
#include <sim_avr.h>
#include <sim_elf.h>
#include <sim_io.h>
#include <sim_irq.h>

#define MPU6050_ADDRESS 0x68
enum { REG_SMPLRT_DIV = 0x19, REG_CONFIG = 0x1A, REG_ACCEL_XOUT_H = 0x3B, REG_PWR_MGMT_1 = 0x6B, REG_WHO_AM_I = 0x75 };
#define PWR_MGMT_1_SLEEP 0x40
#define HOST_POLL_CYCLES 16000u /* look at the host's side every 1 ms of AVR time */
#define MAX_WATCHES 4
#define MAX_FAULTS 8
#define F_CPU 16000000u /* an Uno's crystal */
#define USAGE "usage: uno_mpu6050 FIRMWARE.elf FRAMES [--loop] [--realtime] [--log FILE] [--watch ADDR:LEN] [--fault KIND@S[+D]]"

typedef enum { FAULT_NACK, FAULT_STUCK, FAULT_RESET } FaultKind;
static const char *const faultNames[] = {"nack", "stuck", "reset"};

typedef struct {
    FaultKind kind;
    avr_cycle_count_t start, end; /* end: the first cycle after it (UINT64_MAX: for ever) */
} Fault;

typedef struct {
    uint16_t address, length;
} Watch;

/* The MPU6050: a register file, the register pointer of the current transfer, and its sample clock. */
typedef struct {
    uint8_t reg[128];
    uint8_t pointer;      /* next register to read or write (auto-increments, as the chip's does) */
    uint8_t selected;     /* the address byte (with R/W) of the transfer addressed to it, 0 when not addressed */
    uint8_t pointerSet;   /* in a write transfer: the first byte (the register pointer) has arrived */
    int anchored;         /* woken up at least once: the recording plays from anchor on */
    avr_cycle_count_t anchor;
    uint32_t rateHz1000;  /* configured sample rate × 1000, for the log */
} Mpu6050;

static avr_t *avr;
static avr_twi_t *twi;
static avr_irq_t *twiInput, *uartInput;
static Mpu6050 mpu;
static int16_t (*frames)[6];
static long frameCount;
static int loopFrames;
static FILE *logFile;
static Watch watches[MAX_WATCHES];
static int watchCount;
static Fault faults[MAX_FAULTS];
static int faultCount;
static int realtime;
static struct timespec bootTime; /* --realtime: the wall clock at power-on */
static int master = -1; /* the pty's master side: the board's end of the serial cable */
static int quit; /* the host closed our stdin: end */
static uint8_t serialOut[4096];
static size_t serialOutLength;

static void die(const char *what) {
    fprintf(stderr, "uno_mpu6050: %s%s%s\n", what, errno ? ": " : "", errno ? strerror(errno) : "");
    exit(2);
}

static int faultActive(FaultKind kind) {
    for (int i = 0; i < faultCount; i++)
        if (faults[i].kind == kind && avr->cycle >= faults[i].start && avr->cycle < faults[i].end) return 1;
    return 0;
}

/* --- the MPU6050 ------------------------------------------------------------------------------------- */

/* Power-on values (register map RM-MPU-6000A-00 rev 4.2): all 0 but PWR_MGMT_1 (asleep) and WHO_AM_I. */
static void mpuPowerOn(void) {
    memset(mpu.reg, 0, sizeof mpu.reg);
    mpu.reg[REG_PWR_MGMT_1] = PWR_MGMT_1_SLEEP;
    mpu.reg[REG_WHO_AM_I] = MPU6050_ADDRESS;
    mpu.selected = 0;
}

/* Samples per second × 1000: gyro output rate (8 kHz with the DLPF off, CONFIG 0 or 7, else 1 kHz) / (1 + SMPLRT_DIV). */
static uint32_t mpuRateHz1000(void) {
    const uint8_t dlpf = mpu.reg[REG_CONFIG] & 7;
    const uint32_t gyroRate = (dlpf == 0 || dlpf == 7) ? 8000u : 1000u;
    return gyroRate * 1000u / (1u + mpu.reg[REG_SMPLRT_DIV]);
}

/* The frame the sensor holds now: frame 0 from wake-up (a first read gets a sample, not a start-up zero), frame k
 * from anchor + (k − ½) periods. A sketch on its own schedule of the same period reads at a fixed phase: the kit's
 * read 1 ms (logger) and 3 ms (tilt) before an edge, with ±20 µs of jitter, so each frame is read once. */
static long mpuFrameIndex(void) {
    const uint64_t elapsed = avr->cycle - mpu.anchor;
    const uint64_t periods2 = elapsed * 2u * mpuRateHz1000() / (1000u * (uint64_t)avr->frequency); /* 2 × periods */
    const long k = (long)((periods2 + 1u) / 2u);
    if (k < frameCount) return k;
    return loopFrames ? k % frameCount : frameCount - 1;
}

static void logWatches(void) {
    for (int w = 0; w < watchCount; w++) {
        fputc(' ', logFile);
        for (uint16_t i = 0; i < watches[w].length; i++) fprintf(logFile, "%02x", avr->data[watches[w].address + i]);
    }
}

/* A read transfer starts: latch the current sample into the data registers (the chip's burst reads are
 * consistent: its shadow registers do not change during a read) and log it when it starts at ACCEL_XOUT_H. */
static void mpuStartRead(void) {
    const int asleep = (mpu.reg[REG_PWR_MGMT_1] & PWR_MGMT_1_SLEEP) != 0;
    const long k = asleep || !mpu.anchored ? -1 : mpuFrameIndex();
    if (k >= 0) {
        /* ax ay az, temperature (0), gx gy gz: big-endian, from 0x3B */
        const int16_t words[7] = {frames[k][0], frames[k][1], frames[k][2], 0, frames[k][3], frames[k][4], frames[k][5]};
        for (int i = 0; i < 7; i++) {
            mpu.reg[REG_ACCEL_XOUT_H + 2 * i] = (uint8_t)((uint16_t)words[i] >> 8);
            mpu.reg[REG_ACCEL_XOUT_H + 2 * i + 1] = (uint8_t)((uint16_t)words[i] & 0xFF);
        }
    }
    if (logFile && mpu.pointer == REG_ACCEL_XOUT_H) {
        fprintf(logFile, "read %llu %ld", (unsigned long long)avr->cycle, k);
        for (int i = 0; i < 7; i++) {
            if (i == 3) continue;
            const uint8_t *r = &mpu.reg[REG_ACCEL_XOUT_H + 2 * i];
            fprintf(logFile, " %d", (int16_t)(((uint16_t)r[0] << 8) | r[1]));
        }
        logWatches();
        fputc('\n', logFile);
    }
}

static void mpuWrite(uint8_t value) {
    const uint8_t r = mpu.pointer & 0x7F;
    if (logFile) fprintf(logFile, "write %llu 0x%02X 0x%02X\n", (unsigned long long)avr->cycle, r, value);
    if (r == REG_WHO_AM_I) return; /* read-only */
    mpu.reg[r] = value;
    if (r == REG_PWR_MGMT_1 && !(value & PWR_MGMT_1_SLEEP) && !mpu.anchored) {
        mpu.anchored = 1; /* the recording starts at the first wake-up and plays on through later resets */
        mpu.anchor = avr->cycle;
    }
    if (mpuRateHz1000() != mpu.rateHz1000 && logFile) {
        mpu.rateHz1000 = mpuRateHz1000();
        fprintf(logFile, "rate %llu %.3f\n", (unsigned long long)avr->cycle, mpu.rateHz1000 / 1000.0);
    }
    mpu.pointer++;
}

static void twiReply(uint8_t msg, uint8_t address, uint8_t data) {
    avr_raise_irq(twiInput, avr_twi_irq_msg(msg, address, data));
}

/* What the AVR's TWI (the I2C master) puts on the bus, one message per condition or byte (simavr's model):
 * START with the address byte, a data byte written (WRITE) or wanted (READ), STOP. An acknowledge is an
 * ACK message back; a byte read is a READ message back with the data. */
static void onTwiBus(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq, (void)param;
    avr_twi_msg_irq_t m;
    m.u.v = value;
    if (faultActive(FAULT_STUCK)) return;
    if (m.u.twi.msg & TWI_COND_STOP) mpu.selected = 0;
    if (m.u.twi.msg & TWI_COND_START) {
        mpu.selected = 0;
        if ((m.u.twi.addr >> 1) != MPU6050_ADDRESS) return;
        if (faultActive(FAULT_NACK)) {
            if (logFile) fprintf(logFile, "nack %llu\n", (unsigned long long)avr->cycle);
            return; /* no ACK: the master reads a NACK */
        }
        mpu.selected = m.u.twi.addr;
        mpu.pointerSet = 0;
        twiReply(TWI_COND_ACK, mpu.selected, 1);
        if (mpu.selected & 1) mpuStartRead();
        return;
    }
    if (!mpu.selected) return;
    if (m.u.twi.msg & TWI_COND_WRITE) {
        if (!mpu.pointerSet) {
            mpu.pointer = m.u.twi.data & 0x7F;
            mpu.pointerSet = 1;
        } else {
            mpuWrite(m.u.twi.data);
        }
        twiReply(TWI_COND_ACK, mpu.selected, 1);
    } else if (m.u.twi.msg & TWI_COND_READ) {
        twiReply(TWI_COND_READ, mpu.selected, mpu.reg[mpu.pointer & 0x7F]);
        mpu.pointer++;
    }
}

/* A stuck bus: the AVR's TWI waits for the bus for ever, i.e. the state change simavr has scheduled for what
 * was just written to TWCR (START sent, byte sent, ...) never happens and TWINT stays low. This hook runs
 * after simavr's own TWCR handler and cancels the state change it scheduled. */
static void onTwcrWrite(struct avr_t *a, avr_io_addr_t address, uint8_t value, void *param) {
    (void)address, (void)value, (void)param;
    if (!faultActive(FAULT_STUCK)) return;
    avr_cycle_timer_slot_p slot = a->cycle_timers.timer;
    while (slot) {
        if (slot->param == twi) {
            avr_cycle_timer_cancel(a, slot->timer, twi);
            slot = a->cycle_timers.timer; /* the list has changed: look again from its start */
        } else {
            slot = slot->next;
        }
    }
}

static avr_cycle_count_t onFaultStart(struct avr_t *a, avr_cycle_count_t when, void *param) {
    const Fault *f = param;
    (void)when;
    if (logFile) fprintf(logFile, "fault %llu %s\n", (unsigned long long)a->cycle, faultNames[f->kind]);
    if (f->kind == FAULT_RESET) mpuPowerOn();
    return 0;
}

/* --- the serial port: UART0 ↔ pty ------------------------------------------------------------------------ */

/* Wait until the pty takes more (the host reads) or the emulator's stdin closes (then end). */
static void waitForHost(short events) {
    struct pollfd fds[2] = {{master, events, 0}, {STDIN_FILENO, POLLIN, 0}};
    if (poll(fds, 2, -1) < 0 && errno != EINTR) die("poll");
    if (fds[1].revents) {
        char c;
        if (read(STDIN_FILENO, &c, 1) <= 0) quit = 1; /* stdin closed: the host is done with us */
    }
}

static void flushSerial(void) {
    size_t done = 0;
    while (done < serialOutLength && !quit) {
        const ssize_t n = write(master, serialOut + done, serialOutLength - done);
        if (n > 0) {
            done += (size_t)n;
        } else if (n < 0 && errno != EAGAIN && errno != EINTR) {
            die("writing to the pty");
        } else {
            waitForHost(POLLOUT); /* the pty is full: the AVR waits, its clock stands still */
        }
    }
    serialOutLength = 0;
}

static void onUartByte(struct avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq, (void)param;
    serialOut[serialOutLength++] = (uint8_t)value;
    if (value == '\n' || serialOutLength == sizeof serialOut) flushSerial();
}

/* Every millisecond of AVR time: pass what the host typed to the UART, and end when stdin closes. */
static avr_cycle_count_t pollHost(struct avr_t *a, avr_cycle_count_t when, void *param) {
    (void)param;
    uint8_t input[64];
    const ssize_t n = read(master, input, sizeof input);
    for (ssize_t i = 0; i < n; i++) avr_raise_irq(uartInput, input[i]);
    struct pollfd in = {STDIN_FILENO, POLLIN, 0};
    if (poll(&in, 1, 0) > 0) {
        char c;
        if (read(STDIN_FILENO, &c, 1) <= 0) quit = 1;
    }
    if (realtime) { /* ahead of the wall clock: wait until it catches up */
        struct timespec now;
        clock_gettime(CLOCK_MONOTONIC, &now);
        const double ahead = (double)a->cycle / F_CPU - (double)(now.tv_sec - bootTime.tv_sec) -
                             (now.tv_nsec - bootTime.tv_nsec) * 1e-9;
        if (ahead > 0) nanosleep(&(struct timespec){0, (long)(ahead * 1e9)}, NULL);
    }
    return when + HOST_POLL_CYCLES;
}

static void openPty(void) {
    master = posix_openpt(O_RDWR | O_NOCTTY);
    if (master < 0 || grantpt(master) || unlockpt(master)) die("cannot open a pseudo-terminal");
    const char *name = ptsname(master);
    /* Hold the slave side open in raw mode: no echo (the AVR would read its own "h" and "s"), no CR/LF
     * translation, and the pty keeps what was written while no host has it open. */
    const int slave = open(name, O_RDWR | O_NOCTTY);
    struct termios t;
    if (slave < 0 || tcgetattr(slave, &t)) die("cannot open the pty's slave side");
    cfmakeraw(&t);
    if (tcsetattr(slave, TCSANOW, &t)) die("tcsetattr");
    fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
    printf("pty %s\n", name);
    fflush(stdout);
}

/* --- set-up ------------------------------------------------------------------------------------------------- */

static void readFrames(const char *path) {
    FILE *f = fopen(path, "r");
    if (!f) die(path);
    long capacity = 1024;
    frames = malloc(sizeof *frames * (size_t)capacity);
    int v[6];
    while (frames && fscanf(f, "%d %d %d %d %d %d", &v[0], &v[1], &v[2], &v[3], &v[4], &v[5]) == 6) {
        if (frameCount == capacity) frames = realloc(frames, sizeof *frames * (size_t)(capacity *= 2));
        if (!frames) break;
        for (int i = 0; i < 6; i++) frames[frameCount][i] = (int16_t)v[i];
        frameCount++;
    }
    if (!frames) die("out of memory");
    if (!feof(f) || frameCount == 0) {
        errno = 0;
        die("FRAMES must hold lines of six integers (ax ay az gx gy gz counts)");
    }
    fclose(f);
}

static void parseFault(const char *spec) {
    char kind[8];
    double start = 0, duration = -1;
    errno = 0;
    if (faultCount == MAX_FAULTS || sscanf(spec, "%7[a-z]@%lf+%lf", kind, &start, &duration) < 2 || start < 0)
        die("--fault takes KIND@SECONDS[+SECONDS], e.g. nack@0, stuck@2+0.5, reset@3");
    Fault *f = &faults[faultCount];
    for (f->kind = FAULT_NACK; f->kind <= FAULT_RESET && strcmp(kind, faultNames[f->kind]); f->kind++) continue;
    if (f->kind > FAULT_RESET) die("--fault: the kinds are nack, stuck and reset");
    f->start = (avr_cycle_count_t)(start * F_CPU);
    f->end = duration < 0 ? UINT64_MAX : f->start + (avr_cycle_count_t)(duration * F_CPU);
    faultCount++;
}

static void noSleep(struct avr_t *a, avr_cycle_count_t howLong) {
    (void)a, (void)howLong; /* simavr would usleep() here to keep pace with the wall clock: we do not */
}

/* simavr's messages: errors to stderr, the rest (it announces what it loaded on stdout) nowhere */
static void logSimavr(struct avr_t *a, const int level, const char *format, va_list args) {
    (void)a;
    if (level <= LOG_ERROR) vfprintf(stderr, format, args);
}

static avr_twi_t *findTwi(void) {
    for (avr_io_t *io = avr->io_port; io; io = io->next)
        if (!strcmp(io->kind, "twi")) return (avr_twi_t *)io;
    errno = 0;
    die("this simavr has no TWI for the atmega328p");
    return NULL;
}

int main(int argc, char **argv) {
    const char *firmware = NULL, *framesPath = NULL;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--loop")) {
            loopFrames = 1;
        } else if (!strcmp(argv[i], "--realtime")) {
            realtime = 1;
        } else if (!strcmp(argv[i], "--log") && i + 1 < argc) {
            if (!(logFile = fopen(argv[++i], "w"))) die(argv[i]);
        } else if (!strcmp(argv[i], "--watch") && i + 1 < argc && watchCount < MAX_WATCHES) {
            unsigned address, length;
            if (sscanf(argv[++i], "%x:%u", &address, &length) != 2 || address + length > 0x900) die("--watch ADDR:LEN");
            watches[watchCount++] = (Watch){(uint16_t)address, (uint16_t)length};
        } else if (!strcmp(argv[i], "--fault") && i + 1 < argc) {
            parseFault(argv[++i]);
        } else if (!firmware) {
            firmware = argv[i];
        } else if (!framesPath) {
            framesPath = argv[i];
        } else {
            errno = 0;
            die(USAGE);
        }
    }
    errno = 0;
    if (!framesPath) die(USAGE);
    readFrames(framesPath);

    avr_global_logger_set(logSimavr);
    elf_firmware_t image;
    memset(&image, 0, sizeof image);
    if (elf_read_firmware(firmware, &image)) die(firmware);
    avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) die("this simavr does not know the atmega328p");
    avr->log = LOG_ERROR;
    avr_init(avr);
    avr->frequency = F_CPU;
    avr->sleep = noSleep;
    avr_load_firmware(avr, &image);

    /* the MPU6050 on the TWI, the UART on the pty */
    twi = findTwi();
    twiInput = avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_TWI_GETIRQ(0), TWI_IRQ_OUTPUT), onTwiBus, NULL);
    avr_register_io_write(avr, twi->r_twcr, onTwcrWrite, NULL);
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~(uint32_t)(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP); /* no console echo, no sleeping */
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    uartInput = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), onUartByte, NULL);
    mpuPowerOn();
    openPty();

    /* power on with the host's first byte (it opened the port and flushed it: nothing sent is lost) */
    for (uint8_t c; read(master, &c, 1) != 1;) {
        waitForHost(POLLIN);
        if (quit) return 0;
    }
    if (logFile) fprintf(logFile, "boot %llu\n", (unsigned long long)avr->cycle);
    clock_gettime(CLOCK_MONOTONIC, &bootTime);
    for (int i = 0; i < faultCount; i++)
        if (faults[i].start > avr->cycle) avr_cycle_timer_register(avr, faults[i].start - avr->cycle, onFaultStart, &faults[i]);
        else onFaultStart(avr, avr->cycle, &faults[i]);
    avr_cycle_timer_register(avr, HOST_POLL_CYCLES, pollHost, NULL);

    int state = cpu_Running;
    while (!quit && state != cpu_Done && state != cpu_Crashed) state = avr_run(avr);
    if (!quit) flushSerial();
    if (logFile) {
        fprintf(logFile, "end %llu\n", (unsigned long long)avr->cycle);
        fclose(logFile);
    }
    return state == cpu_Crashed ? 3 : 0;
}
