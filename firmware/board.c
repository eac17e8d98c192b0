/* board: the firmware's 1 kHz tick around the supervisor (board.h). */
#include "board.h"

#include <math.h>
#include <string.h>

#include "hal.h"

static int32_t seq_diff(uint32_t a, uint32_t b) { return (int32_t)(a - b); }

/* sup_config_t is the CONFIG frame's first DEM_CONFIG_SUP floats, in that order (supervisor.c reads it as an array) */
typedef char board_sup_config_is_the_links[sizeof(sup_config_t) == DEM_CONFIG_SUP * sizeof(float) ? 1 : -1];

void board_config_to_link(const board_config_t *cfg, dem_config_t *out)
{
    memcpy(out->v, &cfg->sup, sizeof cfg->sup);
    memcpy(out->v + DEM_CONFIG_SUP, cfg->gap_c, sizeof cfg->gap_c);
    memcpy(out->v + DEM_CONFIG_SUP + 8, cfg->i_gain, sizeof cfg->i_gain);
    memcpy(out->v + DEM_CONFIG_SUP + 10, cfg->i_offset, sizeof cfg->i_offset);
    out->command_delay = cfg->command_delay;
}

static void config_from_link(board_config_t *cfg, const dem_config_t *c)
{
    memcpy(&cfg->sup, c->v, sizeof cfg->sup);
    memcpy(cfg->gap_c, c->v + DEM_CONFIG_SUP, sizeof cfg->gap_c);
    memcpy(cfg->i_gain, c->v + DEM_CONFIG_SUP + 8, sizeof cfg->i_gain);
    memcpy(cfg->i_offset, c->v + DEM_CONFIG_SUP + 10, sizeof cfg->i_offset);
    cfg->command_delay = c->command_delay;
}

/* The rules of a configuration, board_init()'s and a CONFIG frame's, in this order: the calibration finite,
 * sup_init()'s checks (it fills s), the command delay, the ADC. Returns 0 or enum dem_config_result. */
static int config_check(const board_config_t *cfg, sup_t *s)
{
    int j, p, r;
    for (j = 0; j < 2; ++j) {
        for (p = 0; p < 4; ++p)
            if (!isfinite(cfg->gap_c[j][p])) return DEM_CFG_NONFINITE;
        if (!isfinite(cfg->i_gain[j]) || !isfinite(cfg->i_offset[j])) return DEM_CFG_NONFINITE;
    }
    r = sup_init(s, &cfg->sup, SUP_OFF, NULL);
    if (r != SUP_CFG_OK) return r;
    if (cfg->command_delay < 1 || cfg->command_delay > BOARD_MAX_DELAY) return DEM_CFG_DELAY;
    if (cfg->adc_bits < 8 || cfg->adc_bits > 16) return DEM_CFG_NOT_POSITIVE;
    return DEM_CFG_OK;
}

static uint32_t config_crc(const board_config_t *cfg)
{
    dem_config_t c;
    board_config_to_link(cfg, &c);
    return dem_config_crc(&c);
}

int board_init(board_t *b, const board_config_t *cfg)
{
    int r;
    memset(b, 0, sizeof *b);
    b->cfg = *cfg;
    r = config_check(cfg, &b->sup);
    if (r != DEM_CFG_OK) return r;
    b->config_crc = config_crc(cfg);
    b->request = DEM_OFF;
    b->t0_us = hal_micros();
    return 0;
}

int board_configure(board_t *b, const dem_config_t *c, dem_config_ack_t *ack)
{
    const uint32_t crc = dem_config_crc(c);
    const int mode = sup_mode(&b->sup);
    int r = DEM_CFG_OK;
    if (mode != SUP_OFF && mode != SUP_LANDED) {
        r = DEM_CFG_BUSY; /* never a change in flight (or with a latched fault) */
    } else if (crc != b->config_crc) {
        board_config_t next = b->cfg;
        sup_t fresh;
        config_from_link(&next, c);
        r = next.sup.dt == b->cfg.sup.dt ? config_check(&next, &fresh) : DEM_CFG_RATE;
        if (r == DEM_CFG_OK) {
            if (memcmp(&next.sup, &b->cfg.sup, sizeof next.sup) != 0) b->sup = fresh; /* restarted, OFF */
            b->cfg = next;
            b->config_crc = crc;
        }
    }
    b->configs += 1;
    if (r == DEM_CFG_OK) b->configured = 1;
    else b->configs_refused += 1;
    ack->active_crc = b->config_crc;
    ack->request_crc = crc;
    ack->result = (uint8_t)r;
    ack->configured = b->configured;
    ack->mode = (uint8_t)sup_mode(&b->sup);
    return r;
}

static void send(const dem_frame_t *f)
{
    uint8_t out[DEM_MAX_FRAME_SIZE];
    size_t n;
    if (dem_encode(f, out, sizeof out, &n) == DEM_OK) hal_link_send(out, n);
}

