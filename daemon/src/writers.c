/* writers.c: see writers.h. */

#include "writers.h"

#include "clock.h"
#include "log.h"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>

#include <vibid_drivers/candump.h>
#include <time.h>
#include <unistd.h>

/* Appends to buf at *off; returns -1 once the buffer is full. */
static int put(char *buf, size_t cap, size_t *off, const char *fmt, ...) __attribute__((format(printf, 4, 5)));
static int put(char *buf, size_t cap, size_t *off, const char *fmt, ...)
{
    if (*off >= cap)
        return -1;
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(buf + *off, cap - *off, fmt, ap);
    va_end(ap);
    if (n < 0 || (size_t)n >= cap - *off)
        return -1;
    *off += (size_t)n;
    return 0;
}

static int put_time_us(char *buf, size_t cap, size_t *off, int64_t t_us)
{
    const char *sign = "";
    uint64_t a = (uint64_t)t_us;
    if (t_us < 0) {
        sign = "-";
        a = (uint64_t)(-(t_us + 1)) + 1u;
    }
    return put(buf, cap, off, "%s%llu.%06llu", sign, (unsigned long long)(a / 1000000u),
               (unsigned long long)(a % 1000000u));
}

static int put_num(char *buf, size_t cap, size_t *off, double v)
{
    return isfinite(v) ? put(buf, cap, off, ",%.10g", v) : put(buf, cap, off, ",nan");
}

int vd_format_tracks_header(char *buf, size_t cap, const vd_config *cfg)
{
    size_t off = 0;
    if (put(buf, cap, &off, "time_s,index"))
        return -1;
    for (size_t k = 0; k < cfg->n_params; k++)
        if (put(buf, cap, &off, ",%s,%s_se", vd_param_name(cfg, k), vd_param_name(cfg, k)))
            return -1;
    for (size_t i = 1; i <= cfg->n_modes; i++)
        if (put(buf, cap, &off, ",f%zu_hz,f%zu_hz_se,zeta%zu,zeta%zu_se", i, i, i, i))
            return -1;
    for (size_t j = 0; j < cfg->n_covariates; j++)
        if (put(buf, cap, &off, ",%s", cfg->chanmap.ch[cfg->cov_chan[j]].name))
            return -1;
    for (size_t k = 0; k < cfg->n_params; k++)
        if (vd_change_columns(cfg, k) &&
            put(buf, cap, &off, ",%s_change_statistic,%s_mdc", vd_param_name(cfg, k), vd_param_name(cfg, k)))
            return -1;
    if (put(buf, cap, &off, ",gap_samples,flags\n"))
        return -1;
    return (int)off;
}

int vd_format_track_row(char *buf, size_t cap, const vd_config *cfg, const vd_row *row)
{
    size_t off = 0;
    if (put_time_us(buf, cap, &off, row->t_us) || put(buf, cap, &off, ",%llu", (unsigned long long)row->index))
        return -1;
    for (size_t k = 0; k < cfg->n_params; k++)
        if (put_num(buf, cap, &off, row->theta[k]) || put_num(buf, cap, &off, row->se[k]))
            return -1;
    for (size_t i = 0; i < cfg->n_modes; i++)
        if (put_num(buf, cap, &off, row->freq[i]) || put_num(buf, cap, &off, row->freq_se[i]) ||
            put_num(buf, cap, &off, row->zeta[i]) || put_num(buf, cap, &off, row->zeta_se[i]))
            return -1;
    for (size_t j = 0; j < cfg->n_covariates; j++)
        if (put_num(buf, cap, &off, row->cov[j]))
            return -1;
    for (size_t k = 0; k < cfg->n_params; k++)
        if (vd_change_columns(cfg, k) &&
            (put_num(buf, cap, &off, row->change_stat[k]) || put_num(buf, cap, &off, row->change_mdc[k])))
            return -1;
    char fl[VD_FLAG_LETTERS_MAX];
    vd_flag_letters(row->flags, fl);
    if (put(buf, cap, &off, ",%llu,%s\n", (unsigned long long)row->gap_samples, fl))
        return -1;
    return (int)off;
}

void vd_influx_escape_tag(char *dst, size_t cap, const char *src)
{
    size_t o = 0;
    for (; *src && o + 2 < cap; src++) {
        if (*src == ',' || *src == ' ' || *src == '=' || *src == '\\')
            dst[o++] = '\\';
        dst[o++] = *src;
    }
    dst[o] = '\0';
}

static int put_field(char *buf, size_t cap, size_t *off, int *first, const char *name, const char *suffix, double v)
{
    if (!isfinite(v))
        return 0;
    int rc = put(buf, cap, off, "%s%s%s=%.10g", *first ? " " : ",", name, suffix, v);
    *first = 0;
    return rc;
}

/* A sample time in us as line protocol's ns, saturated at the ends of int64 (a time beyond
 * the year 2262 cannot be written; the MQTT module's slot sizing probes with INT64_MIN) */
static long long ns_of_us(int64_t t_us)
{
    if (t_us > INT64_MAX / 1000)
        return INT64_MAX;
    if (t_us < INT64_MIN / 1000)
        return INT64_MIN;
    return (long long)t_us * 1000LL;
}

