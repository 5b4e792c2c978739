"""Drive `stagesim` and the stage firmware over its pty, as a GRBL sender would.

Plain os/termios/select, no pyserial. Every wait has a generous wall-clock
limit only to avoid hanging forever; what the tests assert on is protocol
text, step counts from the state socket and simulated cycles.
"""
import json
import os
import re
import select
import signal
import socket
import subprocess
import termios
import time
import tty
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
STAGESIM = ROOT / "sim" / "stage" / "build" / "stagesim"
# STAGE_ELF points the tests (and the bench) at another build of the firmware
FIRMWARE = Path(os.environ.get("STAGE_ELF", ROOT / "firmware" / "build" / "spherepose-stage.elf"))
TESTFW = ROOT / "sim" / "stage" / "build" / "testfw.elf"

BANNER_RE = re.compile(r"^Grbl \S+ \['\$' for help\]")
STATUS_RE = re.compile(r"^<([A-Za-z]+)(?::(\d))?\|MPos:(-?[\d.]+),(-?[\d.]+),(-?[\d.]+)(\|.*)?>$")
STEPS_PER_DEG = 800
RX_BUFFER_SIZE = 128
F_CPU = 16_000_000


class StageError(AssertionError):
    pass


def build_stagesim():
    """Build stagesim (and the test program) when missing; cheap when up to date."""
    subprocess.run(["make", "-s", "-C", str(ROOT / "sim" / "stage")], check=True)


