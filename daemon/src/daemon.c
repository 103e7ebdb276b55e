/* daemon.c: see daemon.h. */

#include "daemon.h"

#include "clock.h"
#include "reference.h"
#include "log.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <sched.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/eventfd.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

#include <vibid/change.h>
#include <vibid_drivers/source_modbus.h>
#include <vibid_drivers/source_replay.h>
#include <vibid_drivers/source_socketcan.h>

/* Internal: the estimation thread's "finished" to the main thread, which waits for signals
 * in sigtimedwait. Blocked in every thread, so an outside SIGUSR1 only ends one wait early. */
#define VD_WAKE_SIGNAL SIGUSR1

#define VD_REPLAY_RING 4096u /* ring slots used for a file source (see vd_daemon_init) */

/* ---------------------------------------------------------------- source ---- */

static bool is_recording(const char *path)
{
    FILE *f = fopen(path, "re");
    if (!f)
        return false;
    char line[64] = "";
    bool yes = fgets(line, sizeof line, f) && strncmp(line, VD_RECORDING_MAGIC, strlen(VD_RECORDING_MAGIC)) == 0;
    fclose(f);
    return yes;
}

/* The replay source's configuration for capture `path` (vibidd's own recording: columns
 * by channel name, time column t). 0, or -1 with err. */
static int replay_config(const vd_config *cfg, const char *path, int format, bool paced, double speed,
                         vibid_source_replay_config *out, char *err, size_t cap)
{
    vibid_source_replay_config rc;
    memset(&rc, 0, sizeof rc);
    rc.path = path;
    rc.paced = paced;
    rc.speed = speed > 0 ? speed : 1.0;
    rc.sample_period_s = 1.0 / cfg->sample_rate;
    rc.chanmap = cfg->chanmap;
    const vibid_replay_format resolved = vibid_replay_format_resolve((vibid_replay_format)format, path, err, cap);
    if (resolved == VIBID_REPLAY_AUTO)
        return -1;
    if (resolved == VIBID_REPLAY_CSV) {
        rc.format = VIBID_REPLAY_CSV;
        if (is_recording(path)) {
            /* Our own recording: columns are the channel names, time in column t. */
            for (size_t i = 0; i < rc.chanmap.n; i++) {
                rc.chanmap.ch[i].source = VIBID_CHAN_COLUMN;
                snprintf(rc.chanmap.ch[i].ref, sizeof rc.chanmap.ch[i].ref, "%s", rc.chanmap.ch[i].name);
                rc.chanmap.ch[i].message[0] = '\0';
            }
            snprintf(rc.chanmap.time_column, sizeof rc.chanmap.time_column, "t");
            rc.chanmap.counter[0] = rc.chanmap.trigger[0] = '\0';
        } else {
            for (size_t i = 0; i < rc.chanmap.n; i++)
                if (rc.chanmap.ch[i].source != VIBID_CHAN_COLUMN) {
                    snprintf(err, cap,
                             "%s: not a vibidd recording, and channel '%s' of %s:%u names no CSV column: a CSV "
                             "capture needs source.channels with column = \"...\"",
                             path, rc.chanmap.ch[i].name, cfg->path, rc.chanmap.ch[i].line);
                    return -1;
                }
        }
    } else {
        rc.format = VIBID_REPLAY_CANDUMP;
        if (!cfg->dbc) {
            snprintf(err, cap, "%s: a candump capture needs a DBC: %s has no source.dbc", path, cfg->path);
            return -1;
        }
        rc.dbc = cfg->dbc;
    }
    *out = rc;
    return 0;
}

static int open_replay(vd_daemon *d, const char *path, int format, bool paced, double speed, char *err, size_t cap)
{
    vibid_source_replay_config rc;
    if (replay_config(d->cfg, path, format, paced, speed, &rc, err, cap))
        return -1;
    /* data that do not fit the stand are refused before anything is written (rate_check.h) */
    if (vd_rate_check_capture(d->cfg, &rc, d->opt.rate_check, NULL, 0, err, cap))
        return -1;
    vibid_drv_error de = {0};
    d->src = vibid_source_open(&vibid_source_replay_ops, &rc, &de);
    if (!d->src) {
        snprintf(err, cap, "replay of %s: %s", path, de.text);
        return -1;
    }
    d->rec_chanmap = rc.chanmap;
    d->file_source = true;
    d->measure_latency = paced;
    return 0;
}

int vd_daemon_check_capture(const vd_config *cfg, const vd_options *opt, char *note, size_t note_cap, char *err,
                            size_t cap)
{
    if (note_cap)
        note[0] = '\0';
    const char *path = opt->replay ? opt->replay : cfg->source_kind == VD_SRC_REPLAY ? cfg->replay_file : NULL;
    int format = opt->replay ? VIBID_REPLAY_AUTO : cfg->replay_format;
    vibid_source_replay_config rc;
    if (!path || opt->rate_check == VD_RATE_MODE_OFF)
        return 0;
    if (replay_config(cfg, path, format, false, 1.0, &rc, err, cap))
        return -1;
    return vd_rate_check_capture(cfg, &rc, opt->rate_check, note, note_cap, err, cap);
}

static int open_source(vd_daemon *d, char *err, size_t cap)
{
    vd_config *cfg = d->cfg;
    vibid_drv_error de = {0};
    if (d->opt.replay)
        return open_replay(d, d->opt.replay, VIBID_REPLAY_AUTO, d->opt.pace, d->opt.speed, err, cap);
    switch (cfg->source_kind) {
    case VD_SRC_REPLAY:
        return open_replay(d, cfg->replay_file, cfg->replay_format, cfg->paced || d->opt.pace,
                           d->opt.pace ? d->opt.speed : cfg->speed, err, cap);
    case VD_SRC_SOCKETCAN: {
        vibid_source_socketcan_config sc;
        memset(&sc, 0, sizeof sc);
        sc.iface = cfg->iface;
        sc.dbc = cfg->dbc;
        sc.chanmap = cfg->chanmap;
        sc.rcvbuf_bytes = cfg->rcvbuf_bytes;
        sc.hw_timestamps = cfg->hw_timestamps;
        sc.batch = cfg->can_batch;
        sc.sample_period_s = 1.0 / cfg->sample_rate;
        d->src = vibid_source_open(&vibid_source_socketcan_ops, &sc, &de);
        break;
    }
    case VD_SRC_MODBUS: {
        vibid_source_modbus_config mc;
        memset(&mc, 0, sizeof mc);
        mc.transport = cfg->transport;
        mc.host = cfg->host;
        mc.port = cfg->port;
        mc.device = cfg->device;
        mc.baud = cfg->baud;
        mc.parity = cfg->parity;
        mc.unit_id = cfg->unit_id;
        mc.regmap = cfg->regmap;
        mc.chanmap = cfg->chanmap;
        mc.mode = cfg->modbus_mode;
        mc.sample_period_s = 1.0 / cfg->sample_rate;
        mc.poll_period_s = cfg->poll_period_s;
        mc.fifo_base = cfg->fifo_base;
        mc.response_timeout_s = cfg->response_timeout_s;
        mc.backoff_initial_s = cfg->backoff_initial_s;
        mc.backoff_max_s = cfg->backoff_max_s;
        mc.max_timeouts = cfg->max_timeouts;
        d->src = vibid_source_open(&vibid_source_modbus_ops, &mc, &de);
        break;
    }
    }
    if (!d->src) {
        snprintf(err, cap, "%s source (%s:%d): %s", vd_source_kind_name(cfg->source_kind), cfg->path, cfg->source_line,
                 de.text);
        return -1;
    }
    d->rec_chanmap = cfg->chanmap;
    d->measure_latency = true;
    return 0;
}

/* ------------------------------------------------------ acquisition thread ---- */

static void set_realtime(vd_daemon *d)
{
    int prio = d->cfg->rt_priority;
    if (prio <= 0)
        return;
    struct sched_param sp = {.sched_priority = prio};
    int rc = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp);
    if (rc == 0)
        vd_info("acquisition thread runs SCHED_FIFO priority %d", prio);
    else
        vd_warning("acquisition.realtime_priority = %d: SCHED_FIFO not permitted (%s); the thread stays "
                   "SCHED_OTHER. Grant CAP_SYS_NICE, or RLIMIT_RTPRIO >= %d (systemd: LimitRTPRIO=%d), or set "
                   "realtime_priority = 0 to silence this",
                   prio, strerror(rc), prio, prio);
}

static void wake_consumer(vd_daemon *d)
{
    atomic_thread_fence(memory_order_seq_cst);
    if (atomic_load_explicit(&d->consumer_sleeping, memory_order_relaxed)) {
        uint64_t one = 1;
        ssize_t w = write(d->efd, &one, sizeof one);
        (void)w; /* an eventfd write only fails when the counter would overflow: already awake */
    }
}