int vd_format_influx_row(char *buf, size_t cap, const vd_config *cfg, const char *stand, const vd_row *row)
{
    size_t off = 0;
    char tag[256], site[256];
    vd_influx_escape_tag(tag, sizeof tag, stand);
    vd_influx_escape_tag(site, sizeof site, cfg->files.influx_site);
    /* tags in key order (InfluxDB's advice: the server sorts them otherwise). A refinement's
     * row (flag W) is tagged estimate=refined: it may fall on the sample of a recursive row,
     * and a point of the same series and time would overwrite that row's fields */
    if (put(buf, cap, &off, "%s%s%s%s,stand=%s", cfg->files.influx_measurement,
            (row->flags & VD_FLAG_REFINED) ? ",estimate=refined" : "", site[0] ? ",site=" : "", site, tag))
        return -1;
    int first = 1;
    char fname[160];
    for (size_t k = 0; k < cfg->n_params; k++) {
        /* field keys escape commas, spaces and equals signs like tags */
        vd_influx_escape_tag(fname, sizeof fname, vd_param_name(cfg, k));
        if (put_field(buf, cap, &off, &first, fname, "", row->theta[k]) ||
            put_field(buf, cap, &off, &first, fname, "_se", row->se[k]))
            return -1;
        if (vd_change_columns(cfg, k) &&
            (put_field(buf, cap, &off, &first, fname, "_change_statistic", row->change_stat[k]) ||
             put_field(buf, cap, &off, &first, fname, "_mdc", row->change_mdc[k])))
            return -1;
    }
    for (size_t i = 0; i < cfg->n_modes; i++) {
        char f[32], z[32];
        snprintf(f, sizeof f, "f%zu_hz", i + 1);
        snprintf(z, sizeof z, "zeta%zu", i + 1);
        if (put_field(buf, cap, &off, &first, f, "", row->freq[i]) ||
            put_field(buf, cap, &off, &first, f, "_se", row->freq_se[i]) ||
            put_field(buf, cap, &off, &first, z, "", row->zeta[i]) ||
            put_field(buf, cap, &off, &first, z, "_se", row->zeta_se[i]))
            return -1;
    }
    for (size_t j = 0; j < cfg->n_covariates; j++) {
        vd_influx_escape_tag(fname, sizeof fname, cfg->chanmap.ch[cfg->cov_chan[j]].name);
        if (put_field(buf, cap, &off, &first, fname, "", row->cov[j]))
            return -1;
    }
    char fl[VD_FLAG_LETTERS_MAX];
    vd_flag_letters(row->flags, fl);
    if (put(buf, cap, &off, "%sindex=%llui,gap_samples=%llui,flags=\"%s\" %lld\n", first ? " " : ",",
            (unsigned long long)row->index, (unsigned long long)row->gap_samples, fl, ns_of_us(row->t_us)))
        return -1;
    return (int)off;
}

int vd_influx_add_fields(char *buf, size_t cap, int n, const char *fields)
{
    if (n <= 0)
        return -1;
    if (buf[n - 1] == '\n')
        n--;
    char *sp = NULL; /* the space before the timestamp: the last one (field values are numbers
                        or quoted flag letters without spaces) */
    for (int i = n - 1; i >= 0; i--)
        if (buf[i] == ' ') {
            sp = buf + i;
            break;
        }
    if (!sp)
        return -1;
    char ts[40];
    size_t tl = (size_t)(buf + n - sp), fl = strlen(fields), at = (size_t)(sp - buf);
    if (tl >= sizeof ts || at + 1 + fl + tl + 1 > cap)
        return -1;
    memcpy(ts, sp, tl);
    buf[at] = ',';
    memcpy(buf + at + 1, fields, fl);
    memcpy(buf + at + 1 + fl, ts, tl);
    buf[at + 1 + fl + tl] = '\0';
    return (int)(at + 1 + fl + tl);
}

int vd_format_influx_alarm(char *buf, size_t cap, const vd_config *cfg, const char *stand, const vd_output_alarm *a)
{
    size_t off = 0;
    char tag[256], ptag[160], site[256];
    vd_influx_escape_tag(tag, sizeof tag, stand);
    vd_influx_escape_tag(ptag, sizeof ptag, a->param);
    vd_influx_escape_tag(site, sizeof site, cfg->files.influx_site);
    if (put(buf, cap, &off, "%s_alarm,parameter=%s%s%s,stand=%s state=\"%s\",test=\"%s\",onset_index=%llui,index=%llui",
            cfg->files.influx_measurement, ptag, site[0] ? ",site=" : "", site, tag, a->raised ? "raised" : "cleared",
            a->test, (unsigned long long)a->onset_index, (unsigned long long)a->row->index))
        return -1;
    int first = 0;
    if (put_field(buf, cap, &off, &first, "value", "", a->value) ||
        put_field(buf, cap, &off, &first, "baseline", "", a->baseline) ||
        put_field(buf, cap, &off, &first, "z", "", a->z) ||
        put_field(buf, cap, &off, &first, "statistic", "", a->statistic) ||
        put_field(buf, cap, &off, &first, "threshold", "", a->threshold) ||
        put_field(buf, cap, &off, &first, "change", "", a->change) ||
        put_field(buf, cap, &off, &first, "change_se", "", a->change_se))
        return -1;
    if (put(buf, cap, &off, " %lld\n", ns_of_us(a->row->t_us)))
        return -1;
    return (int)off;
}

