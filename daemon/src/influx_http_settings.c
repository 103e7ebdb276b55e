/* influx_http_settings.c: outputs.influx.http's settings (output.h, "Settings"): read,
 * checked and printed here, in the core, so that every program reads the same
 * configuration; the client that writes (libcurl) is influx_http.c, outside the core. The
 * group lies inside outputs.influx (the file outputs' group, writers.c). docs/vibidd.md,
 * "InfluxDB over HTTP". */

#include <stdio.h>
#include <string.h>

#include "config_read.h"
#include "output.h"

const char *const vd_influx_http_groups[] = {"influx.http", NULL};

bool vd_influx_http_enabled(const vd_config *cfg) { return cfg->influx_http.url[0] != '\0'; }

/* outputs.influx.http (docs/vibidd.md, "InfluxDB over HTTP"): off without the group or with
 * url = ""; the group alone writes to database "vibid" on loopback (InfluxDB 1.x). Secrets
 * come from files of their own, for the reasons given at vd_mqtt_load (mqtt_settings.c). */
int vd_influx_http_load(vd_cfg_ctx *c, const config_setting_t *outputs)
{
    const config_setting_t *i = outputs ? config_setting_get_member(outputs, "influx") : NULL;
    const config_setting_t *h = i ? config_setting_get_member(i, "http") : NULL;
    vd_config *cfg = c->cfg;
    static const char *const hk[] = {"url",      "api",           "database",   "retention_policy", "org",
                                     "bucket",   "username",      "password_file", "token_file",    "ca_file",
                                     "batch_size", "batch_interval", "buffer_size", "timeout",       "drain_timeout",
                                     NULL};
    static const char *const apis[] = {"v1", "v2", NULL};
    const char *S = "outputs.influx.http";
    if (h && !config_setting_is_group(h))
        return vibid_cfg_fail(&c->r, h, S, "must be a group { url = \"http://127.0.0.1:8086\"; database = \"vibid\"; }");
    long long v;
    int api = 0;
    if (vd_cfg_known(c, h, S, hk) ||
        vd_cfg_string(c, h, S, "url", h ? "http://127.0.0.1:8086" : "", cfg->influx_http.url, sizeof cfg->influx_http.url) ||
        vd_cfg_enum(c, h, S, "api", 0, apis, &api) ||
        vd_cfg_string(c, h, S, "database", "vibid", cfg->influx_http.database, sizeof cfg->influx_http.database) ||
        vd_cfg_string(c, h, S, "retention_policy", "", cfg->influx_http.rp, sizeof cfg->influx_http.rp) ||
        vd_cfg_string(c, h, S, "org", "", cfg->influx_http.org, sizeof cfg->influx_http.org) ||
        vd_cfg_string(c, h, S, "bucket", "", cfg->influx_http.bucket, sizeof cfg->influx_http.bucket) ||
        vd_cfg_string(c, h, S, "username", "", cfg->influx_http.username, sizeof cfg->influx_http.username) ||
        vd_cfg_path(c, h, S, "password_file", cfg->influx_http.password_file, sizeof cfg->influx_http.password_file) ||
        vd_cfg_path(c, h, S, "token_file", cfg->influx_http.token_file, sizeof cfg->influx_http.token_file) ||
        vd_cfg_path(c, h, S, "ca_file", cfg->influx_http.ca_file, sizeof cfg->influx_http.ca_file))
        return -1;
    cfg->influx_http.api = api + 1;
    /* 5000 lines: InfluxDB's own advice for a batch; a stand's line is ~0.3-2 KB */
    if (vd_cfg_int(c, h, S, "batch_size", 5000, 1, 100000, &v))
        return -1;
    cfg->influx_http.batch_lines = (unsigned)v;
    if (vd_cfg_double(c, h, S, "batch_interval", 1.0, 0.01, 60.0, &cfg->influx_http.batch_interval_s))
        return -1;
    /* MiB; 16 MiB holds ~40 000 rows of a 6-parameter stand: ~7 min at 100 rows/s */
    if (vd_cfg_int(c, h, S, "buffer_size", 16, 1, 4096, &v))
        return -1;
    cfg->influx_http.buffer_mib = (unsigned)v;
    if (vd_cfg_double(c, h, S, "timeout", 10.0, 0.1, 300.0, &cfg->influx_http.timeout_s) ||
        vd_cfg_double(c, h, S, "drain_timeout", 10.0, 0.0, 300.0, &cfg->influx_http.drain_timeout_s))
        return -1;
    if (!cfg->influx_http.url[0])
        return 0;
    const char *u = cfg->influx_http.url;
    const char *host = !strncmp(u, "http://", 7) ? u + 7 : !strncmp(u, "https://", 8) ? u + 8 : NULL;
    if (!host || !*host || *host == '/' || *host == ':' || strpbrk(u, "?#@ \t"))
        return vibid_cfg_fail(&c->r, config_setting_get_member(h, "url"), "outputs.influx.http.url",
                              "'%s': expected http://HOST[:PORT][/PATH] or https://HOST[:PORT][/PATH] (the "
                              "server's base URL, without a query, fragment or credentials)",
                              u);
    size_t ul = strlen(cfg->influx_http.url);
    while (ul && cfg->influx_http.url[ul - 1] == '/')
        cfg->influx_http.url[--ul] = '\0'; /* "/write" is appended */
    bool tls = !strncmp(u, "https://", 8);
    if (cfg->influx_http.ca_file[0] && !tls)
        return vibid_cfg_fail(&c->r, config_setting_get_member(h, "ca_file"), "outputs.influx.http.ca_file",
                              "is for TLS: the url must be https://");
    if (cfg->influx_http.api == 1) {
        if (!cfg->influx_http.database[0])
            return vibid_cfg_fail(&c->r, config_setting_get_member(h, "database"), "outputs.influx.http.database",
                                  "must not be empty (api \"v1\" writes into a database)");
        if (cfg->influx_http.org[0] || cfg->influx_http.bucket[0] || cfg->influx_http.token_file[0])
            return vibid_cfg_fail(&c->r, h, S,
                                  "org, bucket and token_file belong to api = \"v2\" (InfluxDB 2.x); api \"v1\" "
                                  "uses database, retention_policy, username and password_file");
        if (cfg->influx_http.password_file[0] && !cfg->influx_http.username[0])
            return vibid_cfg_fail(&c->r, config_setting_get_member(h, "password_file"),
                                  "outputs.influx.http.password_file", "a password needs a username (outputs.influx.http.username)");
        if (cfg->influx_http.username[0] && !cfg->influx_http.password_file[0])
            return vibid_cfg_fail(&c->r, config_setting_get_member(h, "username"), "outputs.influx.http.username",
                                  "a username needs its password_file");
    } else {
        if (!cfg->influx_http.org[0] || !cfg->influx_http.bucket[0] || !cfg->influx_http.token_file[0])
            return vibid_cfg_fail(&c->r, h, S,
                                  "api = \"v2\" needs org, bucket and token_file (an InfluxDB 2.x API token with "
                                  "write permission on the bucket)");
        if (config_setting_get_member(h, "database") || cfg->influx_http.rp[0] || cfg->influx_http.username[0] ||
            cfg->influx_http.password_file[0])
            return vibid_cfg_fail(&c->r, h, S,
                                  "database, retention_policy, username and password_file belong to api = "
                                  "\"v1\"; api \"v2\" uses org, bucket and token_file");
        cfg->influx_http.database[0] = '\0';
    }
    return 0;
}

