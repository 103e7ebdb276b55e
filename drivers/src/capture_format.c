/* capture_format.c: see vibid_drivers/capture_format.h. */
#include <vibid_drivers/capture_format.h>

#include <stdio.h>
#include <string.h>
#include <strings.h>

static const vibid_capture_format_info formats[] = {
    {VIBID_CAPTURE_CANDUMP, "candump", "", ".log", "candump -l log", true, true},
    {VIBID_CAPTURE_CSV, "csv", "", ".csv", "CSV", true, false},
    {VIBID_CAPTURE_MDF, "mdf", "mf4 mdf4", ".mf4 .mdf", "ASAM MDF4", false, false},
    {VIBID_CAPTURE_TDMS, "tdms", "", ".tdms", "NI TDMS", false, false},
};
#define N_FORMATS (sizeof formats / sizeof formats[0])

const vibid_capture_format_info *vibid_capture_formats(size_t *n)
{
    if (n) *n = N_FORMATS;
    return formats;
}

const vibid_capture_format_info *vibid_capture_format_info_of(vibid_capture_format f)
{
    for (size_t i = 0; i < N_FORMATS; i++)
        if (formats[i].format == f) return &formats[i];
    return NULL;
}

/* word (len bytes) is one of the space-separated words of list, any case */
static bool in_list(const char *list, const char *word, size_t len)
{
    for (const char *p = list; *p;) {
        size_t n = strcspn(p, " ");
        if (n == len && n > 0 && strncasecmp(p, word, n) == 0) return true;
        p += n;
        p += strspn(p, " ");
    }
    return false;
}

vibid_capture_format vibid_capture_format_by_name(const char *name)
{
    if (!name) return VIBID_CAPTURE_UNKNOWN;
    const size_t len = strlen(name);
    for (size_t i = 0; i < N_FORMATS; i++)
        if ((strlen(formats[i].name) == len && strcasecmp(formats[i].name, name) == 0) ||
            in_list(formats[i].aliases, name, len))
            return formats[i].format;
    return VIBID_CAPTURE_UNKNOWN;
}

vibid_capture_format vibid_capture_format_by_extension(const char *path)
{
    if (!path) return VIBID_CAPTURE_UNKNOWN;
    const char *slash = strrchr(path, '/'), *dot = strrchr(path, '.');
    if (!dot || (slash && dot < slash)) return VIBID_CAPTURE_UNKNOWN;
    for (size_t i = 0; i < N_FORMATS; i++)
        if (in_list(formats[i].extensions, dot, strlen(dot))) return formats[i].format;
    return VIBID_CAPTURE_UNKNOWN;
}

vibid_capture_format vibid_capture_format_sniff(const unsigned char *head, size_t len)
{
    if (len >= 8 && memcmp(head, "MDF     ", 8) == 0) return VIBID_CAPTURE_MDF;
    if (len >= 4 && memcmp(head, "TDSm", 4) == 0) return VIBID_CAPTURE_TDMS;
    /* text: skip a UTF-8 byte order mark, blank lines and '#' comments (vibidd's recordings
     * begin with one), then judge the first line */
    size_t i = len >= 3 && memcmp(head, "\xEF\xBB\xBF", 3) == 0 ? 3 : 0;
    while (i < len) {
        if (head[i] == '\n' || head[i] == '\r') {
            i++;
            continue;
        }
        if (head[i] != '#') break;
        while (i < len && head[i] != '\n') i++;
    }
    if (i >= len) return VIBID_CAPTURE_UNKNOWN;
    size_t end = i;
    while (end < len && head[end] != '\n') end++;
    /* candump -l: "(1700000000.000000) can0 123#..." */
    if (head[i] == '(') {
        size_t j = i + 1, digits = 0;
        while (j < end && head[j] >= '0' && head[j] <= '9') j++, digits++;
        if (digits > 0 && j < end && head[j] == '.') return VIBID_CAPTURE_CANDUMP;
    }
    /* CSV: a line of text (no control byte but tab and carriage return) with a comma */
    bool comma = false;
    for (size_t j = i; j < end; j++) {
        if ((head[j] < 0x20 && head[j] != '\t' && head[j] != '\r') || head[j] == 0x7f) return VIBID_CAPTURE_UNKNOWN;
        comma = comma || head[j] == ',';
    }
    return comma ? VIBID_CAPTURE_CSV : VIBID_CAPTURE_UNKNOWN;
}

vibid_capture_format vibid_capture_format_of_file(const char *path)
{
    unsigned char head[512];
    size_t len = 0;
    FILE *f = path ? fopen(path, "rbe") : NULL;
    if (f) {
        len = fread(head, 1, sizeof head, f);
        fclose(f);
    }
    vibid_capture_format by_content = vibid_capture_format_sniff(head, len);
    return by_content != VIBID_CAPTURE_UNKNOWN ? by_content : vibid_capture_format_by_extension(path);
}

char *vibid_capture_format_list(char *buf, size_t cap, bool vibidd_only)
{
    if (!buf || cap == 0) return buf;
    buf[0] = '\0';
    size_t off = 0;
    for (size_t i = 0; i < N_FORMATS; i++) {
        if (vibidd_only && !formats[i].vibidd_replays) continue;
        int n = snprintf(buf + off, cap - off, "%s%s (%s)", off ? ", " : "", formats[i].name, formats[i].extensions);
        if (n < 0 || (size_t)n >= cap - off) break; /* truncated: what fits stays */
        off += (size_t)n;
    }
    return buf;
}
