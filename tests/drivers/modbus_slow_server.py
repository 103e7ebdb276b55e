#!/usr/bin/env python3
"""A raw-socket Modbus TCP server that serves the same FIFO as modbus_fifo_server.py (its
Fifo class fills the registers) but answers slowly, for the Modbus source's tests of
hostile peers (issue 12). Only function 0x03 (read holding registers) is implemented.

--delay D   every answer is sent D seconds after its request (under the client's
            response timeout: each request is slow but succeeds)
--drip D    every answer is sent one byte per D seconds (each byte under the response
            timeout; libmodbus's per-byte timeout used to let this hold a request for
            minutes)
--period-ns P  the FIFO's sample period (default 10 ms: its 500-record ring then holds 5 s,
            so that answers 0.45 s late can still be read before they are overwritten)
Prints "READY <port>", serves until --max-time, or with --control until its stdin ends
(the test decides when it has seen enough; --max-time 300 is then the last resort).
"""
import argparse
import asyncio
import struct
import sys
import time

from modbus_fifo_server import BASE, DOFF, K, W, Fifo, stdin_lines


class Block:
    """The register array Fifo writes into (pymodbus's setValues interface)."""

    def __init__(self, size):
        self.regs = [0] * size

    def setValues(self, addr, values):
        self.regs[addr:addr + len(values)] = values


async def serve(reader, writer, fifo, block, delay, drip):
    try:
        while True:
            head = await reader.readexactly(7)
            tid, pid, length, unit = struct.unpack(">HHHB", head)
            pdu = await reader.readexactly(length - 1)
            fifo.advance()
            func = pdu[0]
            if func == 3:
                addr, count = struct.unpack(">HH", pdu[1:5])
                regs = block.regs[addr:addr + count]
                body = bytes([3, 2 * count]) + struct.pack(">%dH" % count, *regs)
            else:
                body = bytes([func | 0x80, 1])  # illegal function
            reply = struct.pack(">HHHB", tid, 0, len(body) + 1, unit) + body
            if delay:
                await asyncio.sleep(delay)
            if drip:
                for b in reply:
                    writer.write(bytes([b]))
                    await writer.drain()
                    await asyncio.sleep(drip)
            else:
                writer.write(reply)
                await writer.drain()
    except (asyncio.IncompleteReadError, ConnectionError):
        pass
    except asyncio.CancelledError:  # the server exits while this answer is pending
        pass
    finally:
        writer.close()


async def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--delay", type=float, default=0.0)
    ap.add_argument("--drip", type=float, default=0.0)
    ap.add_argument("--max-time", type=float, default=10.0)
    ap.add_argument("--period-ns", type=int, default=10000000)
    ap.add_argument("--control", action="store_true")
    args = ap.parse_args()
    block = Block(BASE + DOFF + K * W + 16)
    fifo = Fifo(block, args.period_ns)
    server = await asyncio.start_server(lambda r, w: serve(r, w, fifo, block, args.delay, args.drip),
                                        "127.0.0.1", args.port)
    print("READY", args.port, flush=True)
    if args.control:
        args.max_time = max(args.max_time, 300.0)
        eof = asyncio.create_task((await stdin_lines()).read())
    end = time.monotonic() + args.max_time
    while time.monotonic() < end and not (args.control and eof.done()):
        fifo.advance()
        await asyncio.sleep(0.002)
    server.close()
    print("DONE", flush=True)


if __name__ == "__main__":
    asyncio.run(main())
    sys.exit(0)
