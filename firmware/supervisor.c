/* supervisor: the board's safety supervisor, a float32 C99 port of dem_ros/board/ (see supervisor.h).
 * The function names follow the Python's (_observe, _land_law, _stop_gaps, _brake, _GapCheck.step, ...), so the
 * two read side by side; docs/manual/board.md derives the rules and the constants. */
#include "supervisor.h"

#include <math.h>
#include <string.h>

/* constants of dem_ros/board/config.py (same names) */
#define OUTER_BANDWIDTH 30.0f
#define OBS_BANDWIDTH 150.0f
#define BIAS_BANDWIDTH 30.0f
#define CURRENT_BANDWIDTH 500.0f
#define SPEED_FRACTION 0.4f
#define REF_ACCEL 0.2f
#define CAPTURE_ACCEL 5.0f
#define CAPTURE_TIME 0.01f
#define HOLD_DESCENT_FRACTION 0.7f
#define HOLD_RISE_FRACTION 1.0f
#define HOLD_SPEEDUP_FRACTION 0.5f
#define HOLD_GUARD_AFTER (3.0f / BIAS_BANDWIDTH)
#define LANDING_OVERSHOOT 3e-4f
#define I_OFF 0.02f
#define BOUND_MARGIN 0.25f
#define INNOVATION_LIMIT 5e-4f
#define R_LEARN_TIME 0.05f
#define SENSOR_BLIND_SAMPLES 5u
#define FLUX_GAP_MIN_CURRENT 0.5f
#define FLUX_CHECK_TIME 0.05f
#define FLUX_CHECK_R_TIME 0.2f
#define FLUX_CHECK_ARM 0.3f
#define FLUX_CHECK_FILTER 0.003f
#define FLUX_CHECK_NOISE_TIME 1.0f
#define FLUX_CHECK_MIN 3e-4f
#define FLUX_CHECK_SIGMAS 6.0f
#define FLUX_CHECK_SETTLE 50u
#define FLUX_CHECK_SAMPLES 3u

/* Python's min(a, b) / max(a, b) on floats (a unless b is strictly smaller / larger: the same answer with NaN) */
static float pmin(float a, float b) { return b < a ? b : a; }
static float pmax(float a, float b) { return b > a ? b : a; }
static float clampf(float x, float lo, float hi) { return pmin(pmax(x, lo), hi); }
static int finite(float x) { return isfinite(x) ? 1 : 0; }

static void why(sup_why_t *w, int code, int ch, int sub, float a0, float a1, float a2, float a3)
{
    w->code = (uint8_t)code;
    w->ch = (uint8_t)ch;
    w->sub = (uint8_t)sub;
    w->a[0] = a0;
    w->a[1] = a1;
    w->a[2] = a2;
    w->a[3] = a3;
}

static int cfg_ok(const sup_config_t *c)
{
    const float *v = &c->u_max;
    size_t k;
    for (k = 0; k < sizeof *c / sizeof(float); ++k)
        if (!finite(v[k])) return SUP_CFG_NONFINITE;
    if (!(c->u_max > 0 && c->i_max > 0 && c->hold_timeout > 0 && c->landing_gap > 0 && c->landing_speed > 0 &&
          c->m > 0 && c->R > 0 && c->K > 0 && c->L > 0 && c->l > 0 && c->I > 0 && c->dt > 0))
        return SUP_CFG_NOT_POSITIVE;
    if (!(0 <= c->trip_gap_min && c->trip_gap_min < c->landing_gap && c->landing_gap <= c->trip_gap_max))
        return SUP_CFG_GAP_ORDER;
    if (!(c->l < c->L)) return SUP_CFG_ARMS;
    return SUP_CFG_OK;
}

/* -- the gap plausibility check (safety.py _GapCheck) ------------------------------------------------- */
static void check_reset(sup_check_t *c)
{
    memset(c, 0, sizeof *c);
    c->tol[0] = c->tol[1] = INFINITY;
    c->calm = 1;
    c->y_flux[0] = c->y_flux[1] = NAN;
}

static void check_restart_sensor(sup_check_t *c, int n)
{
    c->dy[n] = 0.0f;
    c->over[0] = c->over[1] = 0;
}

