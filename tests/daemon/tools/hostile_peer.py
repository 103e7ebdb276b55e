#!/usr/bin/env python3
"""Small hostile peers on 127.0.0.1 for vibidd's output tests (tests/daemon/e2e_mqtt.sh,
e2e_influx.sh). Each prints "listening on PORT" once it accepts connections and writes what
it saw to a log file, one line per event, for the test to check.

  hostile_peer.py silent PORT LOG
      accepts TCP connections and reads what comes, never answers (a broker that does not
      answer CONNECT). LOG: "accept", "closed BYTES_RECEIVED".
  hostile_peer.py proxy PORT LOG UPSTREAM_PORT [CUT_AFTER_S]
      forwards each connection to 127.0.0.1:UPSTREAM_PORT; with CUT_AFTER_S, closes both
      sides that many seconds after the accept (a flapping network). LOG: "accept",
      "cut", "closed".
  hostile_peer.py http PORT LOG PLAN
      an HTTP/1.1 server (keep-alive) that reads each request whole and answers it as PLAN
      says: comma-separated STATUS[:BODY_BYTES[:RETRY_AFTER_S]] for the 1st, 2nd, ...
      request, the last entry for every later one. A body is streamed in 64 KiB chunks
      with its Content-Length set (1073741824 = the 1 GB of issue 30). LOG, per request:
      "request N status STATUS body_sent BYTES of BODY_BYTES" once the answer is sent or
      the client closed the connection (BYTES is what the kernel took before that).
"""
import socket
import sys
import threading
import time


def log_line(path, text, lock=threading.Lock()):
    with lock:
        with open(path, "a") as f:
            f.write(text + "\n")


def listen(port):
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind(("127.0.0.1", port))
    s.listen(64)
    print(f"listening on {port}", flush=True)
    return s


def serve(srv, handler):
    while True:
        c, _ = srv.accept()
        threading.Thread(target=handler, args=(c,), daemon=True).start()


def silent(port, logf):
    def handle(c):
        log_line(logf, "accept")
        n = 0
        try:
            while True:
                d = c.recv(65536)
                if not d:
                    break
                n += len(d)
        except OSError:
            pass
        log_line(logf, f"closed {n}")
        c.close()

    serve(listen(port), handle)


def proxy(port, upstream, logf, cut_after):
    def pump(a, b, stop):
        try:
            while not stop.is_set():
                d = a.recv(65536)
                if not d:
                    break
                b.sendall(d)
        except OSError:
            pass
        stop.set()

    def handle(c):
        log_line(logf, "accept")
        try:
            u = socket.create_connection(("127.0.0.1", upstream))
        except OSError:
            c.close()
            return
        stop = threading.Event()
        for a, b in ((c, u), (u, c)):
            threading.Thread(target=pump, args=(a, b, stop), daemon=True).start()
        if cut_after > 0:
            cut = not stop.wait(cut_after)  # still open after cut_after: cut it
        else:
            stop.wait()
            cut = False
        if cut:
            log_line(logf, "cut")
        for s in (c, u):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()
        log_line(logf, "closed")

    serve(listen(port), handle)


def http(port, logf, plan):
    steps = []
    for p in plan.split(","):
        f = p.split(":")
        steps.append((int(f[0]), int(f[1]) if len(f) > 1 else 0, f[2] if len(f) > 2 else None))
    count = [0]
    lock = threading.Lock()
    reasons = {200: "OK", 204: "No Content", 429: "Too Many Requests", 500: "Internal Server Error",
               503: "Service Unavailable"}

    def handle(c):
        buf = b""
        try:
            while True:
                while b"\r\n\r\n" not in buf:
                    d = c.recv(65536)
                    if not d:
                        return
                    buf += d
                head, buf = buf.split(b"\r\n\r\n", 1)
                length = 0
                for line in head.split(b"\r\n")[1:]:
                    k, _, v = line.partition(b":")
                    if k.strip().lower() == b"content-length":
                        length = int(v.strip())
                while len(buf) < length:
                    d = c.recv(65536)
                    if not d:
                        return
                    buf += d
                buf = buf[length:]
                with lock:
                    count[0] += 1
                    n = count[0]
                status, body, retry = steps[min(n, len(steps)) - 1]
                hdr = f"HTTP/1.1 {status} {reasons.get(status, 'Status')}\r\nContent-Type: application/json\r\n"
                if retry is not None:
                    hdr += f"Retry-After: {retry}\r\n"
                hdr += f"Content-Length: {body}\r\n\r\n"
                c.sendall(hdr.encode())
                sent = 0
                chunk = b'{"error":"' + b"x" * (65536 - 10)
                try:
                    while sent < body:
                        k = min(len(chunk), body - sent)
                        c.sendall(chunk[:k])
                        sent += k
                finally:
                    log_line(logf, f"request {n} status {status} body_sent {sent} of {body}")
        except OSError:
            pass
        finally:
            c.close()

    serve(listen(port), handle)


if __name__ == "__main__":
    mode, port, a = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
    if mode == "silent":
        silent(port, a[0])
    elif mode == "proxy":
        proxy(port, int(a[1]), a[0], float(a[2]) if len(a) > 2 else 0.0)
    elif mode == "http":
        http(port, a[0], a[1])
    else:
        sys.exit(f"unknown mode {mode}")