int vd_format_recording_header(char *buf, size_t cap, const char *stand, double rate, const vibid_chanmap *map)
{
    size_t off = 0;
    if (put(buf, cap, &off, VD_RECORDING_MAGIC " of stand '%s' at %.17g Hz; replay: vibidd -c CONFIG --replay FILE\nt",
            stand, rate))
        return -1;
    for (size_t i = 0; i < map->n; i++)
        if (put(buf, cap, &off, ",%s", map->ch[i].name))
            return -1;
    if (put(buf, cap, &off, "\n"))
        return -1;
    return (int)off;
}

int vd_format_recording_row(char *buf, size_t cap, const vibid_record *rec)
{
    size_t off = 0;
    if (put_time_us(buf, cap, &off, vd_ns_to_us(rec->t_ns)))
        return -1;
    for (uint32_t i = 0; i < rec->n_values; i++)
        if (put(buf, cap, &off, ",%.17g", rec->values[i]))
            return -1;
    if (put(buf, cap, &off, "\n"))
        return -1;
    return (int)off;
}

int vd_format_recording_frames(char *buf, size_t cap, const vibid_can_assembler *enc, const char *iface,
                               const vibid_record *rec)
{
    vibid_can_frame frames[32];
    size_t nf = 0;
    if (vibid_can_assembler_encode(enc, rec, frames, 32, &nf, NULL) != VIBID_DRV_OK)
        return -1;
    /* the CSV recording's time base: the sample time rounded to the microsecond */
    const int64_t t_ns = vd_ns_to_us(rec->t_ns) * 1000;
    size_t off = 0;
    for (size_t i = 0; i < nf; i++) {
        frames[i].t_ns = t_ns;
        int n = vibid_candump_format(buf + off, cap - off, &frames[i], iface);
        if (n < 0 || (size_t)n + 1 >= cap - off)
            return -1;
        off += (size_t)n;
        buf[off++] = '\n';
    }
    buf[off] = '\0';
    return (int)off;
}

void vd_writers_failed(vd_writers *w, const char *what, const char *path)
{
    const int e = errno;
    int k = 0;
    while (k < VD_OUT_FILES && w->out[k].path != path)
        k++; /* not a file output: the status file */
    w->write_errors++;
    const uint64_t n = ++w->output_errors[k];
    const double now = vd_mono_s();
    if (n == 1 || now - w->output_report[k] > 60.0) {
        vd_error("writing %s %s failed: %s (%llu failed writes of this output so far, %llu of all; output is being "
                 "lost)",
                 what, path, strerror(e), (unsigned long long)n, (unsigned long long)w->write_errors);
        w->output_report[k] = now;
    }
    errno = e;
}

/* true if output k is open; an output closed by a failed reopen counts one more lost record */
static bool wants(vd_writers *w, int k)
{
    vd_output *o = &w->out[k];
    if (o->closed)
        o->lost++;
    return o->f != NULL;
}

static void emit(vd_writers *w, int k, const char *buf, int n)
{
    vd_output *o = &w->out[k];
    if (!o->f || n <= 0)
        return;
    if (fwrite(buf, 1, (size_t)n, o->f) != (size_t)n)
        vd_writers_failed(w, o->what, o->path);
}

/* An output that does not end in a newline was cut mid-line (kill -9, power loss, a full
 * disk): appending would glue the next row onto the torn one, a corrupt row mid-file.
 * The torn tail (everything after the last newline) is cut off before appending, logged
 * and counted. Returns 0, or -1 with err filled. */
static int repair_torn_tail(vd_writers *w, FILE *f, const char *path, char *err, size_t cap)
{
    const int fd = fileno(f);
    struct stat st;
    if (fstat(fd, &st) != 0 || !S_ISREG(st.st_mode) || st.st_size == 0)
        return 0;
    char buf[4096];
    off_t end = st.st_size, keep = 0;
    bool torn = false, found = false;
    while (end > 0 && !found) {
        const off_t start = end > (off_t)sizeof buf ? end - (off_t)sizeof buf : 0;
        const ssize_t n = pread(fd, buf, (size_t)(end - start), start);
        if (n != (ssize_t)(end - start)) {
            snprintf(err, cap, "cannot read the end of %s: %s", path, n < 0 ? strerror(errno) : "short read");
            return -1;
        }
        for (ssize_t i = n - 1; i >= 0; i--) {
            if (buf[i] == '\n') {
                keep = start + i + 1;
                found = true;
                break;
            }
            torn = true;
        }
        end = start;
    }
    if (!torn)
        return 0;
    if (ftruncate(fd, keep) != 0) {
        snprintf(err, cap, "cannot cut the torn last line of %s: %s", path, strerror(errno));
        return -1;
    }
    w->torn_lines++;
    vd_warning("%s: cut off a torn last line of %lld bytes (an earlier run ended in the middle of writing it)",
               path, (long long)(st.st_size - keep));
    return 0;
}

static FILE *open_append(vd_writers *w, const char *path, const char *header, int hlen, char *err, size_t cap)
{
    FILE *f = fopen(path, "a+e"); /* + : the torn-tail check reads the end */
    if (!f) {
        snprintf(err, cap, "cannot open %s for appending: %s", path, strerror(errno));
        return NULL;
    }
    if (repair_torn_tail(w, f, path, err, cap)) {
        fclose(f);
        return NULL;
    }
    struct stat st;
    if (header && fstat(fileno(f), &st) == 0 && st.st_size == 0 && hlen > 0) {
        if (fwrite(header, 1, (size_t)hlen, f) != (size_t)hlen) {
            snprintf(err, cap, "cannot write the header of %s: %s", path, strerror(errno));
            fclose(f);
            return NULL;
        }
    }
    return f;
}

