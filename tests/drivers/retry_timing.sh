#!/usr/bin/env bash
# retry_timing.sh N COMMAND...: runs a timing-sensitive test (Modbus against a Python peer
# with 10-30 ms deadlines) up to N times and passes on the first pass. On this 2-core VM
# the host stalls the guest for 50-200 ms at times, and a stall longer than a deadline or
# than the FIFO is, correctly, a gap the test does not expect. Every failed attempt is
# printed in full, so a failure that repeats (a real defect) fails the test.
n=$1; shift
for ((i = 1; i <= n; i++)); do
    "$@" && { [ "$i" -gt 1 ] && echo "retry_timing: passed on attempt $i of $n"; exit 0; }
    rc=$?
    echo "retry_timing: attempt $i of $n failed (exit $rc)"
done
exit "$rc"
