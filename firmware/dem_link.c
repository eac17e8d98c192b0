/* dem_link: frame codec of the dem_ros device link (see dem_link.h). Portable C99, no malloc. */
#include "dem_link.h"

#include <string.h>

/* --- little-endian access, independent of the host's byte order --- */
static uint16_t rd16(const uint8_t *p) { return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }
static uint32_t rd32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static uint64_t rd64(const uint8_t *p) { return (uint64_t)rd32(p) | ((uint64_t)rd32(p + 4) << 32); }
static void wr16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void wr32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}
static void wr64(uint8_t *p, uint64_t v) { wr32(p, (uint32_t)v); wr32(p + 4, (uint32_t)(v >> 32)); }

/* float <-> IEEE-754 binary32 bit pattern (memcpy: no aliasing problem) */
static uint32_t f2u(float f) { uint32_t u; memcpy(&u, &f, 4); return u; }
static float u2f(uint32_t u) { float f; memcpy(&f, &u, 4); return f; }
static int nonfinite_bits(uint32_t u) { return (u & 0x7F800000ul) == 0x7F800000ul; }
static float rdf(const uint8_t *p) { return u2f(rd32(p)); }
static void wrf(uint8_t *p, float f) { wr32(p, f2u(f)); }

/* --- CRC-32, half-byte table (64 bytes of constants; ~2 lookups per byte) --- */
static const uint32_t crc_nibble[16] = {
    0x00000000ul, 0x1DB71064ul, 0x3B6E20C8ul, 0x26D930ACul, 0x76DC4190ul, 0x6B6B51F4ul,
    0x4DB26158ul, 0x5005713Cul, 0xEDB88320ul, 0xF00F9344ul, 0xD6D6A3E8ul, 0xCB61B38Cul,
    0x9B64C2B0ul, 0x86D3D2D4ul, 0xA00AE278ul, 0xBDBDF21Cul,
};

uint32_t dem_crc32(const uint8_t *data, size_t n)
{
    uint32_t c = 0xFFFFFFFFul;
    size_t i;
    for (i = 0; i < n; ++i) {
        c ^= data[i];
        c = (c >> 4) ^ crc_nibble[c & 0x0Fu];
        c = (c >> 4) ^ crc_nibble[c & 0x0Fu];
    }
    return c ^ 0xFFFFFFFFul;
}

const char *dem_link_reason(int r)
{
    static const char *const names[] = {"ok",       "short", "length", "crc",       "version", "type",
                                        "size",     "reserved", "mode", "nonfinite", "range",   "buffer"};
    if (r < 0 || r > DEM_ERR_BUFFER) return "?";
    return names[r];
}

const char *dem_config_reason(int r)
{
    static const char *const names[] = {"ok",        "not_positive", "gap_order", "arms", "no_braking",
                                        "nonfinite", "delay",        "rate",      "busy"};
    if (r < 0 || r > DEM_CFG_BUSY) return "?";
    return names[r];
}

static void seal(uint8_t *out, uint8_t version, uint8_t type, size_t size)
{
    out[0] = version;
    out[1] = type;
    wr16(out + 2, (uint16_t)size);
    wr32(out + size - 4, dem_crc32(out, size - 4));
}

/* the config frame's bytes, without checks (dem_encode checks; dem_config_crc needs none) */
static void put_config(uint8_t *out, const dem_config_t *c)
{
    size_t k;
    for (k = 0; k < DEM_CONFIG_FLOATS; ++k) wrf(out + 4 + 4 * k, c->v[k]);
    out[120] = c->command_delay;
    out[121] = out[122] = out[123] = 0;
    seal(out, DEM_LINK_VERSION, DEM_CONFIG, DEM_CONFIG_SIZE);
}

uint32_t dem_config_crc(const dem_config_t *c)
{
    uint8_t out[DEM_CONFIG_SIZE];
    put_config(out, c);
    return rd32(out + DEM_CONFIG_SIZE - 4);
}

