#!/bin/sh
# daemon.e2e.vm_socketcan (issue 7, end-to-end test 2): SocketCAN for real.
# In the qemu (TCG) VM of tests/drivers/vm_socketcan.sh (Debian's kernel package, its
# can/can-raw/can-dev/vcan modules, busybox; helpers in tests/drivers/vm_kernel.sh):
#  - vibidd identifies the paper's example 1 live from vcan0 (daemon/examples/
#    socketcan.cfg adapted: sim's own DBC, no SCHED_FIFO/mlockall, local outputs),
#  - can-utils' candump -l records the same bus,
#  - both are started (vibidd's status file says "running") before vibid-sim sends
#    3 s (see dur below) of the paper's example 1 (tests/daemon/data/sim_steady.cfg, 2 kHz, classic
#    frames, paced in real time) on vcan0; then vibidd gets SIGTERM (drain, exit 0) and
#    candump SIGINT;
#  - vibidd --replay of candump's log runs the same pipeline on the recording;
#  - a third vibidd with the stand's sample_rate at 8000 Hz must refuse the 2000 Hz frames
#    (the live sample-rate check, daemon/src/rate_check.h): exit 2, both rates named.
# Checks (host side): live and replay each have samples + missing = every sample the
# simulator sent, no kernel drops; final c1, d, c2 of each within 1 % of the truth
# (issue 7); live and replay final estimates agree within 1e-4 relative. Why 1e-4: both
# saw the same frame sequence from the first frame on (the estimator uses sample
# indices and the nominal h, not receive times), so they should agree to the printed
# precision of the tracks; 1e-4 is far below the 1 % accuracy asked, yet would catch any
# sample lost, duplicated or decoded differently on one side.
# Usage: vm_socketcan_e2e.sh WORKDIR VIBIDD VIBID_SIM SOURCE_DIR [TIMEOUT_S]
# Fails (exit 1) with a clear message if anything is missing (kernel package download,
# qemu, busybox-static, can-utils); never skips.
set -u
work=$1
abs() { echo "$(cd "$(dirname "$1")" && pwd)/$(basename "$1")"; }
vibidd=$(abs "$2")
sim=$(abs "$3")
src=$(cd "$4" && pwd)
timeout_s=${5:-300}
# Seconds vibid-sim sends (paced in real time). 3 s = 6000 samples, 18000 frames: the
# estimates are then already within 0.2 % of the truth. Under TCG the paced simulator
# runs 2 to 25 times slower than real time (on a loaded 2-core machine 2 s took about
# 50 s in the VM; on an idle one 4 s): 3 s give the rate check of the 8 kHz stand its two
# windows of >= 2 s also on the fastest VM seen (2 s were 3.98 s there, one window short).
# VIBID_VM_SIM_DURATION overrides.
dur=${VIBID_VM_SIM_DURATION:-3}
fail() { echo "FAIL [vm_socketcan e2e]: $*" >&2; exit 1; }
. "$src/tests/drivers/vm_kernel.sh"
for t in qemu-system-x86_64 apt-get apt-cache dpkg cpio gzip xz candump flock python3; do
  command -v $t >/dev/null 2>&1 || fail "'$t' not found (Debian: scripts/install-deps.sh --test installs can-utils qemu-system-x86 busybox-static cpio)"
done
[ -x "$vibidd" ] || fail "vibidd not built ($vibidd)"
[ -x "$sim" ] || fail "vibid-sim not built ($sim)"
mkdir -p "$work" || fail "cannot create $work"
cd "$work" || exit 1

# Kernel cache shared with drivers.vm_socketcan (same build tree).
vm_fetch_kernel "$work/../../drivers/vm/cache"

