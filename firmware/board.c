/* board: the firmware's 1 kHz tick around the supervisor (board.h). */
#include "board.h"

#include <math.h>
#include <string.h>

#include "hal.h"

static int32_t seq_diff(uint32_t a, uint32_t b) { return (int32_t)(a - b); }

int board_init(board_t *b, const board_config_t *cfg)
{
    int r;
    memset(b, 0, sizeof *b);
    b->cfg = *cfg;
    r = sup_init(&b->sup, &cfg->sup, SUP_OFF, NULL);
    if (r != SUP_CFG_OK) return r;
    if (cfg->command_delay < 1 || cfg->adc_bits < 8 || cfg->adc_bits > 16) return SUP_CFG_NOT_POSITIVE;
    b->request = DEM_OFF;
    b->t0_us = hal_micros();
    return 0;
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
