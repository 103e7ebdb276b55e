#!/usr/bin/env python3
"""sim.dbc_cantools: cantools (independent of this project) decodes vibid-sim's candump
frames with the DBC vibid-sim wrote (classic and CAN FD) to the simulated values of the
CSV written in the same run; the shipped sim/*.dbc load in cantools.

usage: dbc_cantools_check.py VIBID_SIM STAND SIM_DIR WORK_DIR
"""
import csv
import os
import struct
import subprocess
import sys

import cantools


def f32(x):
    return struct.unpack("<f", struct.pack("<f", x))[0]


def main():
    exe, stand, simdir, work = sys.argv[1:5]
    simcfg = os.path.join(simdir, "examples", "paper_example1_sim.cfg")
    for shipped in sorted(f for f in os.listdir(simdir) if f.endswith(".dbc")):
        db = cantools.database.load_file(os.path.join(simdir, shipped))
        assert db.messages, shipped
        print(f"{shipped}: {len(db.messages)} messages load in cantools {cantools.__version__}")
    for mode in ("--classic", "--fd"):
        tag = mode[2:]
        log = os.path.join(work, f"ct_{tag}.log")
        csvp = os.path.join(work, f"ct_{tag}.csv")
        dbcp = os.path.join(work, f"ct_{tag}.dbc")
        subprocess.run([exe, "-c", stand, "-s", simcfg, "--duration", "0.5", "--csv", csvp, "--candump", log,
                        "--write-dbc", dbcp, "--epoch", "100", mode, "-q"], check=True, timeout=30)
        db = cantools.database.load_file(dbcp)
        with open(csvp) as f:
            rows = list(csv.DictReader(f))
        n = 0
        per_sample = {}
        with open(log) as f:
            for line in f:
                ts, iface, frame = line.split()
                ident, data = frame.split("#", 1)
                is_fd = data.startswith("#")
                if is_fd:
                    data = data[2:]  # flags nibble
                assert is_fd == (mode == "--fd"), line
                msg = db.get_message_by_frame_id(int(ident, 16))
                assert msg.is_fd == is_fd, (msg.name, msg.is_fd)
                vals = msg.decode(bytes.fromhex(data), decode_choices=False, scaling=True)
                k = round((float(ts[1:-1]) - 100.0) / 5e-4)
                assert vals["SampleCounter"] == k % 65536, (vals, k)
                row = rows[k]
                for name, v in vals.items():
                    if name == "SampleCounter":
                        continue
                    want = f32(float(row[name]))
                    assert v == want, (name, k, v, want)
                    per_sample.setdefault(k, set()).add(name)
                n += 1
        assert len(per_sample) == len(rows) == 1000, (len(per_sample), len(rows))
        assert all(s == {"x1", "x2", "s"} for s in per_sample.values())
        print(f"{tag}: cantools decoded {n} frames = {len(rows)} samples; every value equals the CSV's (float32)")
    print("PASS")


if __name__ == "__main__":
    main()