rm -rf root && mkdir -p root/data root/proc root/sys root/dev root/tmp root/run
vm_add_busybox root
vm_add_can_modules root
vm_add_binary root "$vibidd" "$sim" "$(command -v candump)"
cp "$src/examples/stands/paper_example1.cfg" root/data/stand.cfg || fail "stand file missing"
# the live sample-rate check: a third vibidd on the same bus with the stand at 8000 Hz. Not
# a rate below 2000 Hz: the paced simulator's frames arrive at 2000 Hz or slower (under TCG
# at 80-1000 Hz), so a 1000 Hz stand was once matched by a VM running at half real time.
sed 's/^\( *sample_rate = \)2000\.0;/\18000.0;/' root/data/stand.cfg > root/data/stand8k.cfg
grep -q 'sample_rate = 8000.0;' root/data/stand8k.cfg || fail "stand8k.cfg: sample_rate not replaced"
cp "$src/tests/daemon/data/sim_steady.cfg" root/data/sim.cfg || fail "sim_steady.cfg missing"
cp "$src/sim/paper_example1.dbc" root/data/sim.dbc || fail "sim/paper_example1.dbc missing"
for side in live replay wrong; do
  cat > root/data/$side.cfg <<EOF
# daemon/examples/socketcan.cfg adapted for the VM: vibid-sim's own DBC, outputs in /tmp/$side
stand = "/data/$([ $side = wrong ] && echo stand8k || echo stand).cfg";
source = {
  kind = "socketcan";
  interface = "vcan0";
  dbc = "/data/sim.dbc";
  counter = "SampleCounter";
  rcvbuf = 4194304;
  channels = (
    { name = "x1"; quantity = "displacement";      node = 0; unit = "m"; signal = "x1"; },
    { name = "x2"; quantity = "displacement";      node = 1; unit = "m"; signal = "x2"; },
    { name = "s";  quantity = "base_displacement"; node = 0; unit = "m"; signal = "s"; }
  );
};
acquisition = { ring_size = 65536; };
estimator = { method = "rls"; prefilter_hz = 200.0; decimation = 200; };
outputs = {
  tracks = { path = "/tmp/$side/tracks.csv"; flush_interval = 1.0; };
  status = { path = "/tmp/$side/status"; interval = 0.2; };
  $([ $side = live ] && echo 'record = { path = "/tmp/live/raw.log"; format = "candump"; };')
};
EOF
done
# --rate-check warn below: under TCG the paced simulator falls behind real time (2 s of
# simulated 2 kHz took 14-18 s here, in bursts), so the receive stamps of vcan0, of candump's log and of
# vibidd's recording show a rate far below the stand's 2000 Hz; the check would rightly
# refuse that as a device not fitting the stand (docs/vibidd.md, "Sample rate check"). This
# test is about the frames, not the simulator's pace: the mismatch is only a warning here.
vm_init_prologue > root/init
cat >> root/init <<'INIT'
mkdir -p /tmp/live /tmp/replay /tmp/cd /tmp/rec /tmp/wrong
cd /tmp/cd && candump -l vcan0 &
cp=$!
cd /tmp/live
vibidd -c /data/live.cfg --rate-check warn 2> /tmp/live/err &
vp=$!
i=0
until grep -q '^state=running' /tmp/live/status 2>/dev/null; do
  i=$((i + 1)); [ $i -gt 100 ] && { echo "VIBID-FAIL vibidd did not start: $(cat /tmp/live/err)"; break; }
  sleep 0.1
done
# The stand at 8000 Hz against the simulator's 2000 Hz frames (received at 80-1000 Hz under
# TCG): the default --rate-check error must refuse it, exit 2, after two windows of >= 2 s
# and >= 200 samples (a VM that kept real time would need VIBID_VM_SIM_DURATION >= 5).
cd /tmp/wrong
vibidd -c /data/wrong.cfg 2> /tmp/wrong/err &
wp=$!
i=0
until grep -q '^state=running' /tmp/wrong/status 2>/dev/null; do
  i=$((i + 1)); [ $i -gt 100 ] && { echo "VIBID-FAIL vibidd (wrong stand) did not start: $(cat /tmp/wrong/err)"; break; }
  sleep 0.1
done
echo "VIBID-SIM start uptime $(cut -d' ' -f1 /proc/uptime)"
timeout @SIMLIMIT@ vibid-sim -c /data/stand.cfg -s /data/sim.cfg --can vcan0 --duration @DUR@ 2> /tmp/sim.err ||
  echo "VIBID-FAIL vibid-sim: $(tail -3 /tmp/sim.err)"
