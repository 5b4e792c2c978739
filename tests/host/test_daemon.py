"""poseinfer as a daemon: the line protocol over unix: and tcp:, the unix:
frame-server camera, continuous capture, signals, idle CPU."""
import json
import os
import re
import select
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from pihelpers import dots_texture, sphere_frame

cv2 = pytest.importorskip("cv2")


def read_line(pipe, deadline):
    """One line from a program's pipe by time.time() deadline: '' at its end,
    None when the deadline comes first. A byte at a time, so that nothing
    waits in a buffer select() does not see."""
    fd = pipe.fileno()
    line = b""
    while not line.endswith(b"\n"):
        ready, _, _ = select.select([fd], [], [], max(0.0, deadline - time.time()))
        if not ready:
            return None
        byte = os.read(fd, 1)
        if not byte:
            break
        line += byte
    return line.decode(errors="replace")


class Daemon:
    def __init__(self, poseinfer, args, scale):
        self.proc = subprocess.Popen([str(poseinfer)] + [str(a) for a in args], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        self.scale = scale
        self.stderr_lines = []
        self.log = []  # stderr lines read after "listening on" (wait_log); stop() puts them in rest
        # wait for "listening on ..." on stderr
        deadline = time.time() + 30 * scale
        while True:
            line = read_line(self.proc.stderr, deadline)
            if not line:
                break
            self.stderr_lines.append(line)
            if "listening on" in line:
                self.addr = line.split("listening on ")[1].split(" ")[0]
                return
        self.proc.kill()
        self.proc.wait()
        raise AssertionError("daemon did not start: " + "".join(self.stderr_lines) + self.proc.stderr.read())

    def wait_log(self, text, timeout):
        """Read stderr until a line holds text, within timeout (scaled) seconds."""
        deadline = time.time() + timeout * self.scale
        while True:
            line = read_line(self.proc.stderr, deadline)
            assert line, f"no {text!r} on stderr in {timeout * self.scale} s: {''.join(self.log)}"
            self.log.append(line)
            if text in line:
                return line

    def connect(self):
        if self.addr.startswith("unix:"):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.connect(self.addr[5:])
        else:
            host, port = self.addr[4:].rsplit(":", 1)
            s = socket.create_connection((host, int(port)))
        s.settimeout(30 * self.scale)
        return s.makefile("rw", buffering=1)

    def stop(self, sig=signal.SIGTERM):
        self.proc.send_signal(sig)
        rc = self.proc.wait(timeout=30 * self.scale)
        self.rest = "".join(self.log) + self.proc.stderr.read()
        for bad in ("AddressSanitizer", "LeakSanitizer", "runtime error"):
            assert bad not in self.rest, self.rest
        return rc


def ask(f, line):
    f.write(line + "\n")
    f.flush()
    return json.loads(f.readline())


@pytest.fixture
def daemon(poseinfer, timeout_scale):
    started = []

    def _start(*args):
        d = Daemon(poseinfer, args, timeout_scale)
        started.append(d)
        return d

    yield _start
    for d in started:
        if d.proc.poll() is None:
            d.proc.kill()
            d.proc.wait()


def test_unix_protocol(daemon, models, frames, tmp_path):
    sock = tmp_path / "pi.sock"
    d = daemon("--model", models["good"], "--serve", f"unix:{sock}", "--allow-dir", frames["good.png"].parent)
    f = d.connect()
    assert ask(f, "ping") == {"pong": True}
    r = ask(f, f"infer {frames['good.png']}")
    assert r["file"] == str(frames["good.png"]) and "error" not in r
    assert {"x", "y", "z", "ms", "decode_ms", "preprocess_ms", "infer_ms"} <= set(r)
    r = ask(f, f"infer {frames['nosphere.png']}")
    assert "no sphere found in frame" in r["error"]
    r = ask(f, f"infer {frames['truncated.png']}")
    assert "error" in r
    assert "unknown command" in ask(f, "fly away")["error"]
    assert "error" in ask(f, "infer")
    assert "no camera" in ask(f, "grab")["error"]
    st = ask(f, "stats")
    assert st["frames"] == 1 and st["errors"] == 2 and st["clients"] == 1 and st["ms_p50"] > 0
    # two clients at once, pipelined requests
    g = d.connect()
    g.write("ping\nping\nstats\n")
    g.flush()
    assert json.loads(g.readline()) == {"pong": True}
    assert json.loads(g.readline()) == {"pong": True}
    assert json.loads(g.readline())["clients"] == 2
    assert ask(f, "quit") == {"bye": True}
    assert f.readline() == ""
    assert d.stop() == 0
    assert not sock.exists(), "socket file left behind"


def test_tcp_and_long_line(daemon, models, frames):
    d = daemon("--model", models["good"], "--serve", "tcp:127.0.0.1:0", "--allow-dir", frames["good.jpg"].parent)
    assert re.match(r"tcp:127\.0\.0\.1:\d+$", d.addr)
    f = d.connect()
    assert ask(f, "ping") == {"pong": True}
    assert ask(f, f"infer {frames['good.jpg']}")["file"] == str(frames["good.jpg"])
    f.write("x" * 10000 + "\n")
    f.flush()
    assert "too long" in json.loads(f.readline())["error"]
    assert d.stop(signal.SIGINT) == 0


def test_sighup_reload(daemon, models, frames, tmp_path):
    m = tmp_path / "model.onnx"
    shutil.copy(models["good"], m)
    d = daemon("--model", m, "--serve", f"unix:{tmp_path / 's'}", "--allow-dir", frames["good.png"].parent)
    f = d.connect()
    before = ask(f, f"infer {frames['good.png']}")
    shutil.copy(models["size64"], m)
    d.proc.send_signal(signal.SIGHUP)
    deadline = time.time() + 20 * d.scale
    while ask(f, "stats")["reloads"] < 1:
        assert time.time() < deadline, "no reload"
        time.sleep(0.05)
    after = ask(f, f"infer {frames['good.png']}")
    assert (after["x"], after["y"]) != (before["x"], before["y"])  # a different model now
    # a broken model on reload: the old one stays
    shutil.copy(models["nometa"], m)
    d.proc.send_signal(signal.SIGHUP)
    d.wait_log("SIGHUP: reload failed", 20)
    again = ask(f, f"infer {frames['good.png']}")
    assert again["x"] == after["x"]
    r = ask(f, "reload")
    assert "spherepose.preprocess" in r["error"]
    assert d.stop() == 0
    assert "reload failed" in d.rest


def test_grab_from_frame_server(daemon, models, frame_server, tmp_path):
    srv = frame_server([sphere_frame(seed=21), sphere_frame(seed=22, cx=200)])
    d = daemon("--model", models["good"], "--serve", f"unix:{tmp_path / 'pi.sock'}", "--camera", f"unix:{srv.path}")
    f = d.connect()
    a = ask(f, "grab")
    b = ask(f, "grab")
    assert a["camera"] == f"unix:{srv.path}" and "error" not in a and "error" not in b
    assert abs(a["cx"] - 320) < 2 and abs(b["cx"] - 200) < 2
    assert a["decode_ms"] > 0
    assert srv.grabs == 2
    assert d.stop() == 0


@pytest.mark.parametrize("mode,words", [("error", "camera not ready"), ("silent", "timed out"),
                                        ("short", "connection closed")])
def test_frame_server_failures(daemon, models, frame_server, tmp_path, mode, words, timeout_scale):
    srv = frame_server([sphere_frame(seed=23)], mode=mode)
    # short only where the timeout is what is tested: elsewhere a slow machine
    # must not turn the server's own failure into a timeout
    timeout_ms = "500" if mode == "silent" else str(int(10000 * timeout_scale))
    d = daemon("--model", models["good"], "--serve", f"unix:{tmp_path / 'pi.sock'}", "--camera", f"unix:{srv.path}",
               "--timeout-ms", timeout_ms)
    f = d.connect()
    r = ask(f, "grab")
    assert words in r["error"], r
    assert ask(f, "ping") == {"pong": True}  # the daemon is fine
    assert d.stop() == 0


def test_continuous(run, models, frame_server):
    srv = frame_server([sphere_frame(seed=24), sphere_frame(seed=25, cx=250)])
    r = run("--model", models["good"], "--camera", f"unix:{srv.path}", "--continuous", "--count", "3")
    assert r.rc == 0, r.stderr
    assert [l["frame"] for l in r.lines] == [0, 1, 2]
    for l in r.lines:
        assert {"x", "y", "z", "ms", "time"} <= set(l) and "error" not in l


def test_continuous_stops_on_sigterm(poseinfer, models, frame_server, timeout_scale):
    srv = frame_server([sphere_frame(seed=26)])
    p = subprocess.Popen([str(poseinfer), "--model", str(models["good"]), "--camera", f"unix:{srv.path}",
                          "--continuous", "--interval-ms", "50"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    try:
        first = read_line(p.stdout, time.time() + 30 * timeout_scale)
        assert first, f"no frame in {30 * timeout_scale} s"
        assert "x" in json.loads(first)
        p.send_signal(signal.SIGTERM)
        assert p.wait(timeout=20 * timeout_scale) == 0
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()


def test_continuous_saves_frames(run, models, frame_server, tmp_path):
    frames = [sphere_frame(seed=24), sphere_frame(seed=25, cx=250)]
    srv = frame_server(frames)
    out = tmp_path / "grabbed"  # made by poseinfer
    r = run("--model", models["good"], "--camera", f"unix:{srv.path}", "--continuous", "--count", "3",
            "--save-frames", out)
    assert r.rc == 0, r.stderr
    names = [f"frame_{n:06d}.png" for n in range(3)]
    assert [l["saved"] for l in r.lines] == [str(out / n) for n in names]
    assert sorted(f.name for f in out.iterdir()) == names  # no temporary file left
    for n, name in enumerate(names):  # the server sends its frames in turn, losslessly
        assert np.array_equal(cv2.imread(str(out / name)), frames[n % 2]), name
    # a frame that cannot be written is still measured
    (tmp_path / "blocked").mkdir()
    (tmp_path / "blocked" / "frame_000000.png").mkdir()
    r = run("--model", models["good"], "--camera", f"unix:{srv.path}", "--continuous", "--count", "1",
            "--save-frames", tmp_path / "blocked")
    assert r.rc == 0 and "saved" not in r.lines[0] and "x" in r.lines[0], r.stdout
    assert "frame 0: not saved" in r.stderr and "frame_000000.png" in r.stderr
    assert sorted(f.name for f in (tmp_path / "blocked").iterdir()) == ["frame_000000.png"]
    # usage
    r = run("--model", models["good"], "--save-frames", out, "x.png")
    assert r.rc == 2 and "--save-frames is for --continuous" in r.stderr
    (tmp_path / "file").write_text("")
    r = run("--model", models["good"], "--camera", f"unix:{srv.path}", "--continuous", "--save-frames",
            tmp_path / "file")
    assert r.rc == 2 and "not a folder" in r.stderr


def test_camera_that_is_not_there(run, models, tmp_path):
    r = run("--model", models["good"], "--camera", f"unix:{tmp_path / 'none.sock'}", "--continuous", "--count", "1")
    assert r.rc == 2 and "connect" in r.stderr


def test_idle_cpu(daemon, models, tmp_path):
    d = daemon("--model", models["good"], "--serve", f"unix:{tmp_path / 'pi.sock'}", "--threads", "2")
    f = d.connect()
    ask(f, "ping")

    def cpu():
        fields = open(f"/proc/{d.proc.pid}/stat").read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    c0, t0 = cpu(), time.time()
    time.sleep(2.0)
    used = cpu() - c0
    assert used / (time.time() - t0) < 0.02, f"idle daemon used {used:.3f} s of CPU in 2 s"
    assert d.stop() == 0


def test_real_virtual_camera(run, models, tmp_path, timeout_scale):
    """The unix: client against the project's own frame server (`sim vcam`)."""
    from pihelpers import ROOT
    sim = ROOT / ".venv" / "bin" / "sim"
    if not sim.exists():
        pytest.skip("sim not installed")
    tex = dots_texture(tmp_path / "tex.png")
    sock = tmp_path / "vcam.sock"
    p = subprocess.Popen([str(sim), "vcam", "--texture", str(tex), "--socket", str(sock), "--pose", "10", "-5", "20"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = read_line(p.stdout, time.time() + 60 * timeout_scale)
        assert line is not None, f"sim vcam said nothing in {60 * timeout_scale} s"
        if not line.startswith("VCAM"):
            pytest.skip(f"sim vcam did not start: {line} {p.stderr.read()[-300:] if p.poll() is not None else ''}")
        r = run("--model", models["good"], "--camera", f"unix:{sock}", "--continuous", "--count", "2",
                "--timings", "--timeout-ms", str(int(30000 * timeout_scale)))
        assert r.rc == 0, r.stderr
        assert len(r.lines) == 2
        for l in r.lines:
            assert "error" not in l, l
            # the reference camera: sphere of 40 mm at 250 mm, about 267 px across, centred
            assert abs(l["cx"] - 320) < 3 and abs(l["cy"] - 256) < 3 and abs(l["r"] - 133) < 6, l
        assert r.lines[0]["x"] == r.lines[1]["x"]  # same pose, same frame, same answer
    finally:
        p.terminate()
        p.wait(timeout=30)


GST_PIPELINE = ("gst:filesrc location={path} ! rawvideoparse width={w} height={h} format=bgr framerate=10/1 "
                "! videoconvert ! video/x-raw,format=BGR ! appsink")


def test_gstreamer_camera_gives_the_frames_file_mode_gives(run, models, tmp_path):
    """The gst: source for real: raw BGR frames through filesrc, rawvideoparse and
    appsink (GStreamer's base plugins) reach the model as the same pixels as the
    PNG files of the same frames: the same poses, to the last digit."""
    frames = [sphere_frame(seed=40), sphere_frame(seed=41, cx=260, cy=300), sphere_frame(seed=42, r=110)]
    raw = tmp_path / "frames.bgr"
    raw.write_bytes(b"".join(f.tobytes() for f in frames))
    pngs = []
    for i, f in enumerate(frames):
        p = tmp_path / f"f{i}.png"
        cv2.imwrite(str(p), f)
        pngs.append(p)
    ref = run("--model", models["good"], *pngs)
    assert ref.rc == 0, ref.stderr
    h, w = frames[0].shape[:2]
    r = run("--model", models["good"], "--camera", GST_PIPELINE.format(path=raw, w=w, h=h), "--continuous",
            "--count", "3")
    assert r.rc == 0, r.stderr
    assert [l["frame"] for l in r.lines] == [0, 1, 2]
    for got, want in zip(r.lines, ref.lines):
        assert "error" not in got, got
        assert (got["x"], got["y"], got["z"]) == (want["x"], want["y"], want["z"])


def test_gstreamer_pipeline_that_cannot_start(run, models):
    r = run("--model", models["good"], "--camera", "gst:nosuchelement ! appsink", "--continuous", "--count", "1")
    assert r.rc == 2 and "gst:" in r.stderr


def test_fifo_does_not_block_the_daemon(daemon, models, frames, tmp_path):
    """`infer FIFO` answers an error at once; another client is served."""
    fifo = tmp_path / "f.png"
    os.mkfifo(fifo)
    d = daemon("--model", models["good"], "--serve", f"unix:{tmp_path / 'pi.sock'}", "--allow-dir", tmp_path)
    f = d.connect()
    r = ask(f, f"infer {fifo}")
    assert "not a regular file (a FIFO)" in r["error"] and r["file"] == str(fifo)
    g = d.connect()
    assert ask(g, "ping") == {"pong": True}
    assert d.stop() == 0


def test_request_bytes_that_are_not_utf8_give_valid_json(daemon, models, tmp_path):
    d = daemon("--model", models["good"], "--serve", f"unix:{tmp_path / 'pi.sock'}")
    s = f = RawClient(d)
    f.write(b"fly\xff\xfe away\ninfer /x/\xe9t\xe9.png\ninfer /x.png\x00/etc/passwd\nping\n")
    replies = [json.loads(f.readline().decode("utf-8")) for _ in range(4)]
    assert "unknown command \"fly\ufffd\ufffd\"" in replies[0]["error"]
    assert replies[1]["file"] == "/x/\ufffdt\ufffd.png" and "error" in replies[1]
    assert "NUL" in replies[2]["error"]
    assert replies[3] == {"pong": True}
    s.close()
    assert d.stop() == 0


class RawClient:
    """Bytes both ways: write() sends all of them, readline() reads a line."""

    def __init__(self, d):
        self.s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.s.connect(d.addr[5:])
        self.s.settimeout(30 * d.scale)
        self.r = self.s.makefile("rb")

    def write(self, data):
        self.s.sendall(data)

    def readline(self):
        return self.r.readline()

    def close(self):
        self.r.close()
        self.s.close()


def send_frame(f, data):
    f.write(b"frame %d\n" % len(data) + data)
    return json.loads(f.readline())


def raw_connect(d):
    c = RawClient(d)
    return c, c


def test_default_reads_no_files_but_takes_frames(daemon, models, frames, tmp_path):
    """Without --allow-dir, `infer PATH` reads nothing (the reply tells nothing
    about the file); images come over the socket with `frame N`."""
    sock = tmp_path / "pi.sock"
    d = daemon("--model", models["good"], "--serve", f"unix:{sock}")
    assert oct(os.stat(sock).st_mode & 0o7777) == "0o660"  # whatever the umask
    s, f = raw_connect(d)
    for p in (frames["good.png"], "/etc/shadow", "/nonexistent"):
        f.write(f"infer {p}\n".encode())
        r = json.loads(f.readline())
        assert "reading files is off" in r["error"] and r["file"] == str(p)
    data = frames["good.png"].read_bytes()
    r = send_frame(f, data)
    assert r["bytes"] == len(data) and "error" not in r and {"x", "y", "z", "infer_ms"} <= set(r)
    r = send_frame(f, frames["nosphere.png"].read_bytes())
    assert "no sphere found" in r["error"]
    r = send_frame(f, b"not an image")
    assert "cannot decode" in r["error"]
    # an image sent in pieces, pipelined with a ping
    f.write(b"frame %d\n" % len(data) + data[:1000])
    time.sleep(0.05)
    f.write(data[1000:] + b"ping\n")
    assert "error" not in json.loads(f.readline())
    assert json.loads(f.readline()) == {"pong": True}
    f.write(b"frame 99999999999\n")
    assert "max_file_bytes" in json.loads(f.readline())["error"]
    assert f.readline() == b""  # closed: what follows cannot be told from commands
    s.close()
    assert d.stop() == 0


def test_allow_dir_confines_infer(daemon, models, frames, tmp_path):
    ok = tmp_path / "frames"
    ok.mkdir()
    shutil.copy(frames["good.png"], ok / "a.png")
    (ok / "out.png").symlink_to(frames["good.png"])  # leads out of the directory
    d = daemon("--model", models["good"], "--serve", f"unix:{tmp_path / 'pi.sock'}", "--allow-dir", ok)
    f = d.connect()
    assert "error" not in ask(f, f"infer {ok / 'a.png'}")
    assert "No such file" in ask(f, f"infer {ok / 'b.png'}")["error"]
    outside = [ok / "out.png", f"{ok}/../frames/../../x.png", frames["good.png"], "/etc/shadow", "/etc/no-such-file",
               "relative.png"]
    answers = [ask(f, f"infer {p}")["error"] for p in outside]
    for p, a in zip(outside[:-1], answers[:-1]):
        assert a == f"infer({p}): not in an allowed directory", a
    assert "absolute" in answers[-1]
    assert d.stop() == 0


def test_allow_dir_must_exist(run, models, tmp_path):
    r = run("--model", models["good"], "--serve", f"unix:{tmp_path / 's'}", "--allow-dir", tmp_path / "none")
    assert r.rc == 2 and f"allow_dir({tmp_path / 'none'})" in r.stderr


def test_socket_mode_and_group_from_config(daemon, models, tmp_path):
    sock = tmp_path / "pi.sock"
    cfg = tmp_path / "pi.conf"
    cfg.write_text(f"model = {models['good']}\nserve = unix:{sock}\nsocket_mode = 0600\n"
                   f"socket_group = {os.getegid()}\n")
    d = daemon("--config", cfg)
    st = os.stat(sock)
    assert st.st_mode & 0o7777 == 0o600 and st.st_gid == os.getegid()
    assert d.stop() == 0


def test_tcp_other_than_loopback_needs_config_and_token(run, daemon, models, tmp_path):
    r = run("--model", models["good"], "--serve", "tcp:0.0.0.0:0")
    assert r.rc == 2 and "not a loopback address" in r.stderr
    cfg = tmp_path / "pi.conf"
    cfg.write_text(f"model = {models['good']}\ntcp_remote = yes\n")
    r = run("--config", cfg, "--serve", "tcp:0.0.0.0:0")
    assert r.rc == 2 and "token_file" in r.stderr
    tok = tmp_path / "token"
    tok.write_text("s3cret-token-of-some-length\n")
    tok.chmod(0o644)
    cfg.write_text(f"model = {models['good']}\ntcp_remote = yes\ntoken_file = {tok}\n")
    r = run("--config", cfg, "--serve", "tcp:0.0.0.0:0")
    assert r.rc == 2 and "readable by every user" in r.stderr
    tok.chmod(0o600)
    d = daemon("--config", cfg, "--serve", "tcp:0.0.0.0:0")
    port = int(d.addr.rsplit(":", 1)[1])

    def conn():
        s = socket.create_connection(("127.0.0.1", port))
        s.settimeout(30 * d.scale)
        return s.makefile("rw", buffering=1)

    f = conn()
    assert "auth required" in ask(f, "ping")["error"]
    assert f.readline() == ""
    f = conn()
    assert "wrong token" in ask(f, "auth s3cret-token-of-some-lengtX")["error"]
    assert f.readline() == ""
    f = conn()
    assert ask(f, "auth s3cret-token-of-some-length") == {"auth": True}
    assert ask(f, "ping") == {"pong": True}
    assert "only the daemon's user" in ask(f, "reload")["error"]  # never over TCP
    assert d.stop() == 0


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to connect as another user")
def test_reload_only_from_the_owner(daemon, models, tmp_path):
    import tempfile
    python = shutil.which("python3", path="/usr/bin:/bin")
    if not python:
        pytest.skip("no system python3 for the other user")
    sockdir = Path(tempfile.mkdtemp(prefix="pi_owner_"))  # pytest's folders are private to root
    sockdir.chmod(0o755)
    sock = sockdir / "pi.sock"
    cfg = tmp_path / "pi.conf"
    cfg.write_text(f"model = {models['good']}\nserve = unix:{sock}\nsocket_mode = 0666\n")
    d = daemon("--config", cfg)
    client = ("import json, socket, sys; s = socket.socket(socket.AF_UNIX); s.connect(sys.argv[1]); "
              "f = s.makefile('rw'); f.write('reload\\nping\\n'); f.flush(); print(f.readline(), f.readline())")
    try:
        out = subprocess.run([python, "-c", client, str(sock)], capture_output=True, text=True, timeout=30,
                             user=65534, cwd="/")
        assert "only the daemon's user (uid 0)" in out.stdout and "pong" in out.stdout, out
        f = d.connect()
        assert ask(f, "reload") == {"reloaded": True}
        assert d.stop() == 0
    finally:
        shutil.rmtree(sockdir, ignore_errors=True)


def rss_kib(pid):
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


def test_idle_clients_are_closed(daemon, models, tmp_path):
    """A client with no complete request for idle_timeout_ms is told and
    closed; a line sent a byte at a time does not keep it open."""
    d = daemon("--model", models["good"], "--serve", f"unix:{tmp_path / 'pi.sock'}", "--idle-timeout-ms", "1000")
    idle = RawClient(d)
    slow = RawClient(d)
    t0 = time.time()
    # a byte every 0.1 s, never a whole line, until the daemon answers or has
    # closed: past idle_timeout_ms, so the bytes alone would keep it open
    while time.time() - t0 < 10 * d.scale:
        try:
            slow.write(b"p")
        except (BrokenPipeError, ConnectionResetError):
            break  # closed; its error line is still to be read
        if select.select([slow.s], [], [], 0.1)[0]:
            break
    assert "idle" in json.loads(slow.readline())["error"]
    assert time.time() - t0 < 10 * d.scale
    r = json.loads(idle.readline())
    assert "idle" in r["error"] and "idle_timeout_ms" in r["error"]
    assert idle.readline() == b""
    f = d.connect()  # a busy client is never idle for long
    for _ in range(6):  # 1.5 s in all, longer than idle_timeout_ms
        assert ask(f, "ping") == {"pong": True}
        time.sleep(0.25)
    assert ask(f, "stats")["idle_closed"] == 2
    assert d.stop() == 0


def test_client_limit_answers_with_an_error(daemon, models, tmp_path):
    d = daemon("--model", models["good"], "--serve", f"unix:{tmp_path / 'pi.sock'}", "--max-clients", "2")
    a, b = d.connect(), d.connect()
    assert ask(a, "ping") == {"pong": True} and ask(b, "ping") == {"pong": True}
    c = RawClient(d)
    r = json.loads(c.readline())
    assert "busy" in r["error"] and "max_clients" in r["error"]
    assert c.readline() == b""
    b.close()
    deadline = time.time() + 10 * d.scale
    while True:  # the slot comes free once the daemon has seen b go
        f = RawClient(d)
        try:
            f.write(b"ping\n")
            line = f.readline()
        except (BrokenPipeError, ConnectionResetError) as e:
            # still full: the daemon wrote "busy" and closed before the ping went out
            line = repr(e).encode()
        f.close()
        if line and line.startswith(b"{") and json.loads(line) == {"pong": True}:
            break
        assert time.time() < deadline, line
        time.sleep(0.05)
    assert ask(a, "stats")["busy_refusals"] >= 1
    assert d.stop() == 0


def test_file_size_bound(run, daemon, models, frames, tmp_path):
    """Files and frames over max_file_bytes are refused before they are read;
    the default bound (64 MiB) is below what the decode bound would let in."""
    big = tmp_path / "big.png"
    with open(big, "wb") as f:
        f.truncate(70 * 1024 * 1024)  # sparse: costs no disk
    r = run("--model", models["good"], big, frames["good.png"])
    assert r.rc == 1
    assert "over the limit of 67108864" in r.lines[0]["error"] and "x" in r.lines[1]
    r = run("--model", models["good"], "--max-file-bytes", "100000", frames["good.png"])
    assert "over the limit of 100000" in r.lines[0]["error"]
    d = daemon("--model", models["good"], "--serve", f"unix:{tmp_path / 'pi.sock'}", "--allow-dir", tmp_path,
               "--max-file-bytes", "100000")
    f = RawClient(d)
    f.write(f"infer {big}\n".encode())
    assert "over the limit of 100000" in json.loads(f.readline())["error"]
    f.write(b"frame 100001\n")
    assert "max_file_bytes" in json.loads(f.readline())["error"]
    assert d.stop() == 0


def test_memory_is_given_back_after_a_large_frame(daemon, models, tmp_path):
    """A 4000 x 4000 BMP (48 MB of file, 48 MB of pixels) is inferred;
    afterwards, and after the next small frame, the daemon's resident memory
    is back near where it was (it kept both buffers: +94 MiB, then +48 MiB)."""
    if os.environ.get("PI_SANITIZED"):
        pytest.skip("AddressSanitizer's allocator keeps freed memory in quarantine: RSS means nothing")
    big = tmp_path / "big.bmp"
    cv2.imwrite(str(big), sphere_frame(h=4000, w=4000, cx=2000, cy=2000, r=1500, noise=0))
    d = daemon("--model", models["good"], "--serve", f"unix:{tmp_path / 'pi.sock'}", "--allow-dir", tmp_path,
               "--max-pixels", str(30_000_000))
    f = d.connect()
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), sphere_frame(seed=3))
    assert "error" not in ask(f, f"infer {small}")
    before = rss_kib(d.proc.pid)
    r = ask(f, f"infer {big}")
    assert "error" not in r, r
    after = rss_kib(d.proc.pid)
    assert after - before < 30 * 1024, f"RSS {before} KiB before the large frame, {after} KiB after"
    assert "error" not in ask(f, f"infer {small}")
    again = rss_kib(d.proc.pid)
    assert again - before < 30 * 1024, f"RSS {before} KiB before the large frame, {again} KiB after the next"
    assert d.stop() == 0


def test_a_slow_frame_holds_only_its_own_client(daemon, models, frames, frame_server, tmp_path, timeout_scale):
    """A grab from a camera that never answers keeps one worker for its
    timeout; other clients' frames are answered meanwhile, and the event loop
    answers at once."""
    srv = frame_server([sphere_frame(seed=30)], mode="silent")
    d = daemon("--model", models["good"], "--serve", f"unix:{tmp_path / 'pi.sock'}", "--camera", f"unix:{srv.path}",
               "--timeout-ms", str(int(4000 * timeout_scale)), "--workers", "2")
    slow = d.connect()
    slow.write("grab\nping\n")
    slow.flush()
    time.sleep(0.2)
    t0 = time.time()
    other = RawClient(d)
    r = send_frame(other, frames["good.png"].read_bytes())
    other.write(b"ping\n")
    assert json.loads(other.readline()) == {"pong": True}
    fast = time.time() - t0
    assert "error" not in r
    g = json.loads(slow.readline())
    assert "timed out" in g["error"]
    assert json.loads(slow.readline()) == {"pong": True}  # its own requests stay in order
    assert fast < 2.0 * timeout_scale, f"another client waited {fast:.2f} s behind the slow grab"
    assert d.stop() == 0