static void *acq_main(void *arg)
{
    vd_daemon *d = arg;
    set_realtime(d);
    const size_t cap = d->cfg->read_batch;
    vibid_record *recs = calloc(cap, sizeof *recs);
    vd_item *item = calloc(1, sizeof *item);
    if (!recs || !item) {
        vd_error("acquisition: out of memory");
        atomic_store(&d->fatal, 1);
        atomic_store(&d->acq_done, 1);
        free(recs);
        free(item);
        return NULL;
    }
    uint64_t pending_overflow = 0, first_lost = 0;
    double t_stats = 0;
    while (!atomic_load_explicit(&d->stop_acq, memory_order_relaxed)) {
        atomic_fetch_add_explicit(&d->acq_beat, 1, memory_order_relaxed);
        size_t n = 0;
        vibid_drv_error de = {0};
        int64_t t0 = vd_mono_ns();
        vibid_drv_status st = vibid_source_read(d->src, recs, cap, &n, d->cfg->read_timeout_ms, &de);
        int64_t t_rx = vd_mono_ns();
        atomic_fetch_add_explicit(&d->acq_reads, 1, memory_order_relaxed);
        for (size_t i = 0; i < n; i++) {
            vibid_record_copy(&item->rec, &recs[i]);
            item->t_rx_ns = t_rx;
            if (pending_overflow) {
                vd_item f;
                memset(&f, 0, sizeof f);
                f.rec.kind = VIBID_REC_FAULT;
                f.rec.fault = VIBID_FAULT_DROPPED;
                f.rec.index = first_lost;
                f.rec.count = pending_overflow;
                snprintf(f.rec.text, sizeof f.rec.text,
                         "ring overflow: %llu records dropped from sample %llu on (estimator too slow; "
                         "acquisition.ring_size)",
                         (unsigned long long)pending_overflow, (unsigned long long)first_lost);
                f.t_rx_ns = t_rx;
                if (vd_ring_push(d->ring, &f))
                    pending_overflow = 0;
            }
            /* replay: wait for room, never drop (and never count a refused push as an
             * overflow: the status of a replay shows ring_overflows=0) */
            while (d->file_source && vd_ring_full(d->ring)) {
                atomic_fetch_add_explicit(&d->acq_wait_full, 1, memory_order_relaxed);
                wake_consumer(d);
                if (atomic_load(&d->stop_acq) && atomic_load(&d->est_done))
                    break;
                struct timespec ts = {0, 50000};
                nanosleep(&ts, NULL);
            }
            if (!vd_ring_push(d->ring, item) && !d->file_source) {
                if (!pending_overflow)
                    first_lost = item->rec.index;
                pending_overflow++;
            }
        }
        if (n) {
            atomic_fetch_add_explicit(&d->acq_records, n, memory_order_relaxed);
            wake_consumer(d);
        }
        double now = (double)t_rx * 1e-9;
        if (now - t_stats > 0.2 || st == VIBID_DRV_E_EOF) {
            /* trylock: the acquisition side never waits for the status writer */
            if (pthread_mutex_trylock(&d->stats_mu) == 0) {
                vibid_source_stats_get(d->src, &d->src_stats);
                pthread_mutex_unlock(&d->stats_mu);
                t_stats = now;
            }
        }
        if (st == VIBID_DRV_OK)
            continue;
        if (st == VIBID_DRV_E_EOF) {
            vd_info("end of the capture reached");
            break;
        }
        if (st == VIBID_DRV_E_AGAIN) {
            /* a source that returns at once without data (e.g. a test double): do not spin */
            if (t_rx - t0 < 1000000) {
                struct timespec ts = {0, 1000000};
                nanosleep(&ts, NULL);
            }
            continue;
        }
        atomic_fetch_add_explicit(&d->acq_read_errors, 1, memory_order_relaxed);
        vd_error("source %s failed: %s (%s)", vibid_source_kind(d->src), de.text, vibid_drv_strerror(st));
        atomic_store(&d->fatal, 1);
        break;
    }
    if (pending_overflow)
        vd_warning("ring overflow: %llu records dropped at the end of acquisition",
                   (unsigned long long)pending_overflow);
    if (pthread_mutex_trylock(&d->stats_mu) == 0) {
        vibid_source_stats_get(d->src, &d->src_stats);
        pthread_mutex_unlock(&d->stats_mu);
    }
    free(recs);
    free(item);
    atomic_store(&d->acq_done, 1);
    wake_consumer(d);
    return NULL;
}

/* ------------------------------------------------------- estimation thread ---- */

static void handle_fault(vd_daemon *d, const vibid_record *rec)
{
    d->faults++;
    unsigned c = (unsigned)rec->fault < 16 ? (unsigned)rec->fault : 15;
    uint64_t k = ++d->faults_by_code[c];
    /* every fault is counted; the log shows the first 20 of each kind, then every 1000th */
    if (k <= 20 || k % 1000 == 0)
        vd_warning("source fault (%s #%llu): %s", vibid_fault_name(rec->fault), (unsigned long long)k,
                   rec->text);
}

static void handle_gap_log(vd_daemon *d, const vibid_record *rec)
{
    d->gap_records++;
    if (d->gap_records <= 20 || d->gap_records % 1000 == 0)
        vd_notice("gap: %llu samples missing from index %llu: %s", (unsigned long long)rec->count,
                  (unsigned long long)rec->index, rec->text);
}

/* The log tells of physically impossible estimates once per episode: a warning at the
 * first row flagged P (what is impossible, the sample index), a notice at the first
 * plausible row after it. Rows without an estimate (E) neither start nor end an episode. */
static void note_plausibility(vd_daemon *d, const vd_row *row)
{
    if (d->est.pref_ready && !d->pref_reported) {
        d->pref_reported = true;
        if (!d->est.pref.zeta_rule)
            vd_info("plausibility: the rule 'zeta >= 1 where the nominal mode is underdamped' is off: %s",
                    d->est.pref.zeta_rule_off);
    }
    if (row->flags & VD_FLAG_NOEST)
        return;
    if (row->flags & VD_FLAG_IMPLAUSIBLE) {
        if (!d->implausible_episode) {
            d->implausible_episode = true;
            d->episode_first = row->index;
            d->episode_rows = 0;
            vd_warning("physically impossible estimate at sample %llu: %s (rows flagged P until the estimates are "
                       "plausible again; the alarms ignore them)",
                       (unsigned long long)row->index, d->est.why);
        }
        d->episode_rows++;
    } else if (d->implausible_episode) {
        d->implausible_episode = false;
        vd_notice("estimates physically plausible again at sample %llu (%llu rows flagged P from sample %llu)",
                  (unsigned long long)row->index, (unsigned long long)d->episode_rows,
                  (unsigned long long)d->episode_first);
    }
}

/* An alarm event to every open output. */
static void outputs_alarm(vd_daemon *d, const vd_output_alarm *ev)
{
    for (size_t i = 0; i < d->n_out; i++)
        if (d->out[i].ops->alarm)
            d->out[i].ops->alarm(d->out[i].o, ev);
}

/* alarms.test = "cusum": the change test (alarm.h, vibid/change.h). Rows of the output-error
 * refinement (W) are not part of the recursive track and are not pushed. */
