# influxd_conf.sh: the configuration of a private InfluxDB 1.x server (Debian's influxd) for
# the tests and benchmarks that start one on loopback (tests/daemon/e2e_influx.sh,
# bench/bench_fleet.sh). Sourced; needs python3 for the free port of the RPC service.
#
# influxd_conf FILE DIR HTTP_PORT AUTH [HTTP_LINES...]: writes FILE for a server with its data
# under DIR, its HTTP API on 127.0.0.1:HTTP_PORT, authentication on when AUTH is "true", no
# usage reporting, no self-monitoring database, no continuous queries, only warnings logged;
# HTTP_LINES are further settings of the [http] section (https).
influxd_conf() {
    local file=$1 dir=$2 port=$3 auth=$4 rpc
    shift 4
    rpc=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
    {
        printf '%s\n' "reporting-disabled = true" "bind-address = \"127.0.0.1:$rpc\"" \
            "[meta]" "  dir = \"$dir/meta\"" \
            "[data]" "  dir = \"$dir/data\"" "  wal-dir = \"$dir/wal\"" "  query-log-enabled = false" \
            "[monitor]" "  store-enabled = false" \
            "[continuous_queries]" "  enabled = false" \
            "[logging]" "  level = \"warn\"" \
            "[http]" "  enabled = true" "  bind-address = \"127.0.0.1:$port\"" "  auth-enabled = $auth" \
            "  log-enabled = false"
        if [ $# -gt 0 ]; then printf "  %s\n" "$@"; fi
    } > "$file"
}