/* Opens output k (its path is set) for appending, with its header when the file is empty:
 * the tracks' preamble ("# " before each line; a CSV reader skips it with comment='#') and
 * column header, the CSV recording's header. 0, or -1 with err. */
static int open_output(vd_writers *w, int k, char *err, size_t cap)
{
    const vd_config *cfg = w->cfg;
    vd_output *o = &w->out[k];
    int n = 0;
    if (k == VD_OUT_TRACKS) {
        size_t off = 0;
        const char *rest = w->tracks_preamble, *line = rest;
        int len;
        while (off < sizeof w->linebuf / 2 && vd_next_line(&rest, &len)) {
            int m = snprintf(w->linebuf + off, sizeof w->linebuf / 2 - off, "# %.*s\n", len, line);
            if (m < 0 || (size_t)m >= sizeof w->linebuf / 2 - off)
                break;
            off += (size_t)m;
            line = rest;
        }
        n = vd_format_tracks_header(w->linebuf + off, sizeof w->linebuf - off, cfg);
        if (n >= 0)
            n += (int)off;
    } else if (k == VD_OUT_RECORD && cfg->files.record_format != VD_REC_CANDUMP) { /* a candump log has no header */
        n = vd_format_recording_header(w->linebuf, sizeof w->linebuf, w->stand_name, cfg->sample_rate, w->chanmap);
    }
    o->f = open_append(w, o->path, n > 0 ? w->linebuf : NULL, n, err, cap);
    return o->f ? 0 : -1;
}

static int open_files(vd_writers *w, char *err, size_t cap)
{
    for (int k = 0; k < VD_OUT_FILES; k++)
        if (w->out[k].path[0] && open_output(w, k, err, cap))
            return -1;
    return 0;
}

/* outputs.influx.udp "HOST:PORT" (the configuration checked the port) -> IPv4 address. */
static int resolve_udp(const char *hostport, struct sockaddr_in *out, char *err, size_t cap)
{
    char host[128];
    const char *colon = strrchr(hostport, ':');
    snprintf(host, sizeof host, "%.*s", (int)(colon - hostport), hostport);
    struct addrinfo hints, *res = NULL;
    memset(&hints, 0, sizeof hints);
    hints.ai_family = AF_INET;
    hints.ai_socktype = SOCK_DGRAM;
    const int rc = getaddrinfo(host, NULL, &hints, &res);
    if (rc != 0 || !res) {
        snprintf(err, cap, "outputs.influx.udp: '%s' does not resolve to an IPv4 address: %s", host,
                 rc == EAI_SYSTEM ? strerror(errno) : gai_strerror(rc));
        return -1;
    }
    memcpy(out, res->ai_addr, sizeof *out);
    out->sin_port = htons((uint16_t)atoi(colon + 1));
    freeaddrinfo(res);
    return 0;
}

/* An output path: its directory exists and is writable; the file, if there, is a
 * writable regular file. */
