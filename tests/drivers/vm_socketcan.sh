#!/bin/sh
# drivers.vm_socketcan: the SocketCAN source against a real kernel CAN stack.
# Boots Debian's own kernel (apt-get download of the package linux-image-amd64 depends
# on, unpacked with dpkg -x, never installed) under qemu TCG with a busybox initramfs
# holding can.ko, can-raw.ko, can-dev.ko, vcan.ko from that package, vm_can_check and
# can-utils (candump, cangen, canplayer). In the VM:
#  1. cangen sends 3000 frames on vcan0; our SocketCAN source and can-utils' candump -L
#     both receive them; our replay source reads candump's log back; the two record
#     streams must be identical (indices, microsecond times, values).
#  2. canplayer plays a log written here (5000 frames, known values); the live records
#     must equal the expected values exactly.
#  3. a reader with a tiny receive buffer that sleeps while cangen floods 2000 frames:
#     the kernel's drops must be reported through SO_RXQ_OVFL, received + dropped = sent.
# Usage: vm_socketcan.sh WORKDIR VM_CAN_CHECK [TIMEOUT_S]
# Fails (exit 1) with a clear message if anything is missing; never skips.
set -u
work=$1
check=$(cd "$(dirname "$2")" && pwd)/$(basename "$2")
timeout_s=${3:-240}
fail() { echo "FAIL: $*" >&2; exit 1; }
for t in qemu-system-x86_64 apt-get apt-cache dpkg cpio gzip xz candump cangen canplayer flock python3; do
  command -v $t >/dev/null 2>&1 || fail "'$t' not found (Debian: scripts/install-deps.sh --test installs can-utils qemu-system-x86 busybox-static cpio)"
done
[ -x "$check" ] || fail "test program '$check' not built"
. "$(dirname "$0")/vm_kernel.sh"
mkdir -p "$work" || fail "cannot create $work"
cd "$work" || exit 1

# --- kernel package (cached in $work/cache, shared with daemon.e2e.vm_socketcan) ---
vm_fetch_kernel "$work/cache"

# --- initramfs ---
rm -rf root && mkdir -p root/data root/proc root/sys root/dev root/tmp
vm_add_busybox root
vm_add_can_modules root
vm_add_binary root "$check" "$(command -v candump)" "$(command -v cangen)" "$(command -v canplayer)"
cat > root/data/vm.dbc <<'DBC'
BO_ 291 Gen: 8 S
 SG_ Cnt : 0|8@1+ (1,0) [0|255] "" X
 SG_ Val : 8|16@1+ (0.5,0) [0|0] "" X
BO_ 512 Play: 8 S
 SG_ Cnt : 0|8@1+ (1,0) [0|255] "" X
 SG_ F : 8|16@1- (0.01,0) [0|0] "N" X
 SG_ Xp : 24|32@1- (1,0) [0|0] "m" X
SIG_VALTYPE_ 512 Xp : 1;
DBC
cat > root/data/gen.cfg <<'CFG'
channels = ( { name = "v"; quantity = "displacement"; node = 0; signal = "Val"; message = "Gen"; } );
counter = "Cnt";
CFG
cat > root/data/play.cfg <<'CFG'
channels = ( { name = "F"; quantity = "force"; node = 0; signal = "F"; },
             { name = "x"; quantity = "displacement"; node = 0; signal = "Xp"; } );
counter = "Cnt";
CFG
# canplayer input (can-utils log format, 6-digit microseconds) and the expected records
python3 - root/data/play.log root/data/play.expect <<'PY' || fail "cannot write the canplayer log"
import struct, sys
log, exp = open(sys.argv[1], "w"), open(sys.argv[2], "w")
for k in range(5000):
    raw = (k * 37 % 20000) - 10000
    x = k * 0.25
    data = bytes([k & 255]) + struct.pack("<h", raw) + struct.pack("<f", x) + b"\0"
    t = 1700000000 + k * 200e-6
    log.write("(%017.6f) can0 200#%s\n" % (t, data.hex().upper()))
    exp.write("S %d %s %s\n" % (k, "%.17g" % (raw * 0.01), "%.17g" % x))
