/* Status texts and the error holder shared by the drivers library. */
#include <vibid_drivers/status.h>

#include <stdarg.h>
#include <stdio.h>

const char *vibid_drv_strerror(vibid_drv_status status)
{
    switch (status) {
    case VIBID_DRV_OK: return "ok";
    case VIBID_DRV_E_ARG: return "invalid argument";
    case VIBID_DRV_E_IO: return "input/output error";
    case VIBID_DRV_E_SYNTAX: return "syntax error";
    case VIBID_DRV_E_NOMEM: return "out of memory";
    case VIBID_DRV_E_RANGE: return "value out of range";
    case VIBID_DRV_E_EOF: return "end of stream";
    case VIBID_DRV_E_AGAIN: return "no data yet";
    case VIBID_DRV_E_UNSUPPORTED: return "unsupported";
    case VIBID_DRV_E_SHORT: return "frame too short";
    case VIBID_DRV_E_NOT_PRESENT: return "signal not present (multiplexed)";
    case VIBID_DRV_E_NOT_FOUND: return "not found";
    case VIBID_DRV_E_LINK: return "link lost";
    }
    return "unknown status";
}

vibid_drv_status vibid_drv_fail(vibid_drv_error *err, vibid_drv_status status, const char *fmt,
                                ...)
{
    if (err) {
        va_list ap;
        va_start(ap, fmt);
        err->status = status;
        vsnprintf(err->text, sizeof err->text, fmt, ap);
        va_end(ap);
    }
    return status;
}