static int check_output_path(const char *what, const char *path, char *err, size_t cap)
{
    if (!path[0])
        return 0;
    char dir[VD_PATH_MAX];
    vd_path_dir(path, dir, sizeof dir);
    struct stat st;
    if (stat(dir, &st) != 0) {
        snprintf(err, cap, "%s %s: the directory %s: %s", what, path, dir, strerror(errno));
        return -1;
    }
    if (!S_ISDIR(st.st_mode)) {
        snprintf(err, cap, "%s %s: %s is not a directory", what, path, dir);
        return -1;
    }
    /* Writability by trying, not by access(): root passes access() on a read-only file
     * system. A probe file is created and removed in the directory; an existing file is
     * opened for appending (nothing written). */
    char probe[VD_PATH_MAX + 64];
    snprintf(probe, sizeof probe, "%s/.vibidd-check-%ld", dir, (long)getpid());
    int fd = open(probe, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
    if (fd < 0) {
        snprintf(err, cap, "%s %s: cannot create files in %s: %s", what, path, dir, strerror(errno));
        return -1;
    }
    close(fd);
    unlink(probe);
    if (stat(path, &st) == 0) {
        if (!S_ISREG(st.st_mode)) {
            snprintf(err, cap, "%s %s: not a regular file", what, path);
            return -1;
        }
        fd = open(path, O_WRONLY | O_APPEND | O_CLOEXEC);
        if (fd < 0) {
            snprintf(err, cap, "%s %s: not writable: %s", what, path, strerror(errno));
            return -1;
        }
        close(fd);
    }
    return 0;
}

/* The configured path of a part, or "" when the part is not selected. */
static const char *part_path(const char *path, unsigned parts, unsigned part) { return parts & part ? path : ""; }

static int check_parts(const vd_config *cfg, unsigned parts, char *err, size_t cap)
{
    if (check_output_path("outputs.tracks.path", part_path(cfg->files.tracks_path, parts, VD_PART_TRACKS), err, cap) ||
        check_output_path("outputs.influx.path", part_path(cfg->files.influx_path, parts, VD_PART_INFLUX), err, cap) ||
        check_output_path("outputs.record.path", part_path(cfg->files.record_path, parts, VD_PART_RECORD), err, cap) ||
        check_output_path("outputs.status.path", part_path(cfg->files.status_path, parts, VD_PART_STATUS), err, cap))
        return -1;
    struct sockaddr_in addr;
    if ((parts & VD_PART_INFLUX) && cfg->files.influx_udp[0] && resolve_udp(cfg->files.influx_udp, &addr, err, cap))
        return -1;
    return 0;
}

int vd_writers_check(const vd_config *cfg, char *err, size_t cap) { return check_parts(cfg, VD_PARTS_ALL, err, cap); }

int vd_writers_open(vd_writers *w, const vd_config *cfg, const vibid_chanmap *chanmap, const char *tracks_preamble,
                    char *err, size_t cap)
{
    return vd_writers_open_parts(w, cfg, chanmap, tracks_preamble, VD_PARTS_ALL, err, cap);
}

int vd_writers_open_parts(vd_writers *w, const vd_config *cfg, const vibid_chanmap *chanmap,
                          const char *tracks_preamble, unsigned parts, char *err, size_t cap)
{
    if (check_parts(cfg, parts, err, cap))
        return -1;
    memset(w, 0, sizeof *w);
    w->cfg = cfg;
    w->tracks_preamble = tracks_preamble;
    w->chanmap = chanmap;
    w->stand_name = cfg->files.influx_stand[0] ? cfg->files.influx_stand : vd_stand_name(cfg);
    w->udp_fd = -1;
    const char *const paths[VD_OUT_FILES] = {part_path(cfg->files.tracks_path, parts, VD_PART_TRACKS),
                                             part_path(cfg->files.influx_path, parts, VD_PART_INFLUX),
                                             part_path(cfg->files.record_path, parts, VD_PART_RECORD)};
    const char *const whats[VD_OUT_FILES] = {"tracks", "influx", "raw recording"};
    for (int k = 0; k < VD_OUT_FILES; k++) {
        w->out[k].path = paths[k];
        w->out[k].what = whats[k];
    }
    w->status_path = part_path(cfg->files.status_path, parts, VD_PART_STATUS);
    if (w->out[VD_OUT_RECORD].path[0] && cfg->files.record_format == VD_REC_CANDUMP) {
        vibid_drv_error de = {0};
        w->record_encoder = cfg->dbc ? vibid_can_assembler_create(cfg->dbc, chanmap, &de) : NULL;
        if (!w->record_encoder) {
            snprintf(err, cap, "outputs.record (candump) %s: %s", cfg->files.record_path,
                     cfg->dbc ? de.text : "no DBC to encode the samples with");
            return -1;
        }
    }
    if (open_files(w, err, cap)) {
        vd_writers_close(w);
        return -1;
    }
    if ((parts & VD_PART_INFLUX) && cfg->files.influx_udp[0]) {
        if (resolve_udp(cfg->files.influx_udp, &w->udp_addr, err, cap)) {
            vd_writers_close(w);
            return -1;
        }
        w->udp_fd = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
        if (w->udp_fd < 0) {
            snprintf(err, cap, "socket(AF_INET, SOCK_DGRAM) for InfluxDB UDP: %s", strerror(errno));
            vd_writers_close(w);
            return -1;
        }
    }
    return 0;
}

static void close_output(vd_writers *w, int k)
{
    vd_output *o = &w->out[k];
    if (o->f && fclose(o->f) != 0)
        vd_writers_failed(w, "closing", o->path);
    o->f = NULL;
}

static const char *lost_unit(int k) { return k == VD_OUT_TRACKS ? "rows" : k == VD_OUT_INFLUX ? "lines" : "samples"; }

#define REOPEN_BACKOFF_FIRST_S 1.0
#define REOPEN_BACKOFF_MAX_S 30.0

/* Opens output k again (a SIGHUP, or the retry of a closed one). When that fails the output
 * stays closed (the others are not touched): counted as a write error and in its
 * open_failures, logged (the first failure of an episode at once, then at most once a
 * minute), retried after a back-off of 1 s doubling to 30 s. true if it is open. */
static bool reopen_output(vd_writers *w, int k, double now, bool sighup)
{
    const char *when = sighup ? "reopening after SIGHUP" : "retrying to open it";
    vd_output *o = &w->out[k];
    char err[1200];
    if (open_output(w, k, err, sizeof err) == 0) {
        if (o->closed)
            vd_notice("%s %s is open again (%s) after %llu failed attempts; %llu %s lost while it was closed, in "
                      "this run (the status's %s_lost_%s)",
                      o->what, o->path, sighup ? "SIGHUP" : "retried", (unsigned long long)o->failed_attempts,
                      (unsigned long long)o->lost,
                      lost_unit(k), k == VD_OUT_RECORD ? "record" : k == VD_OUT_INFLUX ? "influx" : "tracks",
                      lost_unit(k));
        o->closed = false;
        o->failed_attempts = 0;
        return true;
    }
    o->backoff = o->closed ? fmin(o->backoff * 2.0, REOPEN_BACKOFF_MAX_S) : REOPEN_BACKOFF_FIRST_S;
    o->closed = true;
    o->retry_at = now + o->backoff;
    o->open_failures++;
    o->failed_attempts++;
    w->write_errors++;
    w->output_errors[k]++;
    if (o->failed_attempts == 1 || now - w->output_report[k] > 60.0) {
        vd_error("%s: %s; this output stays closed (the others go on), is tried again every %.0f s at most "
                 "and at every SIGHUP; its %s are lost until then and counted (%llu so far, %llu failed attempts)",
                 when, err, REOPEN_BACKOFF_MAX_S, lost_unit(k), (unsigned long long)o->lost,
                 (unsigned long long)o->failed_attempts);
        w->output_report[k] = now;
    }
    return false;
}

unsigned vd_writers_closed(const vd_writers *w)
{
    unsigned n = 0;
    for (int k = 0; k < VD_OUT_FILES; k++)
        n += w->out[k].closed;
    return n;
}

static void flush_files(vd_writers *w, int sync)
{
    for (int k = 0; k < VD_OUT_FILES; k++) {
        vd_output *o = &w->out[k];
        if (!o->f)
            continue;
        if (fflush(o->f) != 0)
            vd_writers_failed(w, "flushing", o->path);
        else if (sync && fdatasync(fileno(o->f)) != 0 && errno != EINVAL)
            vd_writers_failed(w, "fdatasync of", o->path);
    }
}

int vd_writers_reopen(vd_writers *w)
{
    flush_files(w, 0);
    const double now = vd_mono_s();
    unsigned left = 0;
    for (int k = 0; k < VD_OUT_FILES; k++) {
        if (!w->out[k].path[0])
            continue;
        close_output(w, k);
        if (!reopen_output(w, k, now, true))
            left++;
    }
    if (!left)
        vd_info("outputs reopened (SIGHUP)");
    return (int)left;
}

static void send_udp(vd_writers *w, const char *buf, int n)
{
    if (w->udp_fd < 0 || n <= 0)
        return;
    ssize_t s = sendto(w->udp_fd, buf, (size_t)n, MSG_NOSIGNAL, (const struct sockaddr *)&w->udp_addr,
                       sizeof w->udp_addr);
    if (s != n) {
        w->udp_errors++;
        if (w->udp_errors == 1 || w->udp_errors % 10000 == 0)
            vd_warning("InfluxDB UDP to %s: %s (%llu datagrams lost so far)", w->cfg->files.influx_udp, strerror(errno),
                       (unsigned long long)w->udp_errors);
    } else {
        w->udp_sent++;
    }
}

void vd_writers_row(vd_writers *w, const vd_row *row)
{
    if (wants(w, VD_OUT_TRACKS)) {
        int n = vd_format_track_row(w->linebuf, sizeof w->linebuf, w->cfg, row);
        emit(w, VD_OUT_TRACKS, w->linebuf, n);
    }
    if (wants(w, VD_OUT_INFLUX) || w->udp_fd >= 0) {
        int n = vd_format_influx_row(w->linebuf, sizeof w->linebuf, w->cfg, w->stand_name, row);
        emit(w, VD_OUT_INFLUX, w->linebuf, n);
        send_udp(w, w->linebuf, n);
    }
}

void vd_writers_sample(vd_writers *w, const vibid_record *rec)
{
    if (rec->kind != VIBID_REC_SAMPLE || !wants(w, VD_OUT_RECORD))
        return;
    int n = w->record_encoder ? vd_format_recording_frames(w->linebuf, sizeof w->linebuf, w->record_encoder,
                                                           w->cfg->iface[0] ? w->cfg->iface : "can0", rec)
                              : vd_format_recording_row(w->linebuf, sizeof w->linebuf, rec);
    if (n < 0) {
        /* cannot happen for samples decoded with the same DBC; counted and logged */
        errno = ERANGE;
        vd_writers_failed(w, "raw recording (a sample does not fit its DBC signals)", w->cfg->files.record_path);
        return;
    }
    emit(w, VD_OUT_RECORD, w->linebuf, n);
}

void vd_writers_alarm(vd_writers *w, const vd_output_alarm *a)
{
    if (wants(w, VD_OUT_INFLUX) || w->udp_fd >= 0) {
        int n = vd_format_influx_alarm(w->linebuf, sizeof w->linebuf, w->cfg, w->stand_name, a);
        emit(w, VD_OUT_INFLUX, w->linebuf, n);
        send_udp(w, w->linebuf, n);
    }
}

void vd_writers_flush(vd_writers *w, int sync)
{
    if (vd_writers_closed(w)) {
        const double now = vd_mono_s();
        for (int k = 0; k < VD_OUT_FILES; k++)
            if (w->out[k].closed && now >= w->out[k].retry_at)
                reopen_output(w, k, now, false);
    }
    flush_files(w, sync);
}

void vd_writers_close(vd_writers *w)
{
    if (!w->cfg)
        return;
    vd_writers_flush(w, w->cfg->files.fsync_on_flush);
    for (int k = 0; k < VD_OUT_FILES; k++)
        close_output(w, k);
    if (w->udp_fd >= 0)
        close(w->udp_fd);
    w->udp_fd = -1;
    vibid_can_assembler_destroy(w->record_encoder);
    w->record_encoder = NULL;
}

/* The status file is replaced atomically (a .tmp renamed over it). When that fails (a full
 * disk: the .tmp gets no blocks) the .tmp is removed and the file is overwritten in place:
 * it fits the block it already has, so a full disk still shows in it (write_errors)
 * instead of a stale "write_errors=0". Each failure counts (vd_writers_failed), which
 * also makes the exit status 1. */
void vd_writers_status(vd_writers *w, const char *buf, size_t len)
{
    const char *path = w->status_path;
    if (!path || !path[0])
        return;
    char tmp[VD_PATH_MAX + 8];
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    FILE *f = fopen(tmp, "we");
    bool ok = f && fwrite(buf, 1, len, f) == len;
    if (f && fclose(f) != 0)
        ok = false;
    if (ok && rename(tmp, path) == 0)
        return;
    const int e = errno;
    if (f)
        unlink(tmp);
    errno = e;
    vd_writers_failed(w, "the status file", path);
    const int fd = open(path, O_WRONLY | O_CLOEXEC);
    if (fd < 0)
        return;
    if (pwrite(fd, buf, len, 0) == (ssize_t)len)
        (void)ftruncate(fd, (off_t)len);
    close(fd);
}

/* ------------------------------------------------- the output "files" (output.h) ---- */

/* The parts, in the order of the VD_PART_* bits. */
static const char *const files_parts[] = {"tracks", "influx", "record", "status", NULL};

/* Always opened: a part without its path writes nothing, and the write-error accounting
 * (the exit status) lives here. */
static bool files_enabled(const vd_config *cfg)
{
    (void)cfg;
    return true;
}

static int files_check(const vd_config *cfg, char *note, size_t note_cap, char *err, size_t cap)
{
    (void)note;
    (void)note_cap;
    return vd_writers_check(cfg, err, cap);
}

static void *files_open(const vd_output_ctx *ctx, char *err, size_t cap)
{
    unsigned parts = 0;
    for (unsigned i = 0; files_parts[i]; i++)
        if (vd_output_selected(ctx, "files") || vd_output_selected(ctx, files_parts[i]))
            parts |= 1u << i;
    vd_writers *w = calloc(1, sizeof *w);
    if (!w) {
        snprintf(err, cap, "out of memory for the file outputs");
        return NULL;
    }
    if (vd_writers_open_parts(w, ctx->cfg, ctx->rec_chanmap, ctx->tracks_preamble, parts, err, cap)) {
        free(w);
        return NULL;
    }
    return w;
}

static void files_sample(void *o, const vibid_record *rec) { vd_writers_sample(o, rec); }
static void files_row(void *o, const vd_row *row) { vd_writers_row(o, row); }

static void files_alarm(void *o, const vd_output_alarm *a)
{
    vd_writers_alarm(o, a);
}

static bool files_status(void *o, const vd_snapshot *s, const char *text, size_t len, bool final)
{
    (void)s;
    (void)final;
    vd_writers_status(o, text, len);
    return true;
}

static void files_flush(void *o, bool sync) { vd_writers_flush(o, sync); }
static void files_reopen(void *o) { (void)vd_writers_reopen(o); }

static void files_counters(void *o, vd_snapshot *s)
{
    const vd_writers *w = o;
    vd_snapshot_add(s, "write_errors", "vibid_write_errors_total", NULL,
                    "Failed writes of any output (status file included).", false, (double)w->write_errors);
    vd_snapshot_add(s, "torn_lines", "vibid_torn_lines_total", NULL, "Torn last lines cut off the outputs at open.",
                    false, (double)w->torn_lines);
    vd_snapshot_add(s, "influx_udp_sent", "vibid_influx_udp_sent_total", NULL,
                    "InfluxDB line-protocol datagrams sent.", false, (double)w->udp_sent);
    vd_snapshot_add(s, "influx_udp_errors", "vibid_influx_udp_errors_total", NULL,
                    "InfluxDB datagrams that could not be sent.", false, (double)w->udp_errors);
    vd_snapshot_add(s, "outputs_closed", "vibid_outputs_closed", NULL,
                    "File outputs closed now because a reopen failed (retried).", true, (double)vd_writers_closed(w));
    /* per file output: its label, the status file's key of its losses (whose unit it names) */
    static const char *const label[VD_OUT_FILES] = {"output=\"tracks\"", "output=\"influx\"", "output=\"record\""};
    static const char *const lost_key[VD_OUT_FILES] = {"tracks_lost_rows", "influx_lost_lines", "record_lost_samples"};
    uint64_t open_failures = 0;
    for (int k = 0; k < VD_OUT_FILES; k++)
        open_failures += w->out[k].open_failures;
    vd_snapshot_add(s, "output_open_failures", NULL, NULL, NULL, false, (double)open_failures);
    for (int k = 0; k < VD_OUT_FILES; k++) /* a family without a series is not written */
        if (w->out[k].path && w->out[k].path[0])
            vd_snapshot_add(s, NULL, "vibid_output_open_failures_total", label[k],
                            "Failed reopens of a file output (SIGHUP, retries); each also counts in "
                            "vibid_write_errors_total.",
                            false, (double)w->out[k].open_failures);
    for (int k = 0; k < VD_OUT_FILES; k++)
        vd_snapshot_add(s, lost_key[k], NULL, NULL, NULL, false, (double)w->out[k].lost);
    for (int k = 0; k < VD_OUT_FILES; k++)
        if (w->out[k].path && w->out[k].path[0])
            vd_snapshot_add(s, NULL, "vibid_output_lost_records_total", label[k],
                            "Records not written to a file output while it was closed (tracks: rows, influx: "
                            "lines, record: samples).",
                            false, (double)w->out[k].lost);
}

static bool files_failed(void *o) { return ((const vd_writers *)o)->write_errors != 0; }

static void files_close(void *o)
{
    if (!o)
        return;
    vd_writers_close(o);
    free(o);
}

/* ---------------------------------------------------------- settings ---- */

static const char *const files_groups[] = {"tracks", "influx", "record", "status", NULL};

/* outputs.tracks, .influx (its file, UDP and tags; the group also holds the groups other
 * outputs keep inside it: influx.http), .record, .status. */
static int files_load(vd_cfg_ctx *c, const config_setting_t *g)
{
    vd_config *cfg = c->cfg;
    vd_files_config *f = &cfg->files;
    config_setting_t *t = g ? config_setting_get_member(g, "tracks") : NULL;
    static const char *const tk[] = {"path", "flush_interval", "fsync", NULL};
    if (vd_cfg_known(c, t, "outputs.tracks", tk) ||
        vd_cfg_path(c, t, "outputs.tracks", "path", f->tracks_path, sizeof f->tracks_path) ||
        vd_cfg_double(c, t, "outputs.tracks", "flush_interval", 1.0, 0.01, 3600.0, &f->flush_interval_s) ||
        vd_cfg_bool(c, t, "outputs.tracks", "fsync", false, &f->fsync_on_flush))
        return -1;
    config_setting_t *i = g ? config_setting_get_member(g, "influx") : NULL;
    static const char *const ik[] = {"path", "udp", "measurement", "site", "stand", NULL};
    const char *ikeys[16];
    vd_output_known_keys("influx", ik, ikeys, 16);
    if (vd_cfg_known(c, i, "outputs.influx", ikeys) ||
        vd_cfg_path(c, i, "outputs.influx", "path", f->influx_path, sizeof f->influx_path) ||
        vd_cfg_string(c, i, "outputs.influx", "udp", "", f->influx_udp, sizeof f->influx_udp) ||
        vd_cfg_name(c, i, "outputs.influx", "measurement", "vibid", false, f->influx_measurement,
                    sizeof f->influx_measurement) ||
        vd_cfg_name(c, i, "outputs.influx", "site", "", true, f->influx_site, sizeof f->influx_site) ||
        vd_cfg_name(c, i, "outputs.influx", "stand", "", true, f->influx_stand, sizeof f->influx_stand))
        return -1;
    if (f->influx_udp[0]) {
        const char *colon = strrchr(f->influx_udp, ':');
        char *end = NULL;
        long p = colon ? strtol(colon + 1, &end, 10) : 0;
        if (!colon || colon == f->influx_udp || !end || *end || p < 1 || p > 65535)
            return vibid_cfg_fail(&c->r, config_setting_get_member(i, "udp"), "outputs.influx.udp",
                                  "'%s': expected HOST:PORT, e.g. \"127.0.0.1:8089\" or \"localhost:8089\"",
                                  f->influx_udp);
    }
    config_setting_t *r = g ? config_setting_get_member(g, "record") : NULL;
    static const char *const rk[] = {"path", "format", NULL};
    static const char *const rf[] = {"csv", "candump", NULL};
    int fi;
    if (vd_cfg_known(c, r, "outputs.record", rk) ||
        vd_cfg_path(c, r, "outputs.record", "path", f->record_path, sizeof f->record_path) ||
        vd_cfg_enum(c, r, "outputs.record", "format", 0, rf, &fi))
        return -1;
    f->record_format = (vd_record_format)fi;
    if (f->record_format == VD_REC_CANDUMP && !cfg->dbc)
        return vibid_cfg_fail(
            &c->r, config_setting_get_member(r, "format"), "outputs.record.format",
            "a candump recording encodes the samples with the source's DBC: it needs a CAN source "
            "(socketcan, or a candump replay) with source.dbc; use \"csv\" for this source");
    config_setting_t *s = g ? config_setting_get_member(g, "status") : NULL;
    static const char *const sk[] = {"path", "interval", NULL};
    return vd_cfg_known(c, s, "outputs.status", sk) ||
                   vd_cfg_path(c, s, "outputs.status", "path", f->status_path, sizeof f->status_path) ||
                   vd_cfg_double(c, s, "outputs.status", "interval", 1.0, 0.05, 3600.0, &f->status_interval_s)
               ? -1
               : 0;
}

static void files_print(const vd_config *cfg, FILE *o)
{
    const vd_files_config *f = &cfg->files;
    fprintf(o,
            "  tracks = { path = \"%s\"; flush_interval = %s; fsync = %s; };\n"
            "  influx = {\n    path = \"%s\";\n    udp = \"%s\";\n    measurement = \"%s\";\n"
            "    site = \"%s\";  # \"\" = no site tag\n    stand = \"%s\";  # \"\" = the stand's name\n",
            f->tracks_path, vd_cfg_num(f->flush_interval_s), vd_cfg_yes(f->fsync_on_flush), f->influx_path,
            f->influx_udp, f->influx_measurement, vd_cfg_esc(f->influx_site), vd_cfg_esc(f->influx_stand));
    vd_output_print_nested(cfg, "influx", o);
    fprintf(o, "  };\n  record = { path = \"%s\"; format = \"%s\"; };\n  status = { path = \"%s\"; interval = %s; };\n",
            f->record_path, f->record_format == VD_REC_CSV ? "csv" : "candump", f->status_path,
            vd_cfg_num(f->status_interval_s));
}

const vd_output_ops vd_output_files = {
    .name = "files",
    .parts = files_parts,
    .flags = VD_OUTPUT_STATUS_TEXT | VD_OUTPUT_STATUS_AFTER_DRAIN,
    .groups = files_groups,
    .load = files_load,
    .print = files_print,
    .enabled = files_enabled,
    .check = files_check,
    .open = files_open,
    .sample = files_sample,
    .row = files_row,
    .alarm = files_alarm,
    .status = files_status,
    .flush = files_flush,
    .reopen = files_reopen,
    .counters = files_counters,
    .failed = files_failed,
    .close = files_close,
};