PY
vm_init_prologue > root/init
cat >> root/init <<'INIT'
cd /tmp
# 1. cangen -> our live source and candump; our replay of candump's log must match
vm_can_check live vcan0 /data/vm.dbc /data/gen.cfg live_gen.txt 3000 4194304 > live_gen.sum &
lp=$!
sleep 1
candump -L vcan0 > gen.log &
cp=$!
sleep 1
cangen vcan0 -I 123 -L 8 -D i -g 1 -n 3000
wait $lp
sleep 0.3; kill $cp; wait $cp
cat live_gen.sum
vm_can_check replay gen.log /data/vm.dbc /data/gen.cfg replay_gen.txt
echo "VIBID candump-lines $(wc -l < gen.log)"
if cmp -s live_gen.txt replay_gen.txt; then echo "VIBIDCMP gen ok"; else echo "VIBIDCMP gen MISMATCH"; diff live_gen.txt replay_gen.txt | head -5; fi
# 2. canplayer -> our live source; exact expected values
vm_can_check live vcan0 /data/vm.dbc /data/play.cfg live_play.txt 5000 8388608 > live_play.sum &
lp=$!
sleep 1
canplayer -I /data/play.log vcan0=can0
wait $lp
cat live_play.sum
cut -d' ' -f1,2,4- live_play.txt > live_play.vals
if cmp -s live_play.vals /data/play.expect; then echo "VIBIDCMP play ok"; else echo "VIBIDCMP play MISMATCH"; diff live_play.vals /data/play.expect | head -5; fi
# 3. kernel drops reported through SO_RXQ_OVFL: tiny buffer, reader asleep during a flood
vm_can_check live vcan0 /data/vm.dbc /data/gen.cfg live_drop.txt 2000 1 2500 > live_drop.sum &
lp=$!
sleep 1
cangen vcan0 -I 123 -L 8 -D i -g 0 -n 2000
sleep 2.5
# SO_RXQ_OVFL travels with the next queued frame: one more after the reader woke up
cangen vcan0 -I 123 -L 8 -D i -n 1
wait $lp
sed 's/^VIBID live/VIBID drop/' live_drop.sum
echo "VIBID-DONE uptime $(cut -d' ' -f1 /proc/uptime)"
poweroff -f
INIT
chmod +x root/init
(cd root && find . | cpio -o -H newc 2>/dev/null | gzip -1) > initrd.gz || fail "cpio of the initramfs failed"

# --- boot ---
start=$(date +%s.%N)
timeout -k 5 "$timeout_s" qemu-system-x86_64 -accel tcg -m 512 -nographic -no-reboot -smp 1 \
  -kernel "$VM_VMLINUZ" -initrd initrd.gz -append "console=ttyS0 quiet panic=-1 rdinit=/init" \
  -nic none > console.log 2>&1
rc=$?
end=$(date +%s.%N)
tr -d '\r' < console.log > console.txt
grep -E "^VIBID|^S |^>|^<|^[0-9]" console.txt | grep -v "^\[" | head -40
echo "qemu exit $rc after $(python3 -c "print('%.1f' % ($end - $start))") s (kernel $(basename "$VM_VMLINUZ"))"
[ $rc -eq 124 ] || [ $rc -eq 137 ] && fail "VM did not finish within $timeout_s s (killed); console: $work/console.txt"
grep -q "^VIBID-DONE" console.txt || fail "VM run did not complete; console: $work/console.txt"
grep -q "^VIBID-FAIL" console.txt && fail "setup failed in the VM: $(grep '^VIBID-FAIL' console.txt)"
grep -q "^VIBID error" console.txt && fail "vm_can_check failed: $(grep '^VIBID error' console.txt)"
val() { awk -v tag="$1" -v key="$2" '$1 == "VIBID" && $2 == tag { for (i = 3; i <= NF; i++) { split($i, a, "="); if (a[1] == key) { print a[2]; exit } } }' console.txt; }
ok=1
check_eq() { [ "$2" = "$3" ] || { echo "FAIL: $1: got '$2', expected '$3'" >&2; ok=0; }; }
check_gt() { [ -n "$2" ] && [ "$2" -gt "$3" ] || { echo "FAIL: $1: got '$2', expected > $3" >&2; ok=0; }; }
check_eq "cangen: live samples" "$(val live samples)" 3000
check_eq "cangen: live missing" "$(val live missing)" 0
check_eq "cangen: live dropped" "$(val live dropped)" 0
check_gt "cangen: software timestamps" "$(val live sw_ts)" 2999
check_eq "cangen: replay samples" "$(val replay samples)" 3000
grep -q "^VIBIDCMP gen ok" console.txt || { echo "FAIL: live records differ from the replay of candump's log" >&2; ok=0; }
grep -q "^VIBIDCMP play ok" console.txt || { echo "FAIL: canplayer frames decoded differently than expected" >&2; ok=0; }
check_gt "flood: frames dropped by the kernel, reported via SO_RXQ_OVFL" "$(val drop dropped)" 0
# every one of the 2001 frames sent is either received or counted as dropped
check_eq "flood: frames received + dropped" "$(( $(val drop frames) + $(val drop dropped) ))" 2001
[ $ok -eq 1 ] || fail "VM SocketCAN checks failed; console: $work/console.txt"
echo "PASS: SocketCAN source in the VM (cangen 3000 frames = candump replay, canplayer 5000 frames exact, SO_RXQ_OVFL drops reported)"
