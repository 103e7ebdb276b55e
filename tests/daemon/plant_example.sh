#!/usr/bin/env bash
# daemon.plant_example (issue 14): the example plant of docs/vibidd.md ("Many stands on one
# host"), daemon/examples/plant/, checked as far as the test machine has the servers.
#  1. The files agree with each other and with the template unit's rules: each standN.cfg
#     (N = the instance, vibidd@standN) writes only under /var/lib/vibidd/standN and
#     /run/vibidd/standN, publishes as MQTT stand and user standN with the password the
#     unit's credential puts in /run/credentials/vibidd@standN.service/, serves Prometheus
#     on 127.0.0.1:(18813 + N); prometheus.yml scrapes exactly those addresses, labelled
#     with the stand; telegraf.conf is valid TOML (python3's tomllib), its topics match the
#     stands' topics and its data formats the stands' outputs.mqtt.format. Telegraf itself
#     is not run (not a Debian package; not on the test machines).
#  2. `promtool check config prometheus.yml` passes (Debian package prometheus).
#  3. The broker as configured: Debian's mosquitto with the example's mosquitto.conf (only
#     the port and the paths of the password file and ACL changed) and its mosquitto.acl
#     unchanged, users stand1, stand2, telegraf made with mosquitto_passwd. Both stands'
#     configurations (inputs next to them as in /etc/vibidd; changed only: broker port,
#     password file path, Prometheus port 0, realtime_priority 0 and lock_memory false,
#     which the unit's rlimits grant but a test user may lack) pass `vibidd --check` and
#     replay a candump capture (vd_gen_capture, the example's DBC) into the broker; a
#     subscriber with Telegraf's credentials receives every track row of both stands as
#     line protocol (seq 1..N, index and c1, d, c2 equal to the tracks CSV); the ACL refuses
#     stand1 publishing as stand2 (MQTT 5: mosquitto_pub reports it, the broker logs
#     "Denied PUBLISH", nothing arrives) and anonymous clients.
# Exit 77 (skipped, said loudly) when mosquitto or promtool is missing, after the checks that
# could run have passed; a check that did not run is never reported as passed.
# usage: plant_example.sh plant BUILD_DIR SOURCE_DIR
. "$(dirname "$0")/e2e_common.sh" plant_example "$@"
set -eo pipefail # (-u from e2e_common.sh)
EX=$SRC/daemon/examples/plant
GEN=$BUILD/tests/daemon/vd_gen_capture
PY=/usr/bin/python3
[ -x "$PY" ] || PY=$(command -v python3) || fail "python3 not found"
[ "$CASE" = plant ] || fail "unknown case '$CASE' (the only case is 'plant')"
for f in stand1.cfg stand2.cfg mosquitto.conf mosquitto.acl prometheus.yml telegraf.conf vibid_alerts.yml vibid_alerts_test.yml; do
    [ -f "$EX/$f" ] || fail "daemon/examples/plant/$f missing"
done
NOT_RUN=()

PIDS=()
cleanup() {
    exec 2> /dev/null # (bash's job notices of the processes killed here)
    for p in "${PIDS[@]}"; do kill -9 "$p" || true; done # (some may have ended: not an error under set -e)
    wait || true
    rm -rf "$W"
}
trap cleanup EXIT