static void run_cusum(vd_daemon *d, vd_row *row)
{
    if (row->flags & VD_FLAG_REFINED)
        return;
    /* output-only: the rows whose windows do not overlap (oma_track.h) */
    if (d->omat.on) {
        const uint64_t apart = vd_omat_test_stride(d->cfg) * d->omat.every_n; /* >= the window */
        if (d->omat_tested_any && row->index < d->omat_tested_index + apart)
            return;
        d->omat_tested_any = true;
        d->omat_tested_index = row->index;
    }
    /* a block is used when its row has a possible estimate (no E, P), is excited (no I) and
       no sample between the rows is missing or taken out (no G, O) */
    const bool use = vd_row_usable(row->flags) &&
                     !(row->flags & (VD_FLAG_NOT_EXCITED | VD_FLAG_GAP | VD_FLAG_OUTLIER));
    vd_cusum_event ev[VD_MAX_PARAMS];
    bool reference_now, out_of_range;
    size_t ne = vd_cusum_row(&d->cusum, row->index, row->run_s, row->theta, row->cov, use, ev, &reference_now,
                             &out_of_range);
    if (out_of_range) {
        row->flags |= VD_FLAG_COVARIATE;
        if (d->covariate_rows++ == 0)
            vd_warning("covariates outside the range the alarm reference saw (from sample %llu): those rows are "
                       "flagged C and weighed down in the change test (extrapolating the reference's dependence is "
                       "not trusted); learn the reference over the operating conditions of service",
                       (unsigned long long)row->index);
    }
    if (reference_now && d->cfg->alarm_reference_file[0]) {
        char err[VD_PATH_MAX + 256];
        if (vd_reference_save(d->cfg->alarm_reference_file, d->cfg, &d->cusum, row->index, (double)row->t_us / 1e6,
                              err, sizeof err))
            vd_error("alarm reference not saved: %s; the alarms go on with it in this run", err);
        else
            vd_notice("alarm reference learned and saved to %s", d->cfg->alarm_reference_file);
    }
    if (reference_now) {
        for (size_t i = 0; i < d->cusum.n; i++) {
            size_t k = d->cusum.param[i];
            double stat, mdc, mdc_rel;
            bool active;
            const char *name = vd_param_name(d->cfg, k);
            vibid_change_reference ref;
            if (vd_cusum_state(&d->cusum, k, &stat, &mdc, &mdc_rel, &active) &&
                vd_cusum_reference(&d->cusum, k, &ref))
                vd_info("alarm reference of %s: %.9g (%s), block estimates' standard deviation %.3g from %.0f blocks; "
                        "detectable change %.3g (%.3g %%) within %g s with probability %g at %g false alarms a year",
                        name, ref.mean, d->cusum.have_given[i] ? "given" : "learned", ref.block_sd, ref.n_sd, mdc,
                        100.0 * mdc_rel, d->cfg->alarm_horizon_s, d->cfg->alarm_detection_probability,
                        d->cfg->alarm_false_per_year);
            for (size_t j = 0; j < d->cfg->n_covariates; j++) {
                const size_t q = d->cfg->n_covariates, T = ref.n_terms ? ref.n_terms : q;
                const double g = ref.gram_inv[j * T + j];
                vd_info("alarm reference of %s against covariate %s: slope %.4g +- %.2g per %s, learned over [%.6g, "
                        "%.6g]%s",
                        name, d->cfg->chanmap.ch[d->cfg->cov_chan[j]].name, ref.slope[j],
                        ref.block_sd * sqrt(g), d->cfg->cov_unit[j][0] ? d->cfg->cov_unit[j] : "unit", ref.low[j],
                        ref.high[j], g > 0.0 ? "" : " (did not vary: not modelled)");
            }
            if (d->cfg->n_covariates && ref.n_terms > d->cfg->n_covariates)
                vd_info("alarm reference of %s: second-order model (squares and products of the covariates: "
                        "the linear one did not explain the reference's blocks)",
                        name);
        }
    } else if (d->cusum.learning_extended && !d->cusum_extended_reported) {
        vd_warning("alarm reference not complete after [%g, %g) s of sample time: %s; learning goes on",
                   d->cfg->learn_start_s, d->cfg->learn_start_s + d->cfg->learn_duration_s, d->cusum.why);
        d->cusum_extended_reported = true;
    }
    for (size_t j = 0; j < ne; j++) {
        const size_t k = ev[j].param;
        const char *name = vd_param_name(d->cfg, k);
        const double z = ev[j].change_se > 0.0 ? ev[j].change / ev[j].change_se : NAN;
        const vd_output_alarm a = {name,         ev[j].raised,    row,         "cusum",
                                   row->theta[k],   ev[j].reference, z,           ev[j].statistic,
                                   ev[j].threshold, ev[j].change,    ev[j].raised ? ev[j].change_se : NAN,
                                   ev[j].raised ? ev[j].onset_index : row->index};
        if (ev[j].raised) {
            d->alarms_raised++;
            vd_warning("ALARM %s: changed by %.4g +- %.2g from its reference %.6g (CUSUM %.1f >= %.1f), since sample "
                       "%llu (estimated onset); at sample %llu, t = %.3f s",
                       name, ev[j].change, ev[j].change_se, ev[j].reference, ev[j].statistic, ev[j].threshold,
                       (unsigned long long)ev[j].onset_index, (unsigned long long)row->index, row->run_s);
        } else {
            vd_notice("alarm %s cleared: the data favour its reference %.6g over the change %.4g again at sample %llu",
                      name, ev[j].reference, ev[j].change, (unsigned long long)row->index);
        }
        outputs_alarm(d, &a);
    }
    for (size_t i = 0; i < d->cusum.n; i++) {
        const size_t k = d->cusum.param[i];
        double stat, mdc, mdc_rel;
        bool active;
        if (!vd_cusum_state(&d->cusum, k, &stat, &mdc, &mdc_rel, &active))
            continue;
        row->change_stat[k] = stat;
        row->change_mdc[k] = mdc;
        if (active)
            row->flags |= VD_FLAG_ALARM;
    }
}

static void run_alarms(vd_daemon *d, vd_row *row)
{
    if (!d->cfg->alarms_enabled)
        return;
    if (d->cfg->alarm_test == VD_ALARM_CUSUM) {
        run_cusum(d, row);
        return;
    }
    /* rows without an estimate (E) or with an impossible one (P) change no alarm */
    const bool usable = vd_row_usable(row->flags);
    bool any = false;
    for (size_t k = 0; k < d->cfg->n_params; k++) {
        if (!d->cfg->alarm_param[k].enabled)
            continue;
        vd_alarm *a = &d->alarm[k];
        vd_alarm_event ev = vd_alarm_update_row(a, row->run_s, row->theta[k], row->se[k], usable);
        const vibid_param_info pi = {.name = vd_param_name(d->cfg, k)};
        if (ev == VD_ALARM_RAISED) {
            d->alarms_raised++;
            vd_warning("ALARM %s: %.6g differs from its baseline %.6g by %.1f standard errors (threshold %g, held "
                       "%g s) at sample %llu, t = %.3f s",
                       pi.name, row->theta[k], a->base, a->last_z, a->cfg.threshold, a->cfg.hold_s,
                       (unsigned long long)row->index, row->run_s);
            const vd_output_alarm out = {pi.name, 1, row, "threshold", row->theta[k], a->base, a->last_z, a->last_z,
                                        a->cfg.threshold, row->theta[k] - a->base, NAN, row->index};
            outputs_alarm(d, &out);
        } else if (ev == VD_ALARM_CLEARED) {
            vd_notice("alarm %s cleared: %.6g is back within %g standard errors of %.6g at sample %llu", pi.name,
                      row->theta[k], a->cfg.threshold, a->base, (unsigned long long)row->index);
            const vd_output_alarm out = {pi.name, 0, row, "threshold", row->theta[k], a->base, a->last_z, a->last_z,
                                        a->cfg.threshold, row->theta[k] - a->base, NAN, row->index};
            outputs_alarm(d, &out);
        } else if (a->have_baseline && a->cfg.learn && !d->base_reported[k]) {
            vd_info("alarm baseline of %s learned: %.9g (mean standard error %.3g, %llu estimates)", pi.name,
                    a->base, a->base_se, (unsigned long long)a->n_learn);
            d->base_reported[k] = true;
        } else if (a->learn_missed && !d->base_reported[k]) {
            vd_warning("alarm baseline of %s not learned: no usable estimate (a row without flags E and P) in "
                       "[%g, %g) s of sample time; this alarm stays off",
                       pi.name, a->cfg.learn_start_s, a->cfg.learn_start_s + a->cfg.learn_duration_s);
            d->base_reported[k] = true;
        }
        if (a->active)
            any = true;
    }
    if (any)
        row->flags |= VD_FLAG_ALARM;
}

double vd_daemon_latency_us(const vd_daemon *d, double q)
{
    if (!d->lat_n)
        return NAN;
    uint64_t target = (uint64_t)ceil(q * (double)d->lat_n), acc = 0;
    if (target == 0)
        target = 1;
    for (unsigned i = 0; i < VD_LAT_BUCKETS; i++) {
        acc += d->lat_hist[i];
        if (acc >= target)
            return (double)i + 0.5;
    }
    return VD_LAT_BUCKETS;
}

/* The sample rate over the last status interval (the status file's sample_rate_hz). */
static void update_rate(vd_daemon *d, double now)
{
    double dt = now - d->t_last_status;
    if (dt > 0 && d->t_last_status > 0)
        d->rate_hz = (double)(d->est.samples - d->samples_at_last_status) / dt;
    d->samples_at_last_status = d->est.samples;
    d->t_last_status = now;
}

/* Every counter the status file and the metrics show, into d->snap (estimation thread:
 * it owns the estimator's, the writers' and the alarms' counters; the acquisition
 * thread's are atomics or under stats_mu). */
