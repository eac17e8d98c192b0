/*
 * test_board: unit tests of the board firmware (supervisor.c, board.c) on a nominal float32 plant, for the
 * host (make test-host) and the emulated Cortex-M4F (make test-arm: semihosting prints and the exit code).
 * Prints "PASS name" / "FAIL name: why" per test and, on the target, the largest step cost it measured.
 * The equivalence with the Python board is tests/firmware/test_differential.py's (>= 1000 cases).
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "board.h"
#include "hal.h"

/* cycle counter of the target (arm/startup.c: SysTick under qemu -icount); the host build has none */
#ifdef __arm__
unsigned long cost_ticks(void);
unsigned long cost_ticks_per_unit(void);
#else
static unsigned long cost_ticks(void) { return 0; }
static unsigned long cost_ticks_per_unit(void) { return 0; }
#endif

static int failures;
static void check(int ok, const char *name, const char *why)
{
    if (ok) {
        printf("PASS %s\n", name);
    } else {
        printf("FAIL %s: %s\n", name, why);
        ++failures;
    }
}

static sup_config_t table2(void)
{
    sup_config_t c;
    c.u_max = 200.0f; c.i_max = 10.0f; c.trip_gap_min = 0.0015f; c.trip_gap_max = 0.013f; c.hold_timeout = 0.05f;
    c.landing_gap = 0.011f; c.landing_speed = 0.01f;
    c.m = 14.852f; c.R = 20.0f; c.K = 0.0004374f; c.L = 0.3f; c.l = 0.168f; c.I = 0.5648f; c.N1 = 36.5f;
    c.N2 = 36.5f; c.g = 9.81f; c.dt = 1e-3f;
    return c;
}

/* -- the nominal plant (Eqs. 3-8), float, 10 Euler sub-steps per sample; the rig's support at 11.2 mm -- */
typedef struct { float y[2], v[2], lam[2]; } plant_t;
#define SUPPORT 0.0112f
static void plant_currents(const sup_config_t *c, const plant_t *p, float i[2])
{
    const float P = (c->L + c->l) / (2 * c->L), Q = (c->L - c->l) / (2 * c->L);
    const float de0 = P * p->y[0] + Q * p->y[1], de1 = Q * p->y[0] + P * p->y[1];
    i[0] = p->lam[0] * de0 / (2 * c->K);
    i[1] = p->lam[1] * de1 / (2 * c->K);
}
static void plant_hover(const sup_config_t *c, plant_t *p, float gap, float u0[2])
{
    const float P = (c->L + c->l) / (2 * c->L), Q = (c->L - c->l) / (2 * c->L), de = (P + Q) * gap;
    const float i = de * sqrtf((c->N1 + c->m * c->g / 2) / c->K);
    int j;
    for (j = 0; j < 2; ++j) {
        p->y[j] = gap;
        p->v[j] = 0.0f;
        p->lam[j] = 2 * c->K * i / de;
        u0[j] = c->R * i;
    }
}
static void plant_advance(const sup_config_t *c, plant_t *p, const float u[2])
{
    const float A = 1 / c->m + c->L * c->l / c->I, B = 1 / c->m - c->L * c->l / c->I;
    const float C = 1 / c->m + c->L * c->L / c->I, D = 1 / c->m - c->L * c->L / c->I, h = c->dt / 10;
    int k, j;
    for (k = 0; k < 10; ++k) {
        float i[2], F[2], a[2];
        plant_currents(c, p, i);
        for (j = 0; j < 2; ++j) {
            const float P = (c->L + c->l) / (2 * c->L), Q = (c->L - c->l) / (2 * c->L);
            const float de = j == 0 ? P * p->y[0] + Q * p->y[1] : Q * p->y[0] + P * p->y[1];
            F[j] = c->K * i[j] * i[j] / (de * de);
        }
        a[0] = C * c->N1 + D * c->N2 + c->g - A * F[0] - B * F[1];
        a[1] = D * c->N1 + C * c->N2 + c->g - B * F[0] - A * F[1];
        for (j = 0; j < 2; ++j) {
            p->lam[j] += h * (u[j] - c->R * i[j]);
            p->v[j] += h * a[j];
            p->y[j] += h * p->v[j];
            if (p->y[j] >= SUPPORT) {
                p->y[j] = SUPPORT;
                if (p->v[j] > 0) p->v[j] = 0;
            }
        }
    }
}

static unsigned long worst_sup, worst_board;

/* hover at 8 mm under the hover command for 30 samples, then: what = 0 no command, 1 current 1 lost,
 * 2 gap 1 lost, 3 LAND requested. Returns the sample it reached LANDED (-1: never); *closest: the smallest gap. */
