/*
 * hal: the hardware abstraction the board firmware calls; a rig builder writes these six functions for the
 * board (firmware/README.md, "Putting it on a board"). None may block: board_step() runs in the 1 kHz timer
 * interrupt and must finish well within the period.
 */
#ifndef DEM_HAL_H
#define DEM_HAL_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Microseconds since start, monotonic (a free-running timer; 64 bits: no wrap in practice). */
uint64_t hal_micros(void);
/* The conversions of this tick (started by the timer, finished by DMA before the ISR reads them): raw counts of
 * the gap sensors and coil-current sensors, and the DC bus [V]. Return 0, or nonzero when a conversion failed. */
int hal_adc_read(uint16_t gap[2], uint16_t current[2], float *bus_v);
/* Set the bridges' signed duty cycles in [-1, 1] for the next period (shadow registers: takes effect at the
 * next PWM period boundary). */
void hal_pwm_set(const float duty[2]);
/* Hardware status bits (DEM_ST_DRIVER0_FAULT, DEM_ST_ESTOP, DEM_ST_CURRENT0_LIMIT, ...) latched since the last call. */
uint32_t hal_status(void);
/* One received, deframed frame (UDP datagram, or the serial deframer's output) into buf; returns its length,
 * 0 when none is waiting. Called until 0 at every tick; the receive path queues frames (ring), never blocks. */
size_t hal_link_recv(uint8_t *buf, size_t cap);
/* Queue one frame for transmission (UDP datagram, or 0x00 COBS 0x00 on serial by DMA); must not block. */
void hal_link_send(const uint8_t *frame, size_t len);

#ifdef __cplusplus
}
#endif
#endif /* DEM_HAL_H */