static void take_snapshot(vd_daemon *d, const char *state, double now)
{
    const vd_config *cfg = d->cfg;
    vd_snapshot *s = &d->snap;
    memset(s, 0, sizeof *s);
    s->state = state;
    s->stand = vd_stand_name(cfg);
    s->source = vibid_source_kind(d->src);
    s->estimator = cfg->oma.on ? "oma" : vd_estimator_name(cfg->method);
    s->uptime_s = now - d->t_start;
    s->stand_rate_hz = cfg->sample_rate;
    s->samples = d->est.samples;
    s->gaps = d->est.gaps;
    s->missing = d->est.missing;
    s->faults = d->faults;
    s->rate_hz = d->rate_hz;
    s->ring_capacity = vd_ring_capacity(d->ring);
    s->ring_fill = vd_ring_fill(d->ring);
    s->ring_high_water = vd_ring_high_water(d->ring);
    s->ring_overflows = vd_ring_overflows(d->ring);
    s->replay_waits = atomic_load(&d->acq_wait_full);
    pthread_mutex_lock(&d->stats_mu);
    s->src = d->src_stats;
    pthread_mutex_unlock(&d->stats_mu);
    s->n_fault_kinds = (unsigned)VIBID_FAULT_LAST;
    for (unsigned c = 1; c <= (unsigned)VIBID_FAULT_LAST && c < 16; c++) {
        s->fault_kind[c] = vibid_fault_name((vibid_fault_code)c);
        s->faults_by_kind[c] = d->faults_by_code[c];
    }
    s->rows = d->est.rows;
    s->est_errors = d->est.est_errors;
    s->implausible_rows = d->est.implausible_rows;
    s->nonfinite_samples = d->est.push_errors;
    s->outlier_samples = d->est.outliers;
    s->refine_on = d->refine.on;
    s->refine_done = d->refine.done;
    s->refine_failed = d->refine.failed;
    s->refine_overruns = d->refine.overruns;
    s->refine_skipped = d->refine.skipped_busy + d->refine.skipped_gap;
    s->refine_last_s = d->refine.done + d->refine.failed ? d->refine.last_duration_s : NAN;
    s->oma_on = d->omat.on;
    s->oma_done = d->omat.done;
    s->oma_skipped = d->omat.skipped_busy;
    s->oma_lost = d->omat.lost_samples;
    s->oma_without = d->omat.windows_without;
    s->oma_last_s = d->omat.done ? d->omat.last_duration_s : NAN;
    s->lat_p50_us = vd_daemon_latency_us(d, 0.5);
    s->lat_p99_us = vd_daemon_latency_us(d, 0.99);
    s->lat_n = d->lat_n;
    s->lat_sum_s = (double)d->lat_sum_us / 1e6;
    /* cumulative counts at the histogram's bounds: bucket i holds [i, i + 1) us, so the
     * buckets below bound b hold the latencies below b us */
    uint64_t acc = 0;
    unsigned i = 0;
    for (unsigned b = 0; b < VD_METRICS_LAT_BOUNDS; b++) {
        for (; i < vd_metrics_lat_bounds_us[b] && i < VD_LAT_BUCKETS; i++)
            acc += d->lat_hist[i];
        s->lat_le[b] = acc;
    }
    s->alarms_raised = d->alarms_raised;
    s->n_params = cfg->n_params;
    s->n_modes = cfg->n_modes;
    for (size_t k = 0; k < cfg->n_params; k++) {
        s->param[k] = cfg->alarm_param[k].name; /* the parameter's name (config.c) */
        s->alarm_enabled[k] = cfg->alarms_enabled && cfg->alarm_param[k].enabled;
        s->alarm_active[k] = d->alarm[k].active;
        bool active;
        s->have_change[k] = s->alarm_enabled[k] &&
                            vd_cusum_state(&d->cusum, k, &s->change_statistic[k], &s->change_mdc[k],
                                           &s->change_mdc_relative[k], &active);
        if (s->have_change[k])
            s->alarm_active[k] = active;
    }
    s->n_covariates = cfg->n_covariates;
    s->covariate_rows = d->covariate_rows;
    for (size_t j = 0; j < cfg->n_covariates; j++) {
        s->cov_name[j] = cfg->chanmap.ch[cfg->cov_chan[j]].name;
        s->cov_value[j] = d->est.have_last ? d->est.last.cov[j] : NAN;
    }
    if (d->est.have_last) {
        const vd_row *r = &d->est.last;
        s->have_last = true;
        s->last_index = r->index;
        s->last_t_us = r->t_us;
        s->last_flags = r->flags;
        memcpy(s->theta, r->theta, cfg->n_params * sizeof *s->theta);
        memcpy(s->se, r->se, cfg->n_params * sizeof *s->se);
        memcpy(s->freq, r->freq, cfg->n_modes * sizeof *s->freq);
        memcpy(s->freq_se, r->freq_se, cfg->n_modes * sizeof *s->freq_se);
        memcpy(s->zeta, r->zeta, cfg->n_modes * sizeof *s->zeta);
        memcpy(s->zeta_se, r->zeta_se, cfg->n_modes * sizeof *s->zeta_se);
    }
    for (size_t o = 0; o < d->n_out; o++) /* the outputs' own counters (output.h) */
        if (d->out[o].ops->counters)
            d->out[o].ops->counters(d->out[o].o, s);
}

/* The status file's text from the snapshot (key=value lines, docs/vibidd.md) into
 * d->status_text; the MQTT status is the same text as JSON (mqtt.h). */
static void format_status(vd_daemon *d, const vd_snapshot *sn)
{
    const vibid_source_stats *ss = &sn->src;
    char *buf = d->status_text;
    const size_t cap = sizeof d->status_text;
    size_t off = 0;
#define S(...)                                                                                                         \
    do {                                                                                                               \
        int n_ = snprintf(buf + off, off < cap ? cap - off : 0, __VA_ARGS__);                                          \
        if (n_ > 0)                                                                                                    \
            off += (size_t)n_;                                                                                         \
    } while (0)
    S("state=%s\nstand=%s\nsource=%s\nuptime_s=%.3f\n", sn->state, sn->stand, sn->source, sn->uptime_s);
    S("samples=%llu\nsample_rate_hz=%.1f\ngaps=%llu\nmissing_samples=%llu\nfaults=%llu\n",
      (unsigned long long)sn->samples, sn->rate_hz, (unsigned long long)sn->gaps, (unsigned long long)sn->missing,
      (unsigned long long)sn->faults);
    S("ring_capacity=%zu\nring_fill=%zu\nring_high_water=%llu\nring_overflows=%llu\nreplay_waits=%llu\n",
      sn->ring_capacity, sn->ring_fill, (unsigned long long)sn->ring_high_water,
      (unsigned long long)sn->ring_overflows, (unsigned long long)sn->replay_waits);
    S("source_samples=%llu\nsource_gaps=%llu\nsource_missing_samples=%llu\nsource_faults=%llu\n",
      (unsigned long long)ss->samples, (unsigned long long)ss->gaps, (unsigned long long)ss->missing_samples,
      (unsigned long long)ss->faults);
    S("source_frames=%llu\nsource_dropped_frames=%llu\nsource_error_frames=%llu\nsource_bad_lines=%llu\n",
      (unsigned long long)ss->frames, (unsigned long long)ss->dropped, (unsigned long long)ss->error_frames,
      (unsigned long long)ss->bad_lines);
    S("source_polls=%llu\nsource_failed_polls=%llu\nsource_timeouts=%llu\nsource_link_losses=%llu\n"
      "source_reconnects=%llu\nsource_connect_failures=%llu\nsource_overruns=%llu\nsource_implausible=%llu\n",
      (unsigned long long)ss->polls, (unsigned long long)ss->failed_polls, (unsigned long long)ss->timeouts,
      (unsigned long long)ss->link_losses, (unsigned long long)ss->reconnects,
      (unsigned long long)ss->connect_failures, (unsigned long long)ss->overruns, (unsigned long long)ss->implausible);
    S("jitter_mean_s=%.9g\njitter_std_s=%.3g\n", ss->jitter.mean_s, ss->jitter.std_s);
    for (unsigned c = 1; c <= sn->n_fault_kinds && c < 16; c++) /* faults by kind */
        S("faults_%s=%llu\n", sn->fault_kind[c], (unsigned long long)sn->faults_by_kind[c]);
    S("rows=%llu\nestimate_failures=%llu\nimplausible_rows=%llu\nnonfinite_samples=%llu\noutlier_samples=%llu\n",
      (unsigned long long)sn->rows, (unsigned long long)sn->est_errors, (unsigned long long)sn->implausible_rows,
      (unsigned long long)sn->nonfinite_samples, (unsigned long long)sn->outlier_samples);
    if (sn->oma_on)
        S("oma_identifications=%llu\noma_skipped=%llu\noma_lost_samples=%llu\noma_windows_without_modes=%llu\n"
          "oma_last_duration_s=%.3f\n",
          (unsigned long long)sn->oma_done, (unsigned long long)sn->oma_skipped, (unsigned long long)sn->oma_lost,
          (unsigned long long)sn->oma_without, sn->oma_last_s);
    if (sn->refine_on)
        S("refinements=%llu\nrefine_failed=%llu\nrefine_overrun=%llu\nrefine_skipped=%llu\n"
          "refine_last_duration_s=%.3f\n",
          (unsigned long long)sn->refine_done, (unsigned long long)sn->refine_failed,
          (unsigned long long)sn->refine_overruns, (unsigned long long)sn->refine_skipped, sn->refine_last_s);
    S("latency_us_p50=%.1f\nlatency_us_p99=%.1f\n", sn->lat_p50_us, sn->lat_p99_us);
    off += vd_snapshot_status_lines(sn, buf + (off < cap ? off : cap), off < cap ? cap - off : 0);
    S("alarms_raised=%llu\nalarms_active=", (unsigned long long)sn->alarms_raised);
    bool first = true;
    for (size_t k = 0; k < sn->n_params; k++)
        if (sn->alarm_active[k]) {
            S("%s%s", first ? "" : ",", sn->param[k]);
            first = false;
        }
    S("\n");
    for (size_t k = 0; k < sn->n_params; k++)
        if (sn->have_change[k])
            S("change.%s.statistic=%.4g\nchange.%s.mdc=%.4g\nchange.%s.mdc_relative=%.4g\n", sn->param[k],
              sn->change_statistic[k], sn->param[k], sn->change_mdc[k], sn->param[k], sn->change_mdc_relative[k]);
    if (sn->n_covariates)
        S("covariates.out_of_range_rows=%llu\n", (unsigned long long)sn->covariate_rows);
    for (size_t j = 0; j < sn->n_covariates; j++)
        S("covariate.%s=%.10g\n", sn->cov_name[j], sn->cov_value[j]);
    if (sn->have_last) {
        S("last_index=%llu\nlast_time_s=%lld.%06lld\n", (unsigned long long)sn->last_index,
          (long long)(sn->last_t_us / 1000000), (long long)(sn->last_t_us % 1000000));
        for (size_t k = 0; k < sn->n_params; k++)
            S("estimate.%s=%.10g\nestimate.%s_se=%.3g\n", sn->param[k], sn->theta[k], sn->param[k], sn->se[k]);
        for (size_t i = 0; i < sn->n_modes; i++)
            S("f%zu_hz=%.6g\nzeta%zu=%.6g\n", i + 1, sn->freq[i], i + 1, sn->zeta[i]);
    }
#undef S
    for (size_t o = 0; o < d->n_out; o++) /* each open output's own lines, in registry order (output.h) */
        if (d->out[o].ops->status_lines) {
            const size_t at = off < cap ? off : cap;
            off += d->out[o].ops->status_lines(sn, buf + at, cap - at);
        }
    if (off > cap)
        off = cap;
    d->status_len = off;
}