static int landing(int what, int *first_land, float *closest, int *fault)
{
    const sup_config_t c = table2();
    static sup_t s;
    plant_t p;
    float u0[2], u[2];
    int k;
    plant_hover(&c, &p, 0.008f, u0);
    sup_init(&s, &c, SUP_OFF, NULL);
    *first_land = -1;
    *closest = 1.0f;
    *fault = 0;
    for (k = 0; k < 4000; ++k) {
        float y[2], i[2];
        unsigned long t0, t1;
        plant_currents(&c, &p, i);
        y[0] = p.y[0];
        y[1] = p.y[1];
        if (what == 1 && k >= 300) i[0] = NAN;
        if (what == 2 && k >= 300) y[0] = NAN;
        t0 = cost_ticks();
        sup_step(&s, (int64_t)k * 1000, y, i, (k < 30 || what != 0) ? u0 : NULL,
                 (what == 3 && k >= 300) ? SUP_LAND : SUP_RUN, 200.0f, NULL, u);
        t1 = cost_ticks();
        if (t0 - t1 > worst_sup && t0 >= t1) worst_sup = t0 - t1; /* SysTick counts down */
        if (s.mode == SUP_LAND && *first_land < 0) *first_land = k;
        if (s.mode == SUP_FAULT) *fault = 1;
        if (p.y[0] < *closest) *closest = p.y[0];
        if (p.y[1] < *closest) *closest = p.y[1];
        if (s.mode == SUP_LANDED || s.mode == SUP_FAULT) return k;
        plant_advance(&c, &p, u);
    }
    return -1;
}

static void test_config(void)
{
    sup_config_t c = table2();
    static sup_t s;
    check(sup_init(&s, &c, SUP_OFF, NULL) == SUP_CFG_OK, "config_table2_accepted", "refused");
    c.trip_gap_min = 0.012f;
    check(sup_init(&s, &c, SUP_OFF, NULL) == SUP_CFG_GAP_ORDER, "config_gap_order", "accepted");
    c = table2();
    c.R = -1.0f;
    check(sup_init(&s, &c, SUP_OFF, NULL) == SUP_CFG_NOT_POSITIVE, "config_positive", "accepted");
    c = table2();
    c.l = 0.4f;
    check(sup_init(&s, &c, SUP_OFF, NULL) == SUP_CFG_ARMS, "config_arms", "accepted");
    c = table2();
    c.N1 = 500.0f;
    check(sup_init(&s, &c, SUP_OFF, NULL) == SUP_CFG_NO_BRAKING, "config_braking", "accepted");
    c = table2();
    c.K = NAN;
    check(sup_init(&s, &c, SUP_OFF, NULL) == SUP_CFG_NONFINITE, "config_nonfinite", "accepted");
}

static void test_landings(void)
{
    static const char *const names[] = {"lost_commands_hold_then_land", "lost_current_sensor_lands_on_coil_model",
                                        "lost_gap_sensor_lands_on_coil_flux", "requested_land"};
    static const int land_at[] = {80, 305, 305, 300};
    int what;
    for (what = 0; what < 4; ++what) {
        int first, fault, k;
        float closest;
        char why[160];
        k = landing(what, &first, &closest, &fault);
        snprintf(why, sizeof why, "LAND at %d (want %d), LANDED at %d, fault %d, closest %.3f mm", first,
                 land_at[what], k, fault, (double)(closest * 1e3f));
        check(k > 0 && !fault && first == land_at[what] && closest > 0.0079f, names[what], why);
    }
}

/* hover at 10.2 mm (a lift-off's top, 1 mm under the support) under the hover command; at sample 200 one command
 * 3 % under it (the force below the weight: the controller slowing a rise), then none: the held plate falls back
 * toward its support. The hold's speed guard lands it before its descent outruns landing_speed (measured: LAND
 * 13 ms after the last command, descent 9.1 mm/s; the 50 ms hold alone let it reach the support at 57.5 mm/s). */
