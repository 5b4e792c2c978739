"""`sim vcam` against a fake stagesim state socket: frames at the stage's angles, errors, clean shutdown."""
import json
import os
import signal
import socket
import subprocess
import sys
import threading

import cv2
import numpy as np
import pytest

from sim.camera import load_camera
from sim.render import Renderer


class FakeStage:
    """A state socket like stagesim's: `state\\n` -> one JSON line; the angles are set by the test."""

    def __init__(self, path):
        self.path = path
        self.angles = (0.0, 0.0, 0.0)
        self.requests = 0
        self.conns = []
        self.srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.srv.bind(path)
        self.srv.listen(4)
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.srv.accept()
            except OSError:
                return
            self.conns.append(conn)
            threading.Thread(target=self._client, args=(conn,), daemon=True).start()

    def _client(self, conn):
        try:
            with conn:
                for line in conn.makefile("rb"):
                    if line.strip() == b"state":
                        self.requests += 1
                        x, y, z = self.angles
                        reply = {"x": x, "y": y, "z": z, "steps": [int(x * 800), int(y * 800), int(z * 800)],
                                 "enabled": True, "cycle": 1234, "limits": [0, 0, 0]}
                        conn.sendall((json.dumps(reply) + "\n").encode())
        except OSError:
            pass  # closed by close()

    def close(self):
        """Stop like a dead stagesim: the listening socket and every connection go away."""
        for conn in self.conns:
            try:
                conn.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self.srv.close()
        os.unlink(self.path)


def grab(sock):
    """Send grab, return ('FRAME', png bytes) or ('ERROR', message)."""
    sock.sendall(b"grab\n")
    f = sock.makefile("rb")
    header = f.readline().decode().rstrip("\n")
    kind, _, rest = header.partition(" ")
    if kind == "FRAME":
        data = f.read(int(rest))
        assert len(data) == int(rest)
        return kind, data
    return kind, rest


@pytest.fixture
def short_dir():
    """Unix socket paths must stay under ~100 characters: use a short temporary folder."""
    import tempfile
    d = tempfile.mkdtemp(prefix="vc", dir="/tmp")
    yield d
    for name in os.listdir(d):
        os.unlink(os.path.join(d, name))
    os.rmdir(d)


def start_vcam(args):
    proc = subprocess.Popen([sys.executable, "-m", "sim.cli", "vcam", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    if not line.startswith("VCAM "):
        proc.kill()
        raise AssertionError(f"vcam did not start: {line!r} {proc.stderr.read()}")
    return proc, line.split(" ", 1)[1].strip()


def test_vcam_renders_the_stage_angles(short_dir, texture_png, small_camera_json):
    stage = FakeStage(os.path.join(short_dir, "state"))
    vsock = os.path.join(short_dir, "cam")
    proc, path = start_vcam(["--texture", texture_png, "--camera", small_camera_json,
                             "--stage-state", stage.path, "--socket", vsock])
    try:
        assert path == vsock
        direct = Renderer(texture_png, load_camera(small_camera_json))
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as c:
            c.settimeout(20)
            c.connect(vsock)
            for angles in [(0.0, 0.0, 0.0), (12.5, -7.25, 20.0), (-30.0, 30.0, -3.0)]:
                stage.angles = angles
                kind, data = grab(c)
                assert kind == "FRAME", data
                bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
                assert bgr.shape == (128, 160, 3)
                # The frame is exactly what the renderer makes at the stage's angles.
                np.testing.assert_array_equal(bgr[:, :, ::-1], direct.render(angles))
            c.sendall(b"hello\n")
            assert c.makefile("rb").readline().startswith(b"ERROR unknown request")
            # The stage goes away: an ERROR line, not a dead server.
            stage.close()
            stage = None
            kind, msg = grab(c)
            assert kind == "ERROR" and "stage state" in msg
        assert proc.poll() is None
    finally:
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(timeout=20)
        if stage:
            stage.close()
    assert rc == 0
    assert not os.path.exists(vsock), "socket left behind after SIGTERM"


def test_vcam_pose_file_and_sigint(short_dir, texture_png, small_camera_json):
    poses = os.path.join(short_dir, "poses.txt")
    with open(poses, "w") as f:
        f.write("# x y z\n0 0 0\n10 20 -5\n")
    vsock = os.path.join(short_dir, "cam")
    log = os.path.join(short_dir, "frames.jsonl")
    proc, _ = start_vcam(["--texture", texture_png, "--camera", small_camera_json,
                          "--pose-file", poses, "--socket", vsock, "--noise", "3", "--frame-log", log])
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as c:
            c.settimeout(20)
            c.connect(vsock)
            frames = [grab(c)[1] for _ in range(3)]
        assert frames[0] != frames[1]
        a, b = (cv2.imdecode(np.frombuffer(d, np.uint8), cv2.IMREAD_COLOR) for d in (frames[0], frames[2]))
        # Same pose (the file cycles), different noise draw: close but not equal.
        assert not np.array_equal(a, b) and np.abs(a.astype(int) - b).mean() < 4
    finally:
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(timeout=20)
    assert rc == 0 and not os.path.exists(vsock)
    # The frame log records the angles each served frame shows, in order.
    with open(log) as f:
        logged = [json.loads(line) for line in f]
    assert [(d["frame"], d["x"], d["y"], d["z"]) for d in logged] == \
        [(0, 0.0, 0.0, 0.0), (1, 10.0, 20.0, -5.0), (2, 0.0, 0.0, 0.0)]


def test_vcam_needs_one_pose_source(texture_png):
    r = subprocess.run([sys.executable, "-m", "sim.cli", "vcam", "--texture", texture_png, "--socket", "/tmp/x"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "exactly one pose source" in r.stderr


def test_bad_pose_file_names_file_and_line(tmp_path, texture_png):
    bad = tmp_path / "poses.txt"
    bad.write_text("1 2 3\n1 2\n")
    r = subprocess.run([sys.executable, "-m", "sim.cli", "vcam", "--texture", texture_png,
                        "--socket", "/tmp/x", "--pose-file", str(bad)], capture_output=True, text=True)
    assert r.returncode == 2 and f"{bad}:2:" in r.stderr
