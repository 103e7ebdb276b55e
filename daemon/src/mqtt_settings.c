/* mqtt_settings.c: outputs.mqtt's settings (output.h, "Settings"): read, checked and printed
 * here, in the core, so that every program reads the same configuration; the client that
 * publishes (libmosquitto) is mqtt.c, outside the core. docs/vibidd.md, "MQTT". */

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "config_read.h"
#include "output.h"

const char *const vd_mqtt_groups[] = {"mqtt", NULL};

bool vd_mqtt_enabled(const vd_config *cfg) { return cfg->mqtt.url[0] != '\0'; }

/* outputs.mqtt.url: mqtt://HOST[:PORT] (1883) or mqtts://HOST[:PORT] (8883); HOST a name, an
 * IPv4 literal or a bracketed IPv6 literal; nothing after the port. 0, or -1 with why. */
static int parse_mqtt_url(vd_config *cfg, char *why, size_t cap)
{
    const char *u = cfg->mqtt.url, *h;
    if (!strncmp(u, "mqtt://", 7)) {
        cfg->mqtt.tls = false;
        cfg->mqtt.port = 1883;
        h = u + 7;
    } else if (!strncmp(u, "mqtts://", 8)) {
        cfg->mqtt.tls = true;
        cfg->mqtt.port = 8883;
        h = u + 8;
    } else {
        snprintf(why, cap, "'%s': expected mqtt://HOST[:PORT] or mqtts://HOST[:PORT] (TLS)", u);
        return -1;
    }
    const char *end, *port = NULL;
    if (*h == '[') {
        end = strchr(h, ']');
        if (!end) {
            snprintf(why, cap, "'%s': unterminated [IPv6] address", u);
            return -1;
        }
        snprintf(cfg->mqtt.host, sizeof cfg->mqtt.host, "%.*s", (int)(end - h - 1), h + 1);
        end++;
    } else {
        end = h + strcspn(h, ":/?#@");
        snprintf(cfg->mqtt.host, sizeof cfg->mqtt.host, "%.*s", (int)(end - h), h);
    }
    if (!cfg->mqtt.host[0]) {
        snprintf(why, cap, "'%s': no host", u);
        return -1;
    }
    if (*end == ':') {
        port = end + 1;
        char *e;
        long p = strtol(port, &e, 10);
        if (!*port || *e || *port == '-' || *port == '+' || p < 1 || p > 65535) {
            snprintf(why, cap, "'%s': port '%s' outside 1..65535 (nothing may follow the port)", u, port);
            return -1;
        }
        cfg->mqtt.port = (int)p;
    } else if (*end) {
        snprintf(why, cap, "'%s': unexpected '%s' after the host (no user, path or query: username and "
                           "password_file are settings of their own)", u, end);
        return -1;
    }
    return 0;
}

/* outputs.mqtt (docs/vibidd.md, "MQTT"): off without the group or with url = ""; the group
 * alone publishes to the broker on loopback. Only what the file says is checked here; the
 * files it names are read by --check and at start-up (mqtt.c). The password comes from a
 * file of its own, never from this configuration: --check prints the configuration (and
 * systemd's ExecStartPre puts that into the journal), configurations are copied and
 * compared, and /etc/vibidd is readable by the service; a password file can be 0600 (or a
 * systemd credential) and rotated on its own. */