static void test_held_plate_lands_early(void)
{
    const sup_config_t c = table2();
    static sup_t s;
    plant_t p;
    float u0[2], u[2], held[2], vmax = 0.0f, closest = 1.0f;
    int k, first = -1, landed = -1;
    char why[200];
    plant_hover(&c, &p, 0.0102f, u0);
    held[0] = 0.97f * u0[0];
    held[1] = 0.97f * u0[1];
    sup_init(&s, &c, SUP_OFF, NULL);
    for (k = 0; k < 3000 && landed < 0; ++k) {
        float y[2], i[2];
        plant_currents(&c, &p, i);
        y[0] = p.y[0];
        y[1] = p.y[1];
        sup_step(&s, (int64_t)k * 1000, y, i, k < 200 ? u0 : (k == 200 ? held : NULL), SUP_RUN, 200.0f, NULL, u);
        if (s.mode == SUP_LAND && first < 0) first = k;
        if (s.mode == SUP_LANDED) landed = k;
        plant_advance(&c, &p, u);
        if (k > 200 && s.mode != SUP_LANDED) {
            if (p.v[0] > vmax) vmax = p.v[0];
            if (p.v[1] > vmax) vmax = p.v[1];
        }
        if (p.y[0] < closest) closest = p.y[0];
        if (p.y[1] < closest) closest = p.y[1];
    }
    snprintf(why, sizeof why, "LAND at %d (the last command at 200), reason %d/%d, LANDED at %d, descent %.2f mm/s, "
             "closest %.3f mm", first, s.reason.code, s.reason.sub, landed, (double)(vmax * 1e3f),
             (double)(closest * 1e3f));
    check(first > 200 && first < 250 && s.reason.code == SUP_WHY_HOLD_TIMEOUT && s.reason.sub == 1 && landed > 0 &&
          vmax <= 1.17f * c.landing_speed && closest > 0.0097f && s.command_timeout, "held_plate_lands_before_it_falls",
          why);
}

static void test_limits(void)
{
    const sup_config_t c = table2();
    static sup_t s;
    float y[2] = {0.008f, 0.008f}, i[2] = {4.0f, 4.0f}, cmd[2] = {500.0f, -80.0f}, u[2];
    sup_init(&s, &c, SUP_OFF, NULL);
    sup_step(&s, 0, y, i, cmd, SUP_RUN, NAN, NULL, u);
    check(s.mode == SUP_RUN && s.counters.clipped == 1 && u[0] == 200.0f && u[1] == -80.0f, "clip_to_u_max", "");
    sup_init(&s, &c, SUP_OFF, NULL);
    cmd[0] = 80.0f;
    cmd[1] = 80.0f;
    sup_step(&s, 0, y, i, cmd, SUP_RUN, NAN, NULL, u);
    i[1] = 10.5f;
    sup_step(&s, 1000, y, i, cmd, SUP_RUN, NAN, NULL, u);
    check(s.mode == SUP_LAND && s.fault.code == SUP_WHY_I_MAX && s.counters.trips == 1, "current_trip_latches", "");
    sup_clear(&s);
    check(s.mode == SUP_OFF && s.fault.code == SUP_WHY_NONE, "clear_to_off", "");
    y[0] = NAN;
    sup_step(&s, 2000, y, i, NULL, SUP_OFF, NAN, NULL, u);
    check(s.mode == SUP_FAULT && u[0] == 0.0f && u[1] == 0.0f, "nonfinite_while_resting_faults_0V", "");
}

/* -- the board around it, on a fake HAL (a frame queue both ways) ------------------------------------- */
static uint64_t now_us;
static uint16_t adc_gap[2] = {25000, 25000}, adc_i[2] = {45875, 45875};
static float pwm[2];
static uint8_t rxq[8][DEM_MAX_FRAME_SIZE];
static size_t rxn[8], rx_head, rx_tail;
static dem_frame_t last_tx, last_ack;
static unsigned tx_count, acks;
uint64_t hal_micros(void) { return now_us; }
int hal_adc_read(uint16_t gap[2], uint16_t current[2], float *bus_v)
{
    gap[0] = adc_gap[0];
    gap[1] = adc_gap[1];
    current[0] = adc_i[0];
    current[1] = adc_i[1];
    *bus_v = 200.0f;
    return 0;
}
void hal_pwm_set(const float duty[2]) { pwm[0] = duty[0]; pwm[1] = duty[1]; }
uint32_t hal_status(void) { return 0; }
size_t hal_link_recv(uint8_t *buf, size_t cap)
{
    size_t n;
    if (rx_head == rx_tail) return 0;
    n = rxn[rx_tail % 8];
    if (n > cap) n = cap;
    memcpy(buf, rxq[rx_tail % 8], n);
    ++rx_tail;
    return n;
}
void hal_link_send(const uint8_t *frame, size_t len)
{
    dem_decode(frame, len, &last_tx);
    if (last_tx.type == DEM_CONFIG_ACK) {
        last_ack = last_tx;
        ++acks;
    }
    ++tx_count;
}
static void pc_send(const dem_frame_t *f)
{
    size_t n;
    dem_encode(f, rxq[rx_head % 8], DEM_MAX_FRAME_SIZE, &n);
    rxn[rx_head % 8] = n;
    ++rx_head;
}