/* Printed inside outputs.influx (vd_output_print_nested). */
void vd_influx_http_print(const vd_config *cfg, FILE *o)
{
    const vd_influx_http_config *h = &cfg->influx_http;
    fprintf(o,
            "    http = {\n      url = \"%s\";  # \"\" = off\n"
            "      api = \"v%d\";\n      database = \"%s\";\n      retention_policy = \"%s\";\n      org = \"%s\";\n"
            "      bucket = \"%s\";\n      username = \"%s\";\n      password_file = \"%s\";\n      token_file = \"%s\";\n"
            "      ca_file = \"%s\";\n      batch_size = %u;\n      batch_interval = %s;\n      buffer_size = %u;  # MiB\n"
            "      timeout = %s;\n      drain_timeout = %s;\n    };\n",
            vd_cfg_esc(h->url), h->api, vd_cfg_esc(h->database), vd_cfg_esc(h->rp), vd_cfg_esc(h->org),
            vd_cfg_esc(h->bucket), vd_cfg_esc(h->username), vd_cfg_esc(h->password_file), vd_cfg_esc(h->token_file),
            vd_cfg_esc(h->ca_file), h->batch_lines, vd_cfg_num(h->batch_interval_s), h->buffer_mib,
            vd_cfg_num(h->timeout_s), vd_cfg_num(h->drain_timeout_s));
}