static void receive(board_t *b)
{
    uint8_t buf[DEM_MAX_FRAME_SIZE + 1];
    size_t n;
    int k;
    for (k = 0; k < 8 * (int)BOARD_CMD_RING; ++k) { /* bounded: at most this many frames per tick */
        dem_frame_t f;
        n = hal_link_recv(buf, sizeof buf);
        if (n == 0) break;
        if (dem_decode(buf, n, &f) != DEM_OK) {
            b->rx_rejected += 1;
            b->rx_error = 1;
            continue;
        }
        b->rx_frames += 1;
        if (f.type == DEM_HELLO) {
            dem_frame_t h;
            memset(&h, 0, sizeof h);
            h.type = DEM_HELLO;
            h.f.hello.version = DEM_LINK_VERSION;
            h.f.hello.board_id = b->cfg.board_id;
            h.f.hello.rate_hz = (uint32_t)(1.0f / b->cfg.sup.dt + 0.5f);
            h.f.hello.adc_bits = b->cfg.adc_bits;
            h.f.hello.command_delay = b->cfg.command_delay;
            h.f.hello.watchdog_ms = (uint16_t)(b->cfg.sup.hold_timeout * 1e3f + 0.5f);
            h.f.hello.adc_vref = b->cfg.adc_vref;
            b->hellos += 1;
            b->streaming = 1;
            send(&h);
        } else if (f.type == DEM_CONFIG) {
            dem_frame_t a;
            memset(&a, 0, sizeof a);
            a.type = DEM_CONFIG_ACK;
            board_configure(b, &f.f.config, &a.f.config_ack);
            send(&a);
        } else if (f.type == DEM_COMMAND) {
            const dem_command_t *c = &f.f.command;
            if (c->mode == DEM_RUN) { /* kept by the sample it answers */
                b->cmds[c->seq % BOARD_CMD_RING] = *c;
                b->cmd_valid[c->seq % BOARD_CMD_RING] = 1;
            }
            if (!b->have_request || seq_diff(c->seq, b->request_seq) >= 0) {
                b->request = c->mode;
                b->request_seq = c->seq;
                b->have_request = 1;
            }
        }
    }
}

void board_step(board_t *b)
{
    const uint32_t full = (1u << b->cfg.adc_bits) - 1u;
    const uint32_t want = b->n - b->cfg.command_delay;
    uint16_t gc[2], cc[2];
    float bus, y[2], i[2], u[2], duty[2];
    uint32_t status = hal_status();
    const dem_command_t *cmd = &b->cmds[want % BOARD_CMD_RING];
    int fresh, requested, j, mode;
    uint64_t now = hal_micros();
    dem_frame_t s;
    receive(b);
    if (hal_adc_read(gc, cc, &bus) != 0) {
        status |= DEM_ST_ADC_FAULT;
        bus = NAN;
    }
    for (j = 0; j < 2; ++j) {
        const float n = (float)gc[j];
        const float *c = b->cfg.gap_c[j];
        if (gc[j] == 0 || gc[j] >= full || (status & DEM_ST_ADC_FAULT)) { /* dead or saturated: no sample */
            y[j] = NAN;
            status |= DEM_ST_GAP0_RANGE << j;
        } else {
            y[j] = c[0] + n * (c[1] + n * (c[2] + n * c[3]));
        }
        i[j] = (status & DEM_ST_ADC_FAULT) ? NAN : b->cfg.i_gain[j] * ((float)cc[j] - b->cfg.i_offset[j]);
    }
    if (b->rx_error) {
        status |= DEM_ST_RX_ERROR;
        b->rx_error = 0;
    }
    fresh = b->n >= b->cfg.command_delay && b->cmd_valid[want % BOARD_CMD_RING] && cmd->seq == want &&
            b->request == DEM_RUN;
    if (fresh) b->fresh += 1;
    requested = b->request;
    mode = sup_mode(&b->sup);
    if (requested == DEM_OFF && (mode == SUP_LANDED || mode == SUP_FAULT)) sup_clear(&b->sup); /* acknowledged */
    if (requested == DEM_RUN && !fresh && (mode == SUP_OFF || mode == SUP_LANDED)) requested = DEM_OFF;
    if (mode == SUP_RUN && !fresh) status |= DEM_ST_COMMAND_LATE;
    if (status & DEM_ST_ESTOP) sup_estop(&b->sup, 1);
    sup_step(&b->sup, (int64_t)(now - b->t0_us), y, i, fresh ? cmd->u : NULL, requested, bus, b->applied, u);
    mode = sup_mode(&b->sup);
    if ((mode == SUP_LAND || mode == SUP_LANDED) && b->sup.command_timeout) status |= DEM_ST_LINK_TIMEOUT;
    if (fresh && (fabsf(cmd->u[0]) > b->cfg.sup.u_max || fabsf(cmd->u[1]) > b->cfg.sup.u_max))
        status |= DEM_ST_VOLTAGE_CLIPPED;
    for (j = 0; j < 2; ++j)
        if (b->sup.implausible[j]) status |= DEM_ST_GAP0_IMPLAUSIBLE << j;
    memset(&s, 0, sizeof s);
    s.type = DEM_SENSOR;
    s.f.sensor.seq = b->n;
    s.f.sensor.board_time_us = now;
    s.f.sensor.gap_counts[0] = gc[0];
    s.f.sensor.gap_counts[1] = gc[1];
    s.f.sensor.current_counts[0] = cc[0];
    s.f.sensor.current_counts[1] = cc[1];
    s.f.sensor.applied_v[0] = b->applied[0];
    s.f.sensor.applied_v[1] = b->applied[1];
    s.f.sensor.bus_v = isfinite(bus) ? bus : 0.0f;
    s.f.sensor.status = status;
    s.f.sensor.mode = (uint8_t)mode;
    for (j = 0; j < 2; ++j) { /* duty = u / bus: what the bridge applies of the bus it has */
        const float d = isfinite(bus) && bus > 0.0f ? u[j] / bus : 0.0f;
        duty[j] = d > 1.0f ? 1.0f : (d < -1.0f ? -1.0f : d);
        b->applied[j] = isfinite(bus) ? duty[j] * bus : 0.0f;
    }
    hal_pwm_set(duty);
    if (b->streaming) send(&s);
    b->n += 1;
}