/* returns the gap sensor newly found implausible (0, 1), 2 for both at once, -1 for none */
static int check_step(sup_t *s, float y0, float y1, const float i[2], const int i_ok[2], const int given_up[2])
{
    sup_check_t *c = &s->check;
    const float T = s->cfg.dt, K2 = 2.0f * s->cfg.K, P = s->P, Q = s->Q;
    const int gaps = finite(y0) && finite(y1);
    float de[2], lam_m[2] = {NAN, NAN}, yf[2], allow[2], b, v;
    int j, armed, calm, bad0, bad1;
    de[0] = gaps ? P * y0 + Q * y1 : NAN;
    de[1] = gaps ? Q * y0 + P * y1 : NAN;
    for (j = 0; j < 2; ++j) {
        const int measured = gaps && i_ok[j] && fabsf(i[j]) > FLUX_GAP_MIN_CURRENT && de[j] > 0.0f;
        if (measured) lam_m[j] = K2 * i[j] / de[j];
        if (c->n[j] == 0) {
            if (measured) {
                c->lam[j] = c->lam_lp[j] = lam_m[j];
                c->r[j] = s->r_est[j];
                c->i_prev[j] = i[j];
                c->n[j] = 1;
            }
            continue;
        }
        c->lam[j] += T * (s->u_prev[j] - c->r[j] * 0.5f * (c->i_prev[j] + i[j]));
        c->i_prev[j] = i[j];
        if (measured) {
            const float a = T / FLUX_CHECK_TIME;
            c->lam[j] += a * (lam_m[j] - c->lam[j]);
            c->lam_lp[j] += a * (lam_m[j] - c->lam_lp[j]);
            c->n[j] += 1;
        }
        if (!c->armed)
            c->r[j] = s->r_est[j];
        else if (c->calm)
            c->r[j] += T / FLUX_CHECK_R_TIME * (s->r_est[j] - c->r[j]);
    }
    if (!(finite(c->lam[0]) && finite(c->lam[1])) || pmin(c->lam[0], c->lam[1]) <= 0.0f) {
        check_reset(c);
        return -1;
    }
    if (!(finite(lam_m[0]) && finite(lam_m[1])) || c->n[0] == 0 || c->n[1] == 0) return -1;
    {
        const float d0 = K2 * i[0] / c->lam[0], d1 = K2 * i[1] / c->lam[1];
        yf[0] = s->m_inv[0][0] * d0 + s->m_inv[0][1] * d1;
        yf[1] = s->m_inv[1][0] * d0 + s->m_inv[1][1] * d1;
    }
    b = T / FLUX_CHECK_FILTER;
    for (j = 0; j < 2; ++j) {
        if (finite(c->y_flux[j])) c->v_flux[j] += b * ((yf[j] - c->y_flux[j]) / T - c->v_flux[j]);
        c->y_flux[j] = yf[j];
    }
    for (j = 0; j < 2; ++j) allow[j] = s->k_margin * fabsf((lam_m[j] - c->lam_lp[j]) / lam_m[j]) * de[j];
    armed = c->armed;
    v = T / FLUX_CHECK_NOISE_TIME;
    c->dy[0] += b * ((y0 - c->y_flux[0]) - c->dy[0]);
    c->dy[1] += b * ((y1 - c->y_flux[1]) - c->dy[1]);
    if (!armed) {
        const uint32_t nmin = c->n[0] < c->n[1] ? c->n[0] : c->n[1];
        if (nmin > s->n_arm && pmax(fabsf(c->dy[0]), fabsf(c->dy[1])) < FLUX_CHECK_MIN / 3.0f) {
            c->settled += 1;
            c->sum_sq[0] += c->dy[0] * c->dy[0];
            c->sum_sq[1] += c->dy[1] * c->dy[1];
            if (c->settled >= FLUX_CHECK_SETTLE) {
                c->armed = 1;
                c->var[0] = c->sum_sq[0] / (float)c->settled;
                c->var[1] = c->sum_sq[1] / (float)c->settled;
            }
        } else {
            c->settled = 0;
            c->sum_sq[0] = c->sum_sq[1] = 0.0f;
        }
        return -1;
    }
    calm = 1;
    for (j = 0; j < 2; ++j) {
        if (given_up[j]) {
            c->over[j] = 0;
            continue;
        }
        c->tol[j] = FLUX_CHECK_MIN + fabsf(s->m_inv[j][0]) * allow[0] + fabsf(s->m_inv[j][1]) * allow[1] +
                    FLUX_CHECK_SIGMAS * sqrtf(c->var[j]);
        if (fabsf(c->dy[j]) > c->tol[j]) {
            c->over[j] += 1;
            calm = 0;
            continue;
        }
        c->over[j] = 0;
        if (fabsf(c->dy[j]) < 0.5f * c->tol[j])
            c->var[j] += v * (c->dy[j] * c->dy[j] - c->var[j]);
        else
            calm = 0;
    }
    c->calm = calm;
    bad0 = c->over[0] >= FLUX_CHECK_SAMPLES;
    bad1 = c->over[1] >= FLUX_CHECK_SAMPLES;
    if (!bad0 && !bad1) return -1;
    if ((bad0 && bad1) || c->over[bad0 ? 1 : 0] > 0) return 2;
    return bad0 ? 0 : 1;
}

/* -- the kernels (safety.py's numba functions) ------------------------------------------------------ */
static void deltas(const sup_t *s, float y1, float y2, float *de1, float *de2)
{
    *de1 = pmax(s->P * y1 + s->Q * y2, s->DMIN);
    *de2 = pmax(s->Q * y1 + s->P * y2, s->DMIN);
}

static void model_accel(const sup_t *s, float de1, float de2, float i1, float i2, float a[2])
{
    const float K = s->cfg.K, N1 = s->cfg.N1, N2 = s->cfg.N2, g = s->cfg.g;
    const float F1 = K * i1 * i1 / (de1 * de1), F2 = K * i2 * i2 / (de2 * de2);
    a[0] = s->C * N1 + s->D * N2 + g - s->A * F1 - s->B * F2;
    a[1] = s->D * N1 + s->C * N2 + g - s->B * F1 - s->A * F2;
}

static void observe(sup_t *s, float y0, float y1, float i0, float i1)
{
    const float T = s->cfg.dt;
    float de1, de2;
    int j;
    for (j = 0; j < 2; ++j) {
        const float acc = s->acc[j] + s->est[2][j];
        const float pp = s->est[0][j] + T * s->est[1][j] + 0.5f * T * T * acc;
        const float vp = s->est[1][j] + T * acc;
        float e = s->blind_now[j] != 0.0f ? 0.0f : (j == 0 ? y0 : y1) - pp;
        if (s->blind_now[j] != 0.0f) {
            /* no sample: the prediction alone (the wild-sample gate keeps its state) */
        } else if (fabsf(e) > INNOVATION_LIMIT && s->gated[j] == 0.0f) {
            s->gated[j] = 1.0f; /* one wild sample is set aside; a second in a row is real */
            s->wild[j] = pp + e;
            e = 0.0f;
        } else if (fabsf(e) > INNOVATION_LIMIT) {
            const float y = pp + e; /* two in a row: restart gap and rate from the two samples */
            s->gated[j] = 0.0f;
            s->est[0][j] = y;
            s->est[1][j] = (y - s->wild[j]) / T;
            continue;
        } else {
            s->gated[j] = 0.0f;
        }
        s->est[0][j] = pp + s->Lo[0] * e;
        s->est[1][j] = vp + s->Lo[1] * e;
        s->est[2][j] = s->est[2][j] + s->Lo[2] * e;
    }
    deltas(s, s->est[0][0], s->est[0][1], &de1, &de2);
    model_accel(s, de1, de2, i0, i1, s->acc);
}

