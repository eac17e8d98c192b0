/*
 * Host test program for dem_link (not for the board). Built and run by tests/hardware/test_link_c.py:
 *
 *   cc -std=c99 -Wall -Wextra -Werror -pedantic -O2 -o host_test host_test.c dem_link.c
 *   ./host_test vectors ../tests/hardware/vectors/frames.txt   check every vector; exit 0 if all pass
 *   ./host_test verdicts FILE     FILE: one hex frame per line -> "ok <re-encoded hex>" or the reason
 *   ./host_test stream FILE       FILE: raw bytes of a serial stream -> counts of the deframer and decode
 *   ./host_test fuzz SEED N       N random + N mutated frames and a garbage stream -> counts by reason
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dem_link.h"

#define NREASONS (DEM_ERR_BUFFER + 1)
#define MAXLINE 4096

static int hexval(int c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* Parse a hex string into out; returns the byte count or -1. */
static long unhex(const char *s, uint8_t *out, size_t cap)
{
    size_t n = 0;
    while (s[0] && s[0] != '\n' && s[0] != '\r') {
        int hi = hexval(s[0]), lo = s[1] ? hexval(s[1]) : -1;
        if (hi < 0 || lo < 0 || n >= cap) return -1;
        out[n++] = (uint8_t)(hi * 16 + lo);
        s += 2;
    }
    return (long)n;
}

static void puthex(const uint8_t *p, size_t n)
{
    size_t i;
    for (i = 0; i < n; ++i) printf("%02x", p[i]);
}

/* ---------------------------------------------------------------- vectors */
static const char *mode_name(unsigned m)
{
    static const char *const names[] = {"OFF", "RUN", "HOLD", "LAND", "LANDED", "FAULT"};
    return m < 6 ? names[m] : "?";
}

typedef struct {
    char name[128];
    uint8_t hex[256];
    long nhex;
    uint8_t cobs[512];
    long ncobs;
    char expect[32];
    char type[32];
    char fields[32][2][512]; /* key, value text */
    int nfields;
} record_t;

static const char *field(const record_t *r, const char *key)
{
    int i;
    for (i = 0; i < r->nfields; ++i)
        if (strcmp(r->fields[i][0], key) == 0) return r->fields[i][1];
    return NULL;
}

/* A field line of floats normalised: each token read as a float32, printed %.9g, space separated; the count. */
static int floats_text(const char *text, char *out, size_t cap)
{
    int n = 0;
    size_t used = 0;
    const char *p = text;
    out[0] = 0;
    while (p && *p) {
        char *end;
        float v = (float)strtod(p, &end);
        if (end == p) break;
        used += (size_t)snprintf(out + used, used < cap ? cap - used : 0, "%s%.9g", n ? " " : "", (double)v);
        ++n;
        p = end;
        while (*p == ' ') ++p;
    }
    return n;
}