echo "VIBID-SIM end uptime $(cut -d' ' -f1 /proc/uptime)"
sed 's/^/VIBIDSIM /' /tmp/sim.err
sleep 1
kill -TERM $vp; wait $vp; echo "VIBID live-exit $?"
kill -TERM $wp 2>/dev/null; wait $wp; echo "VIBID wrong-exit $?"
grep "off the stand" /tmp/wrong/err | tail -n 1 | sed 's/^/VIBIDWRONG /'
echo "VIBIDWRONG tracks-lines $(wc -l < /tmp/wrong/tracks.csv)"
kill -INT $cp; wait $cp
log=$(ls /tmp/cd/candump-*.log | head -n 1)
echo "VIBID candump-lines $(wc -l < "$log")"
cd /tmp/replay
vibidd -c /data/replay.cfg --replay "$log" --rate-check warn 2> /tmp/replay/err; echo "VIBID replay-exit $?"
# vibidd's own candump recording of the live run, replayed: the live tracks byte for byte
cd /tmp/rec
vibidd -c /data/replay.cfg --replay /tmp/live/raw.log --tracks /tmp/rec/tracks.csv --status /tmp/rec/status \
  --rate-check warn 2> /tmp/rec/err; echo "VIBID rec-replay-exit $?"
echo "VIBID rec-lines $(wc -l < /tmp/live/raw.log)"
if cmp /tmp/live/tracks.csv /tmp/rec/tracks.csv; then echo "VIBID rec-identical yes"; else echo "VIBID rec-identical no"; fi
for side in live replay; do
  for k in samples missing_samples gaps faults source_dropped_frames source_frames; do
    echo "VIBIDST $side $k $(sed -n "s/^$k=//p" /tmp/$side/status)"
  done
  echo "VIBIDROWS $side $(wc -l < /tmp/$side/tracks.csv)"
  echo "VIBIDLAST $side $(tail -n 1 /tmp/$side/tracks.csv)"
  grep -v "source fault" /tmp/$side/err | tail -n 3 | sed "s/^/VIBIDERR $side /"
done
echo "VIBID-DONE uptime $(cut -d' ' -f1 /proc/uptime)"
poweroff -f
INIT
sed -i "s/@DUR@/$dur/; s/@SIMLIMIT@/$((timeout_s / 2))/" root/init
chmod +x root/init
(cd root && find . | cpio -o -H newc 2>/dev/null | gzip -1) > initrd.gz || fail "cpio of the initramfs failed"

# The initramfs is unpacked into RAM: 512 MB suffice for the normal build, but the
# sanitizer build's binaries (with libasan/libubsan) are several times larger, so the VM
# gets 384 MB plus twice the unpacked payload, at least 512 MB.
payload_mb=$(du -sm root | cut -f1)
vm_mb=$((384 + 2 * payload_mb))
(( vm_mb < 512 )) && vm_mb=512
start=$(date +%s)
timeout -k 5 "$timeout_s" qemu-system-x86_64 -accel tcg -m "$vm_mb" -nographic -no-reboot -smp 1 \
  -kernel "$VM_VMLINUZ" -initrd initrd.gz -append "console=ttyS0 quiet panic=-1 rdinit=/init" \
  -nic none > console.log 2>&1
rc=$?
end=$(date +%s)
tr -d '\r' < console.log > console.txt
grep -E "^VIBID" console.txt | head -60
echo "qemu exit $rc after $((end - start)) s (kernel $(basename "$VM_VMLINUZ"))"
{ [ $rc -eq 124 ] || [ $rc -eq 137 ]; } && fail "VM did not finish within $timeout_s s (qemu killed); console: $work/console.txt"
grep -q "^VIBID-DONE" console.txt || fail "VM run did not complete; console: $work/console.txt"
grep -q "^VIBID-FAIL" console.txt && fail "in the VM: $(grep '^VIBID-FAIL' console.txt)"

