#!/usr/bin/env bash
# End-to-end tests of vibidd's state-space estimator (method "ekf": extended Kalman filter on
# the stand's physical model, chosen by `auto` for a stand with a node without sensor or with
# `disturbances`), on captures written by vibid-sim. The stands are those of
# tests/ident/test_ekf.c.
# usage: e2e_ekf.sh CASE BUILD_DIR SOURCE_DIR
. "$(dirname "$0")/e2e_common.sh" e2e_ekf "$@"

# base_stand: the `base_partial_stand` of tests/ident/test_ekf.c (2 DOF on a smooth moving
# base, band-limited random base motion; m1 measured (x1), m2 without sensor, the base
# measured (s); c1, d1, c2, d2 unknown with start values 20-25 % off), with 1 % sensor noise
# on x1 and s (snr_db 40 = std 1 % of the RMS) and c2 losing 10 % at t = 30 s (a crack).
base_stand() {
    cat > stand.cfg <<'EOF'
stand = { name = "base2-partial"; sample_rate = 1000.0;
  nodes = ( { name = "m1"; mass = 1.5; measure = { displacement = "x1"; }; },
            { name = "m2"; mass = 3.0; } );
  base = { measure = { displacement = "s"; }; };
  elements = ( { name = "c1"; kind = "spring"; between = ["m1", "m2"]; unknown = true; value = 7.2e4; true_value = 6.0e4; },
               { name = "d1"; kind = "damper"; between = ["m1", "m2"]; unknown = true; value = 12.0; true_value = 15.0; },
               { name = "c2"; kind = "spring"; between = ["m2", "base"]; unknown = true; value = 1.0e5; true_value = 1.2e5; },
               { name = "d2"; kind = "damper"; between = ["m2", "base"]; unknown = true; value = 37.5; true_value = 30.0; } ); };
simulation = { seed = 7;
  excitation = ( { target = "base"; kind = "noise"; amplitude = 1.0e-4; f_high = 150.0; } );
  noise = ( { channel = "x1"; snr_db = 40.0; }, { channel = "s"; snr_db = 40.0; } );
  changes = ( { parameter = "c2"; at = 30.0; factor = 0.9; } ); };
EOF
}

# base_config OUT SECTIONS: vibidd configuration for base_stand replaying cap.csv
base_config() {
    cat > "$1" <<EOF
stand = "stand.cfg";
source = {
  kind = "replay"; file = "cap.csv"; time_column = "t";
  channels = (
    { name = "x1"; quantity = "displacement"; node = 0; unit = "m"; column = "x1"; },
    { name = "s";  quantity = "base_displacement"; node = 0; unit = "m"; column = "s"; }
  );
};
$2
outputs = { tracks = { path = "tracks.csv"; }; influx = { path = "tracks.influx"; }; };
EOF
}

# The paper's example 3 <-> the stand with the same sampled poles (m = 1 kg), exactly as
# ex3_paper_to_stand / ex3_stand_to_paper in tests/ident/test_ekf.c.
# paper_to_stand H C DP -> "k d"
paper_to_stand() {
    awk -v h="$1" -v c="$2" -v dp="$3" 'function acos(x) { return atan2(sqrt(1 - x * x), x) }
        BEGIN { a1 = 1 + dp; a0 = dp - h * c; r = sqrt(a0); phi = acos(a1 / (2 * r)); lr = log(r)
                printf "%.17g %.17g\n", (lr * lr + phi * phi) / (h * h), -2 * lr / h }'
}
# awk function: stand (k, d) -> paper (C, DP) for h = H (an overdamped estimate: cosh)
S2P_AWK='function s2p(k, d,   s, wd2, cs, q, a1, a0) { s = -0.5 * d; wd2 = k - 0.25 * d * d
    if (wd2 >= 0) cs = cos(sqrt(wd2) * H); else { q = sqrt(-wd2) * H; cs = (exp(q) + exp(-q)) / 2 }
    a1 = 2 * exp(s * H) * cs; a0 = exp(2 * s * H); DP = a1 - 1; C = (DP - a0) / H }'

