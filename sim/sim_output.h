/* sim/sim_output.h: vibid-sim's file and bus outputs: CSV, candump log (through the
 * drivers' writer, can-utils format), live SocketCAN. */
#ifndef VIBID_SIM_OUTPUT_H
#define VIBID_SIM_OUTPUT_H

#include <pthread.h>
#include <stdint.h>
#include <stdio.h>

#include <vibid/stand_file.h>
#include <vibid_drivers/can_frame.h>

#include "sim_config.h"

/* CSV: header "t,<inputs>,<measured>[,<covariates>]" by the stand's channel names; inputs
 * are the force inputs and the base's channels, measured the nodes' channels, each group in
 * the stand's channel order; then the covariates (simulation.covariates) by their names,
 * in their order (values[] as sim_engine_next writes them: output channels). Values in their shortest round-trip form (num_format.h:
 * lossless, at most 17 significant digits).
 *
 * Formatting, not the simulation, is the cost (about 40-80 ns a value against 0.2 us for a
 * whole 10-DOF sample), so a writer thread formats and writes while the simulation goes on:
 * sim_csv_write copies the row into the current batch of SIM_CSV_BATCH rows (no
 * formatting, no system call) and hands a full batch over (double-buffered: it waits only
 * when the writer is still busy with the previous batch). The file therefore lags the
 * simulation by up to two batches plus stdio's buffer; sim_csv_close writes the rest. A
 * write error is seen at the next hand-over or at close (then every later row counts as
 * failed). Ownership: the sim_csv owns its file, batches and thread; one thread calls
 * write and close. */
#define SIM_CSV_BATCH 4096
typedef struct sim_csv {
    FILE *f;
    size_t n;
    size_t order[SIM_MAX_OUTPUTS]; /* output channel of each column after t */
    char path[512];
    double *batch[2];      /* SIM_CSV_BATCH x (1 + n) each: t, then the values in `order` */
    size_t fill;           /* rows in batch[cur] */
    int cur;
    pthread_t thread;
    int started;
    pthread_mutex_t mu;
    pthread_cond_t cv;
    int pending;           /* the batch handed to the writer, -1 when it is idle */
    size_t pending_rows;
    int stop, failed;      /* under mu */
    int failed_seen;       /* the caller's copy of `failed`: every later write returns -1 */
} sim_csv;

int sim_csv_open(sim_csv *c, const char *path, const vibid_stand *stand, char *err, size_t errlen);
/* The same with cfg's covariates as columns after the stand's channels (cfg NULL: none). */
int sim_csv_open_cfg(sim_csv *c, const char *path, const vibid_stand *stand, const sim_config *cfg, char *err,
                     size_t errlen);
/* 0, or -1 for every row once a write of an earlier batch has failed. */
int sim_csv_write(sim_csv *c, double t, const double *values);
/* Writes what is left, joins the writer, closes; returns -1 if any write failed (err says so). */
int sim_csv_close(sim_csv *c, char *err, size_t errlen);

/* Live SocketCAN (CAN_RAW; FD frames enabled when fd). -1 with a clear message when the
 * kernel has no CAN support or the interface does not exist. */
typedef struct sim_socketcan {
    int fd;
    int is_fd;
    char iface[32];
    uint64_t sent, tx_errors;
    int last_errno;
} sim_socketcan;

int sim_socketcan_open(sim_socketcan *s, const char *iface, int fd_frames, char *err, size_t errlen);
/* Sends one frame; 0 or -1 (counted in tx_errors, last_errno kept). */
int sim_socketcan_send(sim_socketcan *s, const vibid_can_frame *f);
void sim_socketcan_close(sim_socketcan *s);

#endif