# ---- 1. the files against each other ----------------------------------------------------
out=$("$PY" - "$EX" 2>&1 << 'PYEOF'
import glob, os, re, sys, tomllib
ex = sys.argv[1]
def val(text, key, where):
    m = re.findall(r'^\s*' + re.escape(key) + r'\s*=\s*"([^"]*)"\s*;', text, re.M)
    if len(m) != 1:
        sys.exit(f"{where}: {len(m)} settings '{key} = \"...\";' (one expected)")
    return m[0]
def block(text, name, where):
    m = re.search(r'^\s*' + name + r'\s*=\s*\{(.*?)\}\s*;', text, re.M | re.S)
    if not m:
        sys.exit(f"{where}: no group {name}")
    return m.group(1)
stands = {}
for path in sorted(glob.glob(os.path.join(ex, "stand*.cfg"))):
    inst = os.path.basename(path)[:-4]
    n = int(inst[5:])
    t = re.sub(r"#.*", "", open(path).read())
    where = f"daemon/examples/plant/{inst}.cfg"
    tracks = val(block(t, "tracks", where), "path", where + ": outputs.tracks")
    status = val(block(t, "status", where), "path", where + ": outputs.status")
    listen = val(block(t, "prometheus", where), "listen", where + ": outputs.prometheus")
    mq = t[t.index("mqtt = {"):]
    mq = mq[:mq.index("};")]
    for p, d in ((tracks, f"/var/lib/vibidd/{inst}/"), (status, f"/run/vibidd/{inst}/")):
        if not p.startswith(d):
            sys.exit(f"{where}: output {p} not under {d} (the template's StateDirectory/RuntimeDirectory for vibidd@{inst})")
    if listen != f"127.0.0.1:{18813 + n}":
        sys.exit(f"{where}: prometheus listen {listen}, the scheme says 127.0.0.1:{18813 + n}")
    for key, want in (("stand", inst), ("username", inst), ("site", "plant1"), ("format", "line"),
                      ("password_file", f"/run/credentials/vibidd@{inst}.service/mqtt.password")):
        got = val(mq, key, where + ": outputs.mqtt")
        if got != want:
            sys.exit(f"{where}: outputs.mqtt.{key} = '{got}', '{want}' expected")
    stands[inst] = listen
if sorted(stands) != ["stand1", "stand2"]:
    sys.exit(f"stand configurations: {sorted(stands)}")
# prometheus.yml: the same targets, each labelled with its stand (a plain reading of the
# example's layout: one target per static_configs entry, labels on the next line)
targets = {}
cur = None
for line in open(os.path.join(ex, "prometheus.yml")):
    m = re.match(r"\s*- targets: \['([^']+)'\]", line)
    if m:
        cur = m.group(1)
        continue
    m = re.match(r"\s*labels: \{ site: (\w+), stand: (\w+) \}", line)
    if m and cur:
        targets[cur] = m.group(2)
        cur = None
want = {v: k for k, v in stands.items()}
if targets != want:
    sys.exit(f"prometheus.yml targets {targets}, the stands listen on {want}")
# telegraf.conf: TOML; its topics cover the stands' tracks, alarms and status topics
tc = tomllib.load(open(os.path.join(ex, "telegraf.conf"), "rb"))
inputs = tc["inputs"]["mqtt_consumer"]
def matches(pattern, topic):
    p, t = pattern.split("/"), topic.split("/")
    return len(p) == len(t) and all(a == "+" or a == b for a, b in zip(p, t))
fmt = {}
for inst in stands:
    for kind in ("tracks", "alarms/c1", "status"):
        topic = f"vibid/v1/plant1/{inst}/{kind}"
        hit = [i for i in inputs if any(matches(p, topic) for p in i["topics"])]
        if len(hit) != 1:
            sys.exit(f"telegraf.conf: {len(hit)} inputs subscribe to {topic} (one expected)")
        i = hit[0]
        fmt[kind] = i["data_format"]
        if i.get("topic_tag", "topic") != "" or i["qos"] != 1 or not i["persistent_session"]:
            sys.exit(f"telegraf.conf: the input of {topic}: topic_tag, qos or persistent_session")
        if kind != "status":
            tp = [x for x in i.get("topic_parsing", []) if matches(x["topic"], topic)]
            if len(tp) != 1 or tp[0]["tags"].split("/")[2:4] != ["site", "stand"]:
                sys.exit(f"telegraf.conf: topic_parsing of {topic}: {tp}")
if fmt != {"tracks": "influx", "alarms/c1": "influx", "status": "json"}:
    sys.exit(f"telegraf.conf data formats {fmt}: tracks and alarms 'influx' (the stands' format = \"line\"), status 'json'")
print(f"the files agree: stands {', '.join(f'{k} on {v}' for k, v in sorted(stands.items()))}; "
      f"prometheus.yml scrapes those; telegraf.conf (TOML) takes tracks and alarms as line protocol, status as JSON")
PYEOF
) || fail "daemon/examples/plant: $out"
note "$out"