static void log_status_line(vd_daemon *d)
{
    char est[512] = "";
    size_t off = 0;
    if (d->est.have_last) {
        for (size_t k = 0; k < d->cfg->n_params && off < sizeof est; k++) {
            int n = snprintf(est + off, sizeof est - off, " %s=%.6g", vd_param_name(d->cfg, k), d->est.last.theta[k]);
            if (n > 0)
                off += (size_t)n;
        }
    }
    vd_info("status: %llu samples (%.0f/s), %llu gaps (%llu missing), %llu faults, %llu ring overflows;%s",
            (unsigned long long)d->est.samples, d->rate_hz, (unsigned long long)d->est.gaps,
            (unsigned long long)d->est.missing, (unsigned long long)d->faults,
            (unsigned long long)vd_ring_overflows(d->ring), est);
}

/* Hands the snapshot (and its text) to every open output whose status is due: those at
 * the status interval when it is due (or when they were busy the last time), those with a
 * status_period at every snapshot (and they make one due at their period). */
static void outputs_status(vd_daemon *d, bool status_due, bool final, double now)
{
    bool snap_due = status_due, text_due = status_due;
    for (size_t i = 0; i < d->n_out; i++) {
        vd_output_slot *o = &d->out[i];
        if (!o->ops->status)
            continue;
        if (o->ops->status_period) {
            o->due = final || o->pending || now - o->t_last >= o->ops->status_period(d->cfg);
        } else {
            o->due = status_due || o->pending;
            if (o->due && (o->ops->flags & VD_OUTPUT_STATUS_TEXT))
                text_due = true;
        }
        snap_due = snap_due || o->due;
    }
    if (!snap_due)
        return;
    take_snapshot(d, final ? "stopped" : "running", now);
    if (text_due)
        format_status(d, &d->snap);
    for (size_t i = 0; i < d->n_out; i++) {
        vd_output_slot *o = &d->out[i];
        if (!o->ops->status)
            continue;
        /* never waits while estimating: a busy output gets the next one (output.h) */
        if (o->ops->status_period) {
            o->pending = !o->ops->status(o->o, &d->snap, d->status_text, d->status_len, final);
            o->t_last = now;
        } else if (o->due) {
            o->pending = !o->ops->status(o->o, &d->snap, d->status_text, d->status_len, final);
        }
    }
}

static void housekeeping(vd_daemon *d, bool final)
{
    double now = vd_mono_s();
    atomic_fetch_add_explicit(&d->est_beat, 1, memory_order_relaxed);
    if (atomic_exchange(&d->reopen, 0))
        for (size_t i = 0; i < d->n_out; i++)
            if (d->out[i].ops->reopen)
                d->out[i].ops->reopen(d->out[i].o);
    if (final || now - d->t_last_flush >= d->cfg->files.flush_interval_s) {
        for (size_t i = 0; i < d->n_out; i++)
            if (d->out[i].ops->flush)
                d->out[i].ops->flush(d->out[i].o, d->cfg->files.fsync_on_flush);
        d->t_last_flush = now;
    }
    /* One snapshot for all: the status file at its interval, the metrics at least every
     * second (sooner with a shorter status interval). */
    const bool status_due = final || now - d->t_last_status >= d->cfg->files.status_interval_s;
    if (status_due)
        update_rate(d, now);
    outputs_status(d, status_due, final, now);
    if (d->cfg->log_status_interval_s > 0 && now - d->t_last_logstatus >= d->cfg->log_status_interval_s) {
        log_status_line(d);
        d->t_last_logstatus = now;
    }
}

/* The pending row: its estimate and modes (vd_est_finish_row), the alarms, and out to
 * every output. Called when the estimation thread has no record waiting, before a record
 * that may start the next row (process), and at the end. */
static void emit_row(vd_daemon *d, vd_row *row);
static void take_oma(vd_daemon *d);

static void finish_row(vd_daemon *d)
{
    vd_row *row = &d->row;
    d->row_pending = false;
    vd_est_finish_row(&d->est, row);
    emit_row(d, row);
}

/* A refinement's result (refine.h): a row flagged W, or a failure counted and logged once
 * per episode (the equation-error rows go on meanwhile; no row for the failed window). */
static void take_refinement(vd_daemon *d)
{
    vd_refine *r = &d->refine;
    const vd_refine_result *res = vd_refine_take(r);
    if (!res)
        return;
    if (res->overrun) {
        r->overruns++;
        if (r->overruns <= 20 || r->overruns % 1000 == 0)
            vd_warning("refinement of the window ending at sample %llu given up: %s (%llu overruns)",
                       (unsigned long long)res->end_index, res->reason, (unsigned long long)r->overruns);
    } else if (!res->ok) {
        r->failed++;
        r->last_duration_s = res->duration_s;
        if (!r->fail_episode)
            vd_warning("refinement of the window ending at sample %llu failed: %s (the equation-error estimate "
                       "stands; no row flagged W until a refinement succeeds again)",
                       (unsigned long long)res->end_index, res->reason);
        r->fail_episode = true;
    } else {
        r->done++;
        r->last_duration_s = res->duration_s;
        if (r->fail_episode)
            vd_notice("refinement succeeded again at sample %llu (%llu failed so far)",
                      (unsigned long long)res->end_index, (unsigned long long)r->failed);
        r->fail_episode = false;
        vd_est_refined_row(&d->est, &d->refined_row, res->end_index, res->end_t_us, res->theta, res->se, res->cov,
                           res->quality, res->n_samples);
        emit_row(d, &d->refined_row);
    }
    vd_refine_release(r);
}

/* After the push of a sample: into the refinement's ring, and the hand-over when one is
 * due. An unpaced replay waits for the refinement here, so that its rows come out at the
 * same place in every replay; a live source or a paced replay (which stands in for one)
 * never waits: the result is taken when the thread has no sample waiting. */
