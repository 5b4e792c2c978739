#!/usr/bin/env python3
"""A scripted fake GRBL controller on a pseudo-terminal, for the stage client's tests.

    rig_fake.py [--log FILE] SCRIPT        (SCRIPT "-" reads stdin)

Prints "PTY <path>" on stdout, then plays SCRIPT against whoever opens that
path. Real-time bytes ('?', '!', '~', 0x18) are taken out of the stream at any
point, as GRBL does; '?' is answered with the current status line.

Script lines (one directive each; '#' starts a comment line):
  send TEXT        write TEXT + CRLF (banner, ok, error:N, ALARM:N, [MSG:...])
  raw HEX          write raw bytes given in hex (no line ending added)
  garbage N        write N pseudo-random bytes (seeded), then CRLF
  junk TEXT        TEXT waits in the fake's line buffer, as bytes an earlier
                   client left without a newline: the host's next line
                   break completes it (then "expect TEXT" sees it)
  expect TEXT      next line from the host must equal TEXT
  expect_re RE     next line from the host must match RE (fullmatch)
  expect_rt HEX    wait for the real-time byte HEX (18 reset, 21 '!', 3f '?')
  state TEXT       answer '?' with TEXT from now on
  mute / unmute    stop / resume answering '?'
  polls N          wait until N more '?' were answered
  sleep MS         pause (still answering '?')
  timeout MS       deadline of each expect/polls (default 5000)
  close            close the pty (the port vanishes) and exit 0
  auto [RUNPOLLS]  emulate a small GRBL for the rest of the run: ok to G0/G1/
                   G4/G90/$X/$H, $$ dump, $N=V, moves report Run for RUNPOLLS
                   polls (default 2) then Idle at the target, 0x18 -> banner
  end              the script is over: further lines from the host fail

An empty line from the host is answered "ok" at once, as GRBL does (a
client sends one when it connects); scripts never see it.

--log FILE records what the host sent, one item a line: "line TEXT",
"break" for an empty line, or "rt 0xNN" for a real-time byte (the '?'
polls are counted, not logged).

Exit status (after SIGTERM, or at "close"): 0 when every expectation held and
the script ran to its end, 1 on a failed expectation (printed on stderr, and
the pty is closed at once), 2 when stopped while the script still waited for
the host.
"""
import os
import random
import re
import select
import signal
import sys
import time
import tty

BANNER = "Grbl 1.1h ['$' for help]"
RT = {0x3F, 0x21, 0x7E, 0x18, 0x84, 0x85}


