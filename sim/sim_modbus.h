/* sim/sim_modbus.h: vibid-sim's Modbus TCP server (libmodbus server API: modbus_receive,
 * modbus_reply on a modbus_mapping_t), serving
 *  - the sample FIFO of drivers/modbus_fifo_layout.md (version 1) at holding register
 *    `fifo_base`, data offset 64, capacity K records, channels in register-map order;
 *  - current-value registers at the register map's addresses (holding or input).
 * Several clients at once through select() in a server thread; a request is answered
 * under a mutex that the producer also takes to write a record and advance the count,
 * so a client's read of the header is always consistent. A client that disconnects or
 * sends garbage is closed; the others are not disturbed (a half-sent request is given
 * up after 50 ms). Write requests are refused (ILLEGAL FUNCTION): the registers are the
 * device's outputs. Requests are answered for any unit id.
 */
#ifndef VIBID_SIM_MODBUS_H
#define VIBID_SIM_MODBUS_H

#include <stddef.h>
#include <stdint.h>

#include <vibid_drivers/register_map.h>

#include "sim_faults.h"

typedef struct sim_modbus sim_modbus;

typedef struct sim_modbus_stats {
    uint64_t accepted, closed, requests, refused_writes, encode_errors, records, sessions;
    uint64_t slow_clients;   /* closed because they did not read their replies (send would block) */
    uint64_t bad_frames;     /* closed because of an impossible MBAP header (length 0, 1 or > 254) */
} sim_modbus_stats;

/* host "127.0.0.1", "0.0.0.0", "::1", ...; port 0 picks a free port (sim_modbus_port).
 * map: entries named by channels; chan[i] = model channel of map entry i. The map is
 * copied. NULL with err on failure (address in use, overlapping registers, FIFO does not fit). */
sim_modbus *sim_modbus_create(const char *host, int port, const vibid_regmap *map, const size_t *chan,
                              unsigned fifo_base, unsigned capacity, double h, char *err, size_t errlen);
int sim_modbus_port(const sim_modbus *m);
/* Writes the sample (values in model channel order) into the current-value registers
 * and the next FIFO record (faults may drop or corrupt the record). */
void sim_modbus_push(sim_modbus *m, const double *values, sim_faults *faults);
/* Stops serving (closes the listening socket and every client) or resumes (listens
 * again; the FIFO restarts: new session, count 0). */
void sim_modbus_set_serving(sim_modbus *m, int on);
void sim_modbus_stats_get(sim_modbus *m, sim_modbus_stats *s);
void sim_modbus_destroy(sim_modbus *m);

#endif
