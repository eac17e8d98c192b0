/*
 * supervisor: the board's safety supervisor (modes, limits and trips, held commands, the stopping-distance
 * bound, the landing observer and law, the gap plausibility (flux) check, the command watchdog), a port of
 * dem_ros/board/ (the Python board; docs/manual/board.md derives every rule and number used here).
 *
 * Portable C99, float32 throughout, no malloc, no libc beyond <math.h> and <string.h>.
 * One sup_step() per sample; tests/firmware/test_differential.py runs it beside the Python Supervisor.
 */
#ifndef DEM_SUPERVISOR_H
#define DEM_SUPERVISOR_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* The modes (the device link's mode byte, enum dem_mode in dem_link.h). */
enum sup_mode { SUP_OFF = 0, SUP_RUN = 1, SUP_HOLD = 2, SUP_LAND = 3, SUP_LANDED = 4, SUP_FAULT = 5 };

/* The schema's values (dem_ros/core/params.py: the plant_sim safety specs and nominal plant), SI units. */
typedef struct {
    float u_max, i_max, trip_gap_min, trip_gap_max, hold_timeout, landing_gap, landing_speed; /* SAFETY_KEYS */
    float m, R, K, L, l, I, N1, N2, g;                                                         /* PLANT_KEYS */
    float dt;                                                                                  /* sample period [s] */
} sup_config_t;

/* sup_init results: SUP_CFG_OK or which check failed (the Python SafetyError's cases). */
enum sup_cfg_result {
    SUP_CFG_OK = 0,
    SUP_CFG_NOT_POSITIVE, /* u_max, i_max, hold_timeout, landing_gap, landing_speed, m, R, K, L, l, I, dt: > 0 */
    SUP_CFG_GAP_ORDER,    /* need 0 <= trip_gap_min < landing_gap <= trip_gap_max */
    SUP_CFG_ARMS,         /* need l < L */
    SUP_CFG_NO_BRAKING,   /* the loads leave no pull away from the rail at an end */
    SUP_CFG_NONFINITE     /* a value is NaN or infinite */
};

/* Why the board is in its mode / why it latched a fault: a code, a channel and up to four numbers
 * (the binding and a board's log format them; the Python board's reason texts say the same). */
enum sup_why_code {
    SUP_WHY_NONE = 0,
    SUP_WHY_REQUESTED,       /* ch: the requested mode (LAND or OFF) */
    SUP_WHY_I_MAX,           /* a0: the coil current [A] */
    SUP_WHY_GAP_MAX,         /* a0: the gap [m] */
    SUP_WHY_STOP_GAP,        /* ch: end; a0: stopping gap [m], a1: gap [m], a2: rate [m/s] */
    SUP_WHY_HOLD_TIMEOUT,    /* a0: time without a command [s]; sub 1: the held plate moved too fast (ch: end,
                                a1: its rate [m/s], a2, a3: the hold's limits [m/s], rising and descending) */
    SUP_WHY_COMMAND_MISSING, /* HOLD */
    SUP_WHY_EXTERNAL,        /* land() / estop() from outside: ch = the caller's code */
    SUP_WHY_ESTOP,           /* estop(): ch = the caller's code */
    SUP_WHY_NONFINITE,       /* sub: 0 resting, 1 no estimate; a0..a3: the raw gaps and currents */
    SUP_WHY_FLUX_GAP_LOST,   /* ch: gap; sub: 0 its current lost too, 1 the other gap blind, 2 current low;
                                a0: samples, a1: the other channel's samples or the current [A] */
    SUP_WHY_GAP_LOST,        /* ch: gap; sub: 0 other already a flux gap, 1 other lost too, 2 current lost,
                                3 current low (a1 [A]), 4 no pair in time; a0: samples -> FAULT */
    SUP_WHY_FLUX_LANDING,    /* ch: gap; a0: samples: landing on that gap from its coil's flux */
    SUP_WHY_CURRENT_LOST,    /* ch: coil; a0: samples: landing on the coil model */
    SUP_WHY_IMPLAUSIBLE,     /* ch: gap; a0: reading, a1: flux gap, a2: tolerance [m] */
    SUP_WHY_BOTH_IMPLAUSIBLE /* sub: 2 at once, else the first sensor's index; a0, a1: readings, a2, a3: flux gaps */
};

typedef struct {
    uint8_t code, ch, sub;
    float a[4];
} sup_why_t;

