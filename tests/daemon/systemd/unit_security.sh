#!/usr/bin/env bash
# daemon.systemd_security (issues 12, 14): the systemd units as `cmake --install` installs
# them (both generated from daemon/vibidd.service.in, component vibidd, into a scratch
# DESTDIR): vibidd.service and the template vibidd@.service, instantiated as
# vibidd@stand1.service (docs/vibidd.md, "Many stands on one host")
#  1. systemd-analyze security --offline=yes: overall exposure <= MAX (2.5), printed, for
#     each unit; the instance's equal to the plain unit's (one source of the hardening);
#  2. systemd-analyze verify: no message at all (errors or warnings about the unit's own
#     directives, unknown directives, missing executables);
#  3. the same two for each unit plus each drop-in that docs/vibidd.md documents (the
#     fenced blocks after a line `<!-- drop-in: NAME -->`; for the template in
#     vibidd@.service.d, where `systemctl edit vibidd@` puts it for all instances), so that
#     the documented snippets are valid and what they cost in exposure is measured, not
#     guessed;
#  4. the two generated units differ exactly in the lines that must (Description, the
#     configuration in ExecStartPre/ExecStart, StateDirectory, RuntimeDirectory, User), with
#     the instance's /etc/vibidd/%i.cfg, vibidd/%i, vibidd-%i.
# Why verify runs with --root: the units name the installed daemon (<prefix>/sbin/vibidd),
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
units=$(cd "$root" && find . -path '*/lib/systemd/system/vibidd*.service' | sort)
plain=$(echo "$units" | grep '/vibidd\.service$' | head -n 1)
tmpl=$(echo "$units" | grep '/vibidd@\.service$' | head -n 1)
[ -n "$plain" ] || fail "no lib/systemd/system/vibidd.service installed under $root"
[ -n "$tmpl" ] || fail "no lib/systemd/system/vibidd@.service installed under $root (next to $plain)"
[ "$(dirname "$plain")" = "$(dirname "$tmpl")" ] || fail "vibidd.service ($plain) and vibidd@.service ($tmpl) installed in different directories"
for unit in $plain $tmpl; do
  unit=${unit#.}
  exe=$(sed -n 's/^ExecStart=\([^ ]*\).*/\1/p' "$root$unit")
  echo "installed unit: $unit (ExecStart: $exe)"
  [ -x "$root$exe" ] || fail "$unit: ExecStart $exe is not where the install put the daemon: $(cd "$root" && find . -name vibidd -type f)"
  grep -q '@[A-Z_]*@' "$root$unit" && fail "placeholders left in the installed $unit: $(grep '@[A-Z_]*@' "$root$unit")"
done
# every directive has a comment line right above it (the unit's own rule)
awk '/^[A-Za-z]+=/ && prev !~ /^#/ { print FILENAME ":" NR ": " $0; bad = 1 } { prev = $0 } END { exit bad }' >&2 \
  "$src/daemon/vibidd.service.in" || fail "directives above without a comment line (daemon/vibidd.service.in)"
# the two units from the one template: only these lines may differ, and they must
diffs=$(diff <(grep -v '^#' "$root/$plain") <(grep -v '^#' "$root/$tmpl") | sed -n 's/^\([<>]\) /\1 /p')
want='< Description=vibid acquisition and identification daemon
< ExecStartPre=EXE -c /etc/vibidd/vibidd.cfg --check
< ExecStart=EXE -c /etc/vibidd/vibidd.cfg
< StateDirectory=vibidd
< RuntimeDirectory=vibidd
< User=vibidd
> Description=vibid acquisition and identification daemon, stand %i
> ExecStartPre=EXE -c /etc/vibidd/%i.cfg --check
> ExecStart=EXE -c /etc/vibidd/%i.cfg
> StateDirectory=vibidd/%i
> RuntimeDirectory=vibidd/%i
> User=vibidd-%i'
got=$(echo "$diffs" | sed "s|=$exe |=EXE |" | sort)
if [ "$got" != "$(echo "$want" | sort)" ]; then
  echo "FAIL [systemd_security]: vibidd.service and vibidd@.service differ in other lines than expected:" >&2
  diff <(echo "$want" | sort) <(echo "$got") >&2
  fail "the template's and the plain unit's directives must come from the one template"
fi
echo "vibidd.service and vibidd@.service: the same directives but Description, the configuration (%i.cfg), StateDirectory and RuntimeDirectory (vibidd/%i), User (vibidd-%i)"

# the rest of the scratch root for verify (see above)
mkdir -p "$root/usr/lib/systemd" "$root/usr/bin" "$root/etc/systemd/system" || fail "mkdir in $root"
cp -a /usr/lib/systemd/system "$root/usr/lib/systemd/" || fail "cannot copy /usr/lib/systemd/system"
[ -e "$root/bin" ] || ln -s usr/bin "$root/bin"
cp /bin/kill "$root/usr/bin/kill" || fail "cannot copy /bin/kill"

ok=1
check() {  # $1: unit name (an instance for the template); $2: label; the drop-ins currently in place
  local name=$1 label=$2 out exposure rc
  out=$(systemd-analyze verify --root="$root" "$name" 2>&1)
  rc=$?
  if [ $rc -ne 0 ] || [ -n "$out" ]; then
    echo "FAIL [systemd_security]: systemd-analyze verify $name ($label), exit $rc:" >&2
    echo "$out" >&2
    ok=0
  else
    echo "verify $name ($label): no messages"
  fi
  systemd-analyze security --offline=yes --root="$root" "$name" > "$work/security_${name}_$label.txt" 2>&1
  exposure=$(sed -n "s/.*Overall exposure level for $name: \([0-9.]*\).*/\1/p" "$work/security_${name}_$label.txt")
  EXPOSURE=
  [ -n "$exposure" ] || { cat "$work/security_${name}_$label.txt" >&2; echo "FAIL: no exposure figure ($name, $label)" >&2; ok=0; return; }
  echo "exposure $name ($label): $exposure (limit $max); not fully protected:"
  grep '✗' "$work/security_${name}_$label.txt" | sed 's/^/  /'
  if ! awk -v e="$exposure" -v m="$max" 'BEGIN { exit !(e <= m) }'; then
    echo "FAIL [systemd_security]: exposure $exposure > $max ($name, $label)" >&2
    ok=0
  fi
  EXPOSURE=$exposure
}

# the documented drop-ins: `<!-- drop-in: NAME -->` for both units, `<!-- drop-in: NAME
# (vibidd@ only) -->` for the template only (e.g. a credential named after the instance)
markers=$(grep -E '^<!-- drop-in: [a-z0-9_-]+( \(vibidd@ only\))? -->$' "$src/docs/vibidd.md")
[ -n "$markers" ] || fail "docs/vibidd.md documents no drop-in (<!-- drop-in: NAME --> markers)"
summary= e_plain= e_inst=
# unit name to check, its drop-in directory: the plain unit, and the template through one instance
for pair in vibidd.service:vibidd.service.d vibidd@stand1.service:vibidd@.service.d; do
  name=${pair%%:*} d=$root/etc/systemd/system/${pair#*:}
  rm -rf "$d"
  check "$name" unit
  if [ "$name" = vibidd.service ]; then e_plain=$EXPOSURE; else e_inst=$EXPOSURE; fi
  summary="$summary $name $EXPOSURE;"
  # the documented drop-ins, each alone on top of the unit
  while IFS= read -r m; do
    n=$(echo "$m" | sed 's/^<!-- drop-in: \([a-z0-9_-]*\).*/\1/')
    case "$m:$name" in *"(vibidd@ only) -->:vibidd.service") continue ;; esac
    rm -rf "$d" && mkdir -p "$d"
    awk -v m="$m" '$0 == m { want = 1; next }
                   want && /^```/ { if (inside) exit; inside = 1; next }
                   inside { print }' "$src/docs/vibidd.md" > "$d/$n.conf"
    grep -q '^\[Service\]' "$d/$n.conf" || { echo "FAIL: drop-in $n: no [Service] block after its marker" >&2; ok=0; continue; }
    check "$name" "drop-in-$n" < /dev/null
    summary="$summary $name + $n $EXPOSURE;"
  done <<< "$markers"
  rm -rf "$d"
done
if [ -z "$e_plain" ] || [ "$e_plain" != "$e_inst" ]; then
  echo "FAIL [systemd_security]: exposure of vibidd@stand1.service '$e_inst' differs from vibidd.service's '$e_plain' (same hardening expected)" >&2
  ok=0
fi

[ $ok -eq 1 ] || fail "see above"
echo "PASS: installed vibidd.service and vibidd@.service (as vibidd@stand1.service): exposure $e_plain and $e_inst <= $max, verify clean; documented drop-ins verified on both:$summary"