class Fake:
    def __init__(self, lines, log=None):
        self.lines = lines
        self.log = log
        self.pc = 0
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.buf = b""
        self.rx_lines = []
        self.rt = []
        self.state = "<Idle|MPos:0.000,0.000,0.000|FS:0,0>"
        self.muted = False
        self.polls = 0
        self.timeout = 5.0
        self.ended = False
        self.auto = None
        self.stopping = False
        self.done = False

    def write(self, data):
        os.write(self.master, data)

    def send(self, text):
        self.write(text.encode("latin-1") + b"\r\n")

    def fail(self, msg):
        sys.stderr.write("rig_fake: line %d: %s\n" % (self.pc, msg))
        sys.stderr.flush()
        os._exit(1)

    def pump(self, timeout):
        """Read what the host sent within timeout seconds; handle real-time bytes."""
        r, _, _ = select.select([self.master], [], [], max(0.0, timeout))
        if not r:
            return
        try:
            data = os.read(self.master, 4096)
        except OSError:
            return
        for b in data:
            if b in RT:
                if b == 0x3F:
                    if self.auto is not None:
                        self.auto_status()
                    elif not self.muted:
                        self.send(self.state)
                        self.polls += 1
                else:
                    self.rt.append(b)
                    self.note("rt 0x%02x" % b)
                    if self.auto is not None and b == 0x21:
                        self.auto_hold()
                    if self.auto is not None and b == 0x18:
                        self.auto_reset()
                continue
            if b == 0x0A:
                line = self.buf.decode("latin-1").strip("\r")
                self.buf = b""
                if line == "":
                    self.note("break")
                    self.send("ok")
                    continue
                self.note("line " + line)
                if self.auto is not None:
                    self.auto_line(line)
                elif self.ended:
                    self.fail("unexpected line after the end of the script: %r" % line)
                else:
                    self.rx_lines.append(line)
            else:
                self.buf += bytes([b])

    def note(self, text):
        if self.log:
            self.log.write(text + "\n")
            self.log.flush()

    def wait(self, pred, what):
        deadline = time.monotonic() + self.timeout
        while not pred():
            if self.stopping:
                # Stopped while still waiting for the host: the script did
                # not run to its end.
                sys.stderr.write("rig_fake: stopped at script line %d of %d, waiting for %s\n"
                                 % (self.pc, len(self.lines), what))
                os._exit(2)
            left = deadline - time.monotonic()
            if left <= 0:
                self.fail("timed out waiting for %s" % what)
            self.pump(min(left, 0.05))

    def next_line(self, what):
        self.wait(lambda: self.rx_lines, what)
        return self.rx_lines.pop(0)

    # ---- a small GRBL for the rest of a run ----
    def auto_status(self):
        a = self.auto
        if a["run"] > 0:
            a["run"] -= 1
            pos, st = a["from"], "Run"
        else:
            pos, st = a["pos"], a["state"]
        self.send("<%s|MPos:%.3f,%.3f,%.3f|FS:0,0>" % (st, pos[0], pos[1], pos[2]))

    def auto_hold(self):
        # Feed hold: the motion stops (at once, here) where it is.
        a = self.auto
        if a["run"] > 0:
            a["run"] = 0
            a["pos"] = list(a["from"])
            a["state"] = "Hold:0"

    def auto_reset(self):
        a = self.auto
        a["run"] = 0
        a["state"] = "Idle"
        self.send(BANNER)

    def auto_line(self, line):
        a = self.auto
        a["log"].append(line)
        up = line.upper().replace(" ", "")
        if up == "$$":
            for n, v in sorted(a["settings"].items()):
                self.send("$%d=%.3f" % (n, v))
            self.send("ok")
            return
        m = re.fullmatch(r"\$(\d+)=(-?[\d.]+)", up)
        if m:
            a["settings"][int(m.group(1))] = float(m.group(2))
            self.send("ok")
            return
        if up in ("$X", "$H"):
            if up == "$H":
                a["pos"] = [0.0, 0.0, 0.0]
            a["state"] = "Idle"
            self.send("ok")
            return
        if up.startswith("G"):
            words = dict(re.findall(r"([XYZF])(-?[\d.]+)", up))
            if any(k in words for k in "XYZ"):
                a["from"] = list(a["pos"])
                for i, k in enumerate("XYZ"):
                    if k in words:
                        a["pos"][i] = float(words[k])
                a["run"] = a["runpolls"]
            self.send("ok")
            return
        self.send("error:20")

    def run(self):
        while self.pc < len(self.lines):
            raw = self.lines[self.pc]
            self.pc += 1
            line = raw.strip()
            if not line or line.startswith("#"):
                continue
            op, _, arg = line.partition(" ")
            if op == "send":
                self.send(arg)
            elif op == "raw":
                self.write(bytes.fromhex(arg))
            elif op == "junk":
                self.buf += arg.encode("latin-1")
            elif op == "garbage":
                rnd = random.Random(int(arg) * 7919)
                self.write(bytes(rnd.choice([b for b in range(256) if b not in RT and b != 0x0A])
                                 for _ in range(int(arg))) + b"\r\n")
            elif op == "expect":
                got = self.next_line("line %r" % arg)
                if got != arg:
                    self.fail("expected %r, got %r" % (arg, got))
            elif op == "expect_re":
                got = self.next_line("a line matching %r" % arg)
                if not re.fullmatch(arg, got):
                    self.fail("expected a match of %r, got %r" % (arg, got))
            elif op == "expect_rt":
                want = int(arg, 16)
                self.wait(lambda: want in self.rt, "real-time byte 0x%02x" % want)
                self.rt.remove(want)
            elif op == "state":
                self.state = arg
            elif op == "mute":
                self.muted = True
            elif op == "unmute":
                self.muted = False
            elif op == "polls":
                target = self.polls + int(arg)
                self.wait(lambda: self.polls >= target, "%s status queries" % arg)
            elif op == "sleep":
                end = time.monotonic() + int(arg) / 1000.0
                while time.monotonic() < end and not self.stopping:
                    self.pump(end - time.monotonic())
            elif op == "timeout":
                self.timeout = int(arg) / 1000.0
            elif op == "close":
                os.close(self.master)
                os.close(self.slave)
                os._exit(0)
            elif op == "auto":
                self.auto = {"pos": [0.0, 0.0, 0.0], "from": [0.0, 0.0, 0.0], "run": 0,
                             "runpolls": int(arg) if arg else 2, "state": "Idle", "log": [],
                             "settings": {100: 800.0, 101: 800.0, 102: 800.0, 110: 720.0}}
                for line in self.rx_lines:
                    self.auto_line(line)
                self.rx_lines = []
                self.pc = len(self.lines)
                break
            elif op == "end":
                self.ended = True
                break
            else:
                self.fail("unknown directive %r" % op)
        self.pc = len(self.lines) + 1
        self.done = True
        while not self.stopping:
            self.pump(0.05)
            if self.ended and self.rx_lines:
                self.fail("unexpected line after the end of the script: %r" % self.rx_lines[0])


def main():
    args = sys.argv[1:]
    log = None
    if len(args) == 3 and args[0] == "--log":
        log = open(args[1], "a", encoding="latin-1")
        args = args[2:]
    if len(args) != 1:
        sys.stderr.write("usage: rig_fake.py [--log FILE] SCRIPT\n")
        return 2
    src = sys.stdin if args[0] == "-" else open(args[0], encoding="utf-8")
    lines = src.read().splitlines()
    fake = Fake(lines, log)

    def on_term(signum, frame):
        # Finish the directives that need nothing from the host (the client
        # may have its reply and be gone before the fake reached "end");
        # a wait for the host then stops the run with status 2.
        fake.stopping = True

    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, on_term)
    sys.stdout.write("PTY %s\n" % fake.path)
    sys.stdout.flush()
    fake.run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