/* Sample and event counts (the Python board's ``counters``, same names and order). */
typedef struct {
    uint32_t holds, hold_events, longest_hold_us, clipped, rejected, landings, trips, estops, landed, brakes,
        brake_events, sensor_gaps, sensor_gap_events, sensor_losses, implausible;
} sup_counters_t;

/* The gap plausibility check's state (safety.py _GapCheck). */
typedef struct {
    uint32_t n[2];
    float lam[2], lam_lp[2], r[2], i_prev[2], dy[2], var[2], tol[2];
    uint32_t over[2];
    int armed;
    uint32_t settled;
    float sum_sq[2];
    int calm;
    float y_flux[2], v_flux[2];
} sup_check_t;

typedef struct {
    /* configuration and the derived model (safety.py's kernel vector) */
    sup_config_t cfg;
    float P, Q, A, B, C, D, KP, KD, KC, ILIM, DMIN, VREF, RSTOP, KI, KB, KBL, AB, BB, NB1, NB2;
    float Lo[3], m_inv[2][2], k_margin;
    int64_t hold_us;
    uint32_t n_arm;
    float hold_descent, hold_rise; /* the hold's speed guard: a held plate beyond these rates [m/s] lands */
    float hold_speedup;            /* ... once also this much faster that way [m/s] than at the hold's start */
    uint32_t n_guard;              /* ... once the observer has run this many samples */
    /* state */
    int mode;
    sup_why_t reason, fault;
    sup_counters_t counters;
    float est[3][2]; /* observer [gap m, rate m/s, missed acceleration m/s^2] per load point */
    float acc[2], i_last[2], ref[3][2], ui[2], u[2], u_last[2];
    int obs_ready, has_t_fresh, braking, command_timeout;
    uint32_t obs_age; /* samples the observer has run (counted up to n_guard) */
    float hold_v0[2]; /* the observer's rates [m/s] at the hold's first sample */
    int64_t t_fresh;
    float gated[2], wild[2], blind_now[2];
    uint32_t blind[4];
    float i_est[2], lam[2], r_est[2], lam_pred[2], u_prev[2];
    int flux_gap[2], loss_counted[4], implausible[2];
    float lam_flux[2], i_flux[2];
    float stop_gap[2], min_stop_gap;
    sup_check_t check;
} sup_t;

/* Configure and reset. mode: SUP_OFF, or SUP_RUN with u0 (2) the hover voltage (NULL: 0 V).
 * Returns SUP_CFG_OK, or the failed check (the board then refuses to run). */
int sup_init(sup_t *s, const sup_config_t *cfg, int mode, const float *u0);

/* One sample at t_us [us, monotonic]: gaps y (2) [m] and currents i (2) [A] (NaN: no sample), the command
 * for this sample u_cmd (2) [V] or NULL, the requested mode (RUN; LAND/OFF start a landing), the measured bus
 * [V] (NaN: not measured), the voltages applied over the last period (2) [V] or NULL. Writes the voltages to
 * apply over [t, t + T) to u (2) [V]. Never blocks, no allocation; bounded time (no loop over time). */
void sup_step(sup_t *s, int64_t t_us, const float y[2], const float i[2], const float *u_cmd, int requested,
              float bus, const float *applied, float u[2]);

/* What diagnostics read (a status frame, a log; the host binding): copied out of the state. */
typedef struct {
    int32_t mode, command_timeout, implausible[2];
    sup_why_t reason, fault;
    sup_counters_t counters;
    float est[3][2], stop_gap[2], min_stop_gap, u[2];
    float ref[3][2], ui[2], r_est[2]; /* the landing reference, the current loop's integral, the coil model's R */
} sup_view_t;
void sup_view(const sup_t *s, sup_view_t *v);
int sup_mode(const sup_t *s);
/* sizeof(sup_t), for hosts that hold the state as bytes (the ctypes binding) */
uint32_t sup_sizeof(void);

/* A controlled landing from outside (ignored when landing, landed or faulted); code: the caller's reason. */
void sup_land(sup_t *s, int code);
/* Emergency stop: a latched fault that lands the plate (never a 0 V cut at hover). */
void sup_estop(sup_t *s, int code);
/* Acknowledge: LAND/LANDED/FAULT -> OFF, the latched fault forgotten (counters stay). */
void sup_clear(sup_t *s);

#ifdef __cplusplus
}
#endif
#endif /* DEM_SUPERVISOR_H */
