#!/usr/bin/env bash
# daemon.systemd_security (issue 12): the systemd unit as `cmake --install` installs it
# (generated from daemon/vibidd.service.in, component vibidd, into a scratch DESTDIR)
#  1. systemd-analyze security --offline=yes: overall exposure <= MAX (2.5), printed;
#  2. systemd-analyze verify: no message at all (errors or warnings about the unit's own
#     directives, unknown directives, missing executables);
#  3. the same two for the unit plus each drop-in that docs/vibidd.md documents (the
#     fenced blocks after a line `<!-- drop-in: NAME -->`), so that the documented
#     snippets are valid and what they cost in exposure is measured, not guessed.
# Why verify runs with --root: the unit names the installed daemon (<prefix>/sbin/vibidd),
# which does not exist on this machine, and verify rightly reports a missing executable.
# Instead of editing a copy (which would no longer be the unit as installed), the check
# runs against a scratch root: the DESTDIR of the install (the daemon at the unit's path)
# plus a copy of this machine's unit directory (the targets the unit depends on) and
# /bin/kill (ExecReload). Nothing of the unit is changed.
# Usage: unit_security.sh BUILD_DIR SOURCE_DIR WORK_DIR [MAX]
# Fails (never skips) when systemd-analyze is missing (Debian package systemd,
# scripts/install-deps.sh --test).
set -u
build=$(cd "$1" && pwd)
src=$(cd "$2" && pwd)
work=$3
max=${4:-2.5}
fail() { echo "FAIL [systemd_security]: $*" >&2; exit 1; }
command -v systemd-analyze >/dev/null 2>&1 ||
  fail "systemd-analyze not found (Debian: package systemd; scripts/install-deps.sh --test installs it)"
command -v cmake >/dev/null 2>&1 || fail "cmake not found"

rm -rf "$work" && mkdir -p "$work" || fail "cannot create $work"
root=$work/root
DESTDIR=$root cmake --install "$build" --component vibidd > "$work/install.log" 2>&1 ||
  { cat "$work/install.log" >&2; fail "cmake --install --component vibidd failed"; }
unit=$(cd "$root" && find . -path '*/lib/systemd/system/vibidd.service' | head -n 1)
[ -n "$unit" ] || fail "no lib/systemd/system/vibidd.service installed under $root"
unit=${unit#.}
exe=$(sed -n 's/^ExecStart=\([^ ]*\).*/\1/p' "$root$unit")
echo "installed unit: $unit (ExecStart: $exe)"
[ -x "$root$exe" ] || fail "the unit's ExecStart $exe is not where the install put the daemon: $(cd "$root" && find . -name vibidd -type f)"
grep -q '@[A-Z_]*@' "$root$unit" && fail "placeholders left in the installed unit: $(grep '@[A-Z_]*@' "$root$unit")"
# every directive has a comment line right above it (the unit's own rule)
awk '/^[A-Za-z]+=/ && prev !~ /^#/ { print FILENAME ":" NR ": " $0; bad = 1 } { prev = $0 } END { exit bad }' >&2 \
  "$src/daemon/vibidd.service.in" || fail "directives above without a comment line (daemon/vibidd.service.in)"

# the rest of the scratch root for verify (see above)
mkdir -p "$root/usr/lib/systemd" "$root/usr/bin" "$root/etc/systemd/system" || fail "mkdir in $root"
cp -a /usr/lib/systemd/system "$root/usr/lib/systemd/" || fail "cannot copy /usr/lib/systemd/system"
[ -e "$root/bin" ] || ln -s usr/bin "$root/bin"
cp /bin/kill "$root/usr/bin/kill" || fail "cannot copy /bin/kill"

ok=1
check() {  # $1: label; the drop-ins currently in $root/etc/systemd/system/vibidd.service.d
  local label=$1 out exposure
  out=$(systemd-analyze verify --root="$root" vibidd.service 2>&1)
  local rc=$?
  if [ $rc -ne 0 ] || [ -n "$out" ]; then
    echo "FAIL [systemd_security]: systemd-analyze verify ($label), exit $rc:" >&2
    echo "$out" >&2
    ok=0
  else
    echo "verify ($label): no messages"
  fi
  systemd-analyze security --offline=yes --root="$root" vibidd.service > "$work/security_$label.txt" 2>&1
  exposure=$(sed -n 's/.*Overall exposure level for vibidd.service: \([0-9.]*\).*/\1/p' "$work/security_$label.txt")
  [ -n "$exposure" ] || { cat "$work/security_$label.txt" >&2; echo "FAIL: no exposure figure ($label)" >&2; ok=0; return; }
  echo "exposure ($label): $exposure (limit $max); not fully protected:"
  grep '✗' "$work/security_$label.txt" | sed 's/^/  /'
  if ! awk -v e="$exposure" -v m="$max" 'BEGIN { exit !(e <= m) }'; then
    echo "FAIL [systemd_security]: exposure $exposure > $max ($label)" >&2
    ok=0
  fi
  EXPOSURE=$exposure
}

check unit
unit_exposure=$EXPOSURE

# the documented drop-ins, each alone on top of the unit
names=$(sed -n 's/^<!-- drop-in: \([a-z0-9_-]*\) -->$/\1/p' "$src/docs/vibidd.md")
[ -n "$names" ] || fail "docs/vibidd.md documents no drop-in (<!-- drop-in: NAME --> markers)"
for n in $names; do
  d=$root/etc/systemd/system/vibidd.service.d
  rm -rf "$d" && mkdir -p "$d"
  awk -v n="$n" '$0 == "<!-- drop-in: " n " -->" { want = 1; next }
                 want && /^```/ { if (inside) exit; inside = 1; next }
                 inside { print }' "$src/docs/vibidd.md" > "$d/$n.conf"
  grep -q '^\[Service\]' "$d/$n.conf" || { echo "FAIL: drop-in $n: no [Service] block after its marker" >&2; ok=0; continue; }
  check "drop-in-$n"
done
rm -rf "$root/etc/systemd/system/vibidd.service.d"

[ $ok -eq 1 ] || fail "see above"
echo "PASS: installed vibidd.service: exposure $unit_exposure <= $max, verify clean; documented drop-ins verified"
