"""Fixtures for the poseinfer program tests (test_poseinfer.py, test_daemon.py,
test_parity.py). They drive the real program from outside.

Environment:
  POSEINFER    the binary to test (default host/build/poseinfer)
  PI_VALGRIND  a command prefix (valgrind ...) for the tests marked `valgrind`
  PI_SANITIZED set when the binary is built with ASan/UBSan (longer timeouts)
"""
import json
import os
import shlex
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import make_model  # noqa: E402
from pihelpers import ROOT, sphere_frame  # noqa: E402,F401

cv2 = pytest.importorskip("cv2")


def pytest_configure(config):
    config.addinivalue_line("markers", "valgrind: also run under valgrind by `make -C host test-valgrind`")


def poseinfer_path():
    return Path(os.environ.get("POSEINFER", ROOT / "host" / "build" / "poseinfer"))


@pytest.fixture(scope="session")
def poseinfer():
    p = poseinfer_path()
    if not p.exists():
        pytest.fail(f"{p} not built: run `make -C host` first")
    return p


@pytest.fixture(scope="session")
def timeout_scale():
    if os.environ.get("PI_VALGRIND"):
        return 20.0
    return 3.0 if os.environ.get("PI_SANITIZED") else 1.0


class Run:
    """Result of one poseinfer run: rc, JSON lines of stdout, stderr."""

    def __init__(self, proc):
        self.rc = proc.returncode
        self.stdout = proc.stdout
        self.stderr = proc.stderr
        self.lines = []
        for l in proc.stdout.splitlines():
            try:
                self.lines.append(json.loads(l))
            except ValueError:
                pass


@pytest.fixture(scope="session")
def run(poseinfer, timeout_scale):
    """run(*args, valgrind=False): run poseinfer; under PI_VALGRIND when asked."""

    def _run(*args, valgrind=False, timeout=60, cwd=None):
        prefix = shlex.split(os.environ.get("PI_VALGRIND", "")) if valgrind else []
        cmd = prefix + [str(poseinfer)] + [str(a) for a in args]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout * timeout_scale, cwd=cwd)
        if prefix and proc.returncode == 99:
            pytest.fail(f"valgrind found errors:\n{proc.stderr[-6000:]}")
        assert "runtime error" not in proc.stderr, proc.stderr  # UBSan
        assert "AddressSanitizer" not in proc.stderr, proc.stderr
        assert "LeakSanitizer" not in proc.stderr, proc.stderr
        return Run(proc)

    return _run


@pytest.fixture(scope="session")
def models(tmp_path_factory):
    """{variant: path} of the test models (make_model.py)."""
    d = tmp_path_factory.mktemp("models")
    return {v: make_model.write(d / f"{v}.onnx", v) for v in make_model.VARIANTS}


@pytest.fixture(scope="session")
def frames(tmp_path_factory):
    """Named test images on disk."""
    d = tmp_path_factory.mktemp("frames")
    out = {}

    def put(name, img):
        p = d / name
        assert cv2.imwrite(str(p), img)
        out[name] = p

    put("good.png", sphere_frame(seed=1))
    put("good.jpg", sphere_frame(seed=2))
    put("gray.png", sphere_frame(seed=3, gray=True))
    put("rgba.png", cv2.cvtColor(sphere_frame(seed=4), cv2.COLOR_BGR2BGRA))
    put("nosphere.png", np.full((480, 640, 3), 60, np.uint8))
    good = out["good.png"].read_bytes()
    (d / "truncated.png").write_bytes(good[: len(good) // 2])
    out["truncated.png"] = d / "truncated.png"
    jpg = out["good.jpg"].read_bytes()
    (d / "truncated.jpg").write_bytes(jpg[: len(jpg) // 2])
    out["truncated.jpg"] = d / "truncated.jpg"
    (d / "corrupt.png").write_bytes(good[:100] + bytes(np.random.default_rng(5).integers(0, 256, 5000, dtype=np.uint8)))
    out["corrupt.png"] = d / "corrupt.png"
    (d / "empty.png").write_bytes(b"")
    out["empty.png"] = d / "empty.png"
    (d / "text.png").write_text("this is not an image\n")
    out["text.png"] = d / "text.png"
    # A valid PNG header that claims 60000 x 60000 pixels, then nothing.
    import struct
    import zlib
    ihdr = struct.pack(">IIBBBBB", 60000, 60000, 8, 2, 0, 0, 0)
    chunk = struct.pack(">I", 13) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    (d / "huge_header.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk)
    out["huge_header.png"] = d / "huge_header.png"
    return out


class FrameServer:
    """A fake `unix:` frame server (docs/interfaces.md): answers `grab` with
    FRAME <n> + PNG bytes from `frames` in turn, or ERROR, or nothing."""

    def __init__(self, path, frames, mode="ok"):
        self.path = str(path)
        self.frames = [cv2.imencode(".png", f)[1].tobytes() for f in frames]
        self.mode = mode
        self.grabs = 0
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.bind(self.path)
        self.sock.listen(4)
        self.stop = False
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        self.sock.settimeout(0.2)
        while not self.stop:
            try:
                conn, _ = self.sock.accept()
            except (socket.timeout, OSError):
                continue
            threading.Thread(target=self._client, args=(conn,), daemon=True).start()

    def _client(self, conn):
        f = conn.makefile("rb")
        try:
            for line in f:
                if line.strip() != b"grab":
                    conn.sendall(b"ERROR unknown command\n")
                    continue
                data = self.frames[self.grabs % len(self.frames)]
                self.grabs += 1
                if self.mode == "error":
                    conn.sendall(b"ERROR camera not ready\n")
                elif self.mode == "silent":
                    continue
                elif self.mode == "short":
                    conn.sendall(b"FRAME %d\n" % len(data) + data[: len(data) // 2])
                    conn.close()
                    return
                else:
                    conn.sendall(b"FRAME %d\n" % len(data) + data)
        except OSError:
            pass
        finally:
            conn.close()

    def close(self):
        self.stop = True
        self.sock.close()
        self.thread.join(timeout=2)


@pytest.fixture
def frame_server(tmp_path):
    servers = []

    def _make(frames, mode="ok", name="cam.sock"):
        s = FrameServer(tmp_path / name, frames, mode)
        servers.append(s)
        return s

    yield _make
    for s in servers:
        s.close()