/* Compare a decoded frame with the record's field lines; writes what differs into why. */
static int fields_match(const record_t *r, const dem_frame_t *f, char *why, size_t nwhy)
{
    char got[1600];
    char want[1600];
    got[0] = want[0] = 0;
#define FMTF(x) ((double)(x))
    if (strcmp(r->type, "hello") == 0) {
        const dem_hello_t *h = &f->f.hello;
        if (f->type != DEM_HELLO) { snprintf(why, nwhy, "type %u", f->type); return 0; }
        snprintf(got, sizeof got, "%u %lu %lu %u %.9g %u %u", h->version, (unsigned long)h->board_id,
                 (unsigned long)h->rate_hz, h->adc_bits, FMTF(h->adc_vref), h->watchdog_ms, h->command_delay);
        snprintf(want, sizeof want, "%s %s %s %s %.9g %s %s", field(r, "version"), field(r, "board_id"),
                 field(r, "rate_hz"), field(r, "adc_bits"), (double)(float)strtod(field(r, "adc_vref"), NULL),
                 field(r, "watchdog_ms"), field(r, "command_delay"));
    } else if (strcmp(r->type, "sensor") == 0) {
        const dem_sensor_t *s = &f->f.sensor;
        float a0, a1;
        char gaps[64], curr[64], appl[128];
        if (f->type != DEM_SENSOR) { snprintf(why, nwhy, "type %u", f->type); return 0; }
        snprintf(got, sizeof got, "%lu %llu %u %u %u %u %.9g %.9g %.9g 0x%08lx %s", (unsigned long)s->seq,
                 (unsigned long long)s->board_time_us, s->gap_counts[0], s->gap_counts[1], s->current_counts[0],
                 s->current_counts[1], FMTF(s->applied_v[0]), FMTF(s->applied_v[1]), FMTF(s->bus_v),
                 (unsigned long)s->status, mode_name(s->mode));
        strcpy(gaps, field(r, "gap_counts"));
        strcpy(curr, field(r, "current_counts"));
        strcpy(appl, field(r, "applied_v"));
        {
            char *sp = strchr(appl, ' ');
            *sp = 0;
            a0 = (float)strtod(appl, NULL);
            a1 = (float)strtod(sp + 1, NULL);
        }
        snprintf(want, sizeof want, "%s %s %s %s %.9g %.9g %.9g %s %s", field(r, "seq"), field(r, "board_time_us"),
                 gaps, curr, (double)a0, (double)a1, (double)(float)strtod(field(r, "bus_v"), NULL),
                 field(r, "status"), field(r, "mode"));
    } else if (strcmp(r->type, "command") == 0) {
        const dem_command_t *c = &f->f.command;
        char u[128];
        float u0, u1;
        if (f->type != DEM_COMMAND) { snprintf(why, nwhy, "type %u", f->type); return 0; }
        snprintf(got, sizeof got, "%lu %.9g %.9g %s", (unsigned long)c->seq, FMTF(c->u[0]), FMTF(c->u[1]),
                 mode_name(c->mode));
        strcpy(u, field(r, "u"));
        {
            char *sp = strchr(u, ' ');
            *sp = 0;
            u0 = (float)strtod(u, NULL);
            u1 = (float)strtod(sp + 1, NULL);
        }
        snprintf(want, sizeof want, "%s %.9g %.9g %s", field(r, "seq"), (double)u0, (double)u1, field(r, "mode"));
    } else if (strcmp(r->type, "config") == 0) {
        const dem_config_t *c = &f->f.config;
        char sup[512], cal[512];
        size_t k, used = 0;
        if (f->type != DEM_CONFIG) { snprintf(why, nwhy, "type %u", f->type); return 0; }
        for (k = 0; k < DEM_CONFIG_FLOATS; ++k)
            used += (size_t)snprintf(got + used, sizeof got - used, "%.9g ", (double)c->v[k]);
        snprintf(got + used, sizeof got - used, "%u", c->command_delay);
        if (floats_text(field(r, "supervisor"), sup, sizeof sup) != (int)DEM_CONFIG_SUP ||
            floats_text(field(r, "calibration"), cal, sizeof cal) != (int)DEM_CONFIG_CAL) {
            snprintf(why, nwhy, "supervisor / calibration lines need %u and %u floats", DEM_CONFIG_SUP,
                     DEM_CONFIG_CAL);
            return 0;
        }
        snprintf(want, sizeof want, "%s %s %s", sup, cal, field(r, "command_delay"));
    } else if (strcmp(r->type, "config_ack") == 0) {
        const dem_config_ack_t *a = &f->f.config_ack;
        if (f->type != DEM_CONFIG_ACK) { snprintf(why, nwhy, "type %u", f->type); return 0; }
        snprintf(got, sizeof got, "0x%08lx 0x%08lx %s %u %s", (unsigned long)a->active_crc,
                 (unsigned long)a->request_crc, dem_config_reason(a->result), a->configured, mode_name(a->mode));
        snprintf(want, sizeof want, "%s %s %s %s %s", field(r, "active_crc"), field(r, "request_crc"),
                 field(r, "result"), field(r, "configured"), field(r, "mode"));
    } else {
        snprintf(why, nwhy, "unknown type line %s", r->type);
        return 0;
    }
    if (strcmp(got, want) != 0) {
        snprintf(why, nwhy, "decoded [%s], file says [%s]", got, want);
        return 0;
    }
    return 1;
}