int dem_encode(const dem_frame_t *fr, uint8_t *out, size_t cap, size_t *len)
{
    size_t size, k;
    *len = 0;
    switch (fr->type) {
    case DEM_HELLO: {
        const dem_hello_t *h = &fr->f.hello;
        if (h->version == 0 || h->adc_bits > 16) return DEM_ERR_RANGE;
        if (nonfinite_bits(f2u(h->adc_vref))) return DEM_ERR_NONFINITE;
        if (h->adc_vref < 0.0f) return DEM_ERR_RANGE;
        size = DEM_HELLO_SIZE;
        if (cap < size) return DEM_ERR_BUFFER;
        wr32(out + 4, h->board_id);
        wr32(out + 8, h->rate_hz);
        out[12] = h->adc_bits;
        out[13] = h->command_delay;
        wr16(out + 14, h->watchdog_ms);
        wrf(out + 16, h->adc_vref);
        seal(out, h->version, DEM_HELLO, size);
        break;
    }
    case DEM_SENSOR: {
        const dem_sensor_t *s = &fr->f.sensor;
        if (s->mode > DEM_FAULT) return DEM_ERR_MODE;
        if (nonfinite_bits(f2u(s->applied_v[0])) || nonfinite_bits(f2u(s->applied_v[1])) ||
            nonfinite_bits(f2u(s->bus_v)))
            return DEM_ERR_NONFINITE;
        size = DEM_SENSOR_SIZE;
        if (cap < size) return DEM_ERR_BUFFER;
        wr32(out + 4, s->seq);
        wr64(out + 8, s->board_time_us);
        wr16(out + 16, s->gap_counts[0]);
        wr16(out + 18, s->gap_counts[1]);
        wr16(out + 20, s->current_counts[0]);
        wr16(out + 22, s->current_counts[1]);
        wrf(out + 24, s->applied_v[0]);
        wrf(out + 28, s->applied_v[1]);
        wrf(out + 32, s->bus_v);
        wr32(out + 36, s->status);
        out[40] = s->mode;
        out[41] = out[42] = out[43] = 0;
        seal(out, DEM_LINK_VERSION, DEM_SENSOR, size);
        break;
    }
    case DEM_COMMAND: {
        const dem_command_t *c = &fr->f.command;
        if (c->mode > DEM_LAND) return DEM_ERR_MODE;
        if (nonfinite_bits(f2u(c->u[0])) || nonfinite_bits(f2u(c->u[1]))) return DEM_ERR_NONFINITE;
        size = DEM_COMMAND_SIZE;
        if (cap < size) return DEM_ERR_BUFFER;
        wr32(out + 4, c->seq);
        wrf(out + 8, c->u[0]);
        wrf(out + 12, c->u[1]);
        out[16] = c->mode;
        out[17] = out[18] = out[19] = 0;
        seal(out, DEM_LINK_VERSION, DEM_COMMAND, size);
        break;
    }
    case DEM_CONFIG: {
        const dem_config_t *c = &fr->f.config;
        for (k = 0; k < DEM_CONFIG_FLOATS; ++k)
            if (nonfinite_bits(f2u(c->v[k]))) return DEM_ERR_NONFINITE;
        size = DEM_CONFIG_SIZE;
        if (cap < size) return DEM_ERR_BUFFER;
        put_config(out, c);
        break;
    }
    case DEM_CONFIG_ACK: {
        const dem_config_ack_t *a = &fr->f.config_ack;
        if (a->mode > DEM_FAULT) return DEM_ERR_MODE;
        if (a->result > DEM_CFG_BUSY || a->configured > 1) return DEM_ERR_RANGE;
        size = DEM_CONFIG_ACK_SIZE;
        if (cap < size) return DEM_ERR_BUFFER;
        wr32(out + 4, a->active_crc);
        wr32(out + 8, a->request_crc);
        out[12] = a->result;
        out[13] = a->configured;
        out[14] = a->mode;
        out[15] = 0;
        seal(out, DEM_LINK_VERSION, DEM_CONFIG_ACK, size);
        break;
    }
    default:
        return DEM_ERR_TYPE;
    }
    *len = size;
    return DEM_OK;
}