static void land_law(sup_t *s, const float i[2], int landed, float u[2])
{
    const float T = s->cfg.dt, K = s->cfg.K, N1 = s->cfg.N1, N2 = s->cfg.N2, g = s->cfg.g;
    float de1, de2, dd1, dd2, istar1 = 0.0f, istar2 = 0.0f, kK, e1, e2;
    float (*ref)[2] = s->ref;
    int j;
    deltas(s, s->est[0][0], s->est[0][1], &de1, &de2);
    dd1 = s->P * s->est[1][0] + s->Q * s->est[1][1];
    dd2 = s->Q * s->est[1][0] + s->P * s->est[1][1];
    if (!landed) {
        const float a1 = ref[2][0] + s->KD * (ref[1][0] - s->est[1][0]) + s->KP * (ref[0][0] - s->est[0][0]);
        const float a2 = ref[2][1] + s->KD * (ref[1][1] - s->est[1][1]) + s->KP * (ref[0][1] - s->est[0][1]);
        const float h1 = s->C * N1 + s->D * N2 + g - a1 + s->est[2][0];
        const float h2 = s->D * N1 + s->C * N2 + g - a2 + s->est[2][1];
        const float det = s->A * s->A - s->B * s->B;
        float F1 = (s->A * h1 - s->B * h2) / det, F2 = (-s->B * h1 + s->A * h2) / det;
        F1 = pmin(pmax(F1, 0.0f), K * s->ILIM * s->ILIM / (de1 * de1));
        F2 = pmin(pmax(F2, 0.0f), K * s->ILIM * s->ILIM / (de2 * de2));
        istar1 = de1 * sqrtf(F1 / K);
        istar2 = de2 * sqrtf(F2 / K);
        for (j = 0; j < 2; ++j) {
            ref[0][j] += T * ref[1][j] + 0.5f * T * T * ref[2][j];
            ref[1][j] += T * ref[2][j];
            if (ref[1][j] < 0.0f) {
                ref[2][j] = pmin(pmax(-ref[1][j] / CAPTURE_TIME, REF_ACCEL), CAPTURE_ACCEL);
            } else if (ref[1][j] >= s->VREF) {
                ref[1][j] = s->VREF;
                ref[2][j] = 0.0f;
            } else {
                ref[2][j] = REF_ACCEL;
            }
            if (ref[0][j] >= s->RSTOP) {
                ref[0][j] = s->RSTOP;
                ref[1][j] = 0.0f;
                ref[2][j] = 0.0f;
            }
        }
    } else {
        s->ui[0] = s->ui[1] = 0.0f;
    }
    kK = 2.0f * K;
    e1 = istar1 - i[0];
    e2 = istar2 - i[1];
    u[0] = s->cfg.R * i[0] + s->ui[0] + kK / de1 * (s->KC * e1 - i[0] * dd1 / de1);
    u[1] = s->cfg.R * i[1] + s->ui[1] + kK / de2 * (s->KC * e2 - i[1] * dd2 / de2);
    for (j = 0; j < 2; ++j) {
        const float lim = s->cfg.u_max;
        if (u[j] > lim) {
            u[j] = lim;
        } else if (u[j] < -lim) {
            u[j] = -lim;
        } else if (!landed) { /* anti-windup: integrate only when not saturated */
            const float e = j == 0 ? e1 : e2, de = j == 0 ? de1 : de2;
            s->ui[j] += T * s->KI * kK / de * e;
        }
    }
}

static void force_bound(const sup_t *s, float i, float de, float uc, float *F, float *lam)
{
    const float a = 2.0f * fabsf(i) / de, c = s->cfg.dt * fabsf(uc);
    const float hi = s->KB * a + c, lo = s->KBL * a + c;
    *F = pmax(hi * hi / (4.0f * s->KB), lo * lo / (4.0f * s->KBL));
    *lam = hi;
}

static void stop_gaps(sup_t *s, const float i[2], const float uc[2], float U, float out[2])
{
    const float T = s->cfg.dt;
    float de1, de2, F[2], lam[2];
    int j;
    deltas(s, s->est[0][0], s->est[0][1], &de1, &de2);
    force_bound(s, i[0], de1, uc[0], &F[0], &lam[0]);
    force_bound(s, i[1], de2, uc[1], &F[1], &lam[1]);
    for (j = 0; j < 2; ++j) {
        const float Fj = F[j], Fk = F[1 - j], lj = lam[j], lk = lam[1 - j];
        const float n = j == 0 ? s->NB1 : s->NB2;
        const float G = s->AB * Fj + s->BB * Fk;
        const float l = s->BB > 0.0f ? pmax(lj, lk) : lj;
        const float tau = l / U + T;
        const float w = -s->est[1][j];
        const float a0 = G - n;
        const float s0 = pmax(w, 0.0f) * T + pmax(a0, 0.0f) * 0.5f * T * T;
        const float w1 = w + a0 * T + G * tau / 3.0f;
        const float D = s0 + (w1 > 0.0f ? w1 * w1 / (2.0f * n) : 0.0f);
        out[j] = s->est[0][j] - D;
    }
}

