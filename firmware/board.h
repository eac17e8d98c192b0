/*
 * board: the board's firmware around the supervisor: one board_step() per timer tick (1 kHz) reads the
 * ADCs through the HAL (hal.h), answers hellos, keeps the newest commands by the sample they answer, runs the
 * supervisor (supervisor.h) with the command of sample k - d, sets the PWM and sends the sensor frame; it takes a
 * configuration over the link (CONFIG, only while OFF or LANDED) and answers it (CONFIG_ACK) with the CRC-32 of the
 * configuration it runs (docs/hardware-link.md). Portable C99, float32, no malloc; the state is one static board_t.
 */
#ifndef DEM_BOARD_H
#define DEM_BOARD_H

#include "dem_link.h"
#include "supervisor.h"

#ifdef __cplusplus
extern "C" {
#endif

#define BOARD_CMD_RING 16u
#define BOARD_MAX_DELAY (BOARD_CMD_RING - 1u) /* the ring holds the commands answering samples k - d .. k */

/* The board's configuration: the supervisor's (the schema's hw_driver values: safety specs, nominal plant, dt) and
 * the sensor calibration (raw counts -> SI), as the PC has them; the hello states rate, ADC, delay, watchdog. All but
 * board_id, adc_bits and adc_vref (the board's own hardware) travel in the link's CONFIG frame. */
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
    uint32_t config_crc;  /* CRC-32 of the active configuration: the CRC field of its CONFIG frame */
    uint8_t configured;   /* 1: set over the link; 0: board_init()'s (the compiled-in defaults) */
    uint32_t configs, configs_refused;
} board_t;

/* Configure with the compiled-in defaults. Returns 0, or why the configuration is refused (enum dem_config_result:
 * 1-5 are sup_init()'s sup_cfg_result; a board never runs a refused configuration). */
int board_init(board_t *b, const board_config_t *cfg);
/* A configuration received over the link (board_step answers every CONFIG frame with it). Taken only while the
 * supervisor is OFF or LANDED (else DEM_CFG_BUSY), only when dt is the board's sample period (DEM_CFG_RATE) and it
 * passes board_init()'s checks; otherwise the active configuration stays. A new supervisor configuration restarts
 * the supervisor (OFF); the same configuration again changes nothing. Fills *ack (the active CRC after it, the
 * request's CRC, the result, the configured flag, the mode) and returns the result. Bounded time; it needs a
 * scratch supervisor state on the stack (sizeof(sup_t)). */
int board_configure(board_t *b, const dem_config_t *config, dem_config_ack_t *ack);
/* A configuration as the link carries it (the CONFIG frame's values). */
void board_config_to_link(const board_config_t *cfg, dem_config_t *out);
/* The 1 kHz tick: call from the timer ISR (or a loop woken by it). Bounded time, never blocks. */
void board_step(board_t *b);

#ifdef __cplusplus
}
#endif
#endif /* DEM_BOARD_H */
