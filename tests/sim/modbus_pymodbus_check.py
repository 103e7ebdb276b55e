#!/usr/bin/env python3
"""sim.modbus_pymodbus: an independent client (pymodbus) reads vibid-sim's Modbus TCP
server on 127.0.0.1 (ephemeral port): FIFO header per drivers/modbus_fifo_layout.md,
records in chunks of <= 125 registers for about 1 s, current-value registers; every
sample read equals the CSV row of the same run (float32). Bounded: the simulator runs 2 s.

usage: modbus_pymodbus_check.py VIBID_SIM STAND WORK_DIR
"""
import csv
import os
import struct
import subprocess
import sys
import time

from pymodbus.client import ModbusTcpClient

B = 1000


def f32(hi, lo):
    return struct.unpack(">f", struct.pack(">HH", hi, lo))[0]


def main():
    exe, stand, work = sys.argv[1:4]
    simcfg = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "sim", "examples", "paper_example1_sim.cfg")
    csvp = os.path.join(work, "pym.csv")
    p = subprocess.Popen([exe, "-c", stand, "-s", simcfg, "--modbus", "127.0.0.1:0", "--duration", "2", "--csv", csvp, "-q"],
                         stdout=subprocess.PIPE, text=True)
    try:
        line = p.stdout.readline()
        port = int(line.split("127.0.0.1:")[1].split()[0])
        c = ModbusTcpClient("127.0.0.1", port=port, timeout=1)
        assert c.connect()
        h = c.read_holding_registers(B, 19, slave=1).registers
        assert h[0] == 0x5646 and h[1] == 1 and h[2] == 3 and h[3] == 7, h
        C, W, K, D = h[2], h[3], h[4], h[5]
        assert ((h[6] << 16) | h[7]) == 500000
        got = {}
        nxt = None
        t_end = time.monotonic() + 1.0
        while time.monotonic() < t_end:
            r = c.read_holding_registers(B + 8, 4, slave=1).registers
            S, ws = (r[0] << 16) | r[1], r[2]
            if nxt is None:
                nxt = max(0, S - K)
            assert S - nxt <= K, "fell behind"
            while nxt < S:
                slot = (ws - (S - nxt)) % K
                n = min(125 // W, S - nxt, K - slot)
                regs = c.read_holding_registers(B + D + slot * W, n * W, slave=1).registers
                for i in range(n):
                    rec = regs[i * W:(i + 1) * W]
                    s = nxt + i
                    assert rec[0] == s % 65536, (rec[0], s)
                    got[s] = [f32(rec[1 + 2 * j], rec[2 + 2 * j]) for j in range(C)]
                nxt += n
            time.sleep(0.02)
        cur = c.read_holding_registers(0, 6, slave=1).registers
        assert all(v == v for v in (f32(cur[0], cur[1]), f32(cur[2], cur[3]), f32(cur[4], cur[5])))
        c.close()
    finally:
        rc = p.wait(timeout=20)
    assert rc == 0, rc
    with open(csvp) as f:
        rows = list(csv.DictReader(f))
    for s, v in got.items():
        want = [struct.unpack("<f", struct.pack("<f", float(rows[s][k])))[0] for k in ("x1", "x2", "s")]
        assert v == want, (s, v, want)
    ks = sorted(got)
    assert ks == list(range(ks[0], ks[-1] + 1)), "gap in the samples read"
    assert len(ks) >= 1500, len(ks)
    print(f"pymodbus: read {len(ks)} consecutive samples ({ks[0]}..{ks[-1]}) from the FIFO, all equal to the CSV (float32)")
    print("PASS")


if __name__ == "__main__":
    main()