/* Checks in the order of the Python codec's REASONS, so both give the same reason for any input. */
int dem_decode(const uint8_t *p, size_t n, dem_frame_t *fr)
{
    uint8_t version, type;
    if (n < 8) return DEM_ERR_SHORT;
    if (rd16(p + 2) != n) return DEM_ERR_LENGTH;
    if (rd32(p + n - 4) != dem_crc32(p, n - 4)) return DEM_ERR_CRC;
    version = p[0];
    type = p[1];
    if (type == DEM_HELLO) {
        dem_hello_t *h = &fr->f.hello;
        uint32_t vref;
        if (n != DEM_HELLO_SIZE) return DEM_ERR_SIZE;
        if (version == 0) return DEM_ERR_VERSION;
        if (p[12] > 16) return DEM_ERR_RANGE;
        vref = rd32(p + 16);
        if (nonfinite_bits(vref)) return DEM_ERR_NONFINITE;
        if (u2f(vref) < 0.0f) return DEM_ERR_RANGE;
        fr->type = DEM_HELLO;
        h->version = version;
        h->board_id = rd32(p + 4);
        h->rate_hz = rd32(p + 8);
        h->adc_bits = p[12];
        h->command_delay = p[13];
        h->watchdog_ms = rd16(p + 14);
        h->adc_vref = u2f(vref);
        return DEM_OK;
    }
    if (version != DEM_LINK_VERSION) return DEM_ERR_VERSION;
    if (type == DEM_SENSOR) {
        dem_sensor_t *s = &fr->f.sensor;
        if (n != DEM_SENSOR_SIZE) return DEM_ERR_SIZE;
        if (p[41] | p[42] | p[43]) return DEM_ERR_RESERVED;
        if (p[40] > DEM_FAULT) return DEM_ERR_MODE;
        if (nonfinite_bits(rd32(p + 24)) || nonfinite_bits(rd32(p + 28)) || nonfinite_bits(rd32(p + 32)))
            return DEM_ERR_NONFINITE;
        fr->type = DEM_SENSOR;
        s->seq = rd32(p + 4);
        s->board_time_us = rd64(p + 8);
        s->gap_counts[0] = rd16(p + 16);
        s->gap_counts[1] = rd16(p + 18);
        s->current_counts[0] = rd16(p + 20);
        s->current_counts[1] = rd16(p + 22);
        s->applied_v[0] = rdf(p + 24);
        s->applied_v[1] = rdf(p + 28);
        s->bus_v = rdf(p + 32);
        s->status = rd32(p + 36);
        s->mode = p[40];
        return DEM_OK;
    }
    if (type == DEM_COMMAND) {
        dem_command_t *c = &fr->f.command;
        if (n != DEM_COMMAND_SIZE) return DEM_ERR_SIZE;
        if (p[17] | p[18] | p[19]) return DEM_ERR_RESERVED;
        if (p[16] > DEM_LAND) return DEM_ERR_MODE;
        if (nonfinite_bits(rd32(p + 8)) || nonfinite_bits(rd32(p + 12))) return DEM_ERR_NONFINITE;
        fr->type = DEM_COMMAND;
        c->seq = rd32(p + 4);
        c->u[0] = rdf(p + 8);
        c->u[1] = rdf(p + 12);
        c->mode = p[16];
        return DEM_OK;
    }
    if (type == DEM_CONFIG) {
        dem_config_t *c = &fr->f.config;
        size_t k;
        if (n != DEM_CONFIG_SIZE) return DEM_ERR_SIZE;
        if (p[121] | p[122] | p[123]) return DEM_ERR_RESERVED;
        for (k = 0; k < DEM_CONFIG_FLOATS; ++k)
            if (nonfinite_bits(rd32(p + 4 + 4 * k))) return DEM_ERR_NONFINITE;
        fr->type = DEM_CONFIG;
        for (k = 0; k < DEM_CONFIG_FLOATS; ++k) c->v[k] = rdf(p + 4 + 4 * k);
        c->command_delay = p[120];
        return DEM_OK;
    }
    if (type == DEM_CONFIG_ACK) {
        dem_config_ack_t *a = &fr->f.config_ack;
        if (n != DEM_CONFIG_ACK_SIZE) return DEM_ERR_SIZE;
        if (p[15]) return DEM_ERR_RESERVED;
        if (p[14] > DEM_FAULT) return DEM_ERR_MODE;
        if (p[12] > DEM_CFG_BUSY || p[13] > 1) return DEM_ERR_RANGE;
        fr->type = DEM_CONFIG_ACK;
        a->active_crc = rd32(p + 4);
        a->request_crc = rd32(p + 8);
        a->result = p[12];
        a->configured = p[13];
        a->mode = p[14];
        return DEM_OK;
    }
    return DEM_ERR_TYPE;
}