static void brake(const sup_t *s, const float i[2], float U, float u[2])
{
    float de[2];
    int j;
    deltas(s, s->est[0][0], s->est[0][1], &de[0], &de[1]);
    for (j = 0; j < 2; ++j) {
        const float v = s->cfg.R * i[j] - 2.0f * s->cfg.K / de[j] * i[j] / s->cfg.dt;
        u[j] = pmin(pmax(v, -U), U);
    }
}

/* -- setup -------------------------------------------------------------------------------------------- */
int sup_init(sup_t *s, const sup_config_t *cfg, int mode, const float *u0)
{
    const float e = BOUND_MARGIN;
    float L, l, m, In, lam, lamb, lm1, lbm1, det;
    int r = cfg_ok(cfg);
    memset(s, 0, sizeof *s);
    if (r != SUP_CFG_OK) return r;
    s->cfg = *cfg;
    L = cfg->L;
    l = cfg->l;
    m = cfg->m;
    In = cfg->I;
    s->P = (L + l) / (2.0f * L);
    s->Q = (L - l) / (2.0f * L);
    s->A = 1.0f / m + L * l / In;
    s->B = 1.0f / m - L * l / In;
    s->C = 1.0f / m + L * L / In;
    s->D = 1.0f / m - L * L / In;
    s->KP = OUTER_BANDWIDTH * OUTER_BANDWIDTH;
    s->KD = 2.0f * OUTER_BANDWIDTH;
    s->KC = CURRENT_BANDWIDTH;
    s->ILIM = 0.95f * cfg->i_max;
    s->DMIN = 1e-4f;
    s->VREF = SPEED_FRACTION * cfg->landing_speed;
    s->RSTOP = cfg->landing_gap + LANDING_OVERSHOOT;
    s->KI = CURRENT_BANDWIDTH * CURRENT_BANDWIDTH / 5.0f;
    s->KB = (1.0f + e) * cfg->K;
    s->KBL = (1.0f - e) * cfg->K;
    s->AB = (1.0f + e) * (1.0f / m + L * l / In);
    s->BB = pmax((1.0f + e) / m - (1.0f - e) * L * l / In, 0.0f);
    s->NB1 = cfg->g + pmin(0.0f, (1.0f + e) * L * L / In * (cfg->N1 - cfg->N2));
    s->NB2 = cfg->g + pmin(0.0f, (1.0f + e) * L * L / In * (cfg->N2 - cfg->N1));
    if (!(pmin(s->NB1, s->NB2) > 0.0f)) return SUP_CFG_NO_BRAKING;
    /* observer gains: (I - Lo C) A with poles exp(-w T) (double) and exp(-w_b T) (safety.observer_gains;
     * Ackermann's formula solved in closed form, with expm1f for the small lam - 1) */
    lm1 = expm1f(-OBS_BANDWIDTH * cfg->dt);
    lbm1 = expm1f(-BIAS_BANDWIDTH * cfg->dt);
    lam = 1.0f + lm1;
    lamb = 1.0f + lbm1;
    s->Lo[0] = 1.0f - lam * lam * lamb;
    s->Lo[1] = lm1 * (3.0f * lam * lamb - lam + lamb - 3.0f) / (2.0f * cfg->dt);
    s->Lo[2] = -lm1 * lm1 * lbm1 / (cfg->dt * cfg->dt);
    det = s->P * s->P - s->Q * s->Q; /* magnet gaps -> sensor gaps */
    s->m_inv[0][0] = s->P / det;
    s->m_inv[0][1] = -s->Q / det;
    s->m_inv[1][0] = -s->Q / det;
    s->m_inv[1][1] = s->P / det;
    s->k_margin = BOUND_MARGIN / (1.0f - BOUND_MARGIN);
    s->n_arm = (uint32_t)(FLUX_CHECK_ARM / cfg->dt + 0.5f);
    s->hold_us = (int64_t)(cfg->hold_timeout * 1e6f + 0.5f);
    s->hold_descent = HOLD_DESCENT_FRACTION * cfg->landing_speed;
    s->hold_rise = HOLD_RISE_FRACTION * cfg->landing_speed;
    s->hold_speedup = HOLD_SPEEDUP_FRACTION * cfg->landing_speed;
    s->n_guard = (uint32_t)(HOLD_GUARD_AFTER / cfg->dt + 0.5f);
    s->r_est[0] = s->r_est[1] = cfg->R;
    s->stop_gap[0] = s->stop_gap[1] = INFINITY;
    s->min_stop_gap = INFINITY;
    s->mode = mode;
    if (u0 != NULL) {
        s->u[0] = u0[0];
        s->u[1] = u0[1];
    }
    s->u_last[0] = s->u[0];
    s->u_last[1] = s->u[1];
    check_reset(&s->check);
    return SUP_CFG_OK;
}

/* -- commands from outside -------------------------------------------------------------------------- */
static void start_reference(sup_t *s)
{
    int j;
    for (j = 0; j < 2; ++j) {
        s->ref[0][j] = s->est[0][j];
        s->ref[1][j] = s->est[1][j] < s->VREF ? s->est[1][j] : (isnan(s->est[1][j]) ? s->est[1][j] : s->VREF);
        s->ref[2][j] = s->ref[1][j] < 0.0f ? clampf(-s->ref[1][j] / CAPTURE_TIME, REF_ACCEL, CAPTURE_ACCEL) : REF_ACCEL;
    }
}