static void refine_sample(vd_daemon *d, const vibid_record *rec)
{
    vd_refine *r = &d->refine;
    if (d->est.gaps != d->refine_gaps_seen) {
        d->refine_gaps_seen = d->est.gaps;
        vd_refine_gap(r);
    }
    vd_refine_push(r, d->est.chan);
    const uint64_t index = rec->index - d->est.first_index;
    if (!vd_refine_due(r, index))
        return;
    /* start values: the latest recursive estimate when usable, else the stand's nominal ones */
    double start[VD_MAX_PARAMS];
    const bool use_last = d->est.have_last && vd_row_usable(d->est.last.flags);
    for (size_t k = 0; k < d->cfg->n_params; k++) {
        vibid_param_info pi;
        vibid_model_param_info(d->est.model, k, &pi);
        start[k] = use_last && isfinite(d->est.last.theta[k]) ? d->est.last.theta[k] : pi.nominal;
    }
    if (!vd_refine_request(r, start, index, vd_ns_to_us(rec->t_ns)) || !d->unpaced_replay)
        return;
    vd_refine_wait(r);
    if (d->row_pending && d->row.index <= index) /* the rows stay in sample order */
        finish_row(d);
    take_refinement(d);
}

/* A result of the mode tracker (oma_track.h): a track row of the tracked modes, or nothing
 * while its window fills; lost samples and rows without a tracked mode logged (the latter
 * once per episode). */
static void take_oma(vd_daemon *d)
{
    vd_omat *o = &d->omat;
    const vd_omat_result *res = vd_omat_take(o);
    if (!res)
        return;
    if (res->lost_samples)
        vd_warning("mode tracking fell behind: %llu samples lost to the identification before sample %llu (a gap "
                   "there; %llu so far)",
                   (unsigned long long)res->lost_samples, (unsigned long long)res->end_index,
                   (unsigned long long)o->lost_samples);
    if (!res->filling) {
        const uint64_t missing = d->est.missing - d->omat_missing_seen;
        d->omat_missing_seen = d->est.missing;
        vd_est_oma_row(&d->est, &d->oma_row, res, missing);
        if (d->oma_row.flags & VD_FLAG_NOEST) {
            if (!d->omat_fail_episode)
                vd_warning("modes at sample %llu: %s (rows flagged E until a tracked mode is found)",
                           (unsigned long long)res->end_index, res->reason);
            d->omat_fail_episode = true;
        } else if (d->omat_fail_episode) {
            vd_notice("modes at sample %llu: %zu of %zu tracked modes found again", (unsigned long long)res->end_index,
                      res->found, d->cfg->oma.n_modes);
            d->omat_fail_episode = false;
        }
        emit_row(d, &d->oma_row);
    }
    vd_omat_release(o);
}

/* Output-only: after the estimator took a sample, into the mode tracker's ring, and the
 * identification when one is due (an unpaced replay waits for it, as for a refinement). */
static void oma_sample(vd_daemon *d, const vibid_record *rec)
{
    vd_omat *o = &d->omat;
    if (d->est.gaps != d->omat_gaps_seen) {
        d->omat_gaps_seen = d->est.gaps;
        vd_omat_gap(o);
    }
    vd_omat_push(o, d->est.chan, rec->values);
    const uint64_t index = rec->index - d->est.first_index;
    if (!vd_omat_due(o, index))
        return;
    if (!d->unpaced_replay) { /* live: the oma thread; a busy one skips this period (counted) */
        vd_omat_request(o, index, vd_ns_to_us(rec->t_ns));
        return;
    }
    if (vd_omat_run_here(o, index, vd_ns_to_us(rec->t_ns)))
        take_oma(d);
}

/* A row out: plausibility log, alarms, every output. */
static void emit_row(vd_daemon *d, vd_row *row)
{
    note_plausibility(d, row);
    run_alarms(d, row);
    for (size_t i = 0; i < d->n_out; i++) /* queued or buffered; never waits (output.h) */
        if (d->out[i].ops->row)
            d->out[i].ops->row(d->out[i].o, row);
}

/* One record as the outlier test releases it (vd_est_next): to the estimator, a row when
 * one is due. t_rx_ns: when the source read that returned it came back. */
static void process_released(vd_daemon *d, const vibid_record *rec, int64_t t_rx_ns)
{
    /* a pending row goes out before anything that may start the next one or write
     * something of its own (a gap): the outputs' order stays the samples' */
    if (d->row_pending && vd_est_row_due(&d->est, rec))
        finish_row(d);
    if (rec->kind == VIBID_REC_GAP)
        handle_gap_log(d, rec);
    const uint64_t samples_before = d->est.samples;
    int due = vd_est_record(&d->est, rec, &d->row);
    if (rec->kind == VIBID_REC_SAMPLE && d->measure_latency) {
        /* the estimate is updated with this sample (pushed; a due row's state kept) */
        int64_t lat = (vd_mono_ns() - t_rx_ns) / 1000;
        if (lat < 0)
            lat = 0;
        d->lat_hist[lat < VD_LAT_BUCKETS ? lat : VD_LAT_BUCKETS - 1]++;
        d->lat_n++;
        d->lat_sum_us += (uint64_t)lat;
    }
    if (due) {
        d->row_pending = true;
        if (!d->est.twin) /* no twin: the estimator's state moves on with the next sample */
            finish_row(d);
    }
    if (d->refine.on && d->est.samples != samples_before) /* a sample the estimator took */
        refine_sample(d, rec);
    if (d->omat.on && d->est.samples != samples_before)
        oma_sample(d, rec);
}

static void drain_released(vd_daemon *d)
{
    const vibid_record *r;
    int64_t t_rx;
    while ((r = vd_est_next(&d->est, &t_rx)))
        process_released(d, r, t_rx);
}

static void process(vd_daemon *d, const vd_item *it)
{
    const vibid_record *rec = &it->rec;
    if (d->rate_refused)
        return; /* the source's rate was refused: the ring drains, nothing more is written */
    if (d->rate && rec->kind != VIBID_REC_FAULT) {
        if (vd_rate_check_live(d->rate, rec, d->opt.rate_check)) {
            d->rate_refused = true;
            atomic_store(&d->fatal, 2);
            atomic_store(&d->stop_acq, 1);
            return;
        }
        if (vd_rate_check_done(d->rate)) {
            vd_rate_check_destroy(d->rate);
            d->rate = NULL;
        }
    }
    if (rec->kind == VIBID_REC_FAULT) {
        /* handled at once, also while the outlier test holds a sample for its successor */
        if (d->row_pending && vd_est_row_due(&d->est, rec))
            finish_row(d);
        handle_fault(d, rec);
        return;
    }
    vd_est_feed(&d->est, rec, it->t_rx_ns);
    drain_released(d);
    /* the raw recording keeps every sample as received, glitches included; written after
     * the estimate took it, so that the latency does not include its formatting */
    for (size_t i = 0; i < d->n_out; i++)
        if (d->out[i].ops->sample)
            d->out[i].ops->sample(d->out[i].o, rec);
}

/* acquisition.handoff_spin: waking a thread sleeping in poll() costs 20-40 us on the
 * benchmark machine, most of the receipt -> estimate latency at 1-10 kHz. Busy-waiting a
 * little longer than the sample period before sleeping keeps the estimation thread awake
 * while samples keep coming, for CPU time. true if a record arrived. */
static bool spin_for_record(vd_daemon *d)
{
    int64_t until = vd_mono_ns() + (int64_t)d->cfg->handoff_spin_us * 1000;
    do {
        for (int i = 0; i < 64; i++) {
            if (vd_ring_peek(d->ring))
                return true;
#if defined(__x86_64__) || defined(__i386__)
            __builtin_ia32_pause(); /* spin-wait hint: frees the core's pipeline for its sibling */
#endif
        }
    } while (!atomic_load(&d->acq_done) && vd_mono_ns() < until);
    return vd_ring_peek(d->ring) != NULL;
}

