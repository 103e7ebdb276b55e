#!/usr/bin/env python3
"""Checks vibid's DBC decoder against cantools (an implementation nobody here wrote).

For every DBC given and every message in it, generates random payloads (fixed seed) of
the message's length, writes them as a candump log, decodes the log with our
dbc_decode_dump helper and the same payloads with cantools, and compares the physical
values of every signal.

Tolerance: both sides compute raw * factor + offset in IEEE double from the same raw
integer (or float32/float64 bits), so results are expected to be bit-identical; we
allow 4 ulp (|a-b| <= 4 * eps * max(|a|,|b|)) only so that a legitimate difference in
evaluation order (e.g. an FMA contraction on another compiler) does not fail the test,
and report the largest difference seen. NaN equals NaN (float signals with NaN bits).
Multiplexed messages: for 3/4 of the frames the multiplexor is forced to a value that
selects signals; cantools refuses frames with an unknown multiplexor value, and then
our decoder must report no multiplexed signal present.
"""
import argparse, math, os, random, subprocess, sys, tempfile

import cantools


def set_bits(data, sig, value):
    """Writes raw `value` into `data` at the signal's position (DBC bit numbering)."""
    n = sig.length
    if sig.byte_order == 'little_endian':
        for i in range(n):
            pos = sig.start + i
            bit = (value >> i) & 1
            data[pos // 8] = (data[pos // 8] & ~(1 << (pos % 8))) | (bit << (pos % 8))
    else:
        pos = sig.start
        for i in range(n):
            bit = (value >> (n - 1 - i)) & 1
            data[pos // 8] = (data[pos // 8] & ~(1 << (pos % 8))) | (bit << (pos % 8))
            pos = pos + 15 if pos % 8 == 0 else pos - 1


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--dump', required=True)
    ap.add_argument('--frames', type=int, default=200, help='frames per message')
    ap.add_argument('--seed', type=int, default=20240607)
    ap.add_argument('dbc', nargs='+')
    a = ap.parse_args()
    rng = random.Random(a.seed)
    total_frames = total_values = mux_rejected = 0
    total_defs = [0]
    max_rel = 0.0
    failures = []
    for path in a.dbc:
        db = cantools.database.load_file(path)
        lines, expected = [], []
        for m in db.messages:
            muxor = next((s for s in m.signals if s.is_multiplexer), None)
            mux_ids = sorted({i for s in m.signals for i in (s.multiplexer_ids or [])})
            fd = m.is_fd or m.length > 8
            for k in range(a.frames):
                data = bytearray(rng.getrandbits(8) for _ in range(m.length))
                if muxor is not None and mux_ids and k % 4 != 3:
                    set_bits(data, muxor, rng.choice(mux_ids))
                idtxt = ('%08X' % m.frame_id) if m.is_extended_frame else ('%03X' % m.frame_id)
                sep = '##1' if fd else '#'
                lines.append('(%010d.%06d) vcan0 %s%s%s' % (1700000000 + k, k % 1000000, idtxt, sep,
                                                               data.hex().upper()))
                try:
                    exp = m.decode(bytes(data), decode_choices=False,
                                   scaling=True)
                except cantools.database.errors.DecodeError:
                    exp = None
                    mux_rejected += 1
                expected.append((m, exp))
        with tempfile.NamedTemporaryFile('w', suffix='.log', delete=False) as f:
            f.write('\n'.join(lines) + '\n')
            logname = f.name
        try:
            out = subprocess.run([a.dump, path, logname], check=True, capture_output=True,
                                 text=True).stdout
        finally:
            os.unlink(logname)
        got = {}
        meta = {}
        for row in out.splitlines():
            if row.startswith('META '):
                head, unit = row.split(' "', 1)
                p = head.split(' ')
                meta[(p[1], p[2])] = (int(p[3]), int(p[4]), int(p[5]), int(p[6]), int(p[7]),
                                      float(p[8]), float(p[9]), float(p[10]), float(p[11]),
                                      unit[:-1])
                continue
            parts = row.split(' ')
            if len(parts) != 4:
                failures.append('%s: unexpected dump line %r' % (path, row))
                continue
            got.setdefault(int(parts[0]), {})[parts[2]] = float(parts[3])
        for m in db.messages:
            for s in m.signals:
                total_defs[0] += 1
                mine = meta.get((m.name, s.name))
                ref = (s.start, s.length, 1 if s.byte_order == 'little_endian' else 0,
                       int(s.is_signed), (2 if s.length == 64 else 1) if s.is_float else 0,
                       float(s.scale), float(s.offset),
                       float(s.minimum) if s.minimum is not None else None,
                       float(s.maximum) if s.maximum is not None else None, s.unit or '')
                if mine is None:
                    failures.append('%s: signal %s.%s missing in our reader' % (path, m.name, s.name))
                    continue
                # cantools reports [0|0] as "no limits" (None); we keep the numbers as written.
                same = all(r is None or r == x for r, x in zip(ref, mine))
                if not same:
                    failures.append('%s: %s.%s definition differs: cantools %r, ours %r' %
                                    (path, m.name, s.name, ref, mine))
        if len(meta) != sum(len(m.signals) for m in db.messages):
            failures.append('%s: we read %d signals, cantools %d' %
                            (path, len(meta), sum(len(m.signals) for m in db.messages)))
        for ln, (m, exp) in enumerate(expected, start=1):
            total_frames += 1
            ours = got.get(ln, {})
            if exp is None:
                muxed = {s.name for s in m.signals if s.multiplexer_ids}
                if muxed & set(ours):
                    failures.append('%s line %d %s: multiplexed signals %s present although the '
                                    'multiplexor selects none' % (path, ln, m.name,
                                                                  sorted(muxed & set(ours))))
                continue
            if set(exp) != set(ours):
                failures.append('%s line %d %s: signals differ: cantools %s, ours %s' %
                                (path, ln, m.name, sorted(exp), sorted(ours)))
                continue
            for name, ev in exp.items():
                ev = float(ev)
                ov = ours[name]
                total_values += 1
                if math.isnan(ev) and math.isnan(ov):
                    continue
                scale = max(abs(ev), abs(ov))
                diff = abs(ev - ov)
                if scale > 0 and math.isfinite(scale):
                    max_rel = max(max_rel, diff / scale)
                if not (ev == ov or diff <= 4 * sys.float_info.epsilon * scale):
                    failures.append('%s line %d %s.%s: cantools %r, ours %r' %
                                    (path, ln, m.name, name, ev, ov))
    print('dbc_vs_cantools: %d DBC files, %d signal definitions, %d frames, %d signal values '
          'compared, %d frames with unselected multiplexor checked, max relative difference %.3g'
          % (len(a.dbc), total_defs[0], total_frames, total_values, mux_rejected, max_rel))
    for f in failures[:30]:
        print('MISMATCH', f)
    if failures:
        print('%d mismatches' % len(failures))
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
