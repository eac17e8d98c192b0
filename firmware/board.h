/*
 * board: the board's firmware around the supervisor: one board_step() per timer tick (1 kHz) reads the
 * ADCs through the HAL (hal.h), answers hellos, keeps the newest commands by the sample they answer, runs the
 * supervisor (supervisor.h) with the command of sample k - d, sets the PWM and sends the sensor frame
 * (docs/hardware-link.md). Portable C99, float32, no malloc; the state is one static board_t.
 */
#ifndef DEM_BOARD_H
#define DEM_BOARD_H

#include "dem_link.h"
#include "supervisor.h"

#ifdef __cplusplus
extern "C" {
#endif

#define BOARD_CMD_RING 16u

/* The board's configuration: the supervisor's (the schema's plant_sim values) and the hw_driver group's
 * sensor calibration (raw counts -> SI), as the PC has them; the hello states rate, ADC, delay, watchdog. */
typedef struct {
    sup_config_t sup;
    float gap_c[2][4];     /* gap [m] = c0 + n (c1 + n (c2 + n c3)), n: counts (hw_driver.gapJ_cP) */
    float i_gain[2];       /* current [A] = gain (n - offset) (hw_driver.currentJ_gain, _offset) */
    float i_offset[2];
    uint32_t board_id;
    uint8_t adc_bits;      /* counts 0 and 2^adc_bits - 1: out of range (no sample) */
    uint8_t command_delay; /* d >= 1 */
    float adc_vref;
} board_config_t;

typedef struct {
    board_config_t cfg;
    sup_t sup;
    dem_command_t cmds[BOARD_CMD_RING];
    uint8_t cmd_valid[BOARD_CMD_RING];
    int request;          /* the newest command's mode request */
    uint32_t request_seq;
    int have_request, streaming, rx_error;
    uint32_t n;           /* the sample number (seq) */
    uint64_t t0_us;
    float applied[2];     /* voltage applied over the period now ending [V] */
    uint32_t rx_frames, rx_rejected, fresh, hellos;
} board_t;

/* Configure (the supervisor refuses a bad configuration: returns its sup_cfg_result, nonzero). */
int board_init(board_t *b, const board_config_t *cfg);
/* The 1 kHz tick: call from the timer ISR (or a loop woken by it). Bounded time, never blocks. */
void board_step(board_t *b);

#ifdef __cplusplus
}
#endif
#endif /* DEM_BOARD_H */
