#!/usr/bin/env python3
"""An independent Modbus TCP server (pymodbus) that serves the vibid sample FIFO of
drivers/modbus_fifo_layout.md and current-value registers, with a known signal, for the
drivers' Modbus source test. Nothing of vibid is imported: the layout is re-implemented
here from the document.

Signal of sample s (1 kHz by default):
  ch0 = sin(0.01 s)                     FLOAT32 ABCD  (current value at address 0)
  ch1 = ((s mod 1000) - 500) * 0.001    INT16  ABCD, scale 0.001 (address 2)
  ch2 = 0.5 s                           FLOAT32 CDAB  (address 10)
FIFO at base 1000, data offset 64, K = 500 records of W = 6 registers.

--schedule RUN,PAUSE,RUN,...  seconds serving / not listening (connections closed), each
restart is a new FIFO session (S = 0, new session id). The process exits after the
schedule (and never later than --max-time). Prints "READY <port>" when first listening.

--stop-after N stops producing after sample N-1 (the FIFO then holds a fixed window: a
client's first read is deterministic).

--serial DEVICE serves Modbus RTU (pymodbus serial server, pyserial) on DEVICE, e.g. one
end of a pseudo-terminal pair, instead of TCP; --port is then ignored (pass 0), the
schedule's first phase only is used and "READY 0" is printed once the port is open.
"""
import argparse
import asyncio
import math
import random
import struct
import sys
import time

from pymodbus.datastore import ModbusSequentialDataBlock, ModbusServerContext, ModbusSlaveContext
from pymodbus.framer import Framer
from pymodbus.server import ModbusSerialServer, ModbusTcpServer

BASE, DOFF, K, C = 1000, 64, 500, 3
W = 1 + 2 + 1 + 2
TYPE_INT16, TYPE_FLOAT32 = 0, 4
ORDER_ABCD, ORDER_CDAB = 0, 3


def f32_abcd(v):
    hi, lo = struct.unpack(">HH", struct.pack(">f", v))
    return [hi, lo]


def f32_cdab(v):
    hi, lo = struct.unpack(">HH", struct.pack(">f", v))
    return [lo, hi]


def i16(v):
    return [v & 0xFFFF]


def values(s):
    return math.sin(0.01 * s), (s % 1000) - 500, 0.5 * s


class Fifo:
    def __init__(self, block, period_ns, stop_after=0):
        self.block = block
        self.period_ns = period_ns
        self.stop_after = stop_after  # > 0: produce samples 0 .. stop_after-1, then none
        self.restart()

    def restart(self):
        self.S = 0
        self.ws = 0
        self.session = random.randint(1, 65535)
        self.t0 = time.monotonic()
        hdr = [0x5646, 1, C, W, K, DOFF, self.period_ns >> 16, self.period_ns & 0xFFFF, 0, 0, 0, self.session, 0, 0, 0, 0]
        hdr += [TYPE_FLOAT32 | (ORDER_ABCD << 8), TYPE_INT16 | (ORDER_ABCD << 8), TYPE_FLOAT32 | (ORDER_CDAB << 8)]
        self.block.setValues(BASE, hdr)
        self.block.setValues(BASE + DOFF, [0xFFFF] * (K * W))  # no valid tags yet

    def advance(self):
        due = int((time.monotonic() - self.t0) * 1e9 // self.period_ns)
        if self.stop_after:
            due = min(due, self.stop_after)
        while self.S < due:
            s = self.S
            a, b, c = values(s)
            rec = [s & 0xFFFF] + f32_abcd(a) + i16(b) + f32_cdab(c)
            self.block.setValues(BASE + DOFF + self.ws * W, rec)
            self.block.setValues(0, f32_abcd(a) + i16(b))
            self.block.setValues(10, f32_cdab(c))
            self.S = (self.S + 1) & 0xFFFFFFFF
            self.ws = (self.ws + 1) % K
        # count, write slot: one setValues, between two requests (single event loop)
        self.block.setValues(BASE + 8, [self.S >> 16, self.S & 0xFFFF, self.ws])


async def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--schedule", default="2")
    ap.add_argument("--period-ns", type=int, default=1000000)
    ap.add_argument("--max-time", type=float, default=30.0)
    ap.add_argument("--serial", default="")
    ap.add_argument("--baud", type=int, default=115200)
    ap.add_argument("--stop-after", type=int, default=0)
    args = ap.parse_args()
    phases = [float(x) for x in args.schedule.split(",")]
    block = ModbusSequentialDataBlock(0, [0] * (BASE + DOFF + K * W + 16))
    ctx = ModbusServerContext(slaves=ModbusSlaveContext(hr=block, zero_mode=True), single=True)
    fifo = Fifo(block, args.period_ns, args.stop_after)
    deadline = time.monotonic() + args.max_time
    for i, dur in enumerate(phases):
        if i % 2 == 1:  # pause: nobody listening
            await asyncio.sleep(dur)
            continue
        fifo.restart()
        if args.serial:
            server = ModbusSerialServer(ctx, framer=Framer.RTU, port=args.serial, baudrate=args.baud,
                                        bytesize=8, parity="N", stopbits=1)
        else:
            server = ModbusTcpServer(ctx, address=("127.0.0.1", args.port))
        task = asyncio.create_task(server.serve_forever())
        await asyncio.sleep(0.05)
        if i == 0:
            print("READY", args.port, flush=True)
        end = min(time.monotonic() + dur, deadline)
        while time.monotonic() < end:
            fifo.advance()
            await asyncio.sleep(0.002)
        await server.shutdown()
        await asyncio.wait_for(task, 2)
        print("PHASE", i, "served", fifo.S, "samples", flush=True)
        if time.monotonic() >= deadline or args.serial:
            break
    print("DONE", flush=True)


if __name__ == "__main__":
    asyncio.run(main())
    sys.exit(0)