static void *est_main(void *arg)
{
    vd_daemon *d = arg;
    uint64_t count = 0;
    for (;;) {
        const vd_item *it = vd_ring_peek(d->ring);
        if (it) {
            process(d, it);
            vd_ring_release(d->ring);
            if ((++count & 255u) == 0)
                housekeeping(d, false);
            continue;
        }
        /* nothing waits: the time for a pending row */
        if (d->row_pending) {
            finish_row(d);
            continue;
        }
        if (vd_refine_take(&d->refine)) { /* then for a refinement's row */
            take_refinement(d);
            continue;
        }
        if (vd_omat_ready(&d->omat)) { /* or the mode tracker's */
            take_oma(d);
            continue;
        }
        /* empty: finished, or sleep until the producer wakes us (bounded by 50 ms) */
        if (atomic_load(&d->acq_done) && !vd_ring_peek(d->ring))
            break;
        housekeeping(d, false);
        /* no spinning while a refinement runs: a busy-waiting thread is never woken, so when
         * the idle-class refine thread shares its CPU it gets the CPU back only at the
         * scheduler's tick (1-4 ms; docs/vibidd.md "Refinement"); asleep, the acquisition
         * thread's wake-up preempts the refine thread at once */
        if (d->cfg->handoff_spin_us && !vd_refine_busy(&d->refine) && !vd_omat_busy(&d->omat) &&
            spin_for_record(d))
            continue;
        atomic_store(&d->consumer_sleeping, 1);
        atomic_thread_fence(memory_order_seq_cst);
        if (!vd_ring_peek(d->ring) && !atomic_load(&d->acq_done)) {
            struct pollfd pfd = {.fd = d->efd, .events = POLLIN};
            if (poll(&pfd, 1, 50) > 0) {
                uint64_t v;
                ssize_t r = read(d->efd, &v, sizeof v);
                (void)r;
            }
        }
        atomic_store(&d->consumer_sleeping, 0);
    }
    if (!d->rate_refused) { /* the end: what the outlier test holds goes out, decided */
        vd_est_flush(&d->est);
        drain_released(d);
    }
    if (d->row_pending)
        finish_row(d);
    /* a refinement or identification still running is waited for (at most one each): its
     * row is not lost */
    vd_refine_wait(&d->refine);
    take_refinement(d);
    vd_omat_wait(&d->omat);
    take_oma(d);
    housekeeping(d, true);
    atomic_store(&d->est_done, 1);
    /* End of a replay: wake the main thread now instead of at its next 100 ms tick
     * (which was half the run time of a 100k-sample replay). */
    pthread_kill(d->main_thread, VD_WAKE_SIGNAL);
    return NULL;
}

/* ------------------------------------------------------------ life cycle ---- */

/* Opens every output of the registry (output.h) that is configured and selected, in
 * registry order. 0, or -1 with err (fini closes what was opened). */
static int open_outputs(vd_daemon *d, char *err, size_t cap)
{
    const vd_config *cfg = d->cfg;
    d->out_ctx.cfg = cfg;
    d->out_ctx.rec_chanmap = &d->rec_chanmap;
    d->out_ctx.tracks_preamble = d->est.choices;
    d->out_ctx.stand = cfg->files.influx_stand[0] ? cfg->files.influx_stand : vd_stand_name(cfg);
    d->out_ctx.select = d->opt.outputs;
    for (size_t i = 0; i < vd_n_outputs; i++) {
        const vd_output_ops *ops = vd_outputs[i];
        if (!vd_output_wanted(&d->out_ctx, ops) || (ops->enabled && !ops->enabled(cfg)))
            continue;
        if (d->n_out == VD_MAX_OUTPUTS) {
            snprintf(err, cap, "more than %d outputs", VD_MAX_OUTPUTS);
            return -1;
        }
        if (cap)
            err[0] = '\0';
        void *o = ops->open(&d->out_ctx, err, cap);
        if (!o) {
            if (cap && err[0])
                return -1;
            continue; /* this program has none: the output warned */
        }
        d->out[d->n_out++] = (vd_output_slot){.ops = ops, .o = o};
    }
    return 0;
}

int vd_daemon_init(vd_daemon *d, vd_config *cfg, const vd_options *opt, char *err, size_t cap)
{
    memset(d, 0, sizeof *d);
    d->cfg = cfg;
    d->opt = *opt;
    d->efd = -1;
    pthread_mutex_init(&d->stats_mu, NULL);
    vd_notify_init(&d->notify);
    if (cfg->lock_memory) {
        if (mlockall(MCL_CURRENT | MCL_FUTURE) == 0)
            vd_info("memory locked (mlockall)");
        else
            vd_warning("acquisition.lock_memory: mlockall failed: %s; pages may be swapped out. Grant "
                       "CAP_IPC_LOCK or raise RLIMIT_MEMLOCK (systemd: LimitMEMLOCK=infinity)",
                       strerror(errno));
    }
    d->lat_hist = calloc(VD_LAT_BUCKETS, sizeof *d->lat_hist);
    if (!d->lat_hist) {
        snprintf(err, cap, "out of memory");
        return -1;
    }
    d->efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    if (d->efd < 0) {
        snprintf(err, cap, "eventfd: %s", strerror(errno));
        return -1;
    }
    if (vd_est_init(&d->est, cfg, err, cap))
        return -1;
    for (size_t k = 0; k < cfg->n_params; k++) {
        vd_alarm_config ac = {cfg->alarm_threshold,
                              cfg->alarm_min_relative,
                              cfg->alarm_hold_s,
                              !cfg->alarm_param[k].has_baseline,
                              cfg->alarm_param[k].baseline,
                              cfg->learn_start_s,
                              cfg->learn_duration_s};
        vd_alarm_init(&d->alarm[k], &ac);
    }
    if (cfg->alarms_enabled && cfg->alarm_test == VD_ALARM_CUSUM) {
        bool enabled[VD_MAX_PARAMS], given[VD_MAX_PARAMS];
        double baseline[VD_MAX_PARAMS];
        for (size_t k = 0; k < cfg->n_params; k++) {
            enabled[k] = cfg->alarm_param[k].enabled;
            given[k] = cfg->alarm_param[k].has_baseline;
            baseline[k] = cfg->alarm_param[k].baseline;
        }
        /* output-only: the rows of disjoint windows are independent estimates (forgetting 0,
           vibid/change.h), one every ceil(window / every) periods */
        const double row_interval = cfg->oma.on ? (double)vd_omat_test_stride(cfg) * round(cfg->oma.every_s *
                                                                                           cfg->sample_rate)
                                                : (double)cfg->decimation;
        const vd_cusum_config cc = {cfg->sample_rate,
                                    cfg->oma.on ? 0.0 : cfg->forgetting,
                                    row_interval,
                                    cfg->alarm_false_per_year,
                                    cfg->alarm_horizon_s,
                                    cfg->alarm_detection_probability,
                                    cfg->alarm_min_relative,
                                    cfg->learn_start_s,
                                    cfg->learn_duration_s,
                                    cfg->n_params,
                                    cfg->n_covariates,
                                    enabled,
                                    given,
                                    baseline};
        if (vd_cusum_init(&d->cusum, &cc, err, cap))
            return -1;
        const char *rf = cfg->alarm_reference_file;
        vibid_change_reference ref[VD_MAX_PARAMS];
        const int lr = rf[0] && d->cusum.det ? vd_reference_load(rf, cfg, &d->cusum, ref, err, cap) : 0;
        if (lr < 0)
            return -1;
        if (lr > 0) {
            if (vd_cusum_set_reference(&d->cusum, ref, err, cap)) {
                char e2[512];
                snprintf(e2, sizeof e2, "%s", err);
                snprintf(err, cap, "%s: %s", rf, e2);
                return -1;
            }
            vd_notice("alarm reference read from %s (kept across restarts; vibidd --reference learn replaces it)", rf);
        } else if (rf[0]) {
            vd_info("alarm reference: none in %s yet; learned over [%g, %g) s of sample time and saved there",
                    rf, cfg->learn_start_s, cfg->learn_start_s + cfg->learn_duration_s);
        } else {
            vd_info("alarm reference: learned over [%g, %g) s of sample time, not kept (alarms.reference_file)",
                    cfg->learn_start_s, cfg->learn_start_s + cfg->learn_duration_s);
        }
    }
    if (open_source(d, err, cap))
        return -1;
    /* Live CAN: receive stamps measure the device's rate (rate_check.h). Modbus needs none:
     * FIFO mode compares the device's period_ns at every connection, snapshot mode samples
     * on the stand's own clock. */
    if (!d->file_source && cfg->source_kind == VD_SRC_SOCKETCAN && opt->rate_check != VD_RATE_MODE_OFF &&
        !(d->rate = vd_rate_check_create_live(cfg))) {
        snprintf(err, cap, "out of memory for the sample-rate check");
        return -1;
    }
    /* A file source never drops (the producer waits for room), so a ring larger than
     * VD_REPLAY_RING only pushes the records out of the caches: 65536 slots of ~470 bytes
     * are 30 MB, and replay ran at half the speed it reaches with 4096 (bench_vibidd.sh). */
    unsigned ring_size = cfg->ring_size;
    if (d->file_source && ring_size > VD_REPLAY_RING)
        ring_size = VD_REPLAY_RING;
    d->ring = vd_ring_create(ring_size);
    if (!d->ring) {
        snprintf(err, cap, "out of memory for a ring of %u records", ring_size);
        return -1;
    }
    if (vd_refine_resolve(cfg, d->est.resolved.estimator, err, cap))
        return -1;
    /* an unpaced replay: waits for each refinement, runs each identification inline */
    d->unpaced_replay = d->file_source && !d->measure_latency;
    if (vd_refine_init(&d->refine, cfg, d->est.nch, d->est.p, err, cap))
        return -1;
    if (d->refine.on)
        vd_info("refinement on (%s): an output-error fit over the last %g s every %g s of sample time, in a "
                "low-priority thread",
                cfg->refine_why, cfg->refine_window_s, cfg->refine_every_s);
    else
        vd_info("refinement off: %s", cfg->refine_why[0] ? cfg->refine_why : "estimator.refine_every = 0");
    if (vd_omat_init(&d->omat, cfg, err, cap))
        return -1;
    vd_est_log_choices(&d->est);
    /* every output is opened here, before READY=1: an output that cannot be opened (a
     * directory, an address that cannot be bound, a secret file) is a configuration error
     * (exit 2), not a run-time surprise */
    return open_outputs(d, err, cap);
}

