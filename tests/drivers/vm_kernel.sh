# Sourced helper for the qemu SocketCAN tests (tests/drivers/vm_socketcan.sh and
# tests/daemon/vm_socketcan_e2e.sh): Debian's own kernel package and its CAN modules,
# never installed on the host, and the pieces of the VM's initramfs.
#
# vm_add_busybox ROOT: a static busybox (Debian: busybox-static) as ROOT/bin/busybox.
# vm_fetch_kernel CACHE_DIR: apt-get download of the package linux-image-amd64 depends
#   on (once; cached, shared between tests, serialised with flock), dpkg -x; sets
#   VM_VMLINUZ and VM_MODS (the unpacked lib/modules/<version>/kernel). Calls fail()
#   (the caller's) with a clear message when anything is missing.
# vm_add_can_modules ROOT: can.ko, can-raw.ko, can-dev.ko, vcan.ko into ROOT/mod
#   (decompressed; load them in that order).
# vm_add_binary ROOT FILE...: FILE and its shared libraries (ldd) into ROOT/bin and
#   ROOT/lib64 | ROOT/lib/x86_64-linux-gnu (run with LD_LIBRARY_PATH set to the latter).
# vm_init_prologue: the first lines of ROOT/init (mounts, CAN modules, vcan0 up).

vm_fetch_kernel() {
  cache=$1
  mkdir -p "$cache" || fail "cannot create $cache"
  pkg=$(apt-cache depends linux-image-amd64 2>/dev/null | awk '/Depends: linux-image-[0-9]/{print $2; exit}')
  [ -n "$pkg" ] || fail "apt-cache depends linux-image-amd64 named no kernel package (apt-get update needed?)"
  (
    flock -w 600 9 || fail "could not lock $cache/.lock within 600 s"
    deb=$(ls "$cache"/${pkg}_*.deb 2>/dev/null | head -n 1)
    if [ -z "$deb" ]; then
      echo "downloading $pkg (about 70 MB, once; cached in $cache)"
      (cd "$cache" && apt-get download "$pkg") > "$cache/download.log" 2>&1 ||
        { cat "$cache/download.log" >&2; fail "apt-get download $pkg failed (network or apt sources?): the kernel package is needed to boot the VM"; }
      deb=$(ls "$cache"/${pkg}_*.deb 2>/dev/null | head -n 1)
      [ -n "$deb" ] || fail "apt-get download $pkg produced no .deb"
    fi
    kroot=$cache/kernel-$pkg
    if [ ! -d "$kroot" ]; then
      rm -rf "$kroot.tmp" && dpkg -x "$deb" "$kroot.tmp" || fail "dpkg -x $deb failed"
      mv "$kroot.tmp" "$kroot"
    fi
  ) 9> "$cache/.lock" || exit 1
  kroot=$cache/kernel-$pkg
  VM_VMLINUZ=$(ls "$kroot"/boot/vmlinuz-* 2>/dev/null | head -n 1)
  [ -n "$VM_VMLINUZ" ] || fail "no /boot/vmlinuz-* in the package $pkg"
  VM_MODS=$(ls -d "$kroot"/lib/modules/*/kernel 2>/dev/null | head -n 1)
  [ -n "$VM_MODS" ] || fail "no lib/modules/*/kernel in the package $pkg"
}

vm_add_busybox() {
  bb=/bin/busybox
  [ -x "$bb" ] && file -L "$bb" 2>/dev/null | grep -q "statically linked" || bb=$(command -v busybox)
  [ -n "$bb" ] && ldd "$bb" 2>&1 | grep -q "not a dynamic" || fail "a static busybox is needed (Debian: busybox-static)"
  mkdir -p "$1/bin" && cp "$bb" "$1/bin/busybox" || fail "cannot copy $bb"
}

vm_add_can_modules() {
  mkdir -p "$1/mod"
  for m in net/can/can net/can/can-raw drivers/net/can/dev/can-dev drivers/net/can/vcan; do
    name=$(basename $m)
    if [ -f "$VM_MODS/$m.ko" ]; then cp "$VM_MODS/$m.ko" "$1/mod/$name.ko"
    elif [ -f "$VM_MODS/$m.ko.xz" ]; then xz -dc "$VM_MODS/$m.ko.xz" > "$1/mod/$name.ko"
    elif [ -f "$VM_MODS/$m.ko.zst" ]; then zstd -dqc "$VM_MODS/$m.ko.zst" > "$1/mod/$name.ko"
    else fail "module $m.ko(.xz/.zst) not in the kernel package"; fi
  done
}

# The first lines of a VM's /init (busybox shell): mounts, the CAN modules that
# vm_add_can_modules put in /mod, and vcan0 up. The caller appends its own steps.
vm_init_prologue() {
  cat <<'INIT'
#!/bin/busybox sh
/bin/busybox --install -s /bin
export PATH=/bin LD_LIBRARY_PATH=/lib/x86_64-linux-gnu
mount -t proc proc /proc; mount -t sysfs sys /sys; mount -t devtmpfs dev /dev 2>/dev/null
echo "VIBID-BOOTED uptime $(cut -d' ' -f1 /proc/uptime)"
for m in can can-raw can-dev vcan; do insmod /mod/$m.ko || echo "VIBID-FAIL insmod $m"; done
ip link add dev vcan0 type vcan && ip link set up vcan0 || echo "VIBID-FAIL ip link vcan0"
INIT
}

vm_add_binary() {
  root=$1
  shift
  mkdir -p "$root/bin" "$root/lib64" "$root/lib/x86_64-linux-gnu"
  for b in "$@"; do
    cp "$b" "$root/bin/" || fail "cannot copy $b"
    for lib in $(ldd "$b" | awk '/=> \//{print $3} /^\t\/lib64/{print $1}'); do
      case $lib in
        /lib64/*) cp -L "$lib" "$root/lib64/" ;;
        *) cp -L "$lib" "$root/lib/x86_64-linux-gnu/" ;;
      esac
    done
  done
}
