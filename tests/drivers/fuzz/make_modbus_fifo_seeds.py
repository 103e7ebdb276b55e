#!/usr/bin/env python3
"""Writes the seed corpus of fuzz_modbus_fifo (corpus/modbus_fifo/*.bin): a few valid
device scenarios in the input format that fuzz_modbus_fifo.c reads. Run it again after
changing that format: python3 make_modbus_fifo_seeds.py"""
import os
import struct

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "corpus", "modbus_fifo")

# op codes (byte % 20): 0..5 read, 6..7 time passes, 8..9 time passes + device writes,
# 10 produce n, 11 restart, 12 session id, 13 counter jump, 14 write slot, 15 header
# zero/restore, 16 poke, 17 layout, 18 failing requests, 19 failing connections/latency
READ, WAIT, RUN, PRODUCE, RESTART, SESSION, JUMP, SLOT, HEADER, POKE, LAYOUT, FAIL, CONN = (
    0, 6, 8, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19)
# time steps: byte = index | (multiplier - 1) << 3; index into 0, 1us, 100us, 1ms, 10ms,
# 100ms, 1s, 100s
T_10MS, T_20MS, T_100MS, T_1S, T_3S = 4, 4 | 1 << 3, 5, 6, 6 | 2 << 3
# failing requests: kind = 1 + (m & 31) % 6: timeout, exception, reset, bad data, short, torn
TIMEOUT, EXCEPTION, RESET, BADDATA, SHORT, TORN = range(6)


def u16(v):
    return struct.pack(">H", v & 0xFFFF)


def u32(v):
    return struct.pack(">I", v & 0xFFFFFFFF)


def channel(type_byte, scale_byte=0, address=0):
    # type = (t + 4) % 6: t = 0 FLOAT32, 1 FLOAT64, 2 INT16, 3 UINT16, 4 INT32, 5 UINT32;
    # byte order = (t / 6) % 4: ABCD, DCBA, BADC, CDAB. scale_byte: bits 0-2 scale, 3-4
    # offset (tables in fuzz_modbus_fifo.c), 0x20 input register
    return bytes([type_byte, scale_byte]) + u16(address)


def setup(flags, channels, cap=64, k16=0, period=0, d=0, s0=0, session=0x1234, value_mode=0,
          seed=0, h=0, base=None, poll=None, link=None):
    b = bytes([flags, len(channels) - 1]) + b"".join(channels)
    if flags & 0x10:
        b += u16(base)
    if flags & 0x20:
        b += bytes([poll])
    if flags & 0x80:
        b += bytes([link])
    b += bytes([cap - 1]) + u16(k16) + bytes([period])
    b += bytes([d]) + u32(s0) + u16(session) + bytes([value_mode]) + u32(seed) + bytes([h])
    return b


def fail(kind, count, args=0):
    return bytes([FAIL, kind | (count - 1) << 5]) + bytes([args] * count)


three = [channel(0), channel(2, 1, 2), channel(18, 0, 10)]  # FLOAT32, INT16 x0.001, FLOAT32 CDAB
seeds = {
    # 1 kHz, 20 ms polls: steady stream, a restart, a flapping id, a reboot with zeros
    "steady_restart.bin": setup(0x60, three, poll=3, s0=0)
    + bytes([RUN, T_20MS, READ, RUN, T_20MS, READ, READ, RUN, T_100MS, READ])
    + bytes([RESTART]) + u16(0x4321) + bytes([RUN, T_20MS, READ, RUN, T_20MS, READ])
    + bytes([SESSION]) + u16(0x9999) + bytes([RUN, T_20MS, READ, RUN, T_20MS, READ, RUN, T_20MS, READ])
    + bytes([HEADER, 0, READ, WAIT, T_1S, READ, HEADER, 1, WAIT, T_1S, READ, RUN, T_20MS, READ]),
    # timeouts, exceptions, resets, torn answers; reconnects with back-off
    "link_faults.bin": setup(0xE0, three, poll=3, link=2 | 1 << 2 | 2 << 4 | 1 << 6, s0=5000)
    + bytes([RUN, T_20MS, READ]) + fail(TIMEOUT, 2) + bytes([RUN, T_20MS, READ, READ, WAIT, T_1S, READ])
    + fail(EXCEPTION, 1) + bytes([RUN, T_20MS, READ]) + fail(RESET, 1) + bytes([READ, WAIT, T_1S, READ])
    + bytes([CONN, 2, WAIT, T_1S, READ, WAIT, T_3S, READ, WAIT, T_3S, READ])
    + fail(TORN, 2, 3) + bytes([RUN, T_20MS, READ, RUN, T_20MS, READ])
    + fail(SHORT, 1) + fail(BADDATA, 1) + bytes([RUN, T_20MS, READ, RUN, T_20MS, READ]),
    # 10 kHz into a 64-record ring polled too slowly: overruns; a counter jump and wrap
    "overrun_jump.bin": setup(0x20, [channel(1), channel(10, 0x20)], poll=4, k16=62, period=1,
                              s0=0xFFFFFF00)
    + bytes([READ, RUN, T_10MS, READ, RUN, T_100MS, READ])
    + bytes([JUMP, 1]) + u32(100000) + bytes([READ, READ])
    + bytes([JUMP, 3]) + u32(20) + bytes([RUN, T_10MS, READ, READ, READ])
    + bytes([SLOT]) + u16(500) + bytes([READ]) + bytes([POKE, 0]) + u16(70) + u16(0xFFFF) + bytes([RUN, T_10MS, READ])
    + bytes([LAYOUT, 0]) + u16(10) + bytes([RUN, T_10MS, READ]) + fail(RESET, 1) + bytes([READ, WAIT, T_1S, READ]),
    # snapshot mode at 1 kHz: holding and input registers, a missed deadline
    "snapshot.bin": setup(0x0E, [channel(2, 0, 10), channel(4, 0x20, 20), channel(1, 0, 30)], h=0)
    + bytes([RUN, T_10MS, READ, RUN, T_10MS, READ, WAIT, T_1S, READ]) + fail(EXCEPTION, 1)
    + bytes([RUN, T_10MS, READ, RUN, T_10MS, READ]),
    # RTU, UINT16 and FLOAT64 (DCBA) channels, records with any bits (NaN, Inf); the link
    # drops and the device answers with a header that does not fit (3 channels) until restored
    "rtu_nonfinite.bin": setup(0x01, [channel(3), channel(9)], k16=200, value_mode=1, seed=77)
    + bytes([RUN, T_20MS, READ, RUN, T_20MS, READ]) + bytes([POKE, 0]) + u16(2) + u16(3) + fail(RESET, 1)
    + bytes([RUN, T_20MS, READ, WAIT, T_1S, READ, WAIT, T_1S, READ, HEADER, 1, WAIT, T_3S, READ])
    + bytes([RUN, T_20MS, READ, RUN, T_20MS, READ, RUN, T_100MS, READ]),
}

os.makedirs(OUT, exist_ok=True)
for name, data in seeds.items():
    with open(os.path.join(OUT, name), "wb") as f:
        f.write(data)
    print(f"{name}: {len(data)} bytes")
