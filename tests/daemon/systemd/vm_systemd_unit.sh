#!/usr/bin/env bash
# daemon.systemd_vm (issues 12, 14): the hardened unit still runs the daemon, under a real
# systemd as PID 1, in the qemu (TCG) VM of the SocketCAN tests (Debian's kernel package,
# helpers in tests/drivers/vm_kernel.sh).
# The VM's root: this machine's systemd 252 (systemd, systemd-journald, systemctl,
# journalctl and their libraries), a static busybox, the CAN modules, vibidd and vibid-sim.
# The unit is exactly the file `cmake --install --component vibidd` installs (DESTDIR
# install, copied unchanged to its place, <prefix>/lib/systemd/system/vibidd.service); the
# daemon is put at the unit's ExecStart path. The configuration /etc/vibidd/vibidd.cfg is
# the shipped daemon/examples/socketcan.cfg with only what the VM needs changed: stand file
# and DBC next to it in /etc/vibidd (vibid-sim's own DBC and its signal names),
# decimation 50 (a row every 25 ms of samples instead of 100 ms: more rows from a short run).
# Its outputs are the example's own: /var/lib/vibidd/tracks.csv, a candump recording
# /var/lib/vibidd/raw.log, InfluxDB UDP to 127.0.0.1:8089, /run/vibidd/status; SCHED_FIFO
# priority 50 and mlockall.
# In the VM (a busybox /init copies the initramfs to a tmpfs and switch_roots into systemd,
# because the initramfs itself cannot be pivoted away from by the unit's namespaces):
#  - systemctl start vibidd: ExecStartPre (--check) and ExecStart under the unit's sandbox;
#    with Type=notify it returns only after READY=1;
#  - the running daemon as the kernel sees it: not root, no capabilities, no_new_privs,
#    a seccomp filter, a user namespace of its own, its acquisition thread SCHED_FIFO;
#  - vibid-sim sends 300 samples of the paper's example 1 on vcan0 (AF_CAN under
#    RestrictAddressFamilies, no device node under PrivateDevices); all must arrive;
#  - systemctl reload (ExecReload, SIGHUP) keeps it running; systemctl stop: exit 0,
#    result success, no restart;
#  - tracks, raw recording (900 frames) and status file written where the unit allows;
#    the journal has the daemon's lines (StandardError=journal) and no warning about
#    SCHED_FIFO, mlockall or a permission.
#  - the template vibidd@.service (installed beside it, from the same template): instances
#    vibidd@a and vibidd@b started together, each with its own /etc/vibidd/<i>.cfg (b with
#    another decimation), its own dynamic user, outputs in /var/lib/vibidd/<i> and
#    /run/vibidd/<i>; 300 samples from vcan0 reach both; stop clean, /run/vibidd/<i> removed;
#    their MQTT passwords (root-only files) reach them through the credential drop-in of
#    docs/vibidd.md, while vibidd@c, naming its root-only file directly, is refused with
#    "Permission denied", and vibidd@d, without a password file, is not started (a few
#    seconds of the run).
# Why only 300 samples: under TCG vibid-sim delivers 2 kHz of simulated time at about
# 250 Hz, so the live sample-rate check (windows of >= 2 s and >= 200 samples; a refusal
# needs two windows off) would rightly refuse the run with exit 2 after 400 samples; the
# unit cannot be given --rate-check warn without changing it. 300 samples cannot make two
# windows, so the check decides nothing here (daemon.e2e.vm_socketcan tests it).
# Usage: vm_systemd_unit.sh BUILD_DIR SOURCE_DIR WORK_DIR VIBIDD VIBID_SIM [TIMEOUT_S]
# Fails (exit 1) with a clear message if anything is missing; never skips.
set -u
build=$(cd "$1" && pwd)
src=$(cd "$2" && pwd)
work=$3
abs() { echo "$(cd "$(dirname "$1")" && pwd)/$(basename "$1")"; }
vibidd=$(abs "$4")
sim=$(abs "$5")
timeout_s=${6:-300}
fail() { echo "FAIL [systemd_vm]: $*" >&2; exit 1; }
. "$src/tests/drivers/vm_kernel.sh"
for t in qemu-system-x86_64 apt-get apt-cache dpkg cpio gzip xz flock cmake ldd; do
  command -v $t >/dev/null 2>&1 || fail "'$t' not found (Debian: scripts/install-deps.sh --test)"
done
for f in /lib/systemd/systemd /lib/systemd/systemd-journald /bin/systemctl /bin/journalctl; do
  [ -x $f ] || fail "$f not found (Debian: package systemd; scripts/install-deps.sh --test)"
done
[ -x "$vibidd" ] || fail "vibidd not built ($vibidd)"
[ -x "$sim" ] || fail "vibid-sim not built ($sim)"
mkdir -p "$work" || fail "cannot create $work"
cd "$work" || exit 1

# The unit as installed.
rm -rf inst && DESTDIR=$work/inst cmake --install "$build" --component vibidd > install.log 2>&1 ||
  { cat install.log >&2; fail "cmake --install --component vibidd failed"; }
