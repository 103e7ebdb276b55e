/* sim/sim_output.h: vibid-sim's file and bus outputs: CSV, candump log (through the
 * drivers' writer, can-utils format), live SocketCAN. */
#ifndef VIBID_SIM_OUTPUT_H
#define VIBID_SIM_OUTPUT_H

#include <stdint.h>
#include <stdio.h>

#include <vibid/stand_file.h>
#include <vibid_drivers/can_frame.h>

/* CSV: header "t,<inputs>,<measured>" by the stand's channel names; inputs are the
 * force inputs and the base's channels, measured the nodes' channels, each group in
 * the stand's channel order. Values in their shortest round-trip form (num_format.h:
 * lossless, at most 17 significant digits). */
typedef struct sim_csv {
    FILE *f;
    size_t n;
    size_t order[64];
    char path[512];
} sim_csv;

int sim_csv_open(sim_csv *c, const char *path, const vibid_stand *stand, char *err, size_t errlen);
int sim_csv_write(sim_csv *c, double t, const double *values);
/* Closes; returns -1 if any write failed (err says so). */
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