static void stop_threads(vd_daemon *d)
{
    atomic_store(&d->stop_acq, 1);
    if (d->acq_started)
        pthread_join(d->acq_thread, NULL);
    d->acq_started = false;
    atomic_store(&d->acq_done, 1);
    wake_consumer(d);
    if (d->est_started)
        pthread_join(d->est_thread, NULL);
    d->est_started = false;
}

int vd_daemon_run(vd_daemon *d)
{
    /* Signals: blocked here, inherited blocked by both threads, taken synchronously
     * below. SIGPIPE: a vanished UDP/FIFO reader must not kill the daemon. */
    sigset_t set;
    sigemptyset(&set);
    sigaddset(&set, SIGTERM);
    sigaddset(&set, SIGINT);
    sigaddset(&set, SIGHUP);
    sigaddset(&set, VD_WAKE_SIGNAL);
    pthread_sigmask(SIG_BLOCK, &set, NULL);
    d->main_thread = pthread_self();
    signal(SIGPIPE, SIG_IGN);

    d->t_start = vd_mono_s();
    d->t_last_flush = d->t_start;
    {
        /* before the estimation thread, which hands it work */
        char err[256];
        if (vd_refine_start(&d->refine, err, sizeof err) || vd_omat_start(&d->omat, err, sizeof err)) {
            vd_error("%s", err);
            return 1;
        }
    }
    if (pthread_create(&d->est_thread, NULL, est_main, d) != 0) {
        vd_error("cannot start the estimation thread: %s", strerror(errno));
        return 1;
    }
    d->est_started = true;
    if (pthread_create(&d->acq_thread, NULL, acq_main, d) != 0) {
        vd_error("cannot start the acquisition thread: %s", strerror(errno));
        stop_threads(d);
        return 1;
    }
    d->acq_started = true;
    for (size_t i = 0; i < d->n_out; i++) {
        char err[256];
        if (d->out[i].ops->start && d->out[i].ops->start(d->out[i].o, err, sizeof err)) {
            vd_error("%s", err);
            stop_threads(d);
            return 1;
        }
    }
    vd_notify_send(&d->notify, "READY=1\nSTATUS=acquiring");
    vd_notice("running: %s '%s', %s source, %s, %.6g Hz, ring %zu records", d->cfg->oma.on ? "machine" : "stand",
              vd_stand_name(d->cfg), vibid_source_kind(d->src),
              d->cfg->oma.on ? "output-only mode tracking" : vd_estimator_name(d->cfg->method), d->cfg->sample_rate,
              vd_ring_capacity(d->ring));

    uint64_t wd_usec = vd_notify_watchdog_usec(&d->notify);
    double wd_period = wd_usec ? (double)wd_usec * 1e-6 / 2.0 : 0.0, t_wd = 0;
    uint64_t last_acq_beat = 0, last_est_beat = 0;
    int stop_signal = 0;
    while (!atomic_load(&d->est_done)) {
        struct timespec to = {0, 100 * 1000000};
        siginfo_t si;
        int sig = sigtimedwait(&set, &si, &to);
        if (sig == SIGTERM || sig == SIGINT) {
            stop_signal = sig;
            vd_notice("%s received: draining the ring, flushing, exiting", sig == SIGTERM ? "SIGTERM" : "SIGINT");
            vd_notify_send(&d->notify, "STOPPING=1");
            break;
        }
        if (sig == SIGHUP) {
            atomic_store(&d->reopen, 1);
            wake_consumer(d);
        }
        double now = vd_mono_s();
        if (wd_period > 0 && now - t_wd >= wd_period) {
            uint64_t a = atomic_load(&d->acq_beat), e = atomic_load(&d->est_beat);
            bool acq_ok = a != last_acq_beat || atomic_load(&d->acq_done);
            if (acq_ok && e != last_est_beat)
                vd_notify_send(&d->notify, "WATCHDOG=1");
            else
                vd_warning("watchdog: %s thread made no progress for %.1f s; not pinging systemd",
                           acq_ok ? "estimation" : "acquisition", now - t_wd);
            last_acq_beat = a;
            last_est_beat = e;
            t_wd = now;
        }
    }
    stop_threads(d);
    /* the final status is handed over: each output with a drain sends what it holds (its
     * own drain_timeout at most: outputs.mqtt publishes what is queued and disconnects
     * cleanly, outputs.influx.http writes what is buffered), in reverse registry order; then
     * the status file once more, with the counters after the drain (the estimation thread
     * is gone: this thread owns them) */
    bool drained = false;
    for (size_t i = d->n_out; i-- > 0;)
        if (d->out[i].ops->drain) {
            d->out[i].ops->drain(d->out[i].o);
            drained = true;
        }
    if (drained) {
        take_snapshot(d, "stopped", vd_mono_s());
        format_status(d, &d->snap);
        for (size_t i = 0; i < d->n_out; i++)
            if ((d->out[i].ops->flags & VD_OUTPUT_STATUS_AFTER_DRAIN) && d->out[i].ops->status)
                (void)d->out[i].ops->status(d->out[i].o, &d->snap, d->status_text, d->status_len, true);
    }
    vd_notice("stopped: %llu samples, %llu rows, %llu gaps (%llu missing samples), %llu faults, %llu ring overflows, "
              "latency p50 %.1f us p99 %.1f us",
              (unsigned long long)d->est.samples, (unsigned long long)d->est.rows, (unsigned long long)d->est.gaps,
              (unsigned long long)d->est.missing, (unsigned long long)d->faults,
              (unsigned long long)vd_ring_overflows(d->ring), vd_daemon_latency_us(d, 0.5),
              vd_daemon_latency_us(d, 0.99));
    if (atomic_load(&d->fatal))
        return atomic_load(&d->fatal) == 2 ? 2 : 1; /* 2: the source's rate was refused */
    if (d->file_source && !stop_signal && d->est.samples == 0) {
        /* a capture read to its end without one usable line identified nothing: the wrong
         * file, format or channel map, not a run (exit 2, as a capture that cannot be opened) */
        const char *cap_path = d->opt.replay ? d->opt.replay : d->cfg->replay_file;
        if (d->faults)
            vd_error("%s: no usable sample in the whole capture (%llu bad lines, %llu faults: see the source faults "
                     "above): nothing to identify",
                     cap_path, (unsigned long long)d->src_stats.bad_lines, (unsigned long long)d->faults);
        else
            vd_error("%s: no sample in the capture (it has no data line): nothing to identify", cap_path);
        return 2;
    }
    for (size_t i = 0; i < d->n_out; i++) /* a write failed: exit status 1 */
        if (d->out[i].ops->failed && d->out[i].ops->failed(d->out[i].o))
            return 1;
    return 0;
}

void vd_daemon_fini(vd_daemon *d)
{
    stop_threads(d);
    /* after the threads: the final state was published; reverse registry order */
    for (size_t i = d->n_out; i-- > 0;) {
        d->out[i].ops->close(d->out[i].o);
        d->out[i].o = NULL;
    }
    d->n_out = 0;
    vibid_source_close(d->src);
    d->src = NULL;
    vd_rate_check_destroy(d->rate);
    d->rate = NULL;
    vd_refine_fini(&d->refine);
    vd_omat_fini(&d->omat);
    vd_est_free(&d->est);
    vd_cusum_free(&d->cusum);
    vd_ring_destroy(d->ring);
    d->ring = NULL;
    free(d->lat_hist);
    d->lat_hist = NULL;
    if (d->efd >= 0)
        close(d->efd);
    d->efd = -1;
    vd_notify_close(&d->notify);
    pthread_mutex_destroy(&d->stats_mu);
}