static int check_record(const record_t *r)
{
    dem_frame_t f;
    char why[3400] = "";
    int res = dem_decode(r->hex, (size_t)r->nhex, &f);
    if (strcmp(dem_link_reason(res), r->expect) != 0) {
        snprintf(why, sizeof why, "decode gave %s, expected %s", dem_link_reason(res), r->expect);
    } else if (res == DEM_OK) {
        uint8_t buf[256];
        uint8_t back[256];
        size_t n, m;
        if (!fields_match(r, &f, why, sizeof why)) {
            /* why filled */
        } else if (dem_encode(&f, buf, sizeof buf, &n) != DEM_OK || n != (size_t)r->nhex ||
                   memcmp(buf, r->hex, n) != 0) {
            snprintf(why, sizeof why, "re-encoding differs");
        } else if (dem_cobs_encode(r->hex, (size_t)r->nhex, buf, sizeof buf, &n) != DEM_OK ||
                   n != (size_t)r->ncobs || memcmp(buf, r->cobs, n) != 0) {
            snprintf(why, sizeof why, "COBS encoding differs");
        } else if (dem_cobs_decode(r->cobs, (size_t)r->ncobs, back, sizeof back, &m) != DEM_OK ||
                   m != (size_t)r->nhex || memcmp(back, r->hex, m) != 0) {
            snprintf(why, sizeof why, "COBS decoding differs");
        } else if (dem_crc32(r->hex, (size_t)r->nhex - 4) !=
                   ((uint32_t)r->hex[r->nhex - 4] | ((uint32_t)r->hex[r->nhex - 3] << 8) |
                    ((uint32_t)r->hex[r->nhex - 2] << 16) | ((uint32_t)r->hex[r->nhex - 1] << 24))) {
            snprintf(why, sizeof why, "CRC differs");
        }
    }
    if (why[0]) {
        printf("FAIL %s: %s\n", r->name, why);
        return 0;
    }
    printf("PASS %s\n", r->name);
    return 1;
}

static int run_vectors(const char *path)
{
    FILE *fp = fopen(path, "r");
    char line[MAXLINE];
    static record_t r;
    int in = 0, passed = 0, failed = 0, lineno = 0;
    if (!fp) { perror(path); return 2; }
    while (fgets(line, sizeof line, fp)) {
        char *val;
        ++lineno;
        line[strcspn(line, "\r\n")] = 0;
        if (!line[0] || line[0] == '#') continue;
        val = strchr(line, ' ');
        if (val) *val++ = 0; else val = line + strlen(line);
        if (strcmp(line, "vector") == 0) {
            memset(&r, 0, sizeof r);
            snprintf(r.name, sizeof r.name, "%.127s", val);
            r.ncobs = -1;
            in = 1;
        } else if (!in) {
            printf("line %d: %s outside a vector\n", lineno, line);
            fclose(fp);
            return 2;
        } else if (strcmp(line, "end") == 0) {
            if (check_record(&r)) ++passed; else ++failed;
            in = 0;
        } else if (strcmp(line, "hex") == 0) {
            r.nhex = unhex(val, r.hex, sizeof r.hex);
        } else if (strcmp(line, "cobs") == 0) {
            r.ncobs = unhex(val, r.cobs, sizeof r.cobs);
        } else if (strcmp(line, "expect") == 0) {
            snprintf(r.expect, sizeof r.expect, "%.31s", val);
        } else if (strcmp(line, "type") == 0) {
            snprintf(r.type, sizeof r.type, "%.31s", val);
        } else if (r.nfields < 32) {
            snprintf(r.fields[r.nfields][0], 512, "%.511s", line);
            snprintf(r.fields[r.nfields][1], 512, "%.511s", val);
            r.nfields++;
        }
        if (r.nhex < 0) { printf("line %d: bad hex\n", lineno); fclose(fp); return 2; }
    }
    fclose(fp);
    printf("vectors: %d passed, %d failed\n", passed, failed);
    return failed || !passed ? 1 : 0;
}