st() { awk -v s="$1" -v k="$2" '$1 == "VIBIDST" && $2 == s && $3 == k { print $4 }' console.txt; }
ok=1
bad() { echo "FAIL [vm_socketcan e2e]: $*" >&2; ok=0; }
[ "$(awk '$1 == "VIBID" && $2 == "live-exit" { print $3 }' console.txt)" = 0 ] || bad "live vibidd did not exit 0 on SIGTERM"
# the live sample-rate check: the 8000 Hz stand refused (exit 2), the message naming both rates
[ "$(awk '$1 == "VIBID" && $2 == "wrong-exit" { print $3 }' console.txt)" = 2 ] ||
  bad "vibidd with the stand at 8000 Hz did not exit 2: $(grep '^VIBIDWRONG' console.txt)"
grep -Eq "^VIBIDWRONG .*socketcan vcan0: sample rate [0-9.]+ Hz \(from the receive timestamps, samples [0-9]+\.\.[0-9]+\) is [0-9.]+ % off the stand's sample_rate 8000 Hz \(/data/stand8k.cfg\)" console.txt ||
  bad "no refusal message from the 8000 Hz stand: $(grep '^VIBIDWRONG' console.txt)"
[ "$(awk '$1 == "VIBID" && $2 == "replay-exit" { print $3 }' console.txt)" = 0 ] || bad "vibidd --replay did not exit 0"
[ "$(awk '$1 == "VIBID" && $2 == "rec-replay-exit" { print $3 }' console.txt)" = 0 ] ||
  bad "vibidd --replay of its own candump recording did not exit 0"
[ "$(awk '$1 == "VIBID" && $2 == "rec-identical" { print $3 }' console.txt)" = yes ] ||
  bad "replay of vibidd's candump recording of the live run differs from the live tracks"
# dur s at the stand's 2 kHz = 2000 dur samples sent (3 classic frames each)
want=$((dur * 2000))
for side in live replay; do
  n=$(st $side samples); m=$(st $side missing_samples)
  [ -n "$n" ] && [ -n "$m" ] && [ $((n + m)) -eq $want ] || bad "$side: samples $n + missing $m != $want"
  [ "${m:-1}" -eq 0 ] || bad "$side: $m samples missing"
  [ "$(st $side source_dropped_frames)" = 0 ] || bad "$side: frames dropped: $(st $side source_dropped_frames)"
done
python3 - console.txt <<'PY' || ok=0
import sys
last = {}
for line in open(sys.argv[1]):
    p = line.split()
    if len(p) == 3 and p[0] == "VIBIDLAST":
        last[p[1]] = p[2].split(",")
truth = {"c1": 2.5e5, "d": 300.0, "c2": 1.5e6}
cols = {"c1": 2, "d": 4, "c2": 6}  # 0-based columns of tracks.csv (as tests/daemon/e2e.sh check_final)
bad = False
est = {}
for side in ("live", "replay"):
    if side not in last:
        print("FAIL: no final tracks row from the %s run" % side, file=sys.stderr)
        sys.exit(1)
    est[side] = {k: float(last[side][c]) for k, c in cols.items()}
    for k, v in est[side].items():
        e = 100 * (v - truth[k]) / truth[k]
        print("%s: %s = %.6g (%+.3f %% of truth)" % (side, k, v, e))
        if abs(e) > 1.0:
            print("FAIL: %s final %s off by %.3f %% (> 1 %%)" % (side, k, e), file=sys.stderr)
            bad = True
for k in truth:
    r = abs(est["live"][k] - est["replay"][k]) / abs(est["replay"][k])
    print("live vs replay: %s relative difference %.3g (tolerance 1e-4)" % (k, r))
    if r > 1e-4:
        print("FAIL: live and replay final %s differ by %.3g relative (> 1e-4)" % (k, r), file=sys.stderr)
        bad = True
sys.exit(1 if bad else 0)
PY
[ $ok -eq 1 ] || fail "checks failed; console: $work/console.txt"
echo "PASS: vibidd live on vcan0 in the VM and vibidd --replay of candump -l's recording agree and are within 1 % of the truth; the replay of vibidd's own candump recording ($(awk '$1 == "VIBID" && $2 == "rec-lines" { print $3 }' console.txt) frames) gives the live tracks byte for byte"