case $CASE in
check)
    # --check states that the state-space estimator runs and why; a regression estimator
    # asked for explicitly is refused, naming the node without sensor.
    base_stand
    "$SIM" -c stand.cfg --duration 2 --csv cap.csv -q 2>/dev/null || fail "vibid-sim"
    base_config v.cfg ""
    "$VIBIDD" -c v.cfg --check > check.out 2> check.err || fail "--check: $(cat check.err)"
    grep -q 'method = "auto";' check.out || fail "--check does not print method = \"auto\""
    grep -qF "# estimator: extended Kalman filter on the stand's states and physical parameters (automatic: the stand is not fully measured (node 'm2': acceleration needed by 'm2' is not measured" check.out ||
        fail "--check does not say that the ekf runs because m2 has no sensor: $(grep '^# estimator' check.out)"
    for what in '^# discretization: exact over each sample' \
                '^# identifiability: the measured channels determine all 4 unknowns' \
                "^# start: the stand's nominal values"; do
        grep -q "$what" check.out || fail "--check lacks '$what': $(grep '^# ' check.out)"
    done
    # the printout is itself a valid configuration that chooses the same again
    cp check.out again.cfg
    "$VIBIDD" -c again.cfg --check > check2.out 2>&1 || fail "printout does not read back: $(cat check2.out)"
    diff <(grep '^# [a-z -]*:' check.out) <(grep '^# [a-z -]*:' check2.out) ||
        fail "printout read back chooses differently"

    # explicit method = "ekf"
    base_config ekf.cfg 'estimator = { method = "ekf"; };'
    "$VIBIDD" -c ekf.cfg --check > ekf.out 2> ekf.err || fail "--check (ekf): $(cat ekf.err)"
    grep -q 'method = "ekf";' ekf.out || fail "--check does not print method = \"ekf\""
    grep -qF "# estimator: extended Kalman filter on the stand's states and physical parameters (configured)" ekf.out ||
        fail "--check (ekf) estimator line: $(grep '^# estimator' ekf.out)"
    cp ekf.out ekf_again.cfg
    "$VIBIDD" -c ekf_again.cfg --check > ekf2.out 2>&1 || fail "ekf printout does not read back: $(cat ekf2.out)"

    # the regression estimators cannot run on it: refused before any sample (exit 2),
    # naming the node without sensor
    for m in rls iv; do
        base_config $m.cfg "estimator = { method = \"$m\"; };"
        "$VIBIDD" -c $m.cfg --check > $m.out 2> $m.err
        rc=$?
        [ $rc -eq 2 ] || fail "--check with method $m: exit $rc, expected 2: $(cat $m.err)"
        grep -qF "node 'm2': acceleration needed by 'm2' is not measured" $m.err ||
            fail "--check with method $m does not name the node without sensor: $(cat $m.err)"
        grep -q '^vibidd: error: .*estimator: vibid_ident_create' $m.err ||
            fail "--check with method $m: not an estimator error: $(cat $m.err)"
    done
    # the KF+RLS cannot learn c2, d2: they act only on m2, which has no sensor; refused
    # by name, pointing to the ekf
    base_config kfrls.cfg 'estimator = { method = "kf_rls"; };'
    "$VIBIDD" -c kfrls.cfg --check > kfrls.out 2> kfrls.err
    rc=$?
    [ $rc -eq 2 ] || fail "--check with method kf_rls: exit $rc, expected 2: $(cat kfrls.err)"
    grep -qF "KF+RLS cannot estimate 'c2', 'd2': they act only on nodes without a sensor" kfrls.err ||
        fail "--check with method kf_rls does not name c2, d2: $(cat kfrls.err)"
    grep -qF "(use method ekf)" kfrls.err || fail "--check with method kf_rls does not point to ekf: $(cat kfrls.err)"
    note "auto: $(grep '^# estimator' check.out | cut -c1-140)..."
    note "rls refused: $(cat rls.err)"
    note "kf_rls refused: $(cat kfrls.err)"
    ;;
alarm)
    # The issue's target: a 10 % stiffness drop (c2 at 30 s) detected by the alarm within 5 s,
    # with no false alarm before it; 60 s at 1 kHz, 1 % sensor noise, method "ekf" with
    # forgetting 0.9995 (memory 2000 samples = 2 s: the library test's tracking setting).
    # The alarm settings are the documented defaults (learned baseline over 5..15 s,
    # threshold 5 standard errors, min_relative 2 %, hold 2 s); no tuning was needed: the
    # filter has converged by 5 s, c2's standard error is about 0.25 % of it, so the
    # 2 % minimum change decides. Measured with seeds 1-8: before 30 s c2 stays within
    # 0.09 % of its baseline (|z| <= 0.25, against 5 and 2 %), the raise comes 2.3-3.2 s
    # after the drop (about 0.5 s for the estimate to move 2 % plus the 2 s hold).
    base_stand
    "$SIM" -c stand.cfg --duration 60 --csv cap.csv -q 2>/dev/null || fail "vibid-sim"
    base_config v.cfg 'estimator = { method = "ekf"; forgetting = 0.9995; };
