/* vibid_replay.c's interface, callable from C++ (no daemon header needed). */
#ifndef VIBID_PY_REPLAY_H
#define VIBID_PY_REPLAY_H
#include <stddef.h>
#ifdef __cplusplus
extern "C" {
#endif
typedef struct vibid_py_replay vibid_py_replay;
/* vd_log_level_parse / vd_rate_mode_parse: -1 when unknown */
int vibid_py_log_level_parse(const char *name);
int vibid_py_rate_mode_parse(const char *name);
/* Sets the daemon's log level (its format from the environment); returns the old one. */
int vibid_py_log_level_set(int level);
/* Loads config, puts the tracks into `tracks` (other outputs off), checks the paths and runs
 * vd_daemon_init for a replay of capture (NULL: the configured source, which must be a
 * replay). influx: NULL, or a file for the InfluxDB lines too (rows and alarm events, the
 * influx output's format). reference: NULL keeps alarms.reference_file, "" turns it off,
 * else the reference file to read or, learned, to write. NULL with err filled (the daemon's
 * message). */
vibid_py_replay *vibid_py_replay_open(const char *config, const char *capture, const char *tracks, const char *influx,
                                      const char *reference, int rate_mode, char *err, size_t cap);
/* vd_daemon_run: blocks SIGTERM, SIGINT, SIGHUP, SIGUSR1 in the calling thread and returns
 * vibidd's exit status (0 ok) when the replay has ended or SIGTERM reached that thread. */
int vibid_py_replay_run(vibid_py_replay *r);
void vibid_py_replay_close(vibid_py_replay *r);
#ifdef __cplusplus
}
#endif
#endif