static void land(sup_t *s, const sup_why_t *w)
{
    if (s->mode == SUP_LAND || s->mode == SUP_LANDED || s->mode == SUP_FAULT) return;
    if (s->mode == SUP_OFF) { /* nothing airborne under our control */
        s->mode = SUP_LANDED;
        s->reason = *w;
        return;
    }
    s->mode = SUP_LAND;
    s->reason = *w;
    s->counters.landings += 1;
    start_reference(s);
    s->ui[0] = s->u_last[0] - s->cfg.R * s->i_last[0]; /* bumpless */
    s->ui[1] = s->u_last[1] - s->cfg.R * s->i_last[1];
}

static void trip(sup_t *s, const sup_why_t *w)
{
    if (s->fault.code == SUP_WHY_NONE) s->fault = *w;
    s->counters.trips += 1;
    land(s, w);
}

void sup_land(sup_t *s, int code)
{
    sup_why_t w;
    why(&w, SUP_WHY_EXTERNAL, code, 0, 0, 0, 0, 0);
    land(s, &w);
}

void sup_estop(sup_t *s, int code)
{
    sup_why_t w;
    why(&w, SUP_WHY_ESTOP, code, 0, 0, 0, 0, 0);
    s->counters.estops += 1;
    trip(s, &w);
}

void sup_clear(sup_t *s)
{
    s->mode = SUP_OFF;
    memset(&s->reason, 0, sizeof s->reason);
    memset(&s->fault, 0, sizeof s->fault);
    s->has_t_fresh = 0;
    s->braking = 0;
    s->flux_gap[0] = s->flux_gap[1] = 0;
    memset(s->loss_counted, 0, sizeof s->loss_counted);
    s->implausible[0] = s->implausible[1] = 0;
    s->command_timeout = 0;
    check_reset(&s->check);
}

/* -- the sample ----------------------------------------------------------------------------------------- */
static void count_loss(sup_t *s, int n)
{
    if (!s->loss_counted[n]) {
        s->loss_counted[n] = 1;
        s->counters.sensor_losses += 1;
    }
}

static void fault_now(sup_t *s, const sup_why_t *w, float u[2])
{
    s->counters.trips += 1;
    s->fault = s->reason = *w;
    s->mode = SUP_FAULT;
    s->u[0] = s->u[1] = 0.0f;
    u[0] = u[1] = 0.0f;
}

static void gaps_from_flux(sup_t *s, float *y, const float i[2])
{
    const float P = s->P, Q = s->Q, K2 = 2.0f * s->cfg.K;
    int j;
    for (j = 0; j < 2; ++j) {
        float yk;
        if (!s->flux_gap[j] || !finite(i[j])) continue;
        s->lam_flux[j] += s->cfg.dt * (s->u_prev[j] - s->r_est[j] * 0.5f * (s->i_flux[j] + i[j]));
        s->i_flux[j] = i[j];
        yk = y[1 - j];
        if (finite(y[j])) { /* the sensor is back: its gap, and the flux re-anchored on it */
            const float de = finite(yk) ? P * y[j] + Q * yk : NAN;
            if (finite(de) && de > 0.0f) s->lam_flux[j] = K2 * i[j] / de;
        } else if (finite(yk) && fabsf(i[j]) > FLUX_GAP_MIN_CURRENT && s->lam_flux[j] > 0.0f) {
            y[j] = (K2 * i[j] / s->lam_flux[j] - Q * yk) / P;
        } else if (s->mode == SUP_LANDED) {
            y[j] = s->est[0][j];
        }
    }
}

static void coil_model(sup_t *s, const float u[2], const int ok[2])
{
    const float K2 = 2.0f * s->cfg.K, T = s->cfg.dt, R = s->cfg.R;
    float de[2];
    int j;
    deltas(s, s->est[0][0], s->est[0][1], &de[0], &de[1]);
    for (j = 0; j < 2; ++j) {
        const float ij = s->i_last[j];
        float lam = K2 * ij / de[j];
        if (ok[j] && fabsf(ij) > 0.2f && s->lam[j] != 0.0f && !s->flux_gap[j]) {
            float r = (s->u_prev[j] - (lam - s->lam[j]) / T) / ij;
            r = pmin(pmax(r, 0.5f * R), 2.0f * R);
            s->r_est[j] += T / R_LEARN_TIME * (r - s->r_est[j]);
        }
        if (!ok[j]) lam = s->lam_pred[j];
        s->lam[j] = lam;
        s->lam_pred[j] = lam + T * (u[j] - s->r_est[j] * ij);
        s->i_est[j] = s->lam_pred[j] * de[j] / K2;
    }
    s->u_prev[0] = u[0];
    s->u_prev[1] = u[1];
}

/* a non-finite sample: 1 when the board can only FAULT (resting, or no estimate yet) */
static int sensor_gap(sup_t *s, float y0, float y1, float i0, float i1)
{
    int resting;
    s->counters.sensor_gaps += 1;
    if (s->blind[0] == 0 && s->blind[1] == 0 && s->blind[2] == 0 && s->blind[3] == 0)
        s->counters.sensor_gap_events += 1;
    resting = s->mode == SUP_OFF || s->mode == SUP_LANDED || s->mode == SUP_FAULT;
    if (!(resting || !s->obs_ready)) return 0;
    if (s->mode != SUP_FAULT) {
        if (s->fault.code == SUP_WHY_NONE) why(&s->fault, SUP_WHY_NONFINITE, 0, resting ? 0 : 1, y0, y1, i0, i1);
        s->reason = s->fault;
        s->counters.trips += 1;
    }
    s->mode = SUP_FAULT;
    s->u[0] = s->u[1] = 0.0f;
    return 1;
}

