#!/usr/bin/env python3
"""The poseinfer daemon under load: C clients connect at once and each sends
R requests, one after the other (wait for the reply, then the next); the
latency of every request (send to reply, on the client), the daemon's
resident memory (peak, and at the end) and the requests per second.

Several daemons can be compared in one run (e.g. a build before a change and
after it): each --binary starts one, and the rounds alternate between them,
so that the load of a shared machine falls on all of them alike.

    .venv/bin/python bench/daemon_load.py \\
        --binary 'before=/tmp/before/host/build/poseinfer' \\
        --binary 'after=host/build/poseinfer --allow-dir {frames}' \\
        --markdown build/bench/daemon_load.md

In a --binary, {frames} stands for the folder of the test frames. Requests:
`infer PATH` (a 640 x 512 PNG frame on disk), or with --frame-over-socket
`frame N` + the PNG's bytes (a daemon that knows that command).
"""
import argparse
import json
import os
import platform
import shlex
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "host"))


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("--binary", action="append", metavar="LABEL=COMMAND",
                   help="a daemon to load: label, then the poseinfer command without --model and --serve "
                        "(repeat to compare; default now=host/build/poseinfer --allow-dir {frames})")
    p.add_argument("--model", default=str(ROOT / "training" / "models" / "Texture_3_color.onnx"),
                   help="ONNX model (default: the shipped Texture_3_color.onnx)")
    p.add_argument("--clients", type=int, default=50, help="clients at once (default 50)")
    p.add_argument("--requests", type=int, default=20, help="requests per client (default 20)")
    p.add_argument("--rounds", type=int, default=3, help="rounds per daemon, alternating (default 3)")
    p.add_argument("--frame-over-socket", action="store_true", help="send `frame N` + bytes, not `infer PATH`")
    p.add_argument("--slow", type=int, default=0, metavar="K",
                   help="K of the clients ask for a large frame (4000 x 3000) each time; the table then "
                        "gives the other clients' latencies and the slow ones' apart (default 0)")
    p.add_argument("--memory", action="store_true",
                   help="instead of the load: one client asks for a small frame, a 4000 x 4000 BMP (48 MB "
                        "file, 48 MB of pixels), then the small one again; the daemon's RSS after each")
    p.add_argument("--markdown", metavar="FILE", help="also write the table as markdown")
    p.add_argument("--json", metavar="FILE", help="also write every round's numbers as JSON")
    return p.parse_args(argv)


def status_kib(pid, key):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    return 0


