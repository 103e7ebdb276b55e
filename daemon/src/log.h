/* log.h: levelled log lines on stderr, which systemd's journal picks up.
 *
 * Under systemd (JOURNAL_STREAM set, or log_set_prefix_kernel) each line starts with
 * the kernel-style priority "<N>" that the journal turns into the entry's priority, so
 * `journalctl -p warning` works without libsystemd. Otherwise the line is
 * "vibidd: LEVEL: text". Lines are written with one write(2) each, so lines from
 * different threads never interleave. Safe from any thread (no lock, no allocation).
 */
#ifndef VIBIDD_LOG_H
#define VIBIDD_LOG_H

typedef enum vd_log_level {
    VD_LOG_ERROR = 3, /* syslog priorities: err */
    VD_LOG_WARNING = 4,
    VD_LOG_NOTICE = 5,
    VD_LOG_INFO = 6,
    VD_LOG_DEBUG = 7
} vd_log_level;

/* Lines above `level` are not written. Default INFO. */
void vd_log_set_level(vd_log_level level);
vd_log_level vd_log_get_level(void);
/* Parses "error", "warning", "notice", "info", "debug"; -1 if unknown. */
int vd_log_level_parse(const char *name);
const char *vd_log_level_name(vd_log_level level);
/* Decides the line format from the environment (JOURNAL_STREAM). */
void vd_log_init_from_env(void);

void vd_log(vd_log_level level, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

#define vd_error(...) vd_log(VD_LOG_ERROR, __VA_ARGS__)
#define vd_warning(...) vd_log(VD_LOG_WARNING, __VA_ARGS__)
#define vd_notice(...) vd_log(VD_LOG_NOTICE, __VA_ARGS__)
#define vd_info(...) vd_log(VD_LOG_INFO, __VA_ARGS__)
#define vd_debug(...) vd_log(VD_LOG_DEBUG, __VA_ARGS__)

#endif