alarms = { parameters = ( { name = "c1"; }, { name = "d1"; }, { name = "c2"; }, { name = "d2"; } ); };'
    timeout 100 "$VIBIDD" -c v.cfg 2> log || fail "vibidd: $(tail -5 log)"
    grep -q '^# forgetting: 0.9995 on the parameters' tracks.csv || fail "tracks header: $(grep '^# forg' tracks.csv)"
    first=$(grep -m1 '^vibid_alarm,' tracks.influx | sed 's/.*index=\([0-9]*\)i.*/\1/')
    [ -n "$first" ] || fail "no alarm raised: $(grep -i alarm log | head)"
    grep -m1 '^vibid_alarm,' tracks.influx | grep -q '^vibid_alarm,parameter=c2,stand=[^ ]* state="raised"' ||
        fail "first alarm not c2 raised: $(grep -m1 '^vibid_alarm,' tracks.influx)"
    [ "$first" -ge 30000 ] || fail "alarm at sample $first, before the change at 30000 (false alarm)"
    [ "$first" -le 35000 ] || fail "alarm at sample $first: more than 5 s after the change"
    grep -q "ALARM c2: .* at sample $first," log || fail "the log lacks the c2 alarm at sample $first: $(grep ALARM log)"
    # c1, d1, d2 did not change: any alarm on them is a false one
    other=$(grep '^vibid_alarm,' tracks.influx | grep -v 'parameter=c2,' | head -1)
    [ -z "$other" ] || fail "alarm on an unchanged parameter: $other"
    # no row flagged A before the drop
    early=$(grep -v '^#' tracks.csv | awk -F, 'NR > 1 && $2 < 30000 && $NF ~ /A/ { print $2; exit }')
    [ -z "$early" ] || fail "row at sample $early flagged A before the change"
    # final estimates: c2 within 2 % of its new value 0.9 * 1.2e5, c1 within 1 % of 6e4 (the
    # issue's bounds, as in ident.ekf; measured 0.01 % and 0.02 %), standard errors finite
    c1col=$(column c1 tracks.csv); c2col=$(column c2 tracks.csv)
    read -r c1 c1se c2 c2se < <(grep -v '^#' tracks.csv |
        awk -F, -v a="$c1col" -v b="$c2col" 'END { print $a, $(a + 1), $b, $(b + 1) }')
    awk -v v="$c2" 'BEGIN { e = (v - 1.08e5) / 1.08e5; exit !(e < 0.02 && e > -0.02) }' ||
        fail "final c2 = $c2, more than 2 % off the new value 1.08e5"
    awk -v v="$c1" 'BEGIN { e = (v - 6.0e4) / 6.0e4; exit !(e < 0.01 && e > -0.01) }' ||
        fail "final c1 = $c1, more than 1 % off 6e4"
    for se in "$c1se" "$c2se"; do
        awk -v v="$se" 'BEGIN { exit !(v == v + 0 && v > 0 && v < 1e300) }' || fail "final standard error '$se' not finite"
    done
    note "c2 alarm at sample $first ($(awk -v i="$first" 'BEGIN { print i / 1000 }') s, drop at 30 s); final c2 = $c2 (se $c2se; new value 1.08e5), c1 = $c1 (se $c1se; 6e4)"
    ;;
ex3 | ex3_kf_rls)
    # ex3: the EKF; ex3_kf_rls: the paper's KF+RLS (method "kf_rls"), same captures and targets.
    METHOD=ekf
    [ "$CASE" = ex3_kf_rls ] && METHOD=kf_rls
    # The paper's example 3 end to end: one mass (1 kg, known), spring k and damper d to
    # ground unknown, only the position measured, an unmeasured force w (held white samples,
    # std 1 N, simulated by vibid-sim: exact to 5e-13, sim.disturbance), h = 0.05 s. Truth
    # and start values from the paper's c = -1.25, d_p = 0.9 and c0 = -1.0, d_p0 = 0.8 through
    # the pole map of test_ekf.c; the estimates (the last track row) are mapped back and
    # compared in c, d_p as mean absolute relative errors over the runs.
    H=0.05
    read -r kt dt < <(paper_to_stand $H -1.25 0.9)
    read -r k0 d0 < <(paper_to_stand $H -1.0 0.8)
    # the two maps are inverse: a transcription slip in either shows here
    awk -v H=$H -v k="$kt" -v d="$dt" "$S2P_AWK"' BEGIN { s2p(k, d); exit !(C + 1.25 < 1e-12 && C + 1.25 > -1e-12 && DP - 0.9 < 1e-12 && DP - 0.9 > -1e-12) }' ||
        fail "paper_to_stand and s2p are not inverse (k $kt, d $dt)"
    cat > stand.cfg <<EOF
