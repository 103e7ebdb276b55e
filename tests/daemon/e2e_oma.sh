#!/usr/bin/env bash
# End-to-end tests of vibidd's output-only tracking (an `oma` configuration instead of a
# stand; docs/vibidd.md "Output-only tracking"): the vibidd program on vibid-sim's ambient
# capture of a 5-mass chain (examples/oma/chain5.cfg: accelerometers a1..a5 at 200 Hz, white
# and band-limited unmeasured forces; its true modes in its header). Registered for the
# -Werror and the sanitizer builds alike (the oma thread, its ring and the SSI object).
# usage: e2e_oma.sh CASE BUILD_DIR SOURCE_DIR
. "$(dirname "$0")/e2e_common.sh" e2e_oma "$@"

TRUE_F="6.253092 15.962295 24.208118 31.662667 36.472483" # examples/oma/chain5.cfg's header

# max_order 30 (automatic: 94): the 5 modes need 10, and the identifications are quick
# enough for the sanitizer build (at 94 they took 10 s each there)
config() { # config CAPTURE [EXTRA OMA SETTINGS]
    cat > v.cfg <<EOF
oma = { name = "chain5"; sample_rate = 200.0; modes = 5; window = 60.0; every = 20.0; max_order = 30; ${2:-} };
source = {
  kind = "replay"; file = "$1"; time_column = "t";
  channels = (
    { name = "a1"; quantity = "acceleration"; node = 0; unit = "m/s^2"; column = "a1"; },
    { name = "a2"; quantity = "acceleration"; node = 1; unit = "m/s^2"; column = "a2"; },
    { name = "a3"; quantity = "acceleration"; node = 2; unit = "m/s^2"; column = "a3"; },
    { name = "a4"; quantity = "acceleration"; node = 3; unit = "m/s^2"; column = "a4"; },
    { name = "a5"; quantity = "acceleration"; node = 4; unit = "m/s^2"; column = "a5"; }
  );
};
outputs = { tracks = { path = "tracks.csv"; }; status = { path = "status"; interval = 0.2; }; };
EOF
}

# data rows of the tracks (no comments, no header)
rows() { grep -v '^#' "$1" | tail -n +2; }

if [ "$CASE" != modbus ]; then
    "$SIM" -c "$SRC/examples/oma/chain5.cfg" --duration 300 --csv cap.csv -q 2> /dev/null || fail "vibid-sim"
fi

case $CASE in
rows)
    # 60 s windows every 20 s over 300 s: 13 rows (59.995 s .. 299.995 s). Each of the 5 modes
    # found in at least 10 of them (the selection misses a mode in a few percent of short
    # windows), each estimate within 5 of its standard errors of the true frequency (a
    # correct Gaussian estimate is beyond 5 with p = 6e-7), no row flagged E.
    config cap.csv
    "$VIBIDD" -c v.cfg --check > check.out 2> check.err || fail "--check: $(cat check.err)"
    grep -q '^# output-only: SSI-cov' check.out || fail "--check does not describe the tracking"
    timeout 120 "$VIBIDD" -c v.cfg 2> log || fail "vibidd: $(cat log)"
    n=$(rows tracks.csv | wc -l)
    [ "$n" -eq 13 ] || fail "$n rows, expected 13"
    [ "$(status_val oma_identifications)" = 13 ] || fail "oma_identifications=$(status_val oma_identifications)"
    rows tracks.csv | awk -F, '$NF ~ /E/ { exit 1 }' || fail "a row flagged E: $(grep -i modes log)"
    j=0
    for f in $TRUE_F; do
        j=$((j + 1))
        c=$(column "f${j}_hz" tracks.csv)
        [ -n "$c" ] || fail "no column f${j}_hz"
        rows tracks.csv | awk -F, -v c="$c" -v t="$f" -v j="$j" '
            $c != "nan" { n++; z = ($c - t) / $(c + 1); if (z > 5 || z < -5) { print "f" j " = " $c " +- " $(c + 1) ": " z " se off " t; bad = 1 } }
            END { if (n < 10) { print "f" j " found in " n " of the rows"; bad = 1 } exit bad }' > z.out ||
            fail "$(cat z.out)"
    done
    # the printout reads back to the same configuration (the lines naming the file aside;
    # paths relative to the file read come back prefixed with its directory, ./)
    grep -v '^# vibidd effective\|oma.sample_rate in' check.out | sed 's|\./||g' > c1
    cp check.out again.cfg
    "$VIBIDD" -c again.cfg --check > check2.out 2> check.err || fail "--check of the printout: $(cat check.err)"
    grep -v '^# vibidd effective\|oma.sample_rate in' check2.out | sed 's|\./||g' > c2
    cmp -s c1 c2 || fail "the printout does not read back: $(diff c1 c2 | head -4)"
    note "13 rows, every mode within 5 standard errors of the truth, the printout reads back"
    ;;
