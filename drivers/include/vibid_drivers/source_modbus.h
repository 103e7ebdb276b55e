/* vibid_drivers/source_modbus.h: live samples from a Modbus TCP or RTU device
 * (libmodbus client).
 *
 * FIFO mode: the device keeps the last K samples in holding registers, numbered by a
 * sample counter (layout: drivers/modbus_fifo_layout.md). Each poll reads the counter and
 * every new record in requests of at most 125 registers; while the poll interval is
 * shorter than K*h no sample is lost. Overwritten records (counter ran more than K ahead,
 * or a record's tag changed while we read) become GAP records of exactly that many
 * samples. A server restart (new session id) gives a GAP whose length is estimated from
 * the elapsed time (the text says so). Sample time is device time: anchor + s*h.
 *
 * Snapshot mode: the channels' current-value registers (register map addresses; merged
 * into as few requests of <= 125 registers as possible) are read at t_0 + k*h on
 * CLOCK_MONOTONIC with absolute deadlines (clock_nanosleep TIMER_ABSTIME). A failed poll
 * is a POLL fault plus a one-sample GAP; deadlines missed by more than a period (slow
 * device, lost link) are a GAP of the missed ticks (counted as overruns). Sample time is
 * the receive time (CLOCK_REALTIME) of the poll.
 *
 * Link handling (both modes): a request without answer within response_timeout_s is a
 * timeout (counted); after max_timeouts consecutive timeouts, or any socket/serial error,
 * the link is declared lost (LINK fault), the connection closed and re-opened after
 * backoff_initial_s, doubling up to backoff_max_s while attempts fail (each failed
 * attempt counted and reported). Modbus exception answers (illegal address, ...) fail the
 * poll but keep the link. Every failed poll is counted.
 */
#ifndef VIBID_DRIVERS_SOURCE_MODBUS_H
#define VIBID_DRIVERS_SOURCE_MODBUS_H

#include <stdint.h>

#include <vibid_drivers/channel_map.h>
#include <vibid_drivers/register_map.h>
#include <vibid_drivers/source.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum vibid_modbus_transport { VIBID_MODBUS_TCP = 0, VIBID_MODBUS_RTU = 1 } vibid_modbus_transport;
typedef enum vibid_modbus_mode { VIBID_MODBUS_FIFO = 0, VIBID_MODBUS_SNAPSHOT = 1 } vibid_modbus_mode;

#define VIBID_MODBUS_FIFO_MAGIC 0x5646u
#define VIBID_MODBUS_FIFO_VERSION 1u
#define VIBID_MODBUS_FIFO_DEFAULT_BASE 1000u

typedef struct vibid_source_modbus_config {
    vibid_modbus_transport transport;
    const char *host;          /* TCP: address, e.g. "127.0.0.1" */
    int port;                  /* TCP: 1..65535 (0 = 502) */
    const char *device;        /* RTU: serial device, e.g. "/dev/ttyUSB0" */
    int baud;                  /* RTU: e.g. 115200 (0 = 19200) */
    char parity;               /* RTU: 'N', 'E', 'O' (0 = 'E', the Modbus default) */
    int data_bits, stop_bits;  /* RTU: 7|8 (0 = 8), 1|2 (0 = 1) */
    int unit_id;               /* slave / unit id 1..247 (0 = 1) */
    const vibid_regmap *regmap;/* entries named by the channels (copied at open) */
    vibid_chanmap chanmap;     /* channels with register = "<register map name>" */
    vibid_modbus_mode mode;
    double sample_period_s;    /* snapshot: h (> 0, required); FIFO: 0 or the expected
                                  h, checked against the device's period_ns */
    double poll_period_s;      /* FIFO: poll interval (0 = min(K h / 4, 0.05 s)) */
    unsigned fifo_base;        /* FIFO: header address B (0 = 1000) */
    double response_timeout_s; /* per request (0 = 0.5 s) */
    double backoff_initial_s;  /* first reconnect delay (0 = 0.1 s) */
    double backoff_max_s;      /* reconnect delay cap (0 = 5 s) */
    unsigned max_timeouts;     /* consecutive timeouts that mean a lost link (0 = 3) */
} vibid_source_modbus_config;

extern const vibid_source_ops vibid_source_modbus_ops;

#ifdef __cplusplus
}
#endif
#endif