/* --- COBS (Cheshire & Baker 1999) --- */
int dem_cobs_encode(const uint8_t *in, size_t n, uint8_t *out, size_t cap, size_t *len)
{
    size_t code_at = 0, o = 1, i;
    uint8_t code = 1;
    *len = 0;
    if (cap < 1) return DEM_ERR_BUFFER;
    for (i = 0; i < n; ++i) {
        if (in[i] == 0) {
            out[code_at] = code;
            if (o >= cap) return DEM_ERR_BUFFER;
            code_at = o++;
            code = 1;
        } else {
            if (o >= cap) return DEM_ERR_BUFFER;
            out[o++] = in[i];
            if (++code == 0xFF) {
                out[code_at] = code;
                if (o >= cap) return DEM_ERR_BUFFER;
                code_at = o++;
                code = 1;
            }
        }
    }
    out[code_at] = code;
    *len = o;
    return DEM_OK;
}

int dem_cobs_decode(const uint8_t *in, size_t n, uint8_t *out, size_t cap, size_t *len)
{
    size_t i = 0, o = 0, k;
    *len = 0;
    if (n == 0) return DEM_ERR_SHORT;
    while (i < n) {
        uint8_t code = in[i];
        if (code == 0) return DEM_ERR_LENGTH;       /* a zero inside the encoding */
        if (i + code > n) return DEM_ERR_LENGTH;    /* block runs past the end */
        for (k = i + 1; k < i + code; ++k) {
            if (in[k] == 0) return DEM_ERR_LENGTH;
            if (o >= cap) return DEM_ERR_BUFFER;
            out[o++] = in[k];
        }
        i += code;
        if (code < 0xFF && i < n) {
            if (o >= cap) return DEM_ERR_BUFFER;
            out[o++] = 0;
        }
    }
    *len = o;
    return DEM_OK;
}

void dem_deframer_init(dem_deframer_t *d) { memset(d, 0, sizeof *d); }

int dem_deframer_push(dem_deframer_t *d, uint8_t byte, uint8_t *out, size_t cap, size_t *len)
{
    *len = 0;
    if (byte != 0) {
        if (d->skipping) return 0;
        if (d->len >= DEM_MAX_ENCODED_SIZE) { /* too long for any frame: drop up to the next 0x00 */
            d->dropped_oversize++;
            d->len = 0;
            d->skipping = 1;
            return 0;
        }
        d->buf[d->len++] = byte;
        return 0;
    }
    if (d->skipping) {
        d->skipping = 0;
        return 0;
    }
    if (d->len == 0) return 0; /* empty segment: back-to-back delimiters */
    if (dem_cobs_decode(d->buf, d->len, out, cap, len) != DEM_OK) {
        d->dropped_cobs++;
        d->len = 0;
        *len = 0;
        return 0;
    }
    d->len = 0;
    d->frames++;
    return 1;
}
