/* log.c: see log.h. */
#include "log.h"

#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static atomic_int g_level = VD_LOG_INFO;
static atomic_int g_journal = 0;

void vd_log_set_level(vd_log_level level) { atomic_store(&g_level, (int)level); }
vd_log_level vd_log_get_level(void) { return (vd_log_level)atomic_load(&g_level); }

static const char *const level_names[] = {"", "", "", "error", "warning", "notice", "info", "debug"};

int vd_log_level_parse(const char *name)
{
    for (int i = VD_LOG_ERROR; i <= VD_LOG_DEBUG; i++)
        if (strcmp(name, level_names[i]) == 0)
            return i;
    return -1;
}

const char *vd_log_level_name(vd_log_level level)
{
    return level >= VD_LOG_ERROR && level <= VD_LOG_DEBUG ? level_names[level] : "?";
}

void vd_log_init_from_env(void)
{
    /* systemd sets JOURNAL_STREAM when stderr is connected to the journal. */
    const char *js = getenv("JOURNAL_STREAM");
    atomic_store(&g_journal, js && *js ? 1 : 0);
}

void vd_log(vd_log_level level, const char *fmt, ...)
{
    if ((int)level > atomic_load(&g_level))
        return;
    char buf[1024];
    int off;
    if (atomic_load(&g_journal))
        off = snprintf(buf, sizeof buf, "<%d>", (int)level);
    else
        off = snprintf(buf, sizeof buf, "vibidd: %s: ", vd_log_level_name(level));
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(buf + off, sizeof buf - (size_t)off - 1, fmt, ap);
    va_end(ap);
    size_t len = (size_t)off + (n < 0 ? 0 : (size_t)n);
    if (len > sizeof buf - 2)
        len = sizeof buf - 2;
    buf[len++] = '\n';
    ssize_t w = write(STDERR_FILENO, buf, len);
    (void)w; /* nowhere left to report a failed write to stderr */
}
