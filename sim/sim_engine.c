/* sim/sim_engine.c: see sim_engine.h. */
#include "sim_engine.h"

#include <arkode/arkode_erkstep.h>
#include <math.h>
#include <nvector/nvector_serial.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sundials/sundials_context.h>
#include <vibid/discretize.h>

struct sim_engine {
    const vibid_stand *stand;
    const sim_config *cfg;
    const vibid_model *model;
    size_t n, r, p, nch;
    int has_base;
    double h;
    /* excitation */
    sim_exc *base_exc;
    sim_exc **in_exc;      /* r entries, NULL = zero input */
    /* disturbances (vibid_model_add_disturbance): forces on nodes that no channel reports,
     * always held over [t_k, t_k + h) like the model defines them */
    size_t nw;
    sim_exc **w_exc;       /* nw entries, NULL = zero force */
    size_t *w_node;        /* nw node indices */
    /* held base (cfg->base_smooth == 0): s jumps by s_k - s_{k-1} at t_k, and the dampers to
     * the base turn that jump into an impulse d_base (s_k - s_{k-1}) (model.h, vibid_hold) */
    double *d_base;        /* n, N s/m, from vibid_model_assemble at the current parameters */
    double s_prev;         /* m: s_{k-1}; 0 before sample 0 (the stand rests with the base at 0) */
    /* parameters */
    double *theta0, *theta, *theta_k;
    int mass_changes, ramp_in_interval;
    int dep_varies;        /* a parameter follows a covariate that varies: it changes inside every
                              interval, so every interval takes the ramp's path (ARKODE, theta_at(t)) */
    /* covariates (simulation.covariates): output channels nch .. nch + ncov - 1 */
    size_t ncov;
    double cov_noise[SIM_MAX_COVARIATES];  /* std of the recorded value's noise (0 without noise) */
    sim_rng cov_rng[SIM_MAX_COVARIATES];   /* one stream each: a covariate's noise changes no other stream */
    /* mass matrix */
    double *M, *Minv, *work;
    int diag;
    /* integrator: the state x = [y; y'] lives in y for both paths */
    SUNContext sunctx;
    void *ark;
    void *ark_dp;          /* Dormand-Prince 5(4), same tolerances: a piece the configured method fails on */
    N_Vector y, ytmp;      /* ytmp: the accelerations of a sample (rhs at t_k) */
    N_Vector ypiece;       /* the state at the start of the piece being integrated (for a retry) */
    long n_retried;        /* pieces the configured method failed on and Dormand-Prince integrated */
    double hnext;
    /* exact step (linear stands, sim_engine.h): x_{k+1} = Phi [x_k; v0; dv] with input
     * columns v = [u_1..u_r, (s, s') with a base, w_1..w_nw], v0 their values at t_k and dv
     * their increments over the interval (linear inputs; 0 when held) */
    int exact_ok;          /* linear stand and integrator.kind != "arkode" */
    size_t m;              /* input columns */
    double *Phi;           /* 2n x (2n + 2m), ROW-major (row i at Phi + i (2n + 2m)): [Ad  Gamma0  Gamma1];
                              rows so that each x_{k+1,i} is one contiguous dot product */
    double *zin;           /* 2n + 2m: [x_k; v0; dv] */
    double *xn;            /* 2n: x_{k+1} */
    int phi_valid;         /* Phi is that of theta_k (a parameter change clears it) */
    long n_exact, n_arkode; /* intervals taken by each path */
    /* per-RHS scratch */
    double *u, *f;
    /* channels */
    vibid_channel_info *ch;
    double *noise_std, *resolution;
    double *noise_offset; /* per channel: constant sensor zero error (simulation.noise offset) */
    double *noise_ar;     /* per channel: AR(1) coefficient exp(-h / correlation_time); 0 = white */
    double *noise_state;  /* per channel: the coloured noise's last value (channel units) */
    sim_rng noise_rng;
    uint64_t k;
    double tk;
    char err[512];
};