# ---- 2. promtool ----------------------------------------------------------------------------
if command -v promtool > /dev/null; then
    promtool check config "$EX/prometheus.yml" > promtool.out 2>&1 || fail "promtool check config daemon/examples/plant/prometheus.yml: $(cat promtool.out)"
    note "promtool check config daemon/examples/plant/prometheus.yml: $(grep -o 'SUCCESS.*' promtool.out | tr '\n' ' ')"
    # the alert rules (issue 32, item 6): valid, each alert firing on the series that should
    # raise it and not on the others (promtool's rule unit tests), and every vibid_* metric they
    # name one that vibidd exports (daemon/src/metrics.c)
    (cd "$EX" && promtool test rules vibid_alerts_test.yml) > promtest.out 2>&1 ||
        fail "promtool test rules daemon/examples/plant/vibid_alerts_test.yml: $(cat promtest.out)"
    for m in $(grep 'expr:' "$EX/vibid_alerts.yml" | grep -o 'vibid_[a-z_]*' | sort -u); do
        grep -q "\"$m\"" "$SRC/daemon/src/metrics.c" || fail "vibid_alerts.yml names $m, which vibidd does not export"
    done
    note "promtool test rules vibid_alerts_test.yml: $(grep -c 'alertname:' "$EX/vibid_alerts_test.yml") alert checks passed"
else
    echo "NOT RUN [$CASE]: promtool not installed (Debian package prometheus): prometheus.yml NOT checked"
    NOT_RUN+=(promtool)
fi

# ---- 3. broker, stands, subscriber ---------------------------------------------------------
if ! command -v mosquitto > /dev/null && [ ! -x /usr/sbin/mosquitto ]; then
    echo "NOT RUN [$CASE]: the mosquitto broker is not installed (Debian packages mosquitto and mosquitto-clients):"
    echo "NOT RUN [$CASE]: the example's broker configuration, ACL and stand configurations were NOT run"
    NOT_RUN+=(mosquitto)
