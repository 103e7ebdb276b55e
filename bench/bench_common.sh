# Helpers shared by the vibidd benchmark scripts (sourced).
ns() { date +%s%N; }
# cpu_of PID -> "user_ticks sys_ticks"
cpu_of() { awk '{ print $14, $15 }' "/proc/$1/stat"; }
# status_get KEY FILE -> the value of KEY= in a vibidd status file
status_get() { sed -n "s/^$1=//p" "$2"; }
# cpu_window PID SECONDS -> "user_ticks sys_ticks wall_ns" used by PID over the next SECONDS
cpu_window() {
    local u0 s0 u1 s1 t0 t1
    read -r u0 s0 < <(cpu_of "$1")
    t0=$(ns)
    sleep "$2"
    read -r u1 s1 < <(cpu_of "$1")
    t1=$(ns)
    echo $((u1 - u0)) $((s1 - s0)) $((t1 - t0))
}