class Stage:
    """One stagesim process running one ELF, its pty and its state socket."""

    def __init__(self, tmp, elf=FIRMWARE, args=(), eeprom=None, name="stage"):
        self.tmp = Path(tmp)
        self.sock_path = str(self.tmp / f"{name}.sock")
        self.eeprom = str(eeprom or self.tmp / f"{name}.eeprom")
        cmd = [str(STAGESIM), "--state-socket", self.sock_path,
               "--eeprom", self.eeprom, *args, str(elf)]
        self.stderr = open(self.tmp / f"{name}.stderr", "w+")
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self.stderr, bufsize=0)
        self._out = b""
        self.rx = b""           # bytes read from the pty, not yet consumed
        self.log = []           # every line received, for failure messages
        self._sock = None
        self._sockf = None
        self.fd = None
        try:
            lines = [self._stdout_line(10.0) for _ in range(2)]
            if not lines[0].startswith("PTY ") or not lines[1].startswith("STATE "):
                raise StageError(f"stagesim said {lines!r}; stderr: {self.stderr_text()}")
            self.pty = lines[0].split(" ", 1)[1]
            assert lines[1].split(" ", 1)[1] == self.sock_path
            # O_NOCTTY: never become our controlling tty; no TCSAFLUSH: the
            # banner is already waiting in the pty
            self.fd = os.open(self.pty, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            tty.setraw(self.fd, termios.TCSANOW)
        except BaseException:
            self.proc.kill()
            self.proc.wait()
            raise

    # --- process -----------------------------------------------------------
    def _stdout_line(self, timeout):
        t_end = time.monotonic() + timeout
        fd = self.proc.stdout.fileno()
        while b"\n" not in self._out:
            r, _, _ = select.select([fd], [], [], max(0, t_end - time.monotonic()))
            chunk = os.read(fd, 4096) if r else b""
            if not chunk:
                raise StageError(f"stagesim printed {self._out!r}; stderr: {self.stderr_text()}")
            self._out += chunk
        line, self._out = self._out.split(b"\n", 1)
        return line.decode()

    def stderr_text(self):
        self.stderr.flush()
        self.stderr.seek(0)
        return self.stderr.read()

    def alive(self):
        return self.proc.poll() is None

    def close(self, check=True):
        """SIGTERM, and check the clean stop the interface promises."""
        if self._sock:
            self._sockf.close()
            self._sock.close()
            self._sock = None
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                rc = self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                raise StageError("stagesim did not stop on SIGTERM")
        else:
            rc = self.proc.returncode
        self.proc.stdout.close()
        err = self.stderr_text()
        self.stderr.close()
        if check:
            assert rc == 0, f"stagesim exit {rc}: {err}"
            assert not os.path.exists(self.sock_path), "state socket left behind"
        return rc

    # --- state socket ------------------------------------------------------
    def query(self, request="state"):
        if self._sock is None:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self._sock.settimeout(10)
            self._sock.connect(self.sock_path)
            self._sockf = self._sock.makefile("rw")
        self._sockf.write(request + "\n")
        self._sockf.flush()
        return json.loads(self._sockf.readline())

    def state(self):
        return self.query("state")

    def diagnosis(self):
        """The simulator's own account for an error message: its cycle count and the port's opens
        and auto-resets (a reset the test did not send shows there)."""
        try:
            return f"stagesim cycle {self.cycle()}, uart {self.query('uart')}"
        except (OSError, ValueError) as e:
            return f"stagesim state unavailable ({e})"

    def steps(self):
        return self.state()["steps"]

    def cycle(self):
        return self.state()["cycle"]

    def run_cycles(self, cycles, timeout=60):
        """Wait until the simulation has advanced by this many cycles."""
        end = self.cycle() + cycles
        t_end = time.monotonic() + timeout
        while self.cycle() < end:
            if time.monotonic() > t_end:
                raise StageError(f"simulation did not advance {cycles} cycles")
            self.pump(0.02)

    # --- pty ---------------------------------------------------------------
    def write(self, data):
        if isinstance(data, str):
            data = data.encode()
        view = memoryview(data)
        t_end = time.monotonic() + 30
        while view:
            _, w, _ = select.select([], [self.fd], [], 0.05)
            if w:
                n = os.write(self.fd, view)
                view = view[n:]
            self.pump(0)
            if time.monotonic() > t_end:
                raise StageError("pty does not take our bytes")

    def pump(self, timeout):
        """Read what the firmware sent, waiting at most timeout seconds for the first byte."""
        r, _, _ = select.select([self.fd], [], [], timeout)
        while r:
            try:
                chunk = os.read(self.fd, 65536)
            except BlockingIOError:
                break
            if not chunk:
                break
            self.rx += chunk
            r, _, _ = select.select([self.fd], [], [], 0)

    def readline(self, timeout=10.0):
        """One line from the firmware, without its line ending; '\\r\\n' and '\\n' both end a line."""
        t_end = time.monotonic() + timeout
        while b"\n" not in self.rx:
            left = t_end - time.monotonic()
            if left <= 0:
                if not self.alive():
                    raise StageError(f"stagesim exited: {self.stderr_text()}")
                raise StageError(f"no line in {timeout}s; pending {self.rx!r}; last lines {self.log[-10:]}; "
                                 f"{self.diagnosis()}")
            self.pump(min(left, 0.1))
        line, self.rx = self.rx.split(b"\n", 1)
        text = line.decode("latin-1").rstrip("\r")
        self.log.append(text)
        return text

    def expect(self, pattern, timeout=10.0, skip=True):
        """Read lines until one matches the regex; return the match. With skip=False
        the next non-empty line must match."""
        rx = re.compile(pattern)
        t_end = time.monotonic() + timeout
        while True:
            line = self.readline(max(0.1, t_end - time.monotonic()))
            m = rx.search(line)
            if m:
                return m
            if not skip and line.strip():
                raise StageError(f"expected /{pattern}/, got {line!r}")

    def expect_raw(self, pattern, timeout=10.0):
        """Wait until the raw received bytes match the regex (bytes); consume through the match."""
        rx = re.compile(pattern)
        t_end = time.monotonic() + timeout
        while True:
            m = rx.search(self.rx)
            if m:
                self.rx = self.rx[m.end():]
                return m
            left = t_end - time.monotonic()
            if left <= 0:
                raise StageError(f"no {pattern!r} in {timeout}s; received {self.rx[-200:]!r}")
            self.pump(min(left, 0.1))

    def pump_until_quiet(self, quiet=0.2):
        """Read into rx until nothing has come for `quiet` s."""
        while True:
            before = len(self.rx)
            self.pump(quiet)
            if len(self.rx) == before:
                break

    def drain(self, quiet=0.2):
        """Throw away whatever arrives until the line is quiet."""
        self.pump_until_quiet(quiet)
        lines = self.rx.decode("latin-1").splitlines()
        self.log.extend(lines)
        self.rx = b""
        return lines

    def command(self, line, timeout=10.0):
        """Send one line, return (reply lines before the ok/error, final ok/error line)."""
        self.write(line + "\n")
        body = []
        while True:
            text = self.readline(timeout)
            if text == "ok" or text.startswith("error:"):
                return body, text
            if text.startswith("<"):
                continue        # a status report we did not ask for here
            body.append(text)

    def ok(self, line, timeout=10.0):
        body, end = self.command(line, timeout)
        if end != "ok":
            raise StageError(f"{line!r} -> {end} (after {body})")
        return body

    def status(self, timeout=5.0):
        """Send '?' and parse the next status report."""
        self.write(b"?")
        m = self.expect(r"^<.*>$", timeout)
        return parse_status(m.group(0))

    def wait_state(self, names, timeout=60.0, poll=0.1):
        """Poll '?' until the machine state is one of names; return the report."""
        if isinstance(names, str):
            names = (names,)
        t_end = time.monotonic() + timeout
        while True:
            st = self.status()
            if st["state"] in names:
                return st
            if time.monotonic() > t_end:
                raise StageError(f"state stays {st}, wanted {names}")
            time.sleep(poll)

    def drop_reports(self, quiet=0.2):
        """Read until the line has been quiet for `quiet` s and throw away the
        status reports that came: answers to '?' sent before (a streaming
        sender's polls), which the next query would take for its own. Every
        other line is kept."""
        self.pump_until_quiet(quiet)
        head, sep, tail = self.rx.rpartition(b"\n")
        if sep:
            kept = [line for line in head.split(b"\n") if not line.startswith(b"<")]
            self.rx = b"".join(line + b"\n" for line in kept) + tail

    def wait_idle(self, timeout=60.0):
        """Wait for the motion just queued to finish: give the firmware 20 ms of
        simulated time to start it (an 'ok' comes before the cycle starts),
        drop the reports of earlier queries (an Idle of a moment the sender
        starved the planner would end the wait mid-move), then poll until Idle."""
        self.run_cycles(F_CPU // 50)
        self.drop_reports()
        return self.wait_state("Idle", timeout)

    def banner(self, timeout=10.0):
        return self.expect(BANNER_RE.pattern, timeout).string

    def start(self):
        """Banner, then unlock if the firmware starts in alarm (homing enabled)."""
        self.banner()
        self.drain()


def parse_status(text):
    m = STATUS_RE.match(text)
    if not m:
        raise StageError(f"not a status report: {text!r}")
    fields = {}
    for part in (m.group(6) or "").split("|")[1:]:
        k, _, v = part.partition(":")
        fields[k] = v
    return {"state": m.group(1), "sub": m.group(2),
            "mpos": [float(m.group(i)) for i in (3, 4, 5)],
            "fields": fields, "text": text}


def deg_steps(deg):
    return round(deg * STEPS_PER_DEG)