/* channels blind beyond SENSOR_BLIND_SAMPLES: 1 with *w the reason for FAULT, 0 to carry on */
static int lost_channels(sup_t *s, const int ok[4], sup_why_t *w)
{
    const uint32_t B = SENSOR_BLIND_SAMPLES;
    uint32_t *blind = s->blind;
    int j, n;
    for (j = 0; j < 2; ++j) {
        if (s->flux_gap[j] && blind[j] > B && s->mode != SUP_LANDED) {
            if (blind[2 + j] > B) {
                count_loss(s, 2 + j);
                why(w, SUP_WHY_FLUX_GAP_LOST, j, 0, (float)blind[j], (float)blind[2 + j], 0, 0);
            } else if (blind[1 - j] > 0) {
                why(w, SUP_WHY_FLUX_GAP_LOST, j, 1, (float)blind[j], (float)blind[1 - j], 0, 0);
            } else {
                why(w, SUP_WHY_FLUX_GAP_LOST, j, 2, (float)blind[j], s->i_last[j], 0, 0);
            }
            return 1;
        }
    }
    for (n = 0; n < 2; ++n) {
        const int k = 1 - n;
        int sub;
        float a1 = 0.0f;
        if (s->flux_gap[n] || blind[n] <= B) continue;
        if (s->flux_gap[k]) {
            sub = 0;
        } else if (blind[k] > B) {
            sub = 1;
        } else if (blind[2 + n] > B) {
            sub = 2;
        } else if (ok[2 + n] && fabsf(s->i_last[n]) <= FLUX_GAP_MIN_CURRENT) {
            sub = 3;
            a1 = s->i_last[n];
        } else if (blind[k] == 0 && ok[2 + n]) { /* the other gap and this current measured: land on the flux */
            float de[2];
            sup_why_t f;
            deltas(s, s->est[0][0], s->est[0][1], &de[0], &de[1]);
            s->flux_gap[n] = 1;
            s->lam_flux[n] = 2.0f * s->cfg.K * s->i_last[n] / de[n];
            s->i_flux[n] = s->i_last[n];
            why(&f, SUP_WHY_FLUX_LANDING, n, 0, (float)blind[n], 0, 0, 0);
            blind[n] = 0;
            count_loss(s, n);
            if (s->mode == SUP_LAND) {
                if (s->fault.code == SUP_WHY_NONE) s->fault = f;
            } else {
                trip(s, &f);
            }
            continue;
        } else if (blind[n] > 2 * B) {
            sub = 4;
        } else {
            continue; /* the other gap or this current only briefly blind: ride on, decide again */
        }
        count_loss(s, n);
        why(w, SUP_WHY_GAP_LOST, n, sub, (float)blind[n], a1, 0, 0);
        return 1;
    }
    for (n = 2; n < 4; ++n) {
        if (blind[n] > B && !s->loss_counted[n]) { /* a current sensor: land on the coil model */
            count_loss(s, n);
            if (s->mode == SUP_RUN || s->mode == SUP_HOLD) {
                sup_why_t f;
                why(&f, SUP_WHY_CURRENT_LOST, n - 2, 0, (float)blind[n], 0, 0, 0);
                trip(s, &f);
            }
        }
    }
    return 0;
}

static void implausible(sup_t *s, int n, float *y, const float i[2])
{
    sup_check_t *c = &s->check;
    const float i_n = i[n];
    sup_why_t w;
    why(&w, SUP_WHY_IMPLAUSIBLE, n, 0, y[n], c->y_flux[n], c->tol[n], 0);
    s->implausible[n] = 1;
    s->flux_gap[n] = 1;
    s->lam_flux[n] = c->lam[n];
    s->i_flux[n] = i_n;
    s->r_est[n] = c->r[n];
    count_loss(s, n);
    s->counters.implausible += 1;
    y[n] = (2.0f * s->cfg.K * i_n / c->lam[n] - s->Q * y[1 - n]) / s->P;
    s->est[0][n] = y[n];
    s->est[1][n] = c->v_flux[n];
    s->gated[n] = 0.0f;
    check_restart_sensor(c, n);
    if (s->mode == SUP_LAND) {
        if (s->fault.code == SUP_WHY_NONE) s->fault = w;
    } else {
        trip(s, &w);
    }
}

static void both_implausible(sup_t *s, int bad, float y0, float y1, float u[2])
{
    sup_check_t *c = &s->check;
    sup_why_t w;
    int n;
    why(&w, SUP_WHY_BOTH_IMPLAUSIBLE, 0, bad, y0, y1, c->y_flux[0], c->y_flux[1]);
    for (n = 0; n < 2; ++n) {
        if (bad != 2 && n != bad) continue;
        s->implausible[n] = 1;
        count_loss(s, n);
        s->counters.implausible += 1;
    }
    fault_now(s, &w, u);
}

/* the hold's speed guard: the end whose estimated rate is beyond the hold's limits, or -1 (also while the
 * observer is younger than HOLD_GUARD_AFTER); end 1 first. Beyond: descending faster than hold_descent or rising
 * faster than hold_rise, and that way faster by hold_speedup than at the hold's first sample (hold_v0) */
static int held_too_fast(const sup_t *s)
{
    int j;
    if (s->obs_age < s->n_guard) return -1;
    for (j = 0; j < 2; ++j) {
        const float v = s->est[1][j], dv = v - s->hold_v0[j]; /* dv > 0: the hold sped it toward the support */
        if ((v > s->hold_descent && dv > s->hold_speedup) || (v < -s->hold_rise && -dv > s->hold_speedup)) return j;
    }
    return -1;
}

/* RUN/HOLD: the fresh command clipped, or the held one; 0 once the hold timed out or the held plate moves too
 * fast (LAND) */