static board_config_t board_defaults(void)
{
    board_config_t cfg;
    int j;
    memset(&cfg, 0, sizeof cfg);
    cfg.sup = table2();
    for (j = 0; j < 2; ++j) {
        cfg.gap_c[j][1] = 2.5e-7f;
        cfg.gap_c[j][2] = 8e-13f;
        cfg.i_gain[j] = 0.00030517578125f;
        cfg.i_offset[j] = 32768.0f;
    }
    cfg.board_id = 7;
    cfg.adc_bits = 16;
    cfg.command_delay = 1;
    cfg.adc_vref = 10.0f;
    return cfg;
}

/* board_configure(): what a CONFIG frame does to a board at rest (the rules of docs/hardware-link.md) */
static void test_board_configure(void)
{
    static board_t b;
    board_config_t cfg = board_defaults();
    dem_config_t c, c150;
    dem_config_ack_t a;
    uint32_t crc0;
    int r;
    char why[120];
    check(board_init(&b, &cfg) == DEM_CFG_OK && b.configured == 0, "configure_defaults_not_configured", "");
    board_config_to_link(&cfg, &c);
    crc0 = b.config_crc;
    check(crc0 == dem_config_crc(&c), "configure_crc_is_the_frames", "");
    b.sup.counters.landings = 3; /* a restarted supervisor would forget it */
    r = board_configure(&b, &c, &a);
    check(r == DEM_CFG_OK && a.configured == 1 && a.active_crc == crc0 && a.request_crc == crc0 &&
              b.sup.counters.landings == 3, "configure_same_again_changes_nothing", "");
    c150 = c;
    c150.v[0] = 150.0f; /* u_max */
    r = board_configure(&b, &c150, &a);
    check(r == DEM_CFG_OK && b.cfg.sup.u_max == 150.0f && a.active_crc == dem_config_crc(&c150) &&
              a.active_crc == a.request_crc && a.active_crc != crc0 && b.sup.counters.landings == 0 &&
              a.mode == DEM_OFF, "configure_new_limits_restart_the_supervisor", "");
    c = c150;
    c.v[8] = -1.0f; /* R */
    r = board_configure(&b, &c, &a);
    snprintf(why, sizeof why, "result %s, u_max %g", dem_config_reason(r), (double)b.cfg.sup.u_max);
    check(r == DEM_CFG_NOT_POSITIVE && a.active_crc == dem_config_crc(&c150) && a.request_crc == dem_config_crc(&c) &&
              b.cfg.sup.u_max == 150.0f && b.cfg.sup.R == 20.0f, "configure_refused_keeps_the_active_one", why);
    c = c150;
    c.v[2] = 0.012f; /* trip_gap_min above landing_gap */
    check(board_configure(&b, &c, &a) == DEM_CFG_GAP_ORDER, "configure_gap_order", "");
    c = c150;
    c.v[13] = 500.0f; /* N1 */
    check(board_configure(&b, &c, &a) == DEM_CFG_NO_BRAKING, "configure_no_braking", "");
    c = c150;
    c.v[16] = 2e-3f; /* dt */
    check(board_configure(&b, &c, &a) == DEM_CFG_RATE, "configure_rate", "");
    c = c150;
    c.v[DEM_CONFIG_SUP + 9] = NAN; /* current2_gain (the codec refuses it; the board checks anyway) */
    check(board_configure(&b, &c, &a) == DEM_CFG_NONFINITE, "configure_nonfinite_calibration", "");
    c = c150;
    c.command_delay = 0;
    r = board_configure(&b, &c, &a);
    c.command_delay = BOARD_MAX_DELAY + 1;
    r = r == DEM_CFG_DELAY ? board_configure(&b, &c, &a) : r;
    check(r == DEM_CFG_DELAY && b.cfg.command_delay == 1, "configure_delay_range", "");
    c.command_delay = BOARD_MAX_DELAY;
    c.v[DEM_CONFIG_SUP + 1] = 3e-7f; /* gap1_c1 */
    r = board_configure(&b, &c, &a);
    check(r == DEM_CFG_OK && b.cfg.command_delay == BOARD_MAX_DELAY && b.cfg.gap_c[0][1] == 3e-7f &&
              b.configs == 10 && b.configs_refused == 7, "configure_delay_and_calibration", "");
    cfg.command_delay = BOARD_MAX_DELAY + 1;
    check(board_init(&b, &cfg) == DEM_CFG_DELAY, "board_init_delay_range", "");
    cfg = board_defaults();
    cfg.i_offset[1] = INFINITY;
    check(board_init(&b, &cfg) == DEM_CFG_NONFINITE, "board_init_nonfinite_calibration", "");
}