/* ---------------------------------------------------------------- verdicts / stream */
static int run_verdicts(const char *path)
{
    FILE *fp = fopen(path, "r");
    static char line[MAXLINE];
    uint8_t buf[MAXLINE / 2];
    if (!fp) { perror(path); return 2; }
    while (fgets(line, sizeof line, fp)) {
        dem_frame_t f;
        long n;
        int res;
        line[strcspn(line, "\r\n")] = 0;
        n = unhex(line, buf, sizeof buf);
        if (n < 0) { printf("badhex\n"); continue; }
        res = dem_decode(buf, (size_t)n, &f);
        if (res == DEM_OK) {
            uint8_t out[DEM_MAX_FRAME_SIZE];
            size_t m;
            int e = dem_encode(&f, out, sizeof out, &m);
            printf("ok ");
            if (e == DEM_OK) puthex(out, m); else printf("encode-%s", dem_link_reason(e));
            printf("\n");
        } else {
            printf("%s\n", dem_link_reason(res));
        }
    }
    fclose(fp);
    return 0;
}

static void stream_counts(const uint8_t *data, size_t n, unsigned long counts[NREASONS], dem_deframer_t *d)
{
    size_t i, len;
    uint8_t frame[DEM_MAX_FRAME_SIZE];
    dem_frame_t f;
    for (i = 0; i < n; ++i)
        if (dem_deframer_push(d, data[i], frame, sizeof frame, &len)) counts[dem_decode(frame, len, &f)]++;
}

static void print_counts(const char *prefix, const unsigned long counts[NREASONS])
{
    int r;
    for (r = 0; r < NREASONS - 1; ++r) printf("%s%s %lu\n", prefix, dem_link_reason(r), counts[r]);
}

static int run_stream(const char *path)
{
    FILE *fp = fopen(path, "rb");
    static uint8_t data[1 << 22];
    size_t n;
    unsigned long counts[NREASONS] = {0};
    dem_deframer_t d;
    if (!fp) { perror(path); return 2; }
    n = fread(data, 1, sizeof data, fp);
    fclose(fp);
    dem_deframer_init(&d);
    stream_counts(data, n, counts, &d);
    printf("frames %lu\ncobs %lu\noversize %lu\n", (unsigned long)d.frames, (unsigned long)d.dropped_cobs,
           (unsigned long)d.dropped_oversize);
    print_counts("decode_", counts);
    return 0;
}

/* ---------------------------------------------------------------- fuzz (own PRNG: xorshift64*) */
static uint64_t rng_state;
static uint32_t rnd(void)
{
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return (uint32_t)((rng_state * 0x2545F4914F6CDD1Dull) >> 32);
}

