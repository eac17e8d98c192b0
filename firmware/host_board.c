/*
 * Host program: the board's tick (board.c, supervisor.c, dem_link.c) on a fake HAL, driven by a script on stdin,
 * so tests can hold the C board's answers to frames to the Python board's (tests/firmware/test_firmware_c.py).
 * Not for the board. One command per line, one answer line each:
 *
 *   init HEX       board_init() with the configuration of this CONFIG frame (board id 7, 16-bit ADC, 10 V)
 *                  -> "init RESULT CRC"
 *   hello          a hello request, one tick -> "hello RATE WATCHDOG_MS DELAY"
 *   run N U0 U1    N ticks, each sensor frame answered with a RUN command (U0, U1) -> "mode MODE"
 *   config HEX     the frame received, one tick -> "ack RESULT CONFIGURED ACTIVE_CRC REQUEST_CRC MODE"
 *                  (or "rejected REASON" when the codec refuses it)
 *
 * The fake ADC reads a gap of 6.75 mm and 4 A on both channels (the default calibration), the bus 200 V.
 */
#include <stdio.h>
#include <string.h>

#include "board.h"
#include "hal.h"

static uint64_t now_us;
static uint8_t rxq[16][DEM_MAX_FRAME_SIZE];
static size_t rxn[16], rx_head, rx_tail;
static dem_frame_t last_sensor, last_hello, last_ack;
static int got_ack, got_hello;

uint64_t hal_micros(void) { return now_us; }
int hal_adc_read(uint16_t gap[2], uint16_t current[2], float *bus_v)
{
    gap[0] = gap[1] = 25000;
    current[0] = current[1] = 45875;
    *bus_v = 200.0f;
    return 0;
}
void hal_pwm_set(const float duty[2]) { (void)duty; }
uint32_t hal_status(void) { return 0; }
size_t hal_link_recv(uint8_t *buf, size_t cap)
{
    size_t n;
    if (rx_head == rx_tail) return 0;
    n = rxn[rx_tail % 16];
    if (n > cap) n = cap;
    memcpy(buf, rxq[rx_tail % 16], n);
    ++rx_tail;
    return n;
}
void hal_link_send(const uint8_t *frame, size_t len)
{
    dem_frame_t f;
    if (dem_decode(frame, len, &f) != DEM_OK) return;
    if (f.type == DEM_SENSOR) last_sensor = f;
    if (f.type == DEM_HELLO) { last_hello = f; got_hello = 1; }
    if (f.type == DEM_CONFIG_ACK) { last_ack = f; got_ack = 1; }
}
static void pc_send_bytes(const uint8_t *p, size_t n)
{
    memcpy(rxq[rx_head % 16], p, n);
    rxn[rx_head % 16] = n;
    ++rx_head;
}
static void pc_send(const dem_frame_t *f)
{
    size_t n;
    if (dem_encode(f, rxq[rx_head % 16], DEM_MAX_FRAME_SIZE, &n) != DEM_OK) return;
    rxn[rx_head % 16] = n;
    ++rx_head;
}

static int hexval(int c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}
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

static const char *mode_name(unsigned m)
{
    static const char *const names[] = {"OFF", "RUN", "HOLD", "LAND", "LANDED", "FAULT"};
    return m < 6 ? names[m] : "?";
}

static void tick(board_t *b)
{
    now_us += 1000;
    board_step(b);
}

int main(void)
{
    static board_t b;
    static char line[1024];
    uint8_t buf[DEM_MAX_FRAME_SIZE];
    while (fgets(line, sizeof line, stdin)) {
        char *arg = strchr(line, ' ');
        long n;
        line[strcspn(line, "\r\n")] = 0;
        if (arg) *arg++ = 0;
        if (strcmp(line, "init") == 0 || strcmp(line, "config") == 0) {
            dem_frame_t f;
            int r;
            n = arg ? unhex(arg, buf, sizeof buf) : -1;
            if (n < 0) { printf("badhex\n"); continue; }
            r = dem_decode(buf, (size_t)n, &f);
            if (r != DEM_OK || f.type != DEM_CONFIG) {
                printf("rejected %s\n", r != DEM_OK ? dem_link_reason(r) : "type");
                continue;
            }
            if (line[0] == 'i') {
                board_config_t cfg;
                memset(&cfg, 0, sizeof cfg);
                memcpy(&cfg.sup, f.f.config.v, sizeof cfg.sup);
                memcpy(cfg.gap_c, f.f.config.v + DEM_CONFIG_SUP, sizeof cfg.gap_c);
                memcpy(cfg.i_gain, f.f.config.v + DEM_CONFIG_SUP + 8, sizeof cfg.i_gain);
                memcpy(cfg.i_offset, f.f.config.v + DEM_CONFIG_SUP + 10, sizeof cfg.i_offset);
                cfg.command_delay = f.f.config.command_delay;
                cfg.board_id = 7;
                cfg.adc_bits = 16;
                cfg.adc_vref = 10.0f;
                rx_head = rx_tail = 0;
                memset(&last_sensor, 0, sizeof last_sensor);
                r = board_init(&b, &cfg);
                printf("init %s %08lx\n", dem_config_reason(r), (unsigned long)b.config_crc);
            } else {
                got_ack = 0;
                pc_send_bytes(buf, (size_t)n);
                tick(&b);
                if (!got_ack) {
                    printf("noack\n");
                } else {
                    const dem_config_ack_t *a = &last_ack.f.config_ack;
                    printf("ack %s %u %08lx %08lx %s\n", dem_config_reason(a->result), a->configured,
                           (unsigned long)a->active_crc, (unsigned long)a->request_crc, mode_name(a->mode));
                }
            }
        } else if (strcmp(line, "hello") == 0) {
            dem_frame_t f;
            memset(&f, 0, sizeof f);
            f.type = DEM_HELLO;
            f.f.hello.version = DEM_LINK_VERSION;
            got_hello = 0;
            pc_send(&f);
            tick(&b);
            if (got_hello)
                printf("hello %lu %u %u\n", (unsigned long)last_hello.f.hello.rate_hz, last_hello.f.hello.watchdog_ms,
                       last_hello.f.hello.command_delay);
            else
                printf("nohello\n");
        } else if (strcmp(line, "run") == 0) {
            unsigned long k, count = 0;
            float u0 = 0.0f, u1 = 0.0f;
            double d0 = 0.0, d1 = 0.0;
            if (!arg || sscanf(arg, "%lu %lf %lf", &count, &d0, &d1) != 3) { printf("badrun\n"); continue; }
            u0 = (float)d0;
            u1 = (float)d1;
            for (k = 0; k < count; ++k) {
                dem_frame_t c;
                memset(&c, 0, sizeof c);
                c.type = DEM_COMMAND;
                c.f.command.seq = last_sensor.f.sensor.seq;
                c.f.command.u[0] = u0;
                c.f.command.u[1] = u1;
                c.f.command.mode = DEM_RUN;
                pc_send(&c);
                tick(&b);
            }
            printf("mode %s\n", mode_name((unsigned)sup_mode(&b.sup)));
        } else {
            printf("unknown %s\n", line);
        }
        fflush(stdout);
    }
    return 0;
}