static int run_candidate(sup_t *s, int64_t t, int mode, int fresh, float a, float b, float cand[2])
{
    int64_t held;
    int fast;
    if (fresh) {
        const float lim = s->cfg.u_max;
        const float ua = pmin(pmax(a, -lim), lim), ub = pmin(pmax(b, -lim), lim);
        if (ua != a || ub != b) s->counters.clipped += 1;
        s->u_last[0] = ua;
        s->u_last[1] = ub;
        s->t_fresh = t;
        s->has_t_fresh = 1;
        if (mode == SUP_HOLD) {
            s->mode = SUP_RUN;
            memset(&s->reason, 0, sizeof s->reason);
        }
        cand[0] = ua;
        cand[1] = ub;
        return 1;
    }
    if (!s->has_t_fresh) {
        s->t_fresh = t;
        s->has_t_fresh = 1;
    }
    if (mode == SUP_RUN) {
        s->mode = SUP_HOLD;
        why(&s->reason, SUP_WHY_COMMAND_MISSING, 0, 0, 0, 0, 0, 0);
        s->hold_v0[0] = s->est[1][0];
        s->hold_v0[1] = s->est[1][1];
        s->counters.hold_events += 1;
    }
    held = t - s->t_fresh;
    fast = held_too_fast(s);
    if (held <= s->hold_us && fast < 0) {
        s->counters.holds += 1;
        if (held > (int64_t)s->counters.longest_hold_us) s->counters.longest_hold_us = (uint32_t)held;
        cand[0] = s->u_last[0];
        cand[1] = s->u_last[1];
        return 1;
    }
    s->command_timeout = 1;
    {
        sup_why_t w;
        if (fast >= 0) /* the held voltage no longer holds the plate: land before it outruns the landing speed */
            why(&w, SUP_WHY_HOLD_TIMEOUT, fast, 1, (float)held * 1e-6f, s->est[1][fast], -s->hold_rise,
                s->hold_descent);
        else
            why(&w, SUP_WHY_HOLD_TIMEOUT, 0, 0, (float)held * 1e-6f, 0, 0, 0);
        land(s, &w);
    }
    return 0;
}

static int safe(sup_t *s, const float cand[2], float U)
{
    float low;
    stop_gaps(s, s->i_last, cand, U, s->stop_gap);
    low = pmin(s->stop_gap[0], s->stop_gap[1]);
    if (low < s->min_stop_gap) s->min_stop_gap = low;
    return low >= s->cfg.trip_gap_min;
}

static void step_modes(sup_t *s, int64_t t, const float *u_cmd, int requested, float bus, float u[2])
{
    const float i0 = s->i_last[0], i1 = s->i_last[1];
    int mode = s->mode, fresh;
    float U, a = 0.0f, b = 0.0f, cand[2];
    sup_why_t w;
    if (mode == SUP_FAULT) {
        u[0] = u[1] = 0.0f;
        return;
    }
    U = isnan(bus) ? s->cfg.u_max : pmax(pmin(s->cfg.u_max, bus), 1e-6f);
    fresh = u_cmd != NULL;
    if (fresh) {
        a = u_cmd[0];
        b = u_cmd[1];
        if (!(finite(a) && finite(b))) {
            s->counters.rejected += 1;
            fresh = 0;
        }
    }
    if ((mode == SUP_RUN || mode == SUP_HOLD) && (requested == SUP_LAND || requested == SUP_OFF)) {
        why(&w, SUP_WHY_REQUESTED, requested, 0, 0, 0, 0, 0);
        land(s, &w);
        mode = s->mode;
    }
    if (mode == SUP_RUN || mode == SUP_HOLD) {
        const float worst = pmax(fabsf(i0), fabsf(i1)), gmax = pmax(s->est[0][0], s->est[0][1]);
        if (worst > s->cfg.i_max) {
            why(&w, SUP_WHY_I_MAX, 0, 0, worst, 0, 0, 0);
            trip(s, &w);
        } else if (gmax > s->cfg.trip_gap_max) {
            why(&w, SUP_WHY_GAP_MAX, 0, 0, gmax, 0, 0, 0);
            trip(s, &w);
        }
        mode = s->mode;
    }
    if (mode == SUP_OFF) {
        if (fresh && requested == SUP_RUN) {
            s->mode = mode = SUP_RUN;
        } else {
            u[0] = u[1] = 0.0f;
            return;
        }
    }
    if (mode == SUP_RUN || mode == SUP_HOLD) {
        const int has = run_candidate(s, t, mode, fresh, fresh ? a : 0.0f, fresh ? b : 0.0f, cand);
        mode = s->mode;
        if (has) {
            int j;
            if (safe(s, cand, U)) {
                u[0] = cand[0];
                u[1] = cand[1];
                return;
            }
            j = s->stop_gap[1] < s->stop_gap[0] ? 1 : 0;
            why(&w, SUP_WHY_STOP_GAP, j, 0, s->stop_gap[j], s->est[0][j], s->est[1][j], 0);
            trip(s, &w);
            mode = s->mode;
        }
    }
    if (mode == SUP_LAND && pmin(s->est[0][0], s->est[0][1]) >= s->cfg.landing_gap) {
        s->mode = mode = SUP_LANDED;
        s->counters.landed += 1;
        s->braking = 0;
    }
    if (mode == SUP_LANDED) {
        if (pmax(fabsf(i0), fabsf(i1)) < I_OFF) {
            u[0] = u[1] = 0.0f;
        } else {
            land_law(s, s->i_last, 1, u);
        }
        return;
    }
    {
        float i_now[2];
        int ok;
        i_now[0] = i0;
        i_now[1] = i1;
        land_law(s, i_now, 0, u);
        ok = safe(s, u, U);
        if (!ok || (s->braking && pmin(s->est[1][0], s->est[1][1]) < 0.0f)) {
            if (!s->braking) s->counters.brake_events += 1;
            s->braking = 1;
            s->counters.brakes += 1;
            brake(s, i_now, U, u);
        } else if (s->braking) { /* released: land from the state the brake left */
            s->braking = 0;
            start_reference(s);
            s->ui[0] = s->ui[1] = 0.0f;
            land_law(s, i_now, 0, u);
        }
    }
}

