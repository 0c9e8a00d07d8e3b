/*
 * kfkit_protocol.h: the line encoder of kfkit serial protocol version 1 (C99, no allocation).
 *
 *   #KFKIT,1,board=mpu6050,rate_hz=100,fields=t_us|seq|ax|ay|az|gx|gy|gz,accel_fs_g=2,gyro_fs_dps=250
 *   $123456,42,-120,35,16390,12,-8,3*2D
 *
 * A sample line is '$', comma-separated decimal integers, '*', two upper-case hex digits (the XOR
 * of every byte between '$' and '*', NMEA 0183 style) and '\n'. A header line starts "#KFKIT,1,"
 * and carries key=value pairs; it has no checksum. Tagged lines ("$ATT,12.50,-3.25*HH") use
 * the same framing with a text tag first.
 *
 * Usage (the caller owns the buffer; nothing here allocates or calls printf):
 *
 *   kfkit_line line;
 *   kfkit_begin_sample(&line);
 *   kfkit_add_uint(&line, t_us);
 *   kfkit_add_int(&line, seq);
 *   ...
 *   size_t n = kfkit_end(&line);           // 0 if the line did not fit
 *   Serial.write(line.text, n);
 *
 * Host-tested: tests/test_firmware_protocol.py compiles a C program with this header and checks
 * that kfkit's Python parser accepts every line (and rejects each with a byte changed).
 */
#ifndef KFKIT_PROTOCOL_H
#define KFKIT_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

#define KFKIT_PROTOCOL_VERSION 1
/* Longest line: 12 fields of "-2147483648" plus separators and framing fit in 160 bytes. */
#define KFKIT_LINE_MAX 160

typedef struct {
    char text[KFKIT_LINE_MAX];
    size_t length;    /* bytes written so far */
    uint8_t checksum; /* XOR of the bytes after the start character */
    uint8_t fields;   /* values added so far (decides whether a comma comes first) */
    uint8_t overflow; /* 1 once something did not fit: kfkit_end() then returns 0 */
    char start;       /* '$' (checksummed) or '#' (header, no checksum) */
} kfkit_line;

static inline void kfkit_put_char(kfkit_line *line, char c) {
    if (line->length + 4 >= KFKIT_LINE_MAX) { /* keep room for "*HH\n" */
        line->overflow = 1;
        return;
    }
    line->text[line->length++] = c;
    line->checksum ^= (uint8_t)c;
}

static inline void kfkit_begin(kfkit_line *line, char start) {
    line->length = 0;
    line->checksum = 0;
    line->fields = 0;
    line->overflow = 0;
    line->start = start;
    line->text[line->length++] = start; /* the start character is not part of the checksum */
}

static inline void kfkit_begin_sample(kfkit_line *line) { kfkit_begin(line, '$'); }

static inline void kfkit_separate(kfkit_line *line) {
    if (line->fields++ > 0) kfkit_put_char(line, ',');
}

/* Append an unsigned decimal without a separator (digits are produced backwards, then copied). */
static inline void kfkit_put_uint(kfkit_line *line, uint32_t value) {
    char digits[10];
    int n = 0;
    do {
        digits[n++] = (char)('0' + value % 10u);
        value /= 10u;
    } while (value != 0u);
    while (n > 0) kfkit_put_char(line, digits[--n]);
}

static inline void kfkit_add_uint(kfkit_line *line, uint32_t value) {
    kfkit_separate(line);
    kfkit_put_uint(line, value);
}

static inline void kfkit_add_int(kfkit_line *line, int32_t value) {
    kfkit_separate(line);
    if (value < 0) {
        kfkit_put_char(line, '-');
        kfkit_put_uint(line, (uint32_t)(-(int64_t)value)); /* -INT32_MIN does not fit an int32 */
    } else {
        kfkit_put_uint(line, (uint32_t)value);
    }
}

/* Append text as one field (a tag such as "ATT", or "key=value" in a header). */
static inline void kfkit_add_text(kfkit_line *line, const char *text) {
    kfkit_separate(line);
    while (*text) kfkit_put_char(line, *text++);
}

/* Append a fixed-point decimal: value / 10^decimals, e.g. (1250, 2) → "12.50". */
static inline void kfkit_add_fixed(kfkit_line *line, int32_t value, uint8_t decimals) {
    uint32_t scale = 1u, magnitude;
    uint8_t i;
    for (i = 0; i < decimals; i++) scale *= 10u;
    kfkit_separate(line);
    if (value < 0) kfkit_put_char(line, '-');
    magnitude = value < 0 ? (uint32_t)(-(int64_t)value) : (uint32_t)value;
    kfkit_put_uint(line, magnitude / scale);
    if (decimals > 0) {
        uint32_t frac = magnitude % scale;
        kfkit_put_char(line, '.');
        for (scale /= 10u; scale > 0u; scale /= 10u) kfkit_put_char(line, (char)('0' + (frac / scale) % 10u));
    }
}

