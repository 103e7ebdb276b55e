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

Hostile behaviour (issue 12), times in seconds since the start of the first phase:
--zero-header T   the FIFO header reads all zeros (magic 0, capacity 0: a device rebooting
                  with cleared registers) until T, then the valid header appears.
--flap-session    the session id register alternates between the real id and another at
                  every update (every 2 ms) while the counter continues.
--random-counter A,B  between A and B the counter registers hold random 32-bit values
                  (the records themselves stay right).

--control  the test drives the server through stdin, one command a line, each answered on
stdout once done (the test waits for events, never for a schedule; the schedule and
--max-time are then ignored, except as a last resort --max-time 300):
  freeze       stop producing samples             -> "FROZEN <S>"
  stop         close the server and every connection -> "PHASE <i> served <S> samples t0 <T>
               maxgap <G>": T = CLOCK_MONOTONIC (s) of the session start (sample s is due at
               T + (s + 1) h), G = the longest interval (s) between two updates of the
               registers in that session (how stale an answer can have been)
  start        a new session (S = 0, new session id), listening again -> "STARTED <i> t0 <T>"
  header       the valid header appears (with --zero-header -1) -> "HEADER"
  random on|off  the counter registers hold random values (on) or the counter (off)
               -> "RANDOM on|off"
  end of input (or quit)  the server stops and exits -> "DONE"
  With --stop-after N, "PRODUCED N" is printed once the N samples exist.