stand = { name = "ex3"; sample_rate = 20.0;
  nodes = ( { name = "m"; mass = 1.0; measure = { displacement = "x"; }; } );
  elements = ( { name = "k"; kind = "spring"; between = ["m", "ground"]; unknown = true; value = $k0; true_value = $kt; },
               { name = "d"; kind = "damper"; between = ["m", "ground"]; unknown = true; value = $d0; true_value = $dt; } );
  disturbances = ( { name = "w"; node = "m"; std = 1.0; true_std = 1.0; } ); };
EOF
    # vdcfg OUT SECTIONS
    vdcfg() {
        cat > "$1" <<EOF
stand = "stand.cfg";
source = { kind = "replay"; file = "cap.csv"; time_column = "t";
  channels = ( { name = "x"; quantity = "displacement"; node = 0; unit = "m"; column = "x"; } ); };
$2
outputs = { tracks = { path = "tracks.csv"; }; };
EOF
    }
    # auto chooses the ekf for it, because of the disturbance
    "$SIM" -c stand.cfg --duration 15 --csv cap.csv -q 2>/dev/null || fail "vibid-sim"
    vdcfg auto.cfg ""
    "$VIBIDD" -c auto.cfg --check > auto.out 2>&1 || fail "--check: $(cat auto.out)"
    grep -qF "(automatic: the stand declares an unmeasured random force)" auto.out ||
        fail "--check does not say that the disturbance chooses the ekf: $(grep '^# estimator' auto.out)"

    # One study: RUNS seeds, N samples each after a burn-in of 500 samples (25 s: the
    # library test's; 19 time constants 1/d of the stand's energy, so the state is
    # stationary; vibid-sim has no start option and the replay source no skip, so the CSV is
    # cut to its header and last N rows), sensor noise at SNR_DB (< 0: none). Every capture
    # is replayed with two configurations: the default decimation (rows every f_a/10 = 2
    # samples) and DEC_ALL (the first row after the library's 1000-sample start window or
    # the whole capture, i.e. ident.ekf's reading: one estimate after all samples). They
    # differ because an estimate asked for before the start window is full starts the
    # filter on the samples so far (stand_ekf.hpp): with rows every 2 samples the noise
    # level and scales come from the first 10 samples.
    # Prints "mare_c mare_dp mare_c' mare_dp' flagged_U flagged_U' flagged_P flagged_P'".
    study() {
        local N=$1 RUNS=$2 SNR_DB=$3 DEC_ALL=$4 seed sd dur c row
        dur=$(awk -v n="$N" 'BEGIN { print (n + 500) / 20 }')
        vdcfg def.cfg "estimator = { method = \"$METHOD\"; };"
        vdcfg all.cfg "estimator = { method = \"$METHOD\"; decimation = $DEC_ALL; };"
        : > res.txt
        for seed in $(seq 1 "$RUNS"); do
            "$SIM" -c stand.cfg --duration "$dur" --csv full.csv --seed "$seed" -q 2>/dev/null || fail "vibid-sim seed $seed"
            if awk -v s="$SNR_DB" 'BEGIN { exit !(s >= 0) }'; then
                # SNR over the N samples kept, as ident.ekf (vibid-sim's snr_db takes the
                # RMS of the first 2 s from rest: 18.6 dB instead of 20 here); the noise has
                # its own stream, so the trajectory is the same as without it
                sd=$(tail -n "$N" full.csv | awk -F, -v s="$SNR_DB" '{ q += $2 * $2 } END { printf "%.17g", sqrt(q / NR) * 10 ^ (-s / 20) }')
                echo "simulation = { noise = ( { channel = \"x\"; std = $sd; } ); };" > noise.cfg
                "$SIM" -c stand.cfg -s noise.cfg --duration "$dur" --csv full.csv --seed "$seed" -q 2>/dev/null ||
                    fail "vibid-sim (noise) seed $seed"
            fi
            { head -1 full.csv; tail -n "$N" full.csv; } > cap.csv
            for c in def all; do
                rm -f tracks.csv
                timeout 60 "$VIBIDD" -c $c.cfg 2> log || fail "vibidd ($c.cfg) seed $seed: $(tail -3 log)"
                row=$(grep -v '^#' tracks.csv | tail -1)
                echo "$row" | awk -F, -v n="$N" '$2 == n - 1 && $NF !~ /E/ && $3 == $3 + 0 && $5 == $5 + 0 { ok = 1 } END { exit !ok }' ||
                    fail "seed $seed ($c.cfg): last row is not an estimate at sample $((N - 1)): $row"
                echo "$row" | awk -F, -v c=$c '{ print c, $3, $5, $NF }' >> res.txt
            done
        done
        awk -v H=$H "$S2P_AWK"' { s2p($2, $3); ec = C / -1.25 - 1; ed = DP / 0.9 - 1
              ac[$1] += ec < 0 ? -ec : ec; ad[$1] += ed < 0 ? -ed : ed; n[$1]++
              if ($4 ~ /U/) u[$1]++; if ($4 ~ /P/) p[$1]++ }
            END { printf "%.6f %.6f %.6f %.6f %d %d %d %d\n", ac["def"] / n["def"], ad["def"] / n["def"],
                  ac["all"] / n["all"], ad["all"] / n["all"], u["def"], u["all"], p["def"], p["all"] }' res.txt
    }
    pct() { awk -v v="$1" 'BEGIN { printf "%.2f %%", 100 * v }'; }
    le() { awk -v v="$1" -v b="$2" 'BEGIN { exit !(v <= b) }'; }

    # Noise-free, N = 200 (10 s), 100 runs. Targets (the issue's): c <= 8 %, d_p <= 2.5 %.
    # ident.ekf on its own exact data: 6.04 % / 1.98 %. Measured here (seeds 1-100): default
    # decimation 5.85 % / 1.49 %, one estimate at the end 5.75 % / 1.57 %; seeds 101-400 in
    # blocks of 100: c 6.3-7.1 %, d_p 1.7-2.0 % (standard error of a mean of 100: 0.55 % and
    # 0.17 %). The seeds are fixed, so the figures are deterministic: the margins are the
    # room the issue allows, not noise allowance. 100 runs take about 6 s.
    t0=$(date +%s)
    # through a file, not a process substitution: fail() inside study must end the script
    study 200 100 -1 200 > study1.txt || exit 1
    read -r c1 d1 c2 d2 u1 u2 p1 p2 < study1.txt
    t1=$(date +%s)
    note "noise-free, N = 200, 100 runs ($((t1 - t0)) s): mean |error| c $(pct "$c1"), d_p $(pct "$d1") (rows every 2 samples); c $(pct "$c2"), d_p $(pct "$d2") (one estimate at the end); final rows flagged U $u1 / $u2, P $p1 / $p2 (targets 8 %, 2.5 %)"
    for v in "$c1" "$c2"; do le "$v" 0.08 || fail "noise-free N = 200: mean |error| of c $(pct "$v") > 8 %"; done
    for v in "$d1" "$d2"; do le "$v" 0.025 || fail "noise-free N = 200: mean |error| of d_p $(pct "$v") > 2.5 %"; done

    # 20 dB, N = 5000 (250 s), 20 runs (the brief's count; 100 runs take about 25 s).
    # Targets (the issue's): c <= 3 %, d_p <= 1.5 %. ident.ekf (100 runs): 1.37 % / 0.29 %.
    # Measured here, seeds 1-20: rows every 2 samples 1.25 % / 1.07 % (3 of the 20 final rows
    # flagged U: the noise level from 10 samples is off), one estimate after the full
    # 1000-sample start window (decimation 1000) 1.05 % / 0.40 %; seeds 1-100: 1.36 % / 0.81 %
    # (13 flagged U) and 1.26 % / 0.38 % (none). d_p with the default decimation is the
    # closest to its bound; a mean of 20 runs has a standard error of about 0.2 point there.
    study 5000 20 20 1000 > study2.txt || exit 1
    read -r c1 d1 c2 d2 u1 u2 p1 p2 < study2.txt
    t2=$(date +%s)
    note "20 dB, N = 5000, 20 runs ($((t2 - t1)) s): mean |error| c $(pct "$c1"), d_p $(pct "$d1") (rows every 2 samples); c $(pct "$c2"), d_p $(pct "$d2") (rows every 1000); final rows flagged U $u1 / $u2, P $p1 / $p2 (targets 3 %, 1.5 %)"
    for v in "$c1" "$c2"; do le "$v" 0.03 || fail "20 dB N = 5000: mean |error| of c $(pct "$v") > 3 %"; done
    for v in "$d1" "$d2"; do le "$v" 0.015 || fail "20 dB N = 5000: mean |error| of d_p $(pct "$v") > 1.5 %"; done
    ;;
*)
    fail "unknown case $CASE"
    ;;
esac
exit 0