int vd_mqtt_load(vd_cfg_ctx *c, const config_setting_t *outputs)
{
    const config_setting_t *q = outputs ? config_setting_get_member(outputs, "mqtt") : NULL;
    vd_config *cfg = c->cfg;
    static const char *const qk[] = {"url",     "site",     "stand",        "topic_prefix", "client_id",
                                     "username", "password_file", "ca_file", "cert_file",   "key_file",
                                     "qos",      "queue_size", "format",     "keepalive",    "protocol",
                                     "drain_timeout", NULL};
    static const char *const fmts[] = {"json", "line", NULL};
    static const char *const protos[] = {"5", "3.1.1", NULL};
    const char *S = "outputs.mqtt";
    if (q && !config_setting_is_group(q))
        return vibid_cfg_fail(&c->r, q, S, "must be a group { url = \"mqtt://127.0.0.1:1883\"; site = \"...\"; }");
    long long v;
    int fi = 0, pi = 0;
    if (vd_cfg_known(c, q, S, qk) ||
        vd_cfg_string(c, q, S, "url", q ? "mqtt://127.0.0.1:1883" : "", cfg->mqtt.url, sizeof cfg->mqtt.url) ||
        vd_cfg_name(c, q, S, "site", "", false, cfg->mqtt.site, sizeof cfg->mqtt.site) ||
        vd_cfg_name(c, q, S, "stand", "", true, cfg->mqtt.stand, sizeof cfg->mqtt.stand) ||
        vd_cfg_string(c, q, S, "topic_prefix", "vibid/v1", cfg->mqtt.prefix, sizeof cfg->mqtt.prefix) ||
        vd_cfg_name(c, q, S, "client_id", "", true, cfg->mqtt.client_id, sizeof cfg->mqtt.client_id) ||
        vd_cfg_string(c, q, S, "username", "", cfg->mqtt.username, sizeof cfg->mqtt.username) ||
        vd_cfg_path(c, q, S, "password_file", cfg->mqtt.password_file, sizeof cfg->mqtt.password_file) ||
        vd_cfg_path(c, q, S, "ca_file", cfg->mqtt.ca_file, sizeof cfg->mqtt.ca_file) ||
        vd_cfg_path(c, q, S, "cert_file", cfg->mqtt.cert_file, sizeof cfg->mqtt.cert_file) ||
        vd_cfg_path(c, q, S, "key_file", cfg->mqtt.key_file, sizeof cfg->mqtt.key_file) ||
        vd_cfg_int(c, q, S, "qos", 1, 1, 2, &v))
        return -1;
    cfg->mqtt.qos = (int)v;
    if (vd_cfg_int(c, q, S, "queue_size", 10000, 1, 10000000, &v))
        return -1;
    cfg->mqtt.queue_size = (unsigned)v;
    if (vd_cfg_enum(c, q, S, "format", 0, fmts, &fi) || vd_cfg_int(c, q, S, "keepalive", 30, 5, 3600, &v))
        return -1;
    cfg->mqtt.format = fi;
    cfg->mqtt.keepalive = (int)v;
    if (vd_cfg_enum(c, q, S, "protocol", 0, protos, &pi) ||
        vd_cfg_double(c, q, S, "drain_timeout", 5.0, 0.0, 60.0, &cfg->mqtt.drain_timeout_s))
        return -1;
    cfg->mqtt.protocol = pi == 0 ? 5 : 4;
    if (!cfg->mqtt.url[0])
        return 0;
    char why[400];
    if (parse_mqtt_url(cfg, why, sizeof why))
        return vibid_cfg_fail(&c->r, config_setting_get_member(q, "url"), "outputs.mqtt.url", "%s", why);
    if (!config_setting_get_member(q, "site"))
        return vibid_cfg_fail(&c->r, q, "outputs.mqtt.site",
                              "missing: the plant or site, the topic level after topic_prefix "
                              "(<topic_prefix>/<site>/<stand>/tracks)");
    /* site and stand are names (get_name): no '/', '+' or '#' can make more topic levels */
    /* topic_prefix: levels separated by '/', each a name */
    for (const char *lv = cfg->mqtt.prefix;;) {
        const char *sl = strchr(lv, '/');
        char level[sizeof cfg->mqtt.prefix], lwhy[512];
        snprintf(level, sizeof level, "%.*s", (int)(sl ? sl - lv : (long)strlen(lv)), lv);
        if (vibid_cfg_name_problem(level, lwhy, sizeof lwhy))
            return vibid_cfg_fail(&c->r, config_setting_get_member(q, "topic_prefix"), "outputs.mqtt.topic_prefix",
                                  "topic levels separated by '/', e.g. \"vibid/v1\"; level %s", lwhy);
        if (!sl)
            break;
        lv = sl + 1;
    }
    if (cfg->mqtt.password_file[0] && !cfg->mqtt.username[0])
        return vibid_cfg_fail(&c->r, config_setting_get_member(q, "password_file"), "outputs.mqtt.password_file",
                              "a password needs a username (outputs.mqtt.username)");
    if (!cfg->mqtt.tls && (cfg->mqtt.ca_file[0] || cfg->mqtt.cert_file[0] || cfg->mqtt.key_file[0]))
        return vibid_cfg_fail(&c->r, q, "outputs.mqtt",
                              "ca_file, cert_file and key_file are for TLS: the url must be mqtts://");
    if (!cfg->mqtt.cert_file[0] != !cfg->mqtt.key_file[0])
        return vibid_cfg_fail(&c->r, q, "outputs.mqtt",
                              "a client certificate needs both cert_file and key_file");
    return 0;
}

void vd_mqtt_print(const vd_config *cfg, FILE *o)
{
    if (!cfg->mqtt.url[0]) {
        fprintf(o, "  mqtt = { url = \"\"; };  # \"\" = off\n");
        return;
    }
    fprintf(o,
            "  mqtt = {\n    url = \"%s\";\n    site = \"%s\";\n    stand = \"%s\";  # \"\" = the stand's name\n"
            "    topic_prefix = \"%s\";\n    client_id = \"%s\";  # \"\" = vibidd-<site>-<stand>\n"
            "    username = \"%s\";\n    password_file = \"%s\";\n    ca_file = \"%s\";\n    cert_file = \"%s\";\n"
            "    key_file = \"%s\";\n    qos = %d;\n    queue_size = %u;\n    format = \"%s\";\n    keepalive = %d;\n"
            "    protocol = \"%s\";\n    drain_timeout = %s;\n  };\n",
            vd_cfg_esc(cfg->mqtt.url), vd_cfg_esc(cfg->mqtt.site), vd_cfg_esc(cfg->mqtt.stand),
            vd_cfg_esc(cfg->mqtt.prefix), vd_cfg_esc(cfg->mqtt.client_id), vd_cfg_esc(cfg->mqtt.username),
            vd_cfg_esc(cfg->mqtt.password_file), vd_cfg_esc(cfg->mqtt.ca_file), vd_cfg_esc(cfg->mqtt.cert_file),
            vd_cfg_esc(cfg->mqtt.key_file), cfg->mqtt.qos, cfg->mqtt.queue_size, cfg->mqtt.format ? "line" : "json",
            cfg->mqtt.keepalive, cfg->mqtt.protocol == 5 ? "5" : "3.1.1", vd_cfg_num(cfg->mqtt.drain_timeout_s));
}