glitch)
    # A glitch in a2 at sample 30000 (150 s): the outlier test takes it out (a gap for the
    # covariances), the next row is flagged O, the rows go on.
    awk -F, 'BEGIN { OFS = "," } NR == 1 { for (i = 1; i <= NF; i++) if ($i == "a2") c = i } NR == 30002 { $c = $c + 1000.0 } { print }' cap.csv > glitch.csv
    config glitch.csv
    timeout 120 "$VIBIDD" -c v.cfg 2> log || fail "vibidd: $(cat log)"
    [ "$(status_val outlier_samples)" -ge 1 ] || fail "the glitch was not taken out: outlier_samples=$(status_val outlier_samples)"
    idx=$(column index tracks.csv)
    rows tracks.csv | awk -F, -v c="$idx" '$c == 31999 && $NF ~ /O/ { f = 1 } END { exit !f }' ||
        fail "the row after the glitch (index 31999) is not flagged O"
    [ "$(rows tracks.csv | wc -l)" -eq 13 ] || fail "$(rows tracks.csv | wc -l) rows, expected 13"
    note "the glitch taken out, the next row flagged O, 13 rows"
    ;;
thread)
    # A paced replay (a live source's path: the estimation thread hands each identification
    # to the oma thread and never waits for it) at 20x: the thread is named vibidd-oma and
    # runs at SCHED_IDLE (policy 5) or nice 19; a row for every identification, none lost.
    config cap.csv
    timeout 60 "$VIBIDD" -c v.cfg --pace --speed 20 2> log &
    tpid=$!
    find_thread $tpid vibidd-oma
    read -r policy nice < <(thread_sched "$TID")
    [ "$policy" = 5 ] || [ "$nice" = 19 ] || fail "vibidd-oma: policy $policy, nice $nice (expected SCHED_IDLE = 5, or nice 19)"
    wait $tpid || fail "vibidd exit $? ($(cat log))"
    # 15 requests (every 20 s): at most 2 of them while the window fills, every other one
    # identified or skipped because the thread was still busy (SCHED_IDLE gets almost no CPU
    # while the machine is busy, e.g. with other tests); the last one is waited for
    done_=$(status_val oma_identifications) skipped=$(status_val oma_skipped)
    [ "$((done_ + skipped))" -ge 13 ] && [ "$done_" -ge 1 ] ||
        fail "oma_identifications=$done_, oma_skipped=$skipped (13 due)"
    [ "$(rows tracks.csv | wc -l)" = "$done_" ] || fail "$(rows tracks.csv | wc -l) rows, $done_ identifications"
    # a thread starved long enough (the sanitizer build beside other tests) loses samples:
    # counted and logged, never silent
    lost=$(status_val oma_lost_samples)
    [ "$lost" = 0 ] || grep -q "mode tracking fell behind" log || fail "oma_lost_samples=$lost, not logged"
    note "vibidd-oma: policy $policy (5 = SCHED_IDLE), nice $nice; $done_ rows paced, $skipped skipped, $lost samples lost"
    ;;
