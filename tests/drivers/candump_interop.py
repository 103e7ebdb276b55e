#!/usr/bin/env python3
"""candump logs against tools nobody here wrote.

1. python-can's CanutilsLogWriter writes classic, extended, RTR, error and CAN FD
   frames (BRS/ESI); vibid reads them and writes them back; python-can's
   CanutilsLogReader reads our output: every field must match, timestamps to the
   microsecond (the candump format's resolution).
2. A log in can-utils' exact format round-trips through vibid byte for byte.
3. can-utils' log2long (when installed) parses our output and prints the same as for
   the can-utils-format input.
"""
import os, random, shutil, subprocess, sys, tempfile

import can


def msgs_equal(a, b):
    if a.is_error_frame:
        # python-can writes every error frame as class 0x80 (bus error) with its data and
        # reads such a line back as id 0 without data, whatever the content; so only the
        # error-frame flag and the time survive its own round trip.
        return b.is_error_frame and abs(a.timestamp - b.timestamp) < 1.5e-6
    return (a.arbitration_id == b.arbitration_id and a.is_extended_id == b.is_extended_id and
            a.is_remote_frame == b.is_remote_frame and a.is_error_frame == b.is_error_frame and
            a.is_fd == b.is_fd and a.bitrate_switch == b.bitrate_switch and
            a.error_state_indicator == b.error_state_indicator and
            (a.is_remote_frame or bytes(a.data) == bytes(b.data)) and
            abs(a.timestamp - b.timestamp) < 1.5e-6)


def main():
    tool = sys.argv[1]
    rng = random.Random(7)
    tmp = tempfile.mkdtemp()
    try:
        src, out = os.path.join(tmp, 'pycan.log'), os.path.join(tmp, 'ours.log')
        msgs = []
        t = 1700000000.0
        fd_lens = [0, 1, 8, 12, 16, 20, 24, 32, 48, 64]
        for k in range(2000):
            t += rng.uniform(1e-4, 1e-2)
            kind = k % 5
            ext = rng.random() < 0.5
            aid = rng.randrange(1 << 29) if ext else rng.randrange(1 << 11)
            if kind == 0 or kind == 1:
                n = rng.randrange(9)
                m = can.Message(timestamp=round(t, 6), arbitration_id=aid, is_extended_id=ext,
                                data=bytes(rng.getrandbits(8) for _ in range(n)), channel='vcan0')
            elif kind == 2:
                n = rng.choice(fd_lens)
                m = can.Message(timestamp=round(t, 6), arbitration_id=aid, is_extended_id=ext,
                                is_fd=True, bitrate_switch=rng.random() < 0.5,
                                error_state_indicator=rng.random() < 0.3,
                                data=bytes(rng.getrandbits(8) for _ in range(n)), channel='vcan0')
            elif kind == 3:
                m = can.Message(timestamp=round(t, 6), arbitration_id=aid, is_extended_id=ext,
                                is_remote_frame=True, dlc=0, channel='vcan0')
            else:
                m = can.Message(timestamp=round(t, 6), arbitration_id=rng.choice([0x4, 0x40, 0x100]),
                                is_error_frame=True, data=bytes(8), channel='vcan0')
            msgs.append(m)
        with can.CanutilsLogWriter(src, channel='vcan0') as w:
            for m in msgs:
                w.on_message_received(m)
        r = subprocess.run([tool, src, out], capture_output=True, text=True)
        if r.returncode != 0 or r.stderr:
            print('FAIL: vibid could not read python-can log:', r.stderr[:2000])
            return 1
        back = list(can.CanutilsLogReader(out))
        bad = [i for i, (a, b) in enumerate(zip(msgs, back)) if not msgs_equal(a, b)]
        if len(back) != len(msgs) or bad:
            print('FAIL: %d frames written by python-can, %d read back, %d differ' %
                  (len(msgs), len(back), len(bad)))
            for i in bad[:5]:
                print('  python-can:', msgs[i], '\n  after vibid:', back[i])
            return 1
        print('python-can -> vibid -> python-can: %d frames identical' % len(msgs))

        canon = os.path.join(tmp, 'canon.log')
        lines = []
        for k in range(3000):
            sec, usec = 1700000000 + k // 1000, (k * 997) % 1000000
            ext = k % 3 == 0
            aid = ('%08X' % rng.randrange(1 << 29)) if ext else ('%03X' % rng.randrange(1 << 11))
            kind = k % 4
            if kind == 0:
                frame = aid + '#' + ''.join('%02X' % rng.getrandbits(8) for _ in range(rng.randrange(9)))
            elif kind == 1:
                frame = aid + '##' + '%X' % rng.randrange(16) + ''.join(
                    '%02X' % rng.getrandbits(8) for _ in range(rng.choice(fd_lens)))
            elif kind == 2:
                frame = aid + '#R' + (str(rng.randrange(1, 9)) if rng.random() < 0.5 else '')
            else:
                frame = '2000%04X#' % rng.choice([4, 0x40, 0x100]) + '00' * 8
            lines.append('(%010d.%06d) vcan0 %s' % (sec, usec, frame))
        lines.append("DROPCOUNT: dropped 5 CAN frames on 'vcan0' socket (total drops 5)")
        with open(canon, 'w') as f:
            f.write('\n'.join(lines) + '\n')
        r = subprocess.run([tool, canon, out], capture_output=True, text=True)
        a, b = open(canon, 'rb').read(), open(out, 'rb').read()
        if r.returncode != 0 or a != b:
            print('FAIL: can-utils format did not round-trip byte for byte', r.stderr[:500])
            for la, lb in zip(a.splitlines(), b.splitlines()):
                if la != lb:
                    print('  in :', la, '\n  out:', lb)
                    break
            return 1
        print('can-utils format: %d lines round-trip byte for byte' % len(lines))

        l2l = shutil.which('log2long')
        if l2l:
            x = subprocess.run([l2l], stdin=open(canon), capture_output=True).stdout
            y = subprocess.run([l2l], stdin=open(out), capture_output=True).stdout
            if x != y or not x:
                print('FAIL: can-utils log2long output differs for our log')
                return 1
            print('can-utils log2long reads our log identically (%d bytes)' % len(x))
        else:
            print('NOTE: log2long (can-utils) not installed: that sub-check was NOT run')
        return 0
    finally:
        shutil.rmtree(tmp)


if __name__ == '__main__':
    sys.exit(main())