static void set_err(sim_engine *e, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void set_err(sim_engine *e, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(e->err, sizeof e->err, fmt, ap);
    va_end(ap);
}

/* The factor (1 + coefficient (c_true(t) - reference)) of dependence entry i at t. */
static double dependence_factor(const sim_engine *e, size_t i, double t)
{
    const sim_dependence *d = &e->cfg->dependence[i];
    return 1.0 + d->coefficient * (sim_covariate_value(&e->cfg->covariates[d->covariate], t) - d->reference);
}

/* theta at time t within interval [tk, tk + h): steps at sample boundaries, ramps continuous;
 * then the dependence on covariates at t (continuous, like a ramp), multiplying the value
 * that the changes set */
static void theta_at(const sim_engine *e, double t, double tk, double *theta)
{
    memcpy(theta, e->theta0, e->p * sizeof *theta);
    for (size_t i = 0; i < e->cfg->n_changes; i++) {
        const sim_change *c = &e->cfg->changes[i];
        double prev = theta[c->param];
        if (c->ramp <= 0.0) {
            /* first sample boundary >= at, with a tolerance for at = k h written in decimal */
            if (tk >= c->at - 1e-9 * e->h) theta[c->param] = c->value;
        } else if (t >= c->at + c->ramp) {
            theta[c->param] = c->value;
        } else if (t > c->at) {
            theta[c->param] = prev + (c->value - prev) * (t - c->at) / c->ramp;
        }
    }
    for (size_t i = 0; i < e->cfg->n_dependence; i++) theta[e->cfg->dependence[i].param] *= dependence_factor(e, i, t);
}

/* A dependence factor <= 0 at t_k would flip the sign of a mass, stiffness or damping: not
 * a drift of the operating condition but a covariate that left the range its coefficient
 * holds for. The run stops naming it (also a ramp that drifts there after hours). */
static int check_dependence(sim_engine *e, double tk)
{
    for (size_t i = 0; i < e->cfg->n_dependence; i++) {
        double f = dependence_factor(e, i, tk);
        if (f > 0.0) continue;
        const sim_dependence *d = &e->cfg->dependence[i];
        vibid_param_info pi;
        vibid_model_param_info(e->model, d->param, &pi);
        set_err(e, "%s: simulation.dependence.[%zu]: the factor of '%s' is %g at t = %g s (covariate '%s' = %g): "
                   "must stay > 0 (a smaller coefficient or a narrower covariate range)",
                e->cfg->file, i, pi.name, f, tk, e->cfg->covariates[d->covariate].name,
                sim_covariate_value(&e->cfg->covariates[d->covariate], tk));
        return -1;
    }
    return 0;
}

/* Gauss-Jordan inverse with partial pivoting of the n x n column-major A (destroyed). */
static int invert(size_t n, double *A, double *Ainv)
{
    for (size_t i = 0; i < n * n; i++) Ainv[i] = 0.0;
    for (size_t i = 0; i < n; i++) Ainv[i + i * n] = 1.0;
    for (size_t c = 0; c < n; c++) {
        size_t piv = c;
        for (size_t i = c + 1; i < n; i++)
            if (fabs(A[i + c * n]) > fabs(A[piv + c * n])) piv = i;
        if (!(fabs(A[piv + c * n]) > 0.0)) return -1;
        if (piv != c)
            for (size_t j = 0; j < n; j++) {
                double t = A[c + j * n]; A[c + j * n] = A[piv + j * n]; A[piv + j * n] = t;
                t = Ainv[c + j * n]; Ainv[c + j * n] = Ainv[piv + j * n]; Ainv[piv + j * n] = t;
            }
        double d = A[c + c * n];
        for (size_t j = 0; j < n; j++) { A[c + j * n] /= d; Ainv[c + j * n] /= d; }
        for (size_t i = 0; i < n; i++) {
            if (i == c) continue;
            double m = A[i + c * n];
            if (m == 0.0) continue;
            for (size_t j = 0; j < n; j++) { A[i + j * n] -= m * A[c + j * n]; Ainv[i + j * n] -= m * Ainv[c + j * n]; }
        }
    }
    return 0;
}

static int refresh_mass(sim_engine *e, const double *theta)
{
    size_t n = e->n;
    if (vibid_model_assemble(e->model, theta, e->M, NULL, NULL, NULL, NULL, NULL) != VIBID_OK) {
        set_err(e, "assembling M failed: %s", vibid_last_error());
        return -1;
    }
    e->diag = 1;
    for (size_t j = 0; j < n; j++)
        for (size_t i = 0; i < n; i++)
            if (i != j && e->M[i + j * n] != 0.0) e->diag = 0;
    if (e->diag) {
        for (size_t i = 0; i < n; i++) {
            if (!(e->M[i + i * n] > 0.0)) {
                set_err(e, "mass of node %zu is %g: must be > 0 for simulation (give true_value)", i, e->M[i + i * n]);
                return -1;
            }
            e->Minv[i] = 1.0 / e->M[i + i * n];
        }
        return 0;
    }
    memcpy(e->work, e->M, n * n * sizeof *e->work);
    if (invert(n, e->work, e->Minv)) {
        set_err(e, "mass matrix is singular at the true values");
        return -1;
    }
    return 0;
}

/* d_base at theta (dampers to the base; they change only through parameter changes). */
static int refresh_d_base(sim_engine *e, const double *theta)
{
    if (vibid_model_assemble(e->model, theta, NULL, NULL, NULL, NULL, e->d_base, NULL) != VIBID_OK) {
        set_err(e, "assembling d_base failed: %s", vibid_last_error());
        return -1;
    }
    return 0;
}

/* Held base: the impulse of the dampers to the base at t_k, M dy' = d_base (s_k - s_{k-1}),
 * applied to the state y'. Returns 1 if the state changed. */
static int apply_base_jump(sim_engine *e, double s_k)
{
    size_t n = e->n;
    double ds = s_k - e->s_prev;
    e->s_prev = s_k;
    if (ds == 0.0) return 0;
    double *x = N_VGetArrayPointer(e->y);
    int changed = 0;
    for (size_t i = 0; i < n; i++) {
        double a = 0.0;
        if (e->diag) a = e->Minv[i] * e->d_base[i];
        else
            for (size_t j = 0; j < n; j++) a += e->Minv[i + j * n] * e->d_base[j];
        if (a != 0.0) {
            x[n + i] += a * ds;
            changed = 1;
        }
    }
    return changed;
}

/* xdot = [y'; M^-1 f(y, y', s, s', u, theta(t))] */
static int rhs(sunrealtype t, N_Vector x, N_Vector xdot, void *user)
{
    sim_engine *e = user;
    size_t n = e->n;
    const double *y = N_VGetArrayPointer(x);
    double *yd = N_VGetArrayPointer(xdot);
    double base[2] = {0.0, 0.0};
    if (e->base_exc) sim_exc_eval(e->base_exc, t, &base[0], &base[1]);
    for (size_t j = 0; j < e->r; j++) {
        double dv;
        e->u[j] = 0.0;
        if (e->in_exc[j]) sim_exc_eval(e->in_exc[j], t, &e->u[j], &dv);
    }
    const double *theta = e->theta_k;
    if (e->ramp_in_interval) {
        theta_at(e, t, e->tk, e->theta);
        theta = e->theta;
    }
    if (vibid_model_forces(e->model, theta, y, y + n, e->has_base ? base : NULL, e->r ? e->u : NULL, e->f) != VIBID_OK)
        return -1;
    for (size_t j = 0; j < e->nw; j++)
        if (e->w_exc[j]) {
            double w, dw;
            sim_exc_eval(e->w_exc[j], t, &w, &dw);
            e->f[e->w_node[j]] += w;
        }
    memcpy(yd, y + n, n * sizeof *yd);
    if (e->diag) {
        for (size_t i = 0; i < n; i++) yd[n + i] = e->Minv[i] * e->f[i];
    } else {
        for (size_t i = 0; i < n; i++) {
            double a = 0.0;
            for (size_t j = 0; j < n; j++) a += e->Minv[i + j * n] * e->f[j];
            yd[n + i] = a;
        }
    }
    return 0;
}

/* dst(i, j) = sign (M^-1 X)(i, j) for X n x ncols (column-major, leading dimension n),
 * dst with leading dimension ld. */
static void minv_cols(const sim_engine *e, const double *X, size_t ncols, double *dst, size_t ld, double sign)
{
    size_t n = e->n;
    for (size_t j = 0; j < ncols; j++)
        for (size_t i = 0; i < n; i++) {
            double a = 0.0;
            if (e->diag) a = e->Minv[i] * X[i + j * n];
            else
                for (size_t l = 0; l < n; l++) a += e->Minv[i + l * n] * X[l + j * n];
            dst[i + j * ld] = sign * a;
        }
}

/* Phi at theta_k: A = [0 I; -M^-1 C  -M^-1 D], Bv = [0; M^-1 [B c_base d_base E_w]] (E_w:
 * the unit force on each disturbance's node), and with v(t_k + tau) = v0 + dv tau / h
 *   x_{k+1} = Ad x_k + Gamma0 v0 + Gamma1 dv,   Ad = e^{A h},
 *   Gamma0 = int_0^h e^{A (h - tau)} Bv dtau,   Gamma1 = int_0^h e^{A (h - tau)} Bv tau / h dtau.
 * One vibid_zoh of the system augmented by the input as a state, xi = [x; v], xi' =
 * [[A Bv]; [0 0]] xi + [0; I / h] dv: its G holds Ad and Gamma0, its Gamma holds Gamma1.
 * The exponential is taken in scaled coordinates xi = S xi~, dv = Sv dv~ (S = diag(I, c I,
 * Sv), c = the largest sqrt((M^-1 C)_ii), an angular frequency, Sv = diag(s_j) with s_j =
 * c^2 / max_i |(M^-1 F)_ij|), in which every block of the augmented matrix times h is
 * about omega h: unscaled, h times the stiffness block is ~omega^2 h (40 for the
 * closed-form test's oscillator at 1 kHz), the exponential needs scaling and squaring, and
 * its rounding grew sim.exact's closed-form velocity error over 1000 samples to 1.8e-12
 * (8e-15 scaled) and the 10-DOF chain's difference from ARKODE at rtol 1e-13 to 1.4e-10
 * (2.6e-13 scaled).
 * Called once, and again after each parameter change (allocates; not per sample). */
static int compute_phi(sim_engine *e)
{
    size_t n = e->n, ns = 2 * n, m = e->m, N = ns + m;
    double *D = calloc(n * n, sizeof(double)), *C = calloc(n * n, sizeof(double));
    double *B = calloc(n * (e->r + 1), sizeof(double)), *cb = calloc(n, sizeof(double));
    double *db = calloc(n, sizeof(double)), *F = calloc(n * (m + 1), sizeof(double));
    double *Aa = calloc(N * N, sizeof(double)), *Ba = calloc(N * (m + 1), sizeof(double));
    double *G = calloc(N * N, sizeof(double)), *Gam = calloc(N * (m + 1), sizeof(double));
    double *sc = calloc(N, sizeof(double)); /* the diagonal of S; its last m entries are Sv */
    int rc = -1;
    if (!D || !C || !B || !cb || !db || !F || !Aa || !Ba || !G || !Gam || !sc) {
        set_err(e, "out of memory");
        goto out;
    }
    if (vibid_model_assemble(e->model, e->theta_k, NULL, D, C, B, db, cb) != VIBID_OK) {
        set_err(e, "assembling the linear matrices failed: %s", vibid_last_error());
        goto out;
    }
    /* F = [B c_base d_base E_w] (n x m), forces per unit of each input column */
    memcpy(F, B, n * e->r * sizeof(double));
    size_t col = e->r;
    if (e->has_base) {
        memcpy(F + col++ * n, cb, n * sizeof(double));
        memcpy(F + col++ * n, db, n * sizeof(double));
    }
    for (size_t j = 0; j < e->nw; j++) F[e->w_node[j] + col++ * n] = 1.0;
    /* A and Bv into the augmented matrix [[A Bv]; [0 0]] (N x N); [0; I / h] (N x m) */
    for (size_t i = 0; i < n; i++) Aa[i + (n + i) * N] = 1.0;
    minv_cols(e, C, n, Aa + n, N, -1.0);
    minv_cols(e, D, n, Aa + n + n * N, N, -1.0);
    minv_cols(e, F, m, Aa + n + ns * N, N, 1.0);
    double kmax = 0.0;
    for (size_t i = 0; i < n; i++) kmax = fmax(kmax, fabs(Aa[n + i + i * N]));
    double cs = kmax > 0.0 ? sqrt(kmax) : 1.0;
    for (size_t i = 0; i < N; i++) sc[i] = i < n ? 1.0 : i < ns ? cs : 1.0;
    for (size_t j = 0; j < m; j++) {
        double fm = 0.0;
        for (size_t i = 0; i < n; i++) fm = fmax(fm, fabs(Aa[n + i + (ns + j) * N]));
        if (fm > 0.0) sc[ns + j] = cs * cs / fm;
    }
    /* A~ = S^-1 Aa S; B~ = S^-1 [0; I / h] Sv = [0; I / h] */
    for (size_t j = 0; j < N; j++)
        for (size_t i = 0; i < N; i++) Aa[i + j * N] *= sc[j] / sc[i];
    for (size_t j = 0; j < m; j++) Ba[ns + j + j * N] = 1.0 / e->h;
    if (vibid_zoh(N, m, Aa, Ba, e->h, G, Gam) != VIBID_OK) {
        set_err(e, "exact discretization (vibid_zoh) failed: %s", vibid_last_error());
        goto out;
    }
    /* back: G = S G~ S^-1 (the top rows: Ad, Gamma0), Gamma1 = S Gamma~ Sv^-1; row-major */
    size_t ld = N + m;
    for (size_t j = 0; j < N; j++)
        for (size_t i = 0; i < ns; i++) e->Phi[i * ld + j] = sc[i] * G[i + j * N] / sc[j];
    for (size_t j = 0; j < m; j++)
        for (size_t i = 0; i < ns; i++) e->Phi[i * ld + N + j] = sc[i] * Gam[i + j * N] / sc[ns + j];
    e->phi_valid = 1;
    rc = 0;
out:
    free(D); free(C); free(B); free(cb); free(db); free(F); free(Aa); free(Ba); free(G); free(Gam); free(sc);
    return rc;
}

sim_engine *sim_engine_create_internal(const vibid_stand *stand, const sim_config *cfg, int with_noise, char *err,
                                       size_t errlen);

sim_engine *sim_engine_create(const vibid_stand *stand, const sim_config *cfg, char *err, size_t errlen)
{
    return sim_engine_create_internal(stand, cfg, 1, err, errlen);
}

#define CFAIL(...) do { set_err(e, __VA_ARGS__); goto fail; } while (0)

sim_engine *sim_engine_create_internal(const vibid_stand *stand, const sim_config *cfg, int with_noise, char *err,
                                       size_t errlen)
{
    sim_engine *e = calloc(1, sizeof *e);
    if (!e) {
        if (err && errlen) snprintf(err, errlen, "out of memory");
        return NULL;
    }
    e->stand = stand;
    e->cfg = cfg;
    e->model = vibid_stand_model(stand);
    vibid_model_dims d;
    if (vibid_model_get_dims(e->model, &d) != VIBID_OK) CFAIL("model: %s", vibid_last_error());
    e->n = d.n_dof;
    e->r = d.n_inputs;
    e->p = d.n_params;
    e->nch = d.n_channels;
    e->nw = d.n_disturbances;
    e->has_base = d.has_base;
    e->h = 1.0 / vibid_stand_sample_rate(stand);
    size_t n = e->n;
    if (e->nch > SIM_MAX_CHANNELS) CFAIL("%zu channels, at most %d", e->nch, SIM_MAX_CHANNELS);

    e->theta0 = calloc(e->p + 1, sizeof(double));
    e->theta = calloc(e->p + 1, sizeof(double));
    e->theta_k = calloc(e->p + 1, sizeof(double));
    e->M = calloc(n * n, sizeof(double));
    e->Minv = calloc(n * n, sizeof(double));
    e->work = calloc(n * n, sizeof(double));
    e->u = calloc(e->r + 1, sizeof(double));
    e->f = calloc(n, sizeof(double));
    e->d_base = calloc(n, sizeof(double));
    e->in_exc = calloc(e->r + 1, sizeof(sim_exc *));
    e->w_exc = calloc(e->nw + 1, sizeof(sim_exc *));
    e->w_node = calloc(e->nw + 1, sizeof(size_t));
    e->ch = calloc(e->nch + 1, sizeof *e->ch);
    e->noise_std = calloc(e->nch + 1, sizeof(double));
    e->resolution = calloc(e->nch + 1, sizeof(double));
    e->noise_offset = calloc(e->nch + 1, sizeof(double));
    e->noise_ar = calloc(e->nch + 1, sizeof(double));
    e->noise_state = calloc(e->nch + 1, sizeof(double));
    if (!e->theta0 || !e->theta || !e->theta_k || !e->M || !e->Minv || !e->work || !e->u || !e->f || !e->in_exc ||
        !e->w_exc || !e->w_node || !e->d_base || !e->ch || !e->noise_std || !e->resolution || !e->noise_offset ||
        !e->noise_ar || !e->noise_state)
        CFAIL("out of memory");
    if (e->p) memcpy(e->theta0, vibid_stand_true_values(stand), e->p * sizeof(double));
    for (size_t i = 0; i < e->p; i++) {
        vibid_param_info pi;
        vibid_model_param_info(e->model, i, &pi);
        if (!isfinite(e->theta0[i])) CFAIL("parameter %s: true value not finite", pi.name);
        for (size_t c = 0; c < cfg->n_changes; c++)
            if (cfg->changes[c].param == i && pi.kind == VIBID_PARAM_MASS) e->mass_changes = 1;
        for (size_t c = 0; c < cfg->n_dependence; c++)
            if (cfg->dependence[c].param == i && pi.kind == VIBID_PARAM_MASS) e->mass_changes = 1;
    }
    /* covariates: a stream each, derived from the run's seed and the position (the other
     * streams stay as they were), and which parameters vary inside the intervals */
    e->ncov = cfg->n_covariates;
    for (size_t j = 0; j < e->ncov; j++) {
        e->cov_noise[j] = with_noise ? cfg->covariates[j].noise : 0.0;
        sim_rng_seed(&e->cov_rng[j], (cfg->seed ^ 0x636F766172ull) * 1000003ull + j + 1);
    }
    for (size_t c = 0; c < cfg->n_dependence; c++)
        if (cfg->dependence[c].coefficient != 0.0 && sim_covariate_varies(&cfg->covariates[cfg->dependence[c].covariate]))
            e->dep_varies = 1;
    if (check_dependence(e, 0.0)) goto fail;
    for (size_t i = 0; i < e->nch; i++) {
        vibid_model_channel_info(e->model, i, &e->ch[i]);
        /* sim_config_load rejects this for simulation.hold = "zoh"; here the stand declared it */
        if (!cfg->base_smooth && e->ch[i].index == VIBID_BASE && e->ch[i].kind != VIBID_CHANNEL_DISPLACEMENT)
            CFAIL("stand.base.hold: the base is held (\"zoh\") and its %s is measured (channel '%s'): a held "
                  "displacement's derivative is a train of impulses that no sensor reports (measure only the base "
                  "displacement, or declare hold = \"smooth\")",
                  e->ch[i].kind == VIBID_CHANNEL_VELOCITY ? "velocity" : "acceleration",
                  vibid_stand_channel_name(stand, i));
    }

    char xerr[256];
    for (size_t i = 0; i < cfg->n_targets; i++) {
        const sim_exc_target *t = &cfg->targets[i];
        /* a disturbance is held whatever simulation.hold says: the model defines it so */
        int smooth = t->is_base ? cfg->base_smooth
                     : t->is_disturbance ? 0
                     : t->input < SIM_MAX_CHANNELS ? cfg->input_smooth[t->input] : 1;
        sim_exc *x = sim_exc_create(t->specs, t->n, e->h, smooth, xerr, sizeof xerr);
        if (!x)
            CFAIL("%s: simulation.excitation (target %s): %s", cfg->file,
                  t->is_base ? "base" : t->is_disturbance ? "disturbance" : "input", xerr);
        if (t->is_base) e->base_exc = x;
        else if (t->is_disturbance) e->w_exc[t->input] = x;
        else e->in_exc[t->input] = x;
    }
    /* Disturbances that no excitation drives: white Gaussian samples of std true_std, held
     * over each interval (a full-band `noise` component, whose gain is exactly 1), each from
     * its own stream derived from the run's seed. */
    for (size_t j = 0; j < e->nw; j++) {
        vibid_disturbance_info wi;
        if (vibid_model_disturbance_info(e->model, j, &wi) != VIBID_OK) CFAIL("model: %s", vibid_last_error());
        e->w_node[j] = wi.node;
        if (e->w_exc[j]) continue;
        double sd = vibid_stand_disturbance_true_std(stand)[j];
        if (sd == 0.0 && wi.std_dev == 0.0)
            CFAIL("stand.disturbances.[%zu].true_std: missing: disturbance '%s' has an unknown std and vibid-sim needs "
                  "the std it simulates (give true_std > 0, or drive '%s' from simulation.excitation)",
                  j, wi.name, wi.name);
        if (sd == 0.0) continue; /* true_std = 0 given: the estimator's model has it, the stand does not */
        sim_exc_spec ws;
        sim_exc_spec_init(&ws, SIM_EXC_NOISE);
        ws.amplitude = sd;
        ws.f_high = INFINITY;
        ws.seed = (cfg->seed ^ 0x6469737475726255ull) * 1000003ull + j + 1;
        if (!(e->w_exc[j] = sim_exc_create(&ws, 1, e->h, 0, xerr, sizeof xerr)))
            CFAIL("disturbance '%s': %s", wi.name, xerr);
    }

    theta_at(e, 0.0, 0.0, e->theta_k);
    if (refresh_mass(e, e->theta_k)) goto fail;
    if (e->has_base && refresh_d_base(e, e->theta_k)) goto fail;

    if (SUNContext_Create(NULL, &e->sunctx)) CFAIL("SUNContext_Create failed");
    e->y = N_VNew_Serial((sunindextype)(2 * n), e->sunctx);
    if (!e->y) CFAIL("N_VNew_Serial failed");
    N_VConst(0.0, e->y); /* the stand starts at rest in its unloaded position */
    e->ytmp = N_VClone(e->y);
    e->ypiece = N_VClone(e->y);
    if (!e->ytmp || !e->ypiece) CFAIL("N_VClone failed");
    /* ARKODE is set up also when the exact step will take every interval: intervals that
     * the exact step cannot take (a ramp, a window edge inside the interval) fall back to it */
    e->ark = ERKStepCreate(rhs, 0.0, e->y, e->sunctx);
    if (!e->ark) CFAIL("ERKStepCreate failed");
    if (ERKStepSetUserData(e->ark, e) || ERKStepSStolerances(e->ark, cfg->rtol, cfg->atol) ||
        ERKStepSetTableNum(e->ark, cfg->method == 1 ? ARKODE_DORMAND_PRINCE_7_4_5 : ARKODE_FEHLBERG_13_7_8) || ERKStepSetMaxNumSteps(e->ark, 1000000) ||
        ERKStepSetMaxStep(e->ark, e->h))
        CFAIL("ERKStep options rejected");
    /* Fehlberg 7(8) at the default tolerances stops now and then with ARK_ERR_FAILURE (its
     * error test failing down to steps of 1e-7 h) on smooth cubic stands (a 1-DOF cubic at
     * 286 Hz under band-limited noise: 5 of 6 seeds; a sine at 30 Hz at 5.8 s), where
     * Dormand-Prince at the same tolerances does not. Such a piece is integrated again from
     * its start by Dormand-Prince (counted: sim_engine_stats.retried_pieces); every run that
     * never fails stays bit for bit what it was. */
    e->ark_dp = ERKStepCreate(rhs, 0.0, e->y, e->sunctx);
    if (!e->ark_dp || ERKStepSetUserData(e->ark_dp, e) || ERKStepSStolerances(e->ark_dp, cfg->rtol, cfg->atol) ||
        ERKStepSetTableNum(e->ark_dp, ARKODE_DORMAND_PRINCE_7_4_5) || ERKStepSetMaxNumSteps(e->ark_dp, 1000000) ||
        ERKStepSetMaxStep(e->ark_dp, e->h))
        CFAIL("ERKStep (Dormand-Prince) options rejected");
    e->hnext = 0.0;

    /* The exact step needs f linear in the state: vibid_model_forces is f = B u + d_base s'
     * + c_base s - D y' - C y - cubic terms, so linear unless a cubic spring is present. */
    e->exact_ok = cfg->integrator != SIM_INTEGRATOR_ARKODE && !d.nonlinear;
    if (cfg->integrator == SIM_INTEGRATOR_EXACT && d.nonlinear)
        CFAIL("integrator \"exact\": the stand has a cubic spring (not linear)");
    if (e->exact_ok) {
        e->m = e->r + (e->has_base ? 2 : 0) + e->nw;
        size_t ns = 2 * n, N = ns + e->m;
        e->Phi = calloc(ns * (N + e->m), sizeof(double));
        e->zin = calloc(N + e->m, sizeof(double));
        e->xn = calloc(ns, sizeof(double));
        if (!e->Phi || !e->zin || !e->xn) CFAIL("out of memory");
        if (compute_phi(e)) goto fail;
    }

    sim_rng_seed(&e->noise_rng, cfg->seed ^ 0x6E6F697365ull);
    /* Measurement noise: the stand's declared noise of each measured quantity (stand.nodes.[i].noise,
     * vibid_model_get_noise), unless simulation.noise gives the channel a std or an SNR. */
    for (size_t i = 0; with_noise && i < e->nch; i++) {
        const vibid_channel_info *ci = &e->ch[i];
        unsigned bit = ci->kind == VIBID_CHANNEL_DISPLACEMENT ? VIBID_MEASURE_DISPLACEMENT
                       : ci->kind == VIBID_CHANNEL_VELOCITY   ? VIBID_MEASURE_VELOCITY
                       : ci->kind == VIBID_CHANNEL_ACCELERATION ? VIBID_MEASURE_ACCELERATION
                                                                : 0u;
        double sd;
        if (bit && vibid_model_get_noise(e->model, ci->index, bit, &sd) == VIBID_OK && sd > 0.0) e->noise_std[i] = sd;
    }
    int need_pilot = 0;
    for (size_t i = 0; with_noise && i < cfg->n_noise; i++) {
        const sim_noise_spec *ns = &cfg->noise[i];
        e->resolution[ns->channel] = ns->resolution;
        e->noise_offset[ns->channel] = ns->offset;
        e->noise_ar[ns->channel] = ns->corr_time > 0.0 ? exp(-e->h / ns->corr_time) : 0.0;
        if (!isnan(ns->snr_db)) need_pilot = 1;
        else if (!isnan(ns->std)) e->noise_std[ns->channel] = ns->std;
    }
    if (need_pilot) {
        /* SNR: noise std from the RMS of the clean signal over a pilot run of the first
         * min(duration, 2 s) (deterministic: same excitation, no noise) */
        sim_engine *pe = sim_engine_create_internal(stand, cfg, 0, xerr, sizeof xerr);
        if (!pe) CFAIL("SNR pilot run: %s", xerr);
        double dur = cfg->duration > 0 ? fmin(cfg->duration, 2.0) : 2.0;
        uint64_t ns = (uint64_t)ceil(dur / e->h);
        if (ns < 2) ns = 2;
        double *sum = calloc(e->nch, sizeof(double)), *v = calloc(e->nch + e->ncov, sizeof(double));
        int bad = !sum || !v;
        for (uint64_t s = 0; s < ns && !bad; s++) {
            uint64_t kk;
            double tt;
            if (sim_engine_next(pe, &kk, &tt, v, NULL)) bad = 2;
            for (size_t c = 0; c < e->nch && !bad; c++) sum[c] += v[c] * v[c];
        }
        /* at most 200 bytes of the pilot's message (up to 511) so that it fits xerr (256 bytes) */
        if (bad == 2) snprintf(xerr, sizeof xerr, "%.200s", sim_engine_error(pe));
        for (size_t i = 0; !bad && i < cfg->n_noise; i++) {
            const sim_noise_spec *nsp = &cfg->noise[i];
            if (isnan(nsp->snr_db)) continue;
            double rms = sqrt(sum[nsp->channel] / (double)ns);
            e->noise_std[nsp->channel] = rms / pow(10.0, nsp->snr_db / 20.0);
        }
        free(sum);
        free(v);
        sim_engine_destroy(pe);
        if (bad == 1) CFAIL("out of memory");
        if (bad == 2) CFAIL("SNR pilot run: %s", xerr);
    }
    e->k = 0;
    return e;
fail:
    if (err && errlen) snprintf(err, errlen, "%s", e->err);
    sim_engine_destroy(e);
    return NULL;
}

void sim_engine_destroy(sim_engine *e)
{
    if (!e) return;
    if (e->ark) ERKStepFree(&e->ark);
    if (e->ark_dp) ERKStepFree(&e->ark_dp);
    if (e->ypiece) N_VDestroy(e->ypiece);
    if (e->y) N_VDestroy(e->y);
    if (e->ytmp) N_VDestroy(e->ytmp);
    free(e->Phi);
    free(e->zin);
    free(e->xn);
    if (e->sunctx) SUNContext_Free(&e->sunctx);
    sim_exc_destroy(e->base_exc);
    for (size_t j = 0; e->in_exc && j < e->r; j++) sim_exc_destroy(e->in_exc[j]);
    free(e->in_exc);
    for (size_t j = 0; e->w_exc && j < e->nw; j++) sim_exc_destroy(e->w_exc[j]);
    free(e->w_exc);
    free(e->w_node);
    free(e->theta0);
    free(e->theta);
    free(e->theta_k);
    free(e->M);
    free(e->Minv);
    free(e->work);
    free(e->u);
    free(e->f);
    free(e->d_base);
    free(e->ch);
    free(e->noise_std);
    free(e->resolution);
    free(e->noise_offset);
    free(e->noise_ar);
    free(e->noise_state);
    free(e);
}

size_t sim_engine_channels(const sim_engine *e) { return e->nch; }
size_t sim_engine_outputs(const sim_engine *e) { return e->nch + e->ncov; }
double sim_engine_period(const sim_engine *e) { return e->h; }
double sim_engine_noise_std(const sim_engine *e, size_t c) { return c < e->nch ? e->noise_std[c] : 0.0; }
const char *sim_engine_error(const sim_engine *e) { return e->err; }
double sim_engine_param(const sim_engine *e, size_t i) { return i < e->p ? e->theta_k[i] : NAN; }

void sim_engine_stats_get(const sim_engine *e, sim_engine_stats *s)
{
    s->steps = s->rhs_evals = 0;
    ERKStepGetNumSteps(e->ark, &s->steps);
    ERKStepGetNumRhsEvals(e->ark, &s->rhs_evals);
    long dp_steps = 0, dp_evals = 0;
    ERKStepGetNumSteps(e->ark_dp, &dp_steps);
    ERKStepGetNumRhsEvals(e->ark_dp, &dp_evals);
    s->steps += dp_steps;
    s->rhs_evals += dp_evals;
    s->retried_pieces = e->n_retried;
    s->exact_intervals = e->n_exact;
    s->arkode_intervals = e->n_arkode;
}

static int check_finite(sim_engine *e, double tk1)
{
    const double *x = N_VGetArrayPointer(e->y);
    for (size_t i = 0; i < 2 * e->n; i++)
        if (!isfinite(x[i])) {
            set_err(e, "state not finite at t = %g s (unstable stand or too large excitation?)", tk1);
            return -1;
        }
    return 0;
}

/* The input columns of the current interval into zin (v0 after x, dv after v0), when every
 * input is linear over it (sim_exc_linear); 0 when one is not (the interval then goes to
 * ARKODE). A held base contributes s' = 0 (its jump at t_k was the impulse, already in
 * the state); a smooth one its slope, the derivative that sim_exc_eval gives ARKODE. */
static int exact_inputs(sim_engine *e)
{
    size_t ns = 2 * e->n, m = e->m;
    double *v0 = e->zin + ns, *dv = e->zin + ns + m;
    for (size_t j = 0; j < e->r; j++) {
        double a = 0.0, b = 0.0;
        if (e->in_exc[j] && !sim_exc_linear(e->in_exc[j], &a, &b)) return 0;
        v0[j] = a;
        dv[j] = b - a;
    }
    size_t col = e->r;
    if (e->has_base) {
        double a = 0.0, b = 0.0, sd = 0.0;
        if (e->base_exc) {
            double v;
            if (!sim_exc_linear(e->base_exc, &a, &b)) return 0;
            sim_exc_eval(e->base_exc, e->tk, &v, &sd);
        }
        v0[col] = a;
        dv[col++] = b - a;
        v0[col] = sd;
        dv[col++] = 0.0;
    }
    for (size_t j = 0; j < e->nw; j++, col++) {
        double a = 0.0, b = 0.0;
        if (e->w_exc[j] && !sim_exc_linear(e->w_exc[j], &a, &b)) return 0;
        v0[col] = a;
        dv[col] = b - a; /* 0: a disturbance is always held */
    }
    return 1;
}

/* x_{k+1} = Phi [x_k; v0; dv]: one matrix-vector product, a dot product per row with four
 * independent partial sums (the build is -O2 for baseline x86-64, which does not vectorize
 * loops; one running sum would chain every multiply-add on the previous one: 0.67 us per
 * sample of the 10-DOF chain against 0.36 us this way), over [Ad Gamma0] only when no input
 * ramps (held inputs: dv = 0). */
static void exact_step(sim_engine *e)
{
    size_t ns = 2 * e->n, m = e->m, ld = ns + 2 * m;
    double *x = N_VGetArrayPointer(e->y);
    double *restrict z = e->zin;
    memcpy(z, x, ns * sizeof *z);
    size_t cols = ns + m;
    for (size_t j = 0; j < m; j++)
        if (z[ns + m + j] != 0.0) cols = ns + 2 * m;
    for (size_t i = 0; i < ns; i++) {
        const double *restrict row = e->Phi + i * ld;
        double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0;
        size_t j = 0;
        for (; j + 4 <= cols; j += 4) {
            a0 += row[j] * z[j];
            a1 += row[j + 1] * z[j + 1];
            a2 += row[j + 2] * z[j + 2];
            a3 += row[j + 3] * z[j + 3];
        }
        for (; j < cols; j++) a0 += row[j] * z[j];
        e->xn[i] = (a0 + a1) + (a2 + a3);
    }
    memcpy(x, e->xn, ns * sizeof *x);
}

int sim_engine_next(sim_engine *e, uint64_t *kout, double *tout, double *values, double *clean)
{
    size_t n = e->n;
    uint64_t k = e->k;
    double tk = (double)k * e->h, tk1 = (double)(k + 1) * e->h;
    e->tk = tk;
    /* inputs of this interval */
    if (e->base_exc) sim_exc_begin_sample(e->base_exc, k);
    for (size_t j = 0; j < e->r; j++)
        if (e->in_exc[j]) sim_exc_begin_sample(e->in_exc[j], k);
    for (size_t j = 0; j < e->nw; j++)
        if (e->w_exc[j]) sim_exc_begin_sample(e->w_exc[j], k);
    /* parameters of this interval */
    int mass_changed = 0;
    if (e->cfg->n_dependence && check_dependence(e, tk)) return -1;
    theta_at(e, tk, tk, e->theta);
    for (size_t i = 0; i < e->p; i++)
        if (e->theta[i] != e->theta_k[i]) mass_changed = 1;
    memcpy(e->theta_k, e->theta, e->p * sizeof(double));
    e->ramp_in_interval = e->dep_varies;
    for (size_t i = 0; i < e->cfg->n_changes; i++) {
        const sim_change *c = &e->cfg->changes[i];
        if (c->ramp > 0.0 && c->at < tk1 && c->at + c->ramp > tk) e->ramp_in_interval = 1;
    }
    if (e->mass_changes && mass_changed && refresh_mass(e, e->theta_k)) return -1;
    if (mass_changed) e->phi_valid = 0; /* any parameter: Phi is recomputed before the next exact step */
    /* Held base: the jump of s at t_k and its impulse, before the sample is taken (the
     * channels at t_k are the state right after the jumps) and before the integrator
     * restarts from t_k. The parameters in force from t_k decide the impulse. */
    int jumped = 0;
    if (e->base_exc && !e->cfg->base_smooth) {
        if (mass_changed && refresh_d_base(e, e->theta_k)) return -1;
        jumped = apply_base_jump(e, sim_exc_sample_value(e->base_exc));
    }

    /* the sample: state at t_k and inputs u_k */
    const double *x = N_VGetArrayPointer(e->y);
    double acc[256];
    int need_acc = 0;
    for (size_t c = 0; c < e->nch; c++)
        if (e->ch[c].kind == VIBID_CHANNEL_ACCELERATION && e->ch[c].index != VIBID_BASE) need_acc = 1;
    if (need_acc) {
        /* accelerations at t_k+ (with the new input), from the equations of motion */
        int rc = rhs(tk, e->y, e->ytmp, e);
        const double *xd = N_VGetArrayPointer(e->ytmp);
        for (size_t i = 0; i < n && i < 256; i++) acc[i] = xd[n + i];
        if (rc) { set_err(e, "force evaluation failed at t = %g: %s", tk, vibid_last_error()); return -1; }
    }
    double s = 0, sd = 0, sdd = 0;
    if (e->base_exc) {
        s = sim_exc_sample_value(e->base_exc);
        double v0, d0;
        sim_exc_eval(e->base_exc, tk, &v0, &d0);
        sd = d0;
        if (e->cfg->base_smooth) {
            double dl = e->h * 1e-3, v1, d1;
            sim_exc_eval(e->base_exc, tk + dl, &v1, &d1);
            sdd = (d1 - d0) / dl;
        }
    }
    for (size_t c = 0; c < e->nch; c++) {
        const vibid_channel_info *ci = &e->ch[c];
        double v = 0.0;
        int base = ci->index == VIBID_BASE;
        switch (ci->kind) {
        case VIBID_CHANNEL_DISPLACEMENT: v = base ? s : x[ci->index]; break;
        case VIBID_CHANNEL_VELOCITY: v = base ? sd : x[n + ci->index]; break;
        case VIBID_CHANNEL_ACCELERATION: v = base ? sdd : (ci->index < 256 ? acc[ci->index] : NAN); break;
        case VIBID_CHANNEL_INPUT: v = e->in_exc[ci->index] ? sim_exc_sample_value(e->in_exc[ci->index]) : 0.0; break;
        }
        if (clean) clean[c] = v;
        if (e->noise_std[c] > 0.0) {
            /* one normal draw per noisy channel and sample, white or coloured, so that colouring
             * one channel leaves every other channel's noise as it was. Coloured: AR(1) with the
             * stationary std noise_std from the first sample on (n_0 ~ N(0, std^2)). */
            double w = e->noise_std[c] * sim_rng_normal(&e->noise_rng), a = e->noise_ar[c];
            e->noise_state[c] = (a > 0.0 && k > 0) ? a * e->noise_state[c] + sqrt(1.0 - a * a) * w : w;
            v += e->noise_state[c];
        }
        v += e->noise_offset[c];
        if (e->resolution[c] > 0.0) v = nearbyint(v / e->resolution[c]) * e->resolution[c];
        values[c] = v;
    }
    /* covariates after the channels: the true value at t_k, plus its noise when recorded */
    for (size_t j = 0; j < e->ncov; j++) {
        double v = sim_covariate_value(&e->cfg->covariates[j], tk);
        if (clean) clean[e->nch + j] = v;
        if (e->cov_noise[j] > 0.0) v += e->cov_noise[j] * sim_rng_normal(&e->cov_rng[j]);
        values[e->nch + j] = v;
    }
    *kout = k;
    *tout = tk;

    if (e->exact_ok && !e->ramp_in_interval && exact_inputs(e)) {
        if (!e->phi_valid && compute_phi(e)) return -1;
        exact_step(e);
        e->n_exact++;
        e->k = k + 1;
        return check_finite(e, tk1);
    }
    e->n_arkode++;
    /* integrate over [t_k, t_{k+1}], restarted at t_k (the input jumped; the state too
     * when the held base's impulse changed y', also at k = 0), and in pieces split at the
     * jumps of smooth inputs inside the interval (a component's window opening or closing),
     * each piece ending on the left limit of the input and the next restarted after the
     * jump: stepping across a jump, the embedded error estimate let through errors of
     * 3e-5 of the response (sim.exact) */
    double ts = tk;
    for (;;) {
        double te = tk1;
        for (size_t j = 0; j < e->r; j++)
            if (e->in_exc[j]) te = fmin(te, sim_exc_next_jump(e->in_exc[j], ts));
        if (e->base_exc) te = fmin(te, sim_exc_next_jump(e->base_exc, ts));
        for (size_t j = 0; j < e->r; j++)
            if (e->in_exc[j]) sim_exc_set_piece_end(e->in_exc[j], te);
        if (e->base_exc) sim_exc_set_piece_end(e->base_exc, te);
        if (ts > tk || k > 0 || e->hnext > 0 || jumped) {
            /* (k + 1) h - k h may be an ulp below h: a whole interval keeps hnext as it is */
            if (e->hnext > 0) ERKStepSetInitStep(e->ark, te < tk1 || ts > tk ? fmin(e->hnext, te - ts) : e->hnext);
            if (ERKStepReset(e->ark, ts, e->y)) { set_err(e, "ERKStepReset failed at t = %g", ts); return -1; }
        }
        ERKStepSetStopTime(e->ark, te);
        sunrealtype tret = ts;
        N_VScale(1.0, e->y, e->ypiece);
        int flag = ERKStepEvolve(e->ark, te, e->y, &tret, ARK_NORMAL);
        if (flag == ARK_ERR_FAILURE) {
            /* the configured method's error test failed repeatedly: this piece again, from
             * its start, by Dormand-Prince (see sim_engine_create) */
            N_VScale(1.0, e->ypiece, e->y);
            if (ERKStepReset(e->ark_dp, ts, e->y)) { set_err(e, "ERKStepReset failed at t = %g", ts); return -1; }
            ERKStepSetStopTime(e->ark_dp, te);
            tret = ts;
            flag = ERKStepEvolve(e->ark_dp, te, e->y, &tret, ARK_NORMAL);
            e->n_retried++;
            /* the configured method restarts from the piece's end (its state is stale) */
            if (flag >= 0 && te < tk1 && ERKStepReset(e->ark, te, e->y)) {
                set_err(e, "ERKStepReset failed at t = %g", te);
                return -1;
            }
        }
        if (flag < 0) {
            set_err(e, "ARKODE ERKStepEvolve failed with flag %d (%s) between t = %g and %g s", flag,
                    ERKStepGetReturnFlagName(flag), ts, te);
            return -1;
        }
        if (te >= tk1) break;
        ts = te;
    }
    if (check_finite(e, tk1)) return -1;
    sunrealtype hc = 0;
    ERKStepGetCurrentStep(e->ark, &hc);
    e->hnext = hc > 0 ? fmin(hc, e->h) : e->h;
    e->k = k + 1;
    return 0;
}