class Daemon:
    def __init__(self, cmd, model, sock):
        self.sock = sock
        self.proc = subprocess.Popen(cmd + ["--model", model, "--serve", f"unix:{sock}"],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        deadline = time.time() + 60
        while time.time() < deadline:
            line = self.proc.stderr.readline()
            if not line:
                break
            if "listening on" in line:
                threading.Thread(target=self.proc.stderr.read, daemon=True).start()  # keep it drained
                return
        self.proc.kill()
        raise SystemExit(f"daemon_load: {cmd[0]} did not start: {line}")

    def stop(self):
        self.proc.terminate()
        self.proc.wait(timeout=60)


def client(sock, requests, payload, barrier, out, errors):
    """One client: connect, wait for the others, then request, wait, ... ."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.connect(sock)
    s.settimeout(120)
    f = s.makefile("rb")
    lat = []
    try:
        barrier.wait()
        for _ in range(requests):
            t0 = time.perf_counter()
            s.sendall(payload)
            line = f.readline()
            lat.append((time.perf_counter() - t0) * 1e3)
            if not line or b'"error"' in line:
                errors.append(line[:200])
    finally:
        f.close()
        s.close()
    out.extend(lat)


def request(path, over_socket):
    if over_socket:
        data = path.read_bytes()
        return b"frame %d\n" % len(data) + data
    return f"infer {path}\n".encode()


def pct(lat, q):
    lat = sorted(lat)
    return lat[min(len(lat) - 1, int(q * len(lat)))] if lat else float("nan")


def one_round(cmd, args, frame, big, sock):
    d = Daemon(cmd, args.model, sock)
    try:
        payload = request(frame, args.frame_over_socket)
        slow_payload = request(big, args.frame_over_socket) if args.slow else b""
        rss0 = status_kib(d.proc.pid, "VmRSS")
        barrier = threading.Barrier(args.clients + 1)
        lat, slow_lat, errors = [], [], []
        threads = [threading.Thread(target=client, args=(sock, args.requests, payload, barrier, lat, errors))
                   for _ in range(args.clients - args.slow)]
        threads += [threading.Thread(target=client, args=(sock, args.requests, slow_payload, barrier, slow_lat,
                                                          errors)) for _ in range(args.slow)]
        for t in threads:
            t.start()
        barrier.wait()
        t0 = time.perf_counter()
        for t in threads:
            t.join()
        wall = time.perf_counter() - t0
        hwm = status_kib(d.proc.pid, "VmHWM")
        rss1 = status_kib(d.proc.pid, "VmRSS")
    finally:
        d.stop()
    n = len(lat) + len(slow_lat)
    return {"p50_ms": pct(lat, 0.5), "p99_ms": pct(lat, 0.99), "max_ms": max(lat),
            "slow_p50_ms": pct(slow_lat, 0.5), "slow_p99_ms": pct(slow_lat, 0.99),
            "req_per_s": n / wall, "rss_start_mib": rss0 / 1024, "rss_peak_mib": hwm / 1024,
            "rss_end_mib": rss1 / 1024, "requests": n, "errors": len(errors),
            "first_error": errors[0].decode("utf-8", "replace") if errors else None}


def memory_round(cmd, args, frame, big, sock):
    """RSS (MiB) of the daemon after a small frame, a large one, the small one again."""
    d = Daemon(cmd, args.model, sock)
    out = []
    try:
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.connect(sock)
        f = s.makefile("rb")
        for path in (frame, big, frame):
            t0 = time.perf_counter()
            s.sendall(request(path, args.frame_over_socket))
            line = f.readline()
            ms = (time.perf_counter() - t0) * 1e3
            out.append((status_kib(d.proc.pid, "VmRSS") / 1024, ms, b'"error"' in line))
        s.close()
    finally:
        d.stop()
    return out


def header(args, argv):
    cmd = [sys.executable.replace(str(ROOT) + "/", ""), "bench/daemon_load.py"]
    cmd += argv if argv is not None else sys.argv[1:]
    return (f"- Command: `{' '.join(shlex.quote(a) for a in cmd)}`\n"
            f"- Date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; machine: {platform.machine()}, "
            f"{os.cpu_count()} logical CPUs, load average {os.getloadavg()[0]:.1f} at the end")


def main(argv=None):
    args = parse_args(argv)
    import cv2
    from pihelpers import sphere_frame

    binaries = args.binary or [f"now={ROOT / 'host' / 'build' / 'poseinfer'} --allow-dir {{frames}}"]
    with tempfile.TemporaryDirectory(prefix="daemon_load_") as tmp:
        tmp = Path(tmp)
        frames = tmp / "frames"
        frames.mkdir()
        frame = frames / "frame.png"
        cv2.imwrite(str(frame), sphere_frame(h=512, w=640, seed=7))
        big = frames / "big.png"
        if args.slow:
            cv2.imwrite(str(big), sphere_frame(h=3000, w=4000, cx=2000, cy=1500, r=1000, seed=8))
        if args.memory:
            big = frames / "big.bmp"
            cv2.imwrite(str(big), sphere_frame(h=4000, w=4000, cx=2000, cy=2000, r=1500, seed=8, noise=0))
        daemons = []
        for b in binaries:
            label, _, cmd = b.partition("=")
            daemons.append((label, shlex.split(cmd.replace("{frames}", str(frames)))))
        results = {label: [] for label, _ in daemons}
        if args.memory:
            lines = [header(args, argv), ""] + ["| daemon | RSS after a small frame MiB | after the 4000 x 4000 BMP | after the small one again "
                     "| the BMP's request ms |", "| --- | ---: | ---: | ---: | ---: |"]
            for label, cmd in daemons:
                m = memory_round(cmd, args, frame, big, str(tmp / "pi.sock"))
                if any(err for _, _, err in m):
                    raise SystemExit(f"daemon_load: {label}: a request failed")
                lines.append(f"| {label} | {m[0][0]:.0f} | {m[1][0]:.0f} | {m[2][0]:.0f} | {m[1][1]:.0f} |")
            text = "\n".join(lines) + "\n"
            print(text)
            if args.markdown:
                Path(args.markdown).write_text(text)
            return 0
        for r in range(args.rounds):
            for label, cmd in daemons:
                res = one_round(cmd, args, frame, big, str(tmp / "pi.sock"))
                results[label].append(res)
                print(f"round {r + 1} {label}: p50 {res['p50_ms']:.1f} ms, p99 {res['p99_ms']:.1f} ms, "
                      + (f"slow clients p50 {res['slow_p50_ms']:.0f} ms, " if args.slow else "")
                      + f"{res['req_per_s']:.0f} req/s, RSS peak {res['rss_peak_mib']:.0f} MiB, "
                      f"errors {res['errors']}" + (f" ({res['first_error']})" if res["errors"] else ""),
                      flush=True)

    def med(label, key):
        return statistics.median(x[key] for x in results[label])

    kind = "`frame N` + bytes" if args.frame_over_socket else "`infer PATH`"
    lines = [
        header(args, argv),
        f"- Load: {args.clients} clients at once x {args.requests} requests each ({kind}, one 640 x 512 PNG"
        + (f"; {args.slow} of the clients a 4000 x 3000 PNG instead" if args.slow else "") + "), "
        f"each client waits for a reply before its next request; model {Path(args.model).name}; "
        f"medians of {args.rounds} rounds per daemon, rounds alternating",
        "",
        "| daemon | p50 ms | p99 ms | max ms | " + ("slow clients p50 ms | p99 ms | " if args.slow else "")
        + "requests/s | RSS start MiB | RSS peak MiB | RSS end MiB | errors |",
        "| --- | ---: | ---: | ---: | " + ("---: | ---: | " if args.slow else "") + "---: | ---: | ---: | ---: | ---: |",
    ]
    for label, cmd in daemons:
        slow = (f"{med(label, 'slow_p50_ms'):.0f} | {med(label, 'slow_p99_ms'):.0f} | " if args.slow else "")
        lines.append(f"| {label} | {med(label, 'p50_ms'):.1f} | {med(label, 'p99_ms'):.1f} | "
                     f"{med(label, 'max_ms'):.1f} | {slow}{med(label, 'req_per_s'):.0f} | "
                     f"{med(label, 'rss_start_mib'):.0f} | {med(label, 'rss_peak_mib'):.0f} | "
                     f"{med(label, 'rss_end_mib'):.0f} | {sum(x['errors'] for x in results[label])} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.markdown:
        Path(args.markdown).parent.mkdir(parents=True, exist_ok=True)
        Path(args.markdown).write_text(text)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