void sup_step(sup_t *s, int64_t t_us, const float y[2], const float i[2], const float *u_cmd, int requested,
              float bus, const float *applied, float u[2])
{
    float yy[2], ii[2];
    int ok[4], n;
    yy[0] = y[0];
    yy[1] = y[1];
    ii[0] = i[0];
    ii[1] = i[1];
    if (applied != NULL && finite(applied[0]) && finite(applied[1])) {
        s->u_prev[0] = applied[0];
        s->u_prev[1] = applied[1];
    }
    if (s->implausible[0]) yy[0] = NAN; /* found implausible: never read again until clear() */
    if (s->implausible[1]) yy[1] = NAN;
    for (n = 0; n < 4; ++n)
        if (finite(n < 2 ? yy[n] : ii[n - 2])) s->loss_counted[n] = 0;
    if (s->flux_gap[0] || s->flux_gap[1]) gaps_from_flux(s, yy, ii);
    ok[0] = finite(yy[0]);
    ok[1] = finite(yy[1]);
    ok[2] = finite(ii[0]);
    ok[3] = finite(ii[1]);
    if (!(ok[0] && ok[1] && ok[2] && ok[3]) && sensor_gap(s, yy[0], yy[1], ii[0], ii[1])) {
        u[0] = s->u[0];
        u[1] = s->u[1];
        return;
    }
    for (n = 0; n < 4; ++n) s->blind[n] = ok[n] ? 0u : s->blind[n] + 1u;
    if (!ok[2]) ii[0] = s->i_est[0]; /* a missing current: the board's coil model */
    if (!ok[3]) ii[1] = s->i_est[1];
    s->i_last[0] = ii[0];
    s->i_last[1] = ii[1];
    if (s->mode == SUP_RUN || s->mode == SUP_HOLD || s->mode == SUP_LAND) {
        const int gone[2] = {s->flux_gap[0], s->flux_gap[1]};
        const int i_ok[2] = {ok[2], ok[3]};
        const int bad = check_step(s, yy[0], yy[1], ii, i_ok, gone);
        if (bad == 2 || (bad >= 0 && gone[1 - bad])) {
            both_implausible(s, bad, yy[0], yy[1], u);
            return;
        }
        if (bad >= 0) implausible(s, bad, yy, ii);
    } else {
        check_reset(&s->check);
    }
    s->blind_now[0] = ok[0] ? 0.0f : 1.0f;
    s->blind_now[1] = ok[1] ? 0.0f : 1.0f;
    if (s->obs_age < s->n_guard) s->obs_age += 1u;
    if (!s->obs_ready) {
        float de1, de2;
        s->est[0][0] = yy[0];
        s->est[0][1] = yy[1];
        s->est[1][0] = s->est[1][1] = 0.0f;
        deltas(s, yy[0], yy[1], &de1, &de2);
        model_accel(s, de1, de2, ii[0], ii[1], s->acc);
        s->est[2][0] = -s->acc[0]; /* bumpless: at rest, the model misses -a_m */
        s->est[2][1] = -s->acc[1];
        s->obs_ready = 1;
    } else {
        observe(s, yy[0], yy[1], ii[0], ii[1]);
    }
    if (s->mode == SUP_RUN || s->mode == SUP_HOLD || s->mode == SUP_LAND) {
        uint32_t worst = 0;
        sup_why_t w;
        for (n = 0; n < 4; ++n)
            if (s->blind[n] > worst) worst = s->blind[n];
        if (worst > SENSOR_BLIND_SAMPLES && lost_channels(s, ok, &w)) {
            fault_now(s, &w, u);
            return;
        }
    }
    step_modes(s, t_us, u_cmd, requested, bus, u);
    s->u[0] = u[0];
    s->u[1] = u[1];
    coil_model(s, u, ok + 2);
    if (finite(bus)) { /* what the bridges can apply of it */
        const float Ub = pmax(bus, 0.0f);
        s->u_prev[0] = clampf(s->u_prev[0], -Ub, Ub);
        s->u_prev[1] = clampf(s->u_prev[1], -Ub, Ub);
    }
}

void sup_view(const sup_t *s, sup_view_t *v)
{
    v->mode = s->mode;
    v->command_timeout = s->command_timeout;
    v->implausible[0] = s->implausible[0];
    v->implausible[1] = s->implausible[1];
    v->reason = s->reason;
    v->fault = s->fault;
    v->counters = s->counters;
    memcpy(v->est, s->est, sizeof v->est);
    v->stop_gap[0] = s->stop_gap[0];
    v->stop_gap[1] = s->stop_gap[1];
    v->min_stop_gap = s->min_stop_gap;
    v->u[0] = s->u[0];
    v->u[1] = s->u[1];
    memcpy(v->ref, s->ref, sizeof v->ref);
    v->ui[0] = s->ui[0];
    v->ui[1] = s->ui[1];
    v->r_est[0] = s->r_est[0];
    v->r_est[1] = s->r_est[1];
}

int sup_mode(const sup_t *s) { return s->mode; }

uint32_t sup_sizeof(void) { return (uint32_t)sizeof(sup_t); }