/* Finish the line: "*HH\n" for '$' lines, "\n" for '#' lines. Returns its length, 0 on overflow. */
static inline size_t kfkit_end(kfkit_line *line) {
    static const char hex[] = "0123456789ABCDEF";
    if (line->overflow) return 0;
    if (line->start == '$') {
        line->text[line->length++] = '*';
        line->text[line->length++] = hex[line->checksum >> 4];
        line->text[line->length++] = hex[line->checksum & 0x0F];
    }
    line->text[line->length++] = '\n';
    return line->length;
}

/* The header "#KFKIT,1,board=…,rate_hz=…,fields=…[,extra]\n"; ``extra`` may be NULL or "k=v,k=v". */
static inline size_t kfkit_header(kfkit_line *line, const char *board, const char *rate_hz, const char *fields,
                                  const char *extra) {
    kfkit_begin(line, '#');
    kfkit_add_text(line, "KFKIT");
    kfkit_add_uint(line, KFKIT_PROTOCOL_VERSION);
    kfkit_add_text(line, "board=");
    while (*board) kfkit_put_char(line, *board++);
    kfkit_add_text(line, "rate_hz=");
    while (*rate_hz) kfkit_put_char(line, *rate_hz++);
    kfkit_add_text(line, "fields=");
    while (*fields) kfkit_put_char(line, *fields++);
    if (extra && *extra) kfkit_add_text(line, extra);
    return kfkit_end(line);
}

/* A sample line from t_us, seq and ``count`` int32 values. Returns its length, 0 on overflow. */
static inline size_t kfkit_sample(kfkit_line *line, uint32_t t_us, uint16_t seq, const int32_t *values, size_t count) {
    size_t i;
    kfkit_begin_sample(line);
    kfkit_add_uint(line, t_us);
    kfkit_add_uint(line, seq);
    for (i = 0; i < count; i++) kfkit_add_int(line, values[i]);
    return kfkit_end(line);
}

/* --- Arduino helpers (C++ only): send lines to a Serial port -------------------------------------
 * kfkitSendHeader(Serial) sends the header described by these macros (define them before the
 * #include to change them); kfkitSendSample(Serial, values, n) sends values[0] as t_us (uint32),
 * values[1] as seq (uint16) and the rest as integers; kfkitSendMessage(Serial, "ATT", x, n) sends
 * floats with two decimals; kfkitHandleCommands(Serial, &streaming) answers 'h' and 's'. */
#if defined(ARDUINO) && defined(__cplusplus)
#include <Arduino.h>

#ifndef KFKIT_BOARD
#define KFKIT_BOARD "mpu6050"
#endif
#ifndef KFKIT_RATE_HZ
#define KFKIT_RATE_HZ "100"
#endif
#ifndef KFKIT_FIELDS
#define KFKIT_FIELDS "t_us|seq|ax|ay|az|gx|gy|gz"
#endif
#ifndef KFKIT_HEADER_EXTRA
#define KFKIT_HEADER_EXTRA "accel_fs_g=2,gyro_fs_dps=250"
#endif

inline void kfkitSendHeader(Print &out) {
    kfkit_line line;
    size_t n = kfkit_header(&line, KFKIT_BOARD, KFKIT_RATE_HZ, KFKIT_FIELDS, KFKIT_HEADER_EXTRA);
    out.write((const uint8_t *)line.text, n);
}

inline void kfkitSendSample(Print &out, const int32_t *values, size_t count) {
    kfkit_line line;
    size_t n = kfkit_sample(&line, (uint32_t)values[0], (uint16_t)values[1], values + 2, count - 2);
    out.write((const uint8_t *)line.text, n);
}

inline void kfkitSendMessage(Print &out, const char *tag, const float *values, size_t count) {
    kfkit_line line;
    kfkit_begin_sample(&line);
    kfkit_add_text(&line, tag);
    for (size_t i = 0; i < count; i++) kfkit_add_fixed(&line, (int32_t)lroundf(values[i] * 100.0f), 2);
    size_t n = kfkit_end(&line);
    out.write((const uint8_t *)line.text, n);
}

/* Host commands: 'h' sends the header, 's' stops/starts streaming. Returns true after an 's',
 * so the sketch can restart its sample schedule. */
inline bool kfkitHandleCommands(Stream &port, bool *streaming) {
    bool toggled = false;
    while (port.available() > 0) {
        const int c = port.read();
        if (c == 'h') kfkitSendHeader(port);
        if (c == 's') {
            *streaming = !*streaming;
            toggled = true;
        }
    }
    return toggled;
}
#endif

#endif /* KFKIT_PROTOCOL_H */