static size_t valid_frame(uint8_t *out)
{
    dem_frame_t f;
    size_t n = 0;
    uint32_t k = rnd() % 5;
    memset(&f, 0, sizeof f);
    if (k == 0) {
        f.type = DEM_SENSOR;
        f.f.sensor.seq = rnd();
        f.f.sensor.board_time_us = ((uint64_t)rnd() << 32) | rnd();
        f.f.sensor.gap_counts[0] = (uint16_t)rnd();
        f.f.sensor.gap_counts[1] = (uint16_t)rnd();
        f.f.sensor.current_counts[0] = (uint16_t)rnd();
        f.f.sensor.current_counts[1] = (uint16_t)rnd();
        f.f.sensor.applied_v[0] = (float)(rnd() % 30000) / 100.0f - 150.0f;
        f.f.sensor.applied_v[1] = (float)(rnd() % 30000) / 100.0f - 150.0f;
        f.f.sensor.bus_v = (float)(rnd() % 20000) / 100.0f;
        f.f.sensor.status = rnd() & 0x3FFFFu;
        f.f.sensor.mode = (uint8_t)(rnd() % 6);
    } else if (k == 1) {
        f.type = DEM_COMMAND;
        f.f.command.seq = rnd();
        f.f.command.u[0] = (float)(rnd() % 30000) / 100.0f - 150.0f;
        f.f.command.u[1] = (float)(rnd() % 30000) / 100.0f - 150.0f;
        f.f.command.mode = (uint8_t)(rnd() % 4);
    } else if (k == 3) {
        size_t j;
        f.type = DEM_CONFIG;
        for (j = 0; j < DEM_CONFIG_FLOATS; ++j) f.f.config.v[j] = (float)(rnd() % 20000) / 1000.0f - 5.0f;
        f.f.config.command_delay = (uint8_t)(rnd() % 4);
    } else if (k == 4) {
        f.type = DEM_CONFIG_ACK;
        f.f.config_ack.active_crc = rnd();
        f.f.config_ack.request_crc = rnd();
        f.f.config_ack.result = (uint8_t)(rnd() % 9);
        f.f.config_ack.configured = (uint8_t)(rnd() % 2);
        f.f.config_ack.mode = (uint8_t)(rnd() % 6);
    } else {
        f.type = DEM_HELLO;
        f.f.hello.version = 1;
        f.f.hello.board_id = rnd();
        f.f.hello.rate_hz = 1000;
        f.f.hello.adc_bits = (uint8_t)(rnd() % 17);
        f.f.hello.watchdog_ms = 50;
        f.f.hello.command_delay = (uint8_t)(rnd() % 3);
        f.f.hello.adc_vref = 3.0f;
    }
    if (dem_encode(&f, out, DEM_MAX_FRAME_SIZE, &n) != DEM_OK) {
        printf("encode of a valid frame failed\n");
        exit(3);
    }
    return n;
}