static void test_board(void)
{
    static board_t b;
    board_config_t cfg = board_defaults();
    dem_frame_t f;
    int k, timeout_seen = 0, late_seen = 0;
    uint32_t crc0;
    char why[100];
    check(board_init(&b, &cfg) == 0, "board_init", "refused");
    crc0 = b.config_crc;
    memset(&f, 0, sizeof f);
    f.type = DEM_HELLO;
    f.f.hello.version = 1;
    pc_send(&f);
    board_step(&b);
    check(tx_count == 2 && b.streaming && b.hellos == 1, "hello_answered_then_streaming", "");
    for (k = 1; k < 200; ++k) {
        unsigned long t0, t1;
        now_us += 1000;
        if (k == 50) { /* mid-flight, a configuration with another u_max: refused, busy */
            memset(&f, 0, sizeof f);
            f.type = DEM_CONFIG;
            board_config_to_link(&cfg, &f.f.config);
            f.f.config.v[0] = 150.0f;
            pc_send(&f);
        }
        if (k < 100) { /* the PC answers every sensor frame with a RUN command at the hover voltage */
            memset(&f, 0, sizeof f);
            f.type = DEM_COMMAND;
            f.f.command.seq = last_tx.f.sensor.seq;
            f.f.command.u[0] = f.f.command.u[1] = 80.0f;
            f.f.command.mode = DEM_RUN;
            pc_send(&f);
        }
        t0 = cost_ticks();
        board_step(&b);
        t1 = cost_ticks();
        if (t0 >= t1 && t0 - t1 > worst_board) worst_board = t0 - t1;
        if (last_tx.f.sensor.status & DEM_ST_LINK_TIMEOUT) timeout_seen = k;
        if ((last_tx.f.sensor.status & DEM_ST_COMMAND_LATE) && !late_seen) late_seen = k;
    }
    check(last_tx.type == DEM_SENSOR && last_tx.f.sensor.seq == 199 && b.fresh >= 98, "sensor_frames_and_commands",
          "");
    snprintf(why, sizeof why, "late at %d, LINK_TIMEOUT at %d, mode %d", late_seen, timeout_seen,
             last_tx.f.sensor.mode);
    check(late_seen == 100 && timeout_seen > 0 && (last_tx.f.sensor.mode == DEM_LAND ||
                                                    last_tx.f.sensor.mode == DEM_LANDED),
          "link_watchdog_lands", why);
    check(acks == 1 && last_ack.f.config_ack.result == DEM_CFG_BUSY && last_ack.f.config_ack.mode == DEM_RUN &&
              last_ack.f.config_ack.active_crc == crc0 && b.cfg.sup.u_max == 200.0f,
          "config_refused_in_flight", "");
    b.sup.mode = SUP_LANDED; /* (the fake ADC does not move: the landing law would fly on; the plate is down) */
    memset(&f, 0, sizeof f);
    f.type = DEM_CONFIG;
    board_config_to_link(&cfg, &f.f.config);
    f.f.config.v[0] = 150.0f;
    pc_send(&f);
    now_us += 1000;
    board_step(&b);
    snprintf(why, sizeof why, "acks %u, result %s, mode %u", acks, dem_config_reason(last_ack.f.config_ack.result),
             last_ack.f.config_ack.mode);
    check(acks == 2 && last_ack.f.config_ack.result == DEM_CFG_OK && last_ack.f.config_ack.configured == 1 &&
              last_ack.f.config_ack.active_crc == dem_config_crc(&f.f.config) &&
              last_ack.f.config_ack.mode == DEM_OFF && b.cfg.sup.u_max == 150.0f,
          "config_taken_once_landed", why);
}

int main(void)
{
    test_config();
    test_landings();
    test_held_plate_lands_early();
    test_limits();
    test_board_configure();
    test_board();
    if (cost_ticks_per_unit() > 0)
        printf("COST worst sup_step %lu instructions, board_step %lu instructions (qemu -icount shift=0)\n",
               worst_sup * cost_ticks_per_unit(), worst_board * cost_ticks_per_unit());
    printf("RAM board_t %u bytes (sup_t %u)\n", (unsigned)sizeof(board_t), (unsigned)sizeof(sup_t));
    printf("%s: %d failed\n", failures ? "FAILED" : "OK", failures);
    return failures ? 1 : 0;
}