--zero-header -1 (with --control): the header reads zeros until the command "header".

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
    def __init__(self, block, period_ns, stop_after=0, zero_header=0.0, flap=False, random_counter=None):
        self.block = block
        self.period_ns = period_ns
        self.stop_after = stop_after  # > 0: produce samples 0 .. stop_after-1, then none
        self.start = time.monotonic()
        self.zero_header = zero_header
        self.flap = flap
        self.flip = False
        self.random_counter = random_counter
        self.zero_hold = zero_header < 0  # until cleared by the command "header"
        self.random_hold = False  # set and cleared by the command "random on|off"
        self.frozen = None  # the counter at the command "freeze"
        self.restart()

    def zeroed(self):
        return self.zero_hold or time.monotonic() - self.start < self.zero_header

    def restart(self):
        self.S = 0
        self.ws = 0
        self.session = random.randint(1, 65535)
        self.t0 = time.monotonic()
        self.last_advance = self.t0
        self.max_gap = 0.0
        self.frozen = None
        hdr = [0x5646, 1, C, W, K, DOFF, self.period_ns >> 16, self.period_ns & 0xFFFF, 0, 0, 0, self.session, 0, 0, 0, 0]
        hdr += [TYPE_FLOAT32 | (ORDER_ABCD << 8), TYPE_INT16 | (ORDER_ABCD << 8), TYPE_FLOAT32 | (ORDER_CDAB << 8)]
        self.hdr = hdr
        self.block.setValues(BASE, [0] * len(hdr) if self.zeroed() else hdr)
        self.block.setValues(BASE + DOFF, [0xFFFF] * (K * W))  # no valid tags yet

    def advance(self):
        now = time.monotonic()
        self.max_gap = max(self.max_gap, now - self.last_advance)
        self.last_advance = now
        due = int((now - self.t0) * 1e9 // self.period_ns)
        if self.stop_after:
            due = min(due, self.stop_after)
        if self.frozen is not None:
            due = min(due, self.frozen)
        while self.S < due:
            s = self.S
            a, b, c = values(s)
            rec = [s & 0xFFFF] + f32_abcd(a) + i16(b) + f32_cdab(c)
            self.block.setValues(BASE + DOFF + self.ws * W, rec)
            self.block.setValues(0, f32_abcd(a) + i16(b))
            self.block.setValues(10, f32_cdab(c))
            self.S = (self.S + 1) & 0xFFFFFFFF
            self.ws = (self.ws + 1) % K
        el = time.monotonic() - self.start
        zeroed = self.zeroed()
        if zeroed:  # (the header includes the counter words: written first)
            self.block.setValues(BASE, [0] * len(self.hdr))
        elif self.zero_header:
            self.block.setValues(BASE, self.hdr)
        # count, write slot: one setValues, between two requests (single event loop)
        self.block.setValues(BASE + 8, [self.S >> 16, self.S & 0xFFFF, self.ws])
        if zeroed:
            self.block.setValues(BASE + 8, [0, 0, 0])
        if self.flap:
            self.flip = not self.flip
            self.block.setValues(BASE + 11, [self.session ^ 0x5555 if self.flip else self.session])
        if self.random_hold or (self.random_counter and self.random_counter[0] <= el < self.random_counter[1]):
            self.block.setValues(BASE + 8, [random.randint(0, 65535), random.randint(0, 65535)])


async def stdin_lines():
    """stdin as an asyncio StreamReader (the --control commands)."""
    reader = asyncio.StreamReader()
    await asyncio.get_running_loop().connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    return reader


async def listening(port):
    """Returns once the server accepts connections on port (the test connects right after READY)."""
    while True:
        try:
            _, w = await asyncio.open_connection("127.0.0.1", port)
            w.close()
            return
        except OSError:
            await asyncio.sleep(0.01)


async def controlled(args, ctx, fifo):
    """--control: serves one session after another as stdin commands it (module doc)."""
    commands = await stdin_lines()
    phase, server, task = 0, None, None

    async def start():
        nonlocal server, task
        fifo.restart()
        server = ModbusTcpServer(ctx, address=("127.0.0.1", args.port))
        task = asyncio.create_task(server.serve_forever())
        await listening(args.port)

    async def stop():
        nonlocal server, task
        if server:
            await server.shutdown()
            await asyncio.wait_for(task, 60)
            server = task = None

    async def produce():
        produced = False
        while True:
            if server:
                fifo.advance()
                if args.stop_after and fifo.S == args.stop_after and not produced:
                    produced = True
                    print("PRODUCED", fifo.S, flush=True)
            await asyncio.sleep(0.002)

    await start()
    print("READY", args.port, flush=True)
    producer = asyncio.create_task(produce())
    deadline = time.monotonic() + args.max_time
    while True:
        try:
            line = await asyncio.wait_for(commands.readline(), max(0.01, deadline - time.monotonic()))
        except asyncio.TimeoutError:
            line = b""
        cmd = line.decode().split()
        if not cmd or cmd[0] == "quit":
            break
        if cmd[0] == "freeze":
            fifo.frozen = fifo.S
            print("FROZEN", fifo.S, flush=True)
        elif cmd[0] == "stop":
            await stop()
            print("PHASE %d served %d samples t0 %.9f maxgap %.6f" % (phase, fifo.S, fifo.t0, fifo.max_gap), flush=True)
        elif cmd[0] == "start":
            phase += 1
            await start()
            print("STARTED %d t0 %.9f" % (phase, fifo.t0), flush=True)
        elif cmd[0] == "header":
            fifo.zero_hold = False
            fifo.advance()
            print("HEADER", flush=True)
        elif cmd[0] == "random":
            fifo.random_hold = cmd[1:] == ["on"]
            fifo.advance()
            print("RANDOM", "on" if fifo.random_hold else "off", flush=True)
        else:
            print("UNKNOWN", " ".join(cmd), flush=True)
    producer.cancel()
    await stop()
    try:
        print("DONE", flush=True)
    except BrokenPipeError:  # the test has gone (it failed): nobody to tell
        pass


async def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--schedule", default="2")
    ap.add_argument("--period-ns", type=int, default=1000000)
    ap.add_argument("--max-time", type=float, default=30.0)
    ap.add_argument("--serial", default="")
    ap.add_argument("--baud", type=int, default=115200)
    ap.add_argument("--stop-after", type=int, default=0)
    ap.add_argument("--zero-header", type=float, default=0.0)
    ap.add_argument("--flap-session", action="store_true")
    ap.add_argument("--random-counter", default="")
    ap.add_argument("--control", action="store_true")
    args = ap.parse_args()
    phases = [float(x) for x in args.schedule.split(",")]
    block = ModbusSequentialDataBlock(0, [0] * (BASE + DOFF + K * W + 16))
    ctx = ModbusServerContext(slaves=ModbusSlaveContext(hr=block, zero_mode=True), single=True)
    rc = tuple(float(x) for x in args.random_counter.split(",")) if args.random_counter else None
    fifo = Fifo(block, args.period_ns, args.stop_after, args.zero_header, args.flap_session, rc)
    if args.control:
        args.max_time = max(args.max_time, 300.0)
        await controlled(args, ctx, fifo)
        return
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