else
    MOSQUITTO=$(command -v mosquitto || echo /usr/sbin/mosquitto)
    command -v mosquitto_sub > /dev/null || fail "mosquitto_sub not found (Debian package mosquitto-clients)"
    PORT=$(free_port)
    mosquitto_passwd -c -b passwd stand1 pw-stand1 2> /dev/null || fail "mosquitto_passwd"
    mosquitto_passwd -b passwd stand2 pw-stand2 2> /dev/null || fail "mosquitto_passwd"
    mosquitto_passwd -b passwd telegraf pw-telegraf 2> /dev/null || fail "mosquitto_passwd"
    cp "$EX/mosquitto.acl" acl
    sed -e "s|^listener 1883 127.0.0.1$|listener $PORT 127.0.0.1|" -e "s|^password_file /etc/mosquitto/vibid.passwd$|password_file $W/passwd|" \
        -e "s|^acl_file /etc/mosquitto/vibid.acl$|acl_file $W/acl|" "$EX/mosquitto.conf" > b.conf
    for want in "listener $PORT 127.0.0.1" "password_file $W/passwd" "acl_file $W/acl" "allow_anonymous false"; do
        grep -qx "$want" b.conf || fail "daemon/examples/plant/mosquitto.conf changed: '$want' not in the adapted copy (adapt this test)"
    done
    # what Debian's mosquitto.conf adds around conf.d (the log; root keeps its user), and every
    # log type (a denied PUBLISH is a debug line)
    { echo "log_dest file $W/broker.log"; echo "log_type all"; [ "$(id -u)" = 0 ] && echo "user root"; } >> b.conf
    "$MOSQUITTO" -c b.conf > broker.out 2>&1 &
    BPID=$!
    PIDS+=("$BPID")
    for _ in $(seq 50); do
        "$PY" -c "import socket; socket.create_connection(('127.0.0.1', $PORT), timeout=0.2)" 2> /dev/null && break
        kill -0 $BPID 2> /dev/null || fail "mosquitto exited with the example's configuration: $(cat broker.out; tail -5 broker.log 2> /dev/null)"
        sleep 0.1
    done
    # Telegraf's view: its user, everything under vibid/
    stdbuf -oL mosquitto_sub -h 127.0.0.1 -p "$PORT" -u telegraf -P pw-telegraf -v -q 1 -t 'vibid/#' > sub.out 2> sub.err &
    PIDS+=("$!")
    # ready once it sees a stand's message (telegraf may only read: a stand publishes the probe)
    for _ in $(seq 50); do
        mosquitto_pub -h 127.0.0.1 -p "$PORT" -u stand1 -P pw-stand1 -q 1 -t vibid/v1/plant1/stand1/probe -m ready 2> /dev/null || true
        grep -q '^vibid/v1/plant1/stand1/probe ready' sub.out && break
        sleep 0.1
    done
    grep -q '^vibid/v1/plant1/stand1/probe ready' sub.out || fail "the telegraf user's subscriber got no message from stand1 within 5 s: $(cat sub.err; tail -5 broker.log)"

    "$GEN" "$SRC/examples/stands/paper_example1.cfg" --duration 10 --noise 0.001 --seed 41 --candump cap.log 2> gen.err || fail "vd_gen_capture: $(cat gen.err)"
    for s in stand1 stand2; do
        mkdir -p "etc/$s"
        cp "$SRC/examples/stands/paper_example1.cfg" "$SRC/tests/daemon/data/example1.dbc" "etc/$s/"
        echo "pw-$s" > "etc/$s/mqtt.password"
        chmod 600 "etc/$s/mqtt.password"
        sed -e "s|url = \"mqtt://127.0.0.1:1883\";|url = \"mqtt://127.0.0.1:$PORT\";|" \
            -e "s|password_file = \"/run/credentials/vibidd@$s.service/mqtt.password\";|password_file = \"mqtt.password\";|" \
            -e "s|listen = \"127.0.0.1:188[0-9][0-9]\";|listen = \"127.0.0.1:0\";|" \
            -e 's|realtime_priority = 50;|realtime_priority = 0;|' -e 's|lock_memory = true;|lock_memory = false;|' \
            "$EX/$s.cfg" > "etc/$s/$s.cfg"
        for want in "url = \"mqtt://127.0.0.1:$PORT\";" 'password_file = "mqtt.password";' 'listen = "127.0.0.1:0";' \
                    'realtime_priority = 0;' 'lock_memory = false;'; do
            grep -qF "$want" "etc/$s/$s.cfg" || fail "daemon/examples/plant/$s.cfg changed: '$want' not in the adapted copy (adapt this test)"
        done
        [ "$(diff "$EX/$s.cfg" "etc/$s/$s.cfg" | grep -c '^>')" = 5 ] || fail "$s.cfg: more than the 5 intended lines changed: $(diff "$EX/$s.cfg" "etc/$s/$s.cfg")"
        out="$W/out/$s"
        mkdir -p "$out"
        timeout 10 "$VIBIDD" -c "etc/$s/$s.cfg" --check --tracks "$out/tracks.csv" --status "$out/status" > "$s.check" 2> "$s.check.err" ||
            fail "vibidd --check of daemon/examples/plant/$s.cfg (adapted copy etc/$s/$s.cfg): $(cat "$s.check.err")"
        timeout 60 "$VIBIDD" -c "etc/$s/$s.cfg" --replay cap.log --tracks "$out/tracks.csv" --status "$out/status" 2> "$s.log" ||
            fail "vibidd -c $s.cfg --replay: exit $?: $(tail -5 "$s.log")"
        ! grep -Eq '^vibidd: (error|warning):' "$s.log" || fail "$s: $(grep -E '^vibidd: (error|warning):' "$s.log" | head -3)"
        grep -q "mqtt: connected to mqtt://127.0.0.1:$PORT as 'vibidd-plant1-$s'" "$s.log" || fail "$s: no connection as vibidd-plant1-$s: $(grep mqtt "$s.log")"
        grep -q 'mqtt: every message acknowledged by the broker' "$s.log" || fail "$s: queue not drained: $(grep mqtt "$s.log")"
        [ "$(sed -n 's/^mqtt_refused=//p' "$out/status")" = 0 ] || fail "$s: the broker refused $(sed -n 's/^mqtt_refused=//p' "$out/status") of its own messages (ACL)"
    done
    note "stand1.cfg and stand2.cfg: --check passes, a replay into the example broker as users stand1 and stand2: every message acknowledged, none refused"
    # the ACL: stand1 cannot write as stand2 (MQTT 5 reports the refusal), nobody anonymous
    mosquitto_pub -h 127.0.0.1 -p "$PORT" -V mqttv5 -u stand1 -P pw-stand1 -q 1 -t vibid/v1/plant1/stand2/tracks -m forged > forge.out 2>&1 || true
    grep -qi 'not authori[sz]ed' forge.out || fail "stand1 publishing on stand2's topic: mosquitto_pub said '$(cat forge.out)' (a refusal expected)"
    grep -q 'Denied PUBLISH' broker.log || fail "the broker logged no 'Denied PUBLISH'"
    if mosquitto_pub -h 127.0.0.1 -p "$PORT" -q 1 -t vibid/v1/plant1/stand1/tracks -m anon > anon.out 2>&1; then
        fail "an anonymous client could publish"
    fi
    sleep 0.5
    ! grep -q ' forged$\| anon$' sub.out || fail "a refused message reached the subscriber: $(grep ' forged$\| anon$' sub.out)"
    note "ACL: stand1 on stand2's topic refused ($(grep -io 'not authori[sz]ed' forge.out | head -1)), anonymous refused ($(head -1 anon.out))"
    for _ in $(seq 50); do
        [ "$(grep -c '/status {.*"state":"stopped"' sub.out || true)" -ge 2 ] && break
        sleep 0.1
    done
    res=$("$PY" - sub.out "$W/out" 2>&1 << 'PYEOF'
import csv, re, sys
sub, out = sys.argv[1], sys.argv[2]
lines = {"stand1": [], "stand2": []}
for l in open(sub):
    t, _, p = l.rstrip("\n").partition(" ")
    m = re.fullmatch(r"vibid/v1/plant1/(stand[12])/tracks", t)
    if m:
        lines[m.group(1)].append(p)
def parse(line):
    # vibid,stand=NAME field=value,... TIMESTAMP (no spaces or commas inside these values)
    head, fields, ts = line.split(" ")
    meas, _, tags = head.partition(",")
    f = {}
    for kv in fields.split(","):
        k, _, v = kv.partition("=")
        f[k] = int(v[:-1]) if v.endswith("i") else (v.strip('"') if v.startswith('"') else float(v))
    return meas, dict(t.split("=") for t in tags.split(",")), f, int(ts)
summary = []
for s, ls in lines.items():
    rows = list(csv.DictReader(l for l in open(f"{out}/{s}/tracks.csv") if not l.startswith("#")))
    msgs = [parse(l) for l in ls]
    by = {}
    for meas, tags, f, ts in msgs:
        # a refinement's row (flag W) is a series of its own: tag estimate=refined
        refined = "W" in f["flags"].strip('"')
        assert meas == "vibid" and tags == ({"estimate": "refined", "stand": s} if refined else {"stand": s}), (
            s, meas, tags, f["flags"])
        by.setdefault(f["seq"], (f, ts))
    if sorted(by) != list(range(1, len(rows) + 1)) or not rows:
        sys.exit(f"{s}: seq {sorted(by)[:5]}..{len(by)} for {len(rows)} rows")
    for k, r in enumerate(rows, 1):
        f, ts = by[k]
        assert f["index"] == int(r["index"]), (s, k, f["index"], r["index"])
        assert ts == round(float(r["time_s"]) * 1e6) * 1000, (s, k, ts, r["time_s"])
        for p in ("c1", "d", "c2", "c1_se", "d_se", "c2_se"):
            if r[p] in ("nan", "inf", "-inf"):  # line protocol has no such numbers: left out
                assert p not in f, (s, k, p, f[p], r[p])
            else:
                assert f[p] == float(r[p]), (s, k, p, f[p], r[p])
        assert f["dropped_before"] == 0, (s, k)
    summary.append(f"{s} {len(rows)} rows = {len(msgs)} messages")
print("as Telegraf's user: every track row as line protocol (seq 1..N, index, time, c1, d, c2 and their standard errors equal to the tracks CSV): " + ", ".join(summary))
PYEOF
) || fail "the stands' line protocol against their tracks CSV: $res"
    note "$res"
fi

if [ ${#NOT_RUN[@]} -gt 0 ]; then
    echo "SKIPPED [$CASE]: the checks above passed, but NOT run for lack of: ${NOT_RUN[*]}"
    exit 77
fi
note "PASS: daemon/examples/plant: files consistent, promtool accepts prometheus.yml, broker configuration and ACL as shipped, both stands' configurations run"
exit 0