unit=$(cd inst && find . -path '*/lib/systemd/system/vibidd.service' | head -n 1)
[ -n "$unit" ] || fail "no vibidd.service installed"
unit=${unit#.}
exe=$(sed -n 's/^ExecStart=\([^ ]*\).*/\1/p' "inst$unit")
cfg=$(sed -n 's/^ExecStart=[^ ]* -c \([^ ]*\).*/\1/p' "inst$unit")
[ -n "$exe" ] && [ -n "$cfg" ] || fail "cannot read ExecStart's daemon and -c file from $unit"
echo "unit $unit: ExecStart daemon $exe, configuration $cfg"

vm_fetch_kernel "$build/tests/drivers/vm/cache"

# Root file system: Debian's merged /usr layout.
rm -rf root && mkdir -p root/usr/bin root/usr/sbin root/usr/lib/x86_64-linux-gnu root/usr/lib64 \
  root/etc root/proc root/sys root/dev root/run root/tmp root/var root/data || fail "mkdir root"
for d in bin sbin lib lib64; do ln -s usr/$d root/$d; done
# FILE at its own path and its libraries at theirs; libraries of the build tree (RUNPATH)
# into /usr/lib/x86_64-linux-gnu, where the dynamic loader looks by default.
add() {  # add FILE [DEST]
  local f=$1 dest=${2:-$1} lib
  mkdir -p "root$(dirname "$dest")" && cp -L "$f" "root$dest" || fail "cannot copy $f"
  ldd "$f" | grep -q "not found" && fail "$f: $(ldd "$f" | grep 'not found')"
  for lib in $(ldd "$f" | awk '/=> \//{print $3} /^\t\/lib64/{print $1}'); do
    case $lib in
      /lib/*|/lib64/*|/usr/lib/*) [ -e "root$lib" ] || { mkdir -p "root$(dirname "$lib")" && cp -L "$lib" "root$lib"; } ;;
      *) cp -L "$lib" root/usr/lib/x86_64-linux-gnu/ ;;
    esac || fail "cannot copy $lib"
  done
}
add /lib/systemd/systemd
add /lib/systemd/systemd-journald
add /bin/systemctl
add /bin/journalctl
cp -a inst/. root/ || fail "cannot copy the install into the VM's root"
add "$vibidd" "$exe"
add "$sim" /usr/local/bin/vibid-sim
sanitized=no
ldd "$vibidd" | grep -q libasan && sanitized=yes
vm_add_busybox root                      # root/bin/busybox = root/usr/bin/busybox
for a in $(root/bin/busybox --list); do  # applets where no real program is (kill, sh, ip, ...)
  [ -e root/usr/bin/$a ] || [ -L root/usr/bin/$a ] || ln -s busybox root/usr/bin/$a
done
vm_add_can_modules root

# systemd's own units, only those this boot needs (the host's full set would start
# udev, getty and more that are not in the VM).
mkdir -p root/usr/lib/systemd/system root/etc/systemd/system
for u in sysinit.target basic.target sockets.target timers.target paths.target slices.target \
         local-fs.target local-fs-pre.target swap.target shutdown.target umount.target final.target \
         network.target network-pre.target network-online.target multi-user.target \
         systemd-journald.service systemd-journald.socket systemd-journald-dev-log.socket; do
  cp /usr/lib/systemd/system/$u root/usr/lib/systemd/system/ || fail "no $u on this machine"
done
cat > root/etc/systemd/system/vibid-vm.target <<'EOF'
[Unit]
Description=vibidd unit test in the VM
Requires=basic.target vibid-vm-check.service
Wants=systemd-journald.socket systemd-journald-dev-log.socket systemd-journald.service
After=basic.target
EOF
ln -s vibid-vm.target root/etc/systemd/system/default.target
cat > root/etc/systemd/system/vibid-vm-check.service <<'EOF'
[Unit]
Description=drives and inspects vibidd.service
After=basic.target systemd-journald.service systemd-journald.socket
[Service]
Type=oneshot
ExecStart=/bin/sh /data/check.sh
StandardOutput=tty
StandardError=tty
TTYPath=/dev/ttyS0
EOF
if [ $sanitized = yes ]; then
  # A sanitizer build of vibidd: LeakSanitizer stops the process with ptrace at exit, which
  # the unit's SystemCallFilter forbids by design (@debug). Only then: no leak check.
  mkdir -p root/etc/systemd/system/vibidd.service.d
  printf '[Service]\nEnvironment=ASAN_OPTIONS=detect_leaks=0\n' > root/etc/systemd/system/vibidd.service.d/asan.conf
fi
printf 'root:x:0:0:root:/root:/bin/sh\nnobody:x:65534:65534:nobody:/nonexistent:/bin/false\n' > root/etc/passwd
printf 'root:x:0:\ndialout:x:20:\nnogroup:x:65534:\n' > root/etc/group
printf 'passwd: files\ngroup: files\nshadow: files\nhosts: files\n' > root/etc/nsswitch.conf
printf '127.0.0.1 localhost\n' > root/etc/hosts
cp -L /etc/os-release root/etc/os-release || fail "no /etc/os-release"
: > root/etc/machine-id

# /etc/vibidd: the shipped example, adapted as said above (each change checked).
mkdir -p "root$(dirname "$cfg")"
cp "$src/examples/stands/paper_example1.cfg" "root$(dirname "$cfg")/stand.cfg" || fail "stand file missing"
cp "$src/sim/paper_example1.dbc" "root$(dirname "$cfg")/sim.dbc" || fail "sim/paper_example1.dbc missing"
cp "$src/examples/stands/paper_example1.cfg" root/data/stand.cfg
cp "$src/tests/daemon/data/sim_steady.cfg" root/data/sim.cfg || fail "sim_steady.cfg missing"
ex=$src/daemon/examples/socketcan.cfg
sed -e 's|^stand = .*|stand = "stand.cfg";|' \
    -e 's|^\( *dbc = \)"[^"]*";|\1"sim.dbc";|' \
    -e 's|counter = "Counter";|counter = "SampleCounter";|' \
    -e 's|signal = "X1"; message = "Sample_A";|signal = "x1";|' \
    -e 's|signal = "X2"; message = "Sample_B";|signal = "x2";|' \
    -e 's|signal = "S";  message = "Sample_C";|signal = "s";|' \
    -e 's|decimation = 200;|decimation = 50;|' \
    -e 's|lock_memory = true;|lock_memory = @LOCK@;|' "$ex" > "root$cfg" || fail "cannot adapt $ex"
# mlockall of a sanitizer build would try to lock its terabytes of shadow mappings
sed -i "s|@LOCK@|$([ $sanitized = yes ] && echo false || echo true)|" "root$cfg"
for want in 'stand = "stand.cfg";' 'dbc = "sim.dbc";' 'counter = "SampleCounter";' 'signal = "x1";' 'signal = "x2";' \
            'signal = "s";' 'decimation = 50;' 'realtime_priority = 50;' 'path = "/var/lib/vibidd/tracks.csv";' \
            'path = "/var/lib/vibidd/raw.log"; format = "candump";' 'udp = "127.0.0.1:8089";' 'path = "/run/vibidd/status";'; do
  grep -qF "$want" "root$cfg" || fail "$ex changed: '$want' not in the adapted configuration (adapt this test)"
done

# The drop-ins documented in docs/vibidd.md (fenced block after `<!-- drop-in: NAME -->`).
for n in hw-timestamps serial; do
  awk -v n="$n" '$0 == "<!-- drop-in: " n " -->" { want = 1; next }
                 want && /^```/ { if (inside) exit; inside = 1; next }
                 inside { print }' "$src/docs/vibidd.md" > root/data/dropin-$n.conf
  grep -q '^\[Service\]' root/data/dropin-$n.conf || fail "docs/vibidd.md: no drop-in '$n'"
done
# Serial Modbus RTU: daemon/examples/modbus_fifo.cfg on the VM's second UART (qemu -serial
# null: a real 16550 that nobody answers on), outputs made absolute as the unit requires.
ex=$src/daemon/examples/modbus_fifo.cfg
sed -e 's|^stand = .*|stand = "stand.cfg";|' \
    -e 's|url = "tcp://127.0.0.1:1502";|url = "rtu:///dev/ttyS1";|' \
    -e 's|tracks = { path = "tracks.csv"; };|tracks = { path = "/var/lib/vibidd/rtu_tracks.csv"; };|' \
    -e 's|record = { path = "raw.csv"; };|record = { path = "/var/lib/vibidd/rtu_raw.csv"; };|' \
    -e 's|status = { path = "vibidd.status"; };|status = { path = "/run/vibidd/status"; interval = 0.2; };|' "$ex" > root/data/rtu.cfg
for want in 'stand = "stand.cfg";' 'url = "rtu:///dev/ttyS1";' '/var/lib/vibidd/rtu_tracks.csv' '/var/lib/vibidd/rtu_raw.csv' \
            'path = "/run/vibidd/status"; interval = 0.2;'; do
  grep -qF "$want" root/data/rtu.cfg || fail "$ex changed: '$want' not in the adapted configuration (adapt this test)"
done
# Many stands on one host (vibidd@.service): instances a and b, each with its own
# configuration /etc/vibidd/<instance>.cfg, the VM's socketcan.cfg with the outputs moved into
# the instance's directories; b with decimation 100 (3 rows from 300 samples, a: 6), so
# that each instance is seen to run its own file. Each also publishes to MQTT (no broker in
# the VM: connection failures are counted, drain_timeout 0) with its password, a root-only
# file /etc/vibidd/<instance>.mqtt.password handed over by the credential drop-in of
# docs/vibidd.md as /run/credentials/vibidd@<instance>.service/mqtt.password; instance c
# names its root-only file directly and must be refused (the dynamic user cannot read it).
etc=root$(dirname "$cfg")
for i in a b c d; do
  sed -e "s|/var/lib/vibidd/|/var/lib/vibidd/$i/|g" -e "s|/run/vibidd/|/run/vibidd/$i/|g" "root$cfg" > "$etc/$i.cfg"
  pwf=/run/credentials/vibidd@$i.service/mqtt.password
  [ $i = c ] && pwf=c.mqtt.password
  sed -i "s|^\( *status = { path = \"/run/vibidd/$i/status\";.*\)$|\1\n  mqtt = { url = \"mqtt://127.0.0.1:1883\"; site = \"vm\"; stand = \"$i\"; username = \"$i\"; password_file = \"$pwf\"; drain_timeout = 0.0; };|" "$etc/$i.cfg"
  grep -qF "path = \"/var/lib/vibidd/$i/tracks.csv\";" "$etc/$i.cfg" && grep -qF "path = \"/run/vibidd/$i/status\";" "$etc/$i.cfg" &&
    grep -qF "password_file = \"$pwf\";" "$etc/$i.cfg" || fail "cannot adapt $cfg for instance $i"
  [ $i = d ] && continue # d: no password file, so no credential to load
  (umask 077 && echo "secret-$i" > "$etc/$i.mqtt.password") || fail "cannot write $etc/$i.mqtt.password"
done
sed -i 's|decimation = 50;|decimation = 100;|' "$etc/b.cfg"
mkdir -p root/etc/systemd/system/vibidd@.service.d
awk '$0 == "<!-- drop-in: mqtt-credential (vibidd@ only) -->" { want = 1; next }
     want && /^```/ { if (inside) exit; inside = 1; next }
     inside { print }' "$src/docs/vibidd.md" > root/etc/systemd/system/vibidd@.service.d/mqtt-credential.conf
grep -q '^LoadCredential=mqtt.password:/etc/vibidd/%i.mqtt.password$' root/etc/systemd/system/vibidd@.service.d/mqtt-credential.conf ||
  fail "docs/vibidd.md: no drop-in 'mqtt-credential (vibidd@ only)' with LoadCredential=mqtt.password:/etc/vibidd/%i.mqtt.password"

# Stage 1: busybox in the initramfs; CAN up; everything onto a tmpfs; systemd as PID 1.
cat > root/init <<'INIT'
#!/bin/busybox sh
export PATH=/usr/bin:/usr/sbin
mount -t proc proc /proc; mount -t sysfs sys /sys; mount -t devtmpfs dev /dev
echo "VIBID-BOOTED uptime $(cut -d' ' -f1 /proc/uptime)"
for m in can can-raw can-dev vcan; do insmod /mod/$m.ko || echo "VIBID-FAIL insmod $m"; done
ip link add dev vcan0 type vcan && ip link set up vcan0 || echo "VIBID-FAIL ip link vcan0"
mkdir /newroot && mount -t tmpfs -o mode=0755 tmpfs /newroot || echo "VIBID-FAIL tmpfs"
for e in $(ls -A /); do
  case $e in proc|sys|dev|newroot|init) ;; *) cp -a "/$e" /newroot/ || echo "VIBID-FAIL cp $e" ;; esac
done
mkdir -p /newroot/proc /newroot/sys /newroot/dev
for m in dev proc sys; do mount -o move /$m /newroot/$m || echo "VIBID-FAIL mount --move /$m"; done
exec switch_root /newroot /lib/systemd/systemd
INIT
chmod +x root/init

# Stage 2, run by vibid-vm-check.service (root, outside the sandbox).
# A sanitizer (ASan) build of vibidd: the template's instances are not started in the VM. Under
# TCG emulation every instance's ExecStartPre (vibidd --check) of the ASan binary ran past
# systemd's 90 s start time-out (CI, session 12), while the plain unit's passed; the -Werror
# build of the same suite runs the instance checks in full. Said loudly in the result, never
# counted as tested.
[ $sanitized = yes ] && touch root/data/no_instances
cat > root/data/check.sh <<'CHECK'
echo "VIBID-SYSTEMD up uptime $(cut -d' ' -f1 /proc/uptime) pid1 $(cat /proc/1/comm)"
systemctl start vibidd.service; echo "VIBID start-rc $?"
echo "VIBID started uptime $(cut -d' ' -f1 /proc/uptime)"
systemctl show vibidd.service -p ActiveState -p SubState -p Result | sed 's/^/VIBIDSHOW start /'
pid=$(systemctl show -p MainPID --value vibidd.service)
echo "VIBID mainpid $pid"
if [ -n "$pid" ] && [ "$pid" != 0 ]; then
  grep -E '^(Uid|Gid|CapEff|CapPrm|CapBnd|CapAmb|NoNewPrivs|Seccomp):' /proc/$pid/status | tr -s '\t' ' ' | sed 's/^/VIBIDPROC /'
  echo "VIBIDPROC uid_map: $(tr -s ' \n' ' ' < /proc/$pid/uid_map)"
  for t in /proc/$pid/task/*; do echo "VIBIDTASK $(basename $t) policy $(cut -d' ' -f41 $t/stat)"; done
fi
vibid-sim -c /data/stand.cfg -s /data/sim.cfg --can vcan0 --duration 0.15 2> /tmp/sim.err
echo "VIBID sim-rc $? $(tail -n 1 /tmp/sim.err)"
i=0
until grep -q '^samples=300$' /run/vibidd/status 2>/dev/null; do
  i=$((i + 1)); [ $i -gt 60 ] && { echo "VIBID-FAIL status never showed 300 samples"; break; }
  sleep 0.5
done
sed 's/^/VIBIDST /' /run/vibidd/status
# as logrotate would: move the outputs away, reload (SIGHUP through ExecReload), the daemon
# creates them anew (the tracks file with its header)
s=/var/lib/vibidd
mv $s/tracks.csv $s/tracks.csv.1 && mv $s/raw.log $s/raw.log.1
systemctl reload vibidd.service; echo "VIBID reload-rc $?"
i=0
until [ -s $s/tracks.csv ]; do
  i=$((i + 1)); [ $i -gt 20 ] && break
  sleep 0.5
done
echo "VIBID reopened $([ -s $s/tracks.csv ] && [ -e $s/raw.log ] && echo yes || echo no)"
echo "VIBID after-reload $(systemctl is-active vibidd.service)"
systemctl stop vibidd.service; echo "VIBID stop-rc $?"
systemctl show vibidd.service -p Result -p ExecMainCode -p ExecMainStatus -p NRestarts | sed 's/^/VIBIDSHOW stop /'
echo "VIBID track-rows $(grep -v '^#' $s/tracks.csv.1 | tail -n +2 | wc -l)"
echo "VIBID raw-lines $(wc -l < $s/raw.log.1)"
echo "VIBID last-row $(tail -n 1 $s/tracks.csv.1)"
ls -ln /var/lib/private/vibidd | sed 's/^/VIBIDLS /'
journalctl -b -u vibidd.service -o cat --no-pager | sed 's/^/VIBIDLOG /'
journalctl -b -u vibidd.service -p warning -o cat --no-pager | sed 's/^/VIBIDWARN /'
cur=$(journalctl -b -u vibidd.service --show-cursor -n 0 --no-pager | sed -n 's/^-- cursor: //p')

# The hardware-timestamp drop-in: CAP_NET_ADMIN effective, the host's user namespace.
d=/etc/systemd/system/vibidd.service.d
mkdir -p $d && cp /data/dropin-hw-timestamps.conf $d/ && systemctl daemon-reload
systemctl start vibidd.service; echo "VIBID hw-start-rc $?"
pid=$(systemctl show -p MainPID --value vibidd.service)
grep -E '^(Uid|CapEff|CapAmb):' /proc/$pid/status | tr -s '\t' ' ' | sed 's/^/VIBIDHW /'
echo "VIBIDHW uid_map: $(tr -s ' \n' ' ' < /proc/$pid/uid_map)"
echo "VIBIDHW active $(systemctl is-active vibidd.service)"
systemctl stop vibidd.service; echo "VIBID hw-stop-rc $?"
echo "VIBID hw-result $(systemctl show -p Result --value vibidd.service)"
rm $d/dropin-hw-timestamps.conf

# Serial Modbus RTU on /dev/ttyS1 (root:dialout 0660, as Debian's udev makes it): the
# default unit has no such device (connections fail), with the serial drop-in the port
# opens (connections succeed; nobody answers: time-outs).
chgrp dialout /dev/ttyS1 && chmod 0660 /dev/ttyS1
cp /data/rtu.cfg /etc/vibidd/vibidd.cfg
for mode in default serial; do
  [ $mode = serial ] && cp /data/dropin-serial.conf $d/
  systemctl daemon-reload
  cur=$(journalctl -b -u vibidd.service --show-cursor -n 0 --no-pager | sed -n 's/^-- cursor: //p')
  systemctl start vibidd.service; echo "VIBID rtu-$mode-start-rc $?"
  i=0
  until grep -Eq '^source_(connect_failures|timeouts)=[1-9]' /run/vibidd/status 2>/dev/null; do
    i=$((i + 1)); [ $i -gt 40 ] && break
    sleep 0.25
  done
  for k in source_connect_failures source_timeouts source_reconnects; do
    echo "VIBIDRTU $mode $k $(sed -n "s/^$k=//p" /run/vibidd/status)"
  done
  systemctl stop vibidd.service; echo "VIBID rtu-$mode-stop-rc $?"
  journalctl -u vibidd.service --after-cursor="$cur" -o cat --no-pager | grep -E 'source fault|Modbus|denied' |
    head -n 4 | sed "s/^/VIBIDRTULOG $mode /"
done

if [ ! -e /data/no_instances ]; then  # (the host's note: a sanitizer build, see there)
# Many stands: two instances of the template at once, each its own configuration, user and
# directories. Alone on the host (the plain unit's state directory removed first): the
# plain unit's StateDirectory=vibidd would contain the instances' vibidd/<instance>.
rm -f /etc/vibidd/vibidd.cfg $d/*.conf; systemctl daemon-reload
rm -rf /var/lib/vibidd /var/lib/private/vibidd
systemctl start vibidd@a.service vibidd@b.service; echo "VIBID inst-start-rc $?"
for i in a b; do
  pid=$(systemctl show -p MainPID --value vibidd@$i.service)
  echo "VIBIDINST $i active $(systemctl is-active vibidd@$i.service)"
  echo "VIBIDINST $i uid $(awk '$1 == "Uid:" { print $2 }' /proc/$pid/status)"
  echo "VIBIDINST $i config $(tr '\0' ' ' < /proc/$pid/cmdline | sed 's/.* -c \([^ ]*\).*/\1/')"
done
vibid-sim -c /data/stand.cfg -s /data/sim.cfg --can vcan0 --duration 0.15 2> /tmp/sim.err
echo "VIBID inst-sim-rc $? $(tail -n 1 /tmp/sim.err)"
for i in a b; do
  n=0
  until grep -q '^samples=300$' /run/vibidd/$i/status 2>/dev/null; do
    n=$((n + 1)); [ $n -gt 60 ] && { echo "VIBID-FAIL instance $i: status never showed 300 samples"; break; }
    sleep 0.5
  done
  echo "VIBIDINST $i status-samples $(sed -n 's/^samples=//p' /run/vibidd/$i/status)"
  echo "VIBIDINST $i mqtt-connect-failures $(sed -n 's/^mqtt_connect_failures=//p' /run/vibidd/$i/status)"
  echo "VIBIDINST $i credential $(ls -ln /run/credentials/vibidd@$i.service/mqtt.password | awk '{ print $1, $3 }')"
done
# c names the root-only file itself: its ExecStartPre (--check) cannot read it
systemctl start vibidd@c.service; echo "VIBID inst-c-start-rc $?"
echo "VIBIDINST c result $(systemctl show -p Result --value vibidd@c.service)"
echo "VIBIDINST c exit $(systemctl show -p ExecMainStatus --value vibidd@c.service)"
sleep 0.5 # journald gets the ExecStartPre's last lines
journalctl -u vibidd@c.service -o cat --no-pager | sed 's/^/VIBIDCLOG /'
systemctl reset-failed vibidd@c.service
# d has no /etc/vibidd/d.mqtt.password: the credential drop-in must keep it from starting
systemctl start vibidd@d.service; echo "VIBID inst-d-start-rc $?"
echo "VIBIDINST d result $(systemctl show -p Result --value vibidd@d.service)"
sleep 0.5
journalctl -u vibidd@d.service -o cat --no-pager | head -n 4 | sed 's/^/VIBIDDLOG /'
systemctl reset-failed vibidd@d.service
systemctl stop vibidd@a.service vibidd@b.service; echo "VIBID inst-stop-rc $?"
for i in a b; do
  echo "VIBIDINST $i result $(systemctl show -p Result --value vibidd@$i.service)"
  echo "VIBIDINST $i rows $(grep -v '^#' /var/lib/vibidd/$i/tracks.csv | tail -n +2 | wc -l)"
  echo "VIBIDINST $i raw-lines $(wc -l < /var/lib/vibidd/$i/raw.log)"
  echo "VIBIDINST $i state-dir $(readlink -f /var/lib/vibidd/$i)"
  echo "VIBIDINST $i runtime-dir-after-stop $([ -e /run/vibidd/$i ] && echo present || echo removed)"
done
journalctl -b -u vibidd@a.service -u vibidd@b.service -p warning -o cat --no-pager | sed 's/^/VIBIDINSTWARN /'
fi
echo "VIBID-DONE uptime $(cut -d' ' -f1 /proc/uptime)"
systemctl poweroff --force --force
CHECK

(cd root && find . | cpio -o -H newc 2>/dev/null | gzip -1) > initrd.gz || fail "cpio of the initramfs failed"
payload_mb=$(du -sm root | cut -f1)
vm_mb=$((512 + 3 * payload_mb))   # initramfs, its tmpfs copy, and the services
start=$(date +%s)
timeout -k 5 "$timeout_s" qemu-system-x86_64 -accel tcg -m "$vm_mb" -nographic -no-reboot -smp 1 \
  -kernel "$VM_VMLINUZ" -initrd initrd.gz \
  -append "console=ttyS0 quiet panic=-1 rdinit=/init systemd.show_status=0 systemd.log_level=notice" \
  -serial mon:stdio -serial null -nic none > console.log 2>&1
rc=$?
end=$(date +%s)
tr -d '\r' < console.log > console.txt
grep -E "^VIBID" console.txt | grep -Ev '^VIBID(LOG|ST|PROC|TASK|LS) '
grep -E "^VIBIDST (state|samples|missing_samples|rows|influx_udp_sent|influx_udp_errors|write_errors)=" console.txt
grep -E "^VIBIDLOG [a-zA-Z]" console.txt | grep -Ev '^VIBIDLOG [a-z_]+ = ' | tail -n 15
echo "qemu exit $rc after $((end - start)) s (kernel $(basename "$VM_VMLINUZ"), systemd $(systemctl --version | head -n 1 | cut -d' ' -f2), vibidd sanitized: $sanitized)"
{ [ $rc -eq 124 ] || [ $rc -eq 137 ]; } && fail "VM did not finish within $timeout_s s (qemu killed); console: $work/console.txt"
grep -q "^VIBID-SYSTEMD up .* pid1 systemd" console.txt || fail "systemd did not come up as PID 1 or did not run the check; console: $work/console.txt"
grep -q "^VIBID-DONE" console.txt || fail "VM run did not complete; console: $work/console.txt"
grep -q "^VIBID-FAIL" console.txt && fail "in the VM: $(grep '^VIBID-FAIL' console.txt)"

ok=1
bad() { echo "FAIL [systemd_vm]: $*" >&2; ok=0; }
v() { awk -v k="$1" '$1 == "VIBID" && $2 == k { $1 = ""; $2 = ""; sub(/^ +/, ""); print; exit }' console.txt; }
p() { awk -v k="$1:" '$1 == "VIBIDPROC" && $2 == k { print $3; exit }' console.txt; }
sh_() { awk -v w="$1" -v k="$2" '$1 == "VIBIDSHOW" && $2 == w && index($3, k "=") == 1 { print substr($3, length(k) + 2); exit }' console.txt; }
[ "$(v start-rc)" = 0 ] || bad "systemctl start vibidd failed (exit $(v start-rc)); journal: $(grep '^VIBIDLOG' console.txt | tail -n 5)"
[ "$(sh_ start ActiveState)" = active ] && [ "$(sh_ start SubState)" = running ] ||
  bad "after start: ActiveState $(sh_ start ActiveState), SubState $(sh_ start SubState) (READY=1 not reached?)"
uid=$(p Uid)
[ -n "$uid" ] && [ "$uid" != 0 ] || bad "the daemon runs as uid '$uid' (DynamicUser)"
[ "$(p CapEff)" = 0000000000000000 ] && [ "$(p CapBnd)" = 0000000000000000 ] && [ "$(p CapAmb)" = 0000000000000000 ] ||
  bad "capabilities: eff $(p CapEff) bnd $(p CapBnd) amb $(p CapAmb) (none expected)"
[ "$(p NoNewPrivs)" = 1 ] || bad "no_new_privs not set"
[ "$(p Seccomp)" = 2 ] || bad "no seccomp filter (Seccomp: $(p Seccomp))"
grep -Eq "^VIBIDPROC uid_map: +0 +0 +4294967295" console.txt && bad "no user namespace of its own (PrivateUsers)"
grep -Eq "^VIBIDTASK [0-9]+ policy 1$" console.txt || bad "no SCHED_FIFO thread: $(grep '^VIBIDTASK' console.txt | tr '\n' ' ')"
grep -q "^VIBIDLOG acquisition thread runs SCHED_FIFO priority 50" console.txt || bad "no 'SCHED_FIFO priority 50' line in the journal"
if [ $sanitized = no ]; then
  grep -q "^VIBIDLOG memory locked (mlockall)" console.txt || bad "no 'memory locked (mlockall)' line in the journal"
fi
grep -Ei "^VIBIDWARN .*(SCHED_FIFO|mlockall|denied|not permitted|operation not|address family)" console.txt &&
  bad "warnings about the sandbox in the journal"
[ "$(v sim-rc | cut -d' ' -f1)" = 0 ] || bad "vibid-sim failed: $(v sim-rc)"
st() { awk -v k="$1" '$1 == "VIBIDST" && index($2, k "=") == 1 { print substr($2, length(k) + 2); exit }' console.txt; }
[ "$(st samples)" = 300 ] && [ "$(st missing_samples)" = 0 ] ||
  bad "status file: samples $(st samples), missing $(st missing_samples) (300, 0 expected)"
[ "$(st state)" = running ] || bad "status file: state $(st state)"
[ "$(v reload-rc)" = 0 ] && [ "$(v after-reload)" = active ] || bad "reload: exit $(v reload-rc), then $(v after-reload)"
[ "$(v reopened)" = yes ] && grep -q "^VIBIDLOG outputs reopened (SIGHUP)" console.txt ||
  bad "after systemctl reload the outputs were not created anew"
[ "$(st influx_udp_sent)" -ge 1 ] 2>/dev/null && [ "$(st influx_udp_errors)" = 0 ] ||
  bad "InfluxDB UDP: sent $(st influx_udp_sent), errors $(st influx_udp_errors)"
[ "$(v stop-rc)" = 0 ] || bad "systemctl stop failed"
[ "$(sh_ stop Result)" = success ] && [ "$(sh_ stop ExecMainStatus)" = 0 ] && [ "$(sh_ stop NRestarts)" = 0 ] ||
  bad "after stop: Result $(sh_ stop Result), ExecMainStatus $(sh_ stop ExecMainStatus), NRestarts $(sh_ stop NRestarts)"
rows=$(v track-rows)
[ "${rows:-0}" -eq 6 ] && [ "$(st rows)" = 6 ] || bad "tracks.csv has $rows rows, the status $(st rows) (300 samples / decimation 50 = 6 expected)"
[ "$(v raw-lines)" = 900 ] || bad "raw.log has $(v raw-lines) lines (300 samples x 3 frames expected)"
# the hardware-timestamp drop-in
hw() { awk -v k="$1:" '$1 == "VIBIDHW" && $2 == k { print $3; exit }' console.txt; }
[ "$(v hw-start-rc)" = 0 ] && [ "$(v hw-stop-rc)" = 0 ] && [ "$(v hw-result)" = success ] ||
  bad "with the hw-timestamps drop-in: start $(v hw-start-rc), stop $(v hw-stop-rc), result $(v hw-result)"
[ "$(hw CapEff)" = 0000000000001000 ] && [ "$(hw CapAmb)" = 0000000000001000 ] ||
  bad "with the hw-timestamps drop-in: CapEff $(hw CapEff), CapAmb $(hw CapAmb) (CAP_NET_ADMIN only expected)"
grep -Eq "^VIBIDHW uid_map: +0 +0 +4294967295" console.txt || bad "with the hw-timestamps drop-in: still a private user namespace"
# serial Modbus RTU
rtu() { awk -v m="$1" -v k="$2" '$1 == "VIBIDRTU" && $2 == m && $3 == k { print $4; exit }' console.txt; }
for m in default serial; do
  [ "$(v rtu-$m-start-rc)" = 0 ] && [ "$(v rtu-$m-stop-rc)" = 0 ] || bad "RTU ($m unit): start $(v rtu-$m-start-rc), stop $(v rtu-$m-stop-rc)"
done
# (a FIFO header that does not come counts as a failed connection too: the open is told by
# the time-outs, which only an open port can have, and by the error)
[ "$(rtu default source_timeouts)" = 0 ] && grep -q "^VIBIDRTULOG default .*/dev/ttyS1.*No such file or directory" console.txt ||
  bad "RTU with the default unit: /dev/ttyS1 was not missing (PrivateDevices): $(grep '^VIBIDRTU.* default' console.txt | tr '\n' ' ')"
[ "$(rtu serial source_timeouts)" -ge 1 ] 2>/dev/null && ! grep -Eq "^VIBIDRTULOG serial .*(No such file|denied)" console.txt ||
  bad "RTU with the serial drop-in: the port did not open: $(grep '^VIBIDRTU.* serial' console.txt | tr '\n' ' ')"
if [ $sanitized = no ]; then
# the two instances of vibidd@.service
inst() { awk -v i="$1" -v k="$2" '$1 == "VIBIDINST" && $2 == i && $3 == k { $1 = $2 = $3 = ""; sub(/^ +/, ""); print; exit }' console.txt; }
[ "$(v inst-start-rc)" = 0 ] && [ "$(v inst-stop-rc)" = 0 ] || bad "instances: start $(v inst-start-rc), stop $(v inst-stop-rc)"
[ "$(v inst-sim-rc | cut -d' ' -f1)" = 0 ] || bad "vibid-sim for the instances failed: $(v inst-sim-rc)"
for i in a b; do
  want_rows=6; [ $i = b ] && want_rows=3
  [ "$(inst $i active)" = active ] && [ "$(inst $i result)" = success ] ||
    bad "vibidd@$i: after start $(inst $i active), after stop result $(inst $i result)"
  [ "$(inst $i config)" = "$(dirname "$cfg")/$i.cfg" ] || bad "vibidd@$i runs with -c '$(inst $i config)', not $(dirname "$cfg")/$i.cfg"
  [ "$(inst $i status-samples)" = 300 ] || bad "vibidd@$i: /run/vibidd/$i/status shows $(inst $i status-samples) samples (300 expected)"
  [ "$(inst $i rows)" = $want_rows ] || bad "vibidd@$i: /var/lib/vibidd/$i/tracks.csv has $(inst $i rows) rows ($want_rows expected from its own decimation)"
  [ "$(inst $i raw-lines)" = 900 ] || bad "vibidd@$i: /var/lib/vibidd/$i/raw.log has $(inst $i raw-lines) lines (900 expected)"
  [ "$(inst $i state-dir)" = /var/lib/private/vibidd/$i ] || bad "vibidd@$i: state directory $(inst $i state-dir) (the dynamic user's /var/lib/private/vibidd/$i expected)"
  [ "$(inst $i runtime-dir-after-stop)" = removed ] || bad "vibidd@$i: /run/vibidd/$i still there after stop"
  u=$(inst $i uid)
  [ -n "$u" ] && [ "$u" != 0 ] || bad "vibidd@$i runs as uid '$u'"
done
[ "$(inst a uid)" != "$(inst b uid)" ] || bad "vibidd@a and vibidd@b share the dynamic uid $(inst a uid)"
for i in a b; do
  [ "$(inst $i mqtt-connect-failures)" -ge 1 ] 2>/dev/null ||
    bad "vibidd@$i: mqtt_connect_failures '$(inst $i mqtt-connect-failures)' (MQTT with its credential expected to run, failing to connect)"
  [ "$(inst $i credential)" = "-r-------- $(inst $i uid)" ] ||
    bad "vibidd@$i: credential /run/credentials/vibidd@$i.service/mqtt.password is '$(inst $i credential)' (-r-------- owned by uid $(inst $i uid) expected)"
done
[ "$(v inst-c-start-rc)" != 0 ] && [ "$(inst c result)" = exit-code ] ||
  bad "vibidd@c with a root-only password_file: start $(v inst-c-start-rc), result $(inst c result) (refused expected)"
[ "$(v inst-d-start-rc)" != 0 ] && [ -n "$(inst d result)" ] && [ "$(inst d result)" != success ] ||
  bad "vibidd@d without its password file: start $(v inst-d-start-rc), result $(inst d result) (refused expected: the credential is missing)"
grep -q '^VIBIDDLOG .*status=243/CREDENTIALS' console.txt ||
  bad "vibidd@d: no 'status=243/CREDENTIALS' in its journal: $(grep '^VIBIDDLOG' console.txt | head -n 3)"
grep -q '^VIBIDCLOG .*outputs.mqtt.password_file .*c.mqtt.password: Permission denied' console.txt ||
  bad "vibidd@c: no 'Permission denied' for its password file in the journal: $(grep '^VIBIDCLOG' console.txt | head -n 5)"
grep -Ei "^VIBIDINSTWARN .*(SCHED_FIFO|mlockall|denied|not permitted|operation not|address family)" console.txt &&
  bad "warnings about the sandbox in the instances' journal"
fi
[ $sanitized = yes ] && echo "NOT TESTED [systemd_vm]: vibidd@.service's instances (ASan build: its --check outlasts systemd's start time-out under TCG); the -Werror build tests them"
[ $ok -eq 1 ] || fail "checks failed; console: $work/console.txt"
echo "PASS: the installed vibidd.service under systemd (PID 1) in the VM: READY after $(v started | sed 's/uptime //') s of uptime, uid $uid, no capabilities, seccomp, own user namespace, SCHED_FIFO; 300 samples from vcan0, $rows track rows, 900 frames recorded, InfluxDB UDP; reload (outputs reopened) and stop clean; hw-timestamps drop-in: CAP_NET_ADMIN, host user namespace; serial drop-in: /dev/ttyS1 opens (time-outs $(rtu serial source_timeouts)), without it no device (connect failures $(rtu default source_connect_failures)); vibidd@a and vibidd@b at once: uids $(inst a uid) and $(inst b uid), each its own /etc/vibidd/<i>.cfg, 300 samples each, $(inst a rows) and $(inst b rows) rows in /var/lib/vibidd/a and /b, status in /run/vibidd/a and /b (removed at stop), MQTT passwords as credentials; vibidd@c with a root-only password file refused ('$(grep -o '^VIBIDCLOG .*password_file.*' console.txt | head -n 1 | cut -d' ' -f2-)'), vibidd@d without its password file not started ($(grep -o 'status=243/CREDENTIALS' console.txt | head -n 1)) ($((end - start)) s)"