modbus)
    # Live: vibid-sim serves the chain over Modbus TCP on loopback at 200 Hz (real time),
    # vibidd polls its FIFO and tracks the lowest mode over 10 s windows every 5 s (blocks of
    # 0.5 s: 20 per window) in its oma thread. After 32 s: a row for every identification
    # made (from 10 s on), no sample lost on the way (gaps 0; the thread may lose some when
    # starved: counted and logged), the mode (6.25 Hz, the best excited) within 5 of its
    # standard errors in every row that has it.
    start_sim_modbus -c "$SRC/examples/oma/chain5.cfg" --duration 60
    simpid=$SIMPID port=$PORT
    {
        echo 'oma = { name = "chain5"; sample_rate = 200.0; modes = [6.25]; window = 10.0; every = 5.0; block = 0.5; max_order = 30; };'
        echo "source = { kind = \"modbus\"; url = \"tcp://127.0.0.1:$port\"; mode = \"fifo\"; poll_period = 0.02;"
        echo '  registers = ('
        for j in 1 2 3 4 5; do
            echo "    { name = \"a$j\"; address = $((2 * (j - 1))); type = \"FLOAT32\"; byte_order = \"ABCD\"; }$([ $j -lt 5 ] && echo ,)"
        done
        echo '  );'
        echo '  channels = ('
        for j in 1 2 3 4 5; do
            echo "    { name = \"a$j\"; quantity = \"acceleration\"; node = $((j - 1)); unit = \"m/s^2\"; register = \"a$j\"; }$([ $j -lt 5 ] && echo ,)"
        done
        echo '  ); };'
        echo 'outputs = { tracks = { path = "tracks.csv"; }; status = { path = "status"; interval = 0.2; }; };'
    } > v.cfg
    timeout 60 "$VIBIDD" -c v.cfg 2> log &
    pid=$!
    sleep 32
    kill -TERM $pid
    wait $pid || fail "vibidd exit status $?: $(cat log)"
    kill $simpid 2> /dev/null
    wait $simpid 2> /dev/null
    samples=$(status_val samples)
    [ "$samples" -gt 5000 ] || fail "$samples samples in 32 s at 200 Hz"
    [ "$(status_val gaps)" = 0 ] || fail "gaps on a clean loopback: $(status_val gaps)"
    lost=$(status_val oma_lost_samples)
    [ "$lost" = 0 ] || grep -q "mode tracking fell behind" log || fail "oma_lost_samples=$lost, not logged"
    done_=$(status_val oma_identifications) skipped=$(status_val oma_skipped)
    n=$(rows tracks.csv | wc -l)
    [ "$n" = "$done_" ] && [ "$n" -ge 1 ] || fail "$n rows, oma_identifications=$done_, skipped $skipped"
    c=$(column f1_hz tracks.csv)
    rows tracks.csv | awk -F, -v c="$c" '
        $c != "nan" { f++; z = ($c - 6.253092) / $(c + 1); if (z > 5 || z < -5) { print "f1 = " $c " +- " $(c + 1); bad = 1 } }
        END { if (!f) { print "the mode in no row"; bad = 1 } exit bad }' > z.out || fail "$(cat z.out)"
    note "live Modbus: $samples samples, $n rows ($skipped skipped), f1 within 5 se of 6.253 Hz"
    ;;
errors)
    # configuration errors name file, line and field (exit 2)
    config cap.csv 'channels = ["a1", "a9"];'
    "$VIBIDD" -c v.cfg --check > out 2> err && fail "--check accepted an unknown channel"
    grep -q "v.cfg:1: oma.channels: \[1\]: 'a9' is not a channel of the channel map" err || fail "message: $(cat err)"
    printf 'oma = { sample_rate = 200.0; modes = 5; };\nstand = "x.cfg";\n' | cat - <(sed 1d v.cfg) > both.cfg
    "$VIBIDD" -c both.cfg --check > out 2> err && fail "--check accepted a stand and oma"
    grep -q "give either a stand" err || fail "message: $(cat err)"
    config cap.csv
    printf 'estimator = { method = "iv"; };\n' >> v.cfg
    "$VIBIDD" -c v.cfg --check > out 2> err && fail "--check accepted an estimator group"
    grep -q "estimator: an output-only configuration (oma) has no estimator" err || fail "message: $(cat err)"
    note "unknown channel, stand with oma, estimator with oma: refused with file:line: field"
    ;;
*)
    fail "unknown case $CASE"
    ;;
esac
exit 0
