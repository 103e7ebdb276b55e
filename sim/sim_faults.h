/* sim/sim_faults.h: fault injection for testing the daemon's fault handling.
 *
 * Per frame (CAN) or FIFO record (Modbus), independently with the given probabilities:
 * drop (not sent / record not written), else corrupt (one random payload bit flipped,
 * counter bits included) and/or duplicate (CAN: sent twice in a row). Serving can be
 * stopped and resumed at given times (--stop-at / --resume-at) or by signals
 * (SIGUSR1 stops, SIGUSR2 resumes).
 */
#ifndef VIBID_SIM_FAULTS_H
#define VIBID_SIM_FAULTS_H

#include <signal.h>
#include <stddef.h>
#include <stdint.h>

#include "excitation.h"

#define SIM_MAX_SCHEDULE 64

typedef struct sim_faults {
    double p_drop, p_dup, p_corrupt; /* 0..1 */
    sim_rng rng;
    uint64_t seen, dropped, duplicated, corrupted;
    /* schedule: sorted times at which serving toggles */
    double at[SIM_MAX_SCHEDULE];
    int stop[SIM_MAX_SCHEDULE]; /* 1 = stop, 0 = resume */
    size_t n_sched, next_sched;
    int serving;
    uint64_t stops, resumes;
} sim_faults;

void sim_faults_init(sim_faults *f, double p_drop, double p_dup, double p_corrupt, uint64_t seed);
/* Adds a stop (stop = 1) or resume (0) event at time t; -1 if the table is full. */
int sim_faults_schedule(sim_faults *f, double t, int stop);
/* Fate of one frame of len payload bytes: returns copies to send (0, 1 or 2); may flip
 * one bit of data. */
int sim_faults_frame(sim_faults *f, uint8_t *data, size_t len);
/* Fate of one FIFO record (words 1..n_words-1 hold the channels, word 0 the tag):
 * returns 0 (drop) or 1; may flip one bit of a channel word. */
int sim_faults_record(sim_faults *f, uint16_t *words, size_t n_words);

/* Signal requests (set by the handlers, consumed by sim_faults_update). */
extern volatile sig_atomic_t sim_signal_stop, sim_signal_resume;
void sim_faults_install_signals(void);
/* Applies schedule events with time <= t and pending signals. Returns +1 when serving
 * just resumed, -1 when it just stopped, 0 otherwise. */
int sim_faults_update(sim_faults *f, double t);

#endif