static int run_fuzz(unsigned long seed, unsigned long count)
{
    static uint8_t stream[1 << 22];
    unsigned long random_counts[NREASONS] = {0}, mutated_counts[NREASONS] = {0}, stream_decode[NREASONS] = {0};
    unsigned long i;
    size_t s = 0;
    dem_deframer_t d;
    rng_state = 0x9E3779B97F4A7C15ull ^ (uint64_t)seed;
    if (!rng_state) rng_state = 1;
    for (i = 0; i < count; ++i) { /* random bytes, half with a plausible header and a valid CRC */
        uint8_t buf[160];
        dem_frame_t f;
        size_t n = rnd() % 64, j;
        for (j = 0; j < n; ++j) buf[j] = (uint8_t)rnd();
        if ((i & 1) && n >= 8) { /* plausible: right version/type/length, often zero reserved bytes */
            static const size_t sizes[6] = {0, DEM_HELLO_SIZE, DEM_SENSOR_SIZE, DEM_COMMAND_SIZE, DEM_CONFIG_SIZE,
                                            DEM_CONFIG_ACK_SIZE};
            uint8_t type = (uint8_t)(1 + rnd() % 5);
            size_t size = sizes[type];
            n = rnd() % 4 ? size : (size == 24 ? 48 : 24);
            for (j = 0; j < n; ++j) buf[j] = (uint8_t)(rnd() % 2 ? rnd() : rnd() % 8);
            buf[0] = 1;
            buf[1] = type;
            buf[2] = (uint8_t)n;
            buf[3] = 0;
            if (rnd() % 4) {
                if (type == DEM_HELLO) buf[12] = (uint8_t)(buf[12] % 20); /* adc_bits, often valid */
                else if (type == DEM_SENSOR && n == 48) buf[41] = buf[42] = buf[43] = 0;
                else if (type == DEM_CONFIG && n == DEM_CONFIG_SIZE) buf[121] = buf[122] = buf[123] = 0;
                else if (type == DEM_CONFIG_ACK && n == DEM_CONFIG_ACK_SIZE) {
                    buf[15] = 0;
                    buf[14] = (uint8_t)(buf[14] % 8);
                    buf[12] = (uint8_t)(buf[12] % 12);
                    buf[13] = (uint8_t)(buf[13] % 3);
                } else buf[17] = buf[18] = buf[19] = 0;
            }
            {
                uint32_t c = dem_crc32(buf, n - 4);
                buf[n - 4] = (uint8_t)c; buf[n - 3] = (uint8_t)(c >> 8);
                buf[n - 2] = (uint8_t)(c >> 16); buf[n - 1] = (uint8_t)(c >> 24);
            }
        }
        random_counts[dem_decode(buf, n, &f)]++;
    }
    for (i = 0; i < count; ++i) { /* mutated valid frames */
        uint8_t buf[DEM_MAX_FRAME_SIZE + 16];
        dem_frame_t f;
        size_t n = valid_frame(buf), j;
        switch (rnd() % 4) {
        case 0: { /* 1-3 bit flips */
            unsigned flips = 1 + rnd() % 3, q;
            for (q = 0; q < flips; ++q) buf[rnd() % n] ^= (uint8_t)(1u << (rnd() % 8));
            break;
        }
        case 1: n = rnd() % n; break; /* truncation */
        case 2: { /* extension */
            size_t extra = 1 + rnd() % 16;
            for (j = 0; j < extra; ++j) buf[n + j] = (uint8_t)rnd();
            n += extra;
            break;
        }
        default: buf[rnd() % n] = (uint8_t)rnd(); break; /* byte substitution */
        }
        mutated_counts[dem_decode(buf, n, &f)]++;
    }
    for (i = 0; i < count && s + 300 < sizeof stream; ++i) { /* a stream: frames with garbage between */
        uint8_t fr[DEM_MAX_FRAME_SIZE];
        size_t n = valid_frame(fr), m, j;
        if (rnd() % 4 == 0) {
            size_t g = rnd() % 60;
            for (j = 0; j < g; ++j) stream[s++] = (uint8_t)rnd();
        }
        stream[s++] = 0; /* the wire form: 0x00 COBS(frame) 0x00 */
        if (dem_cobs_encode(fr, n, stream + s, DEM_MAX_ENCODED_SIZE, &m) != DEM_OK) {
            printf("cobs encode failed\n");
            return 3;
        }
        if (rnd() % 16 == 0) stream[s + rnd() % m] ^= (uint8_t)(1u << (rnd() % 8));
        s += m;
        stream[s++] = 0;
    }
    dem_deframer_init(&d);
    stream_counts(stream, s, stream_decode, &d);
    print_counts("random_", random_counts);
    print_counts("mutated_", mutated_counts);
    printf("stream_bytes %lu\nstream_frames %lu\nstream_cobs %lu\nstream_oversize %lu\n", (unsigned long)s,
           (unsigned long)d.frames, (unsigned long)d.dropped_cobs, (unsigned long)d.dropped_oversize);
    print_counts("stream_", stream_decode);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc == 3 && strcmp(argv[1], "vectors") == 0) return run_vectors(argv[2]);
    if (argc == 3 && strcmp(argv[1], "verdicts") == 0) return run_verdicts(argv[2]);
    if (argc == 3 && strcmp(argv[1], "stream") == 0) return run_stream(argv[2]);
    if (argc == 4 && strcmp(argv[1], "fuzz") == 0) return run_fuzz(strtoul(argv[2], NULL, 10), strtoul(argv[3], NULL, 10));
    fprintf(stderr, "usage: %s vectors FILE | verdicts FILE | stream FILE | fuzz SEED N\n", argv[0]);
    return 2;
}
