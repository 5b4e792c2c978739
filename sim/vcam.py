"""The virtual camera: a frame server on a Unix stream socket (docs/interfaces.md, "Frame sources").

A client sends `grab\\n`; the server answers `FRAME <nbytes>\\n` and exactly
nbytes of PNG, or `ERROR <message>\\n`. Each frame shows the sphere at the
pose its source gives at that moment: the stage's true mechanical angles
read from the `stagesim` state socket (send `state\\n`, read one JSON line
with x, y, z in degrees), a fixed pose, or the poses of a file in turn.

One process, one thread, one Renderer: clients are served in turn from a
select loop (OpenGL contexts belong to the thread that made them).
SIGTERM and SIGINT stop the server; the socket file is removed.
"""
import json
import math
import os
import selectors
import signal
import socket
import stat
import sys

import numpy as np

from sim.frames import encode_png
from sim.randomize import Randomization, render_frame

STATE_TIMEOUT_S = 2.0   # longest wait for the stage's state reply
SEND_TIMEOUT_S = 10.0   # longest wait for a slow client to take a frame
MAX_LINE = 4096         # a request line longer than this is an error


class SourceError(RuntimeError):
    """The pose source failed; the message says which and why (sent to the client as ERROR)."""


class FixedPoseSource:
    """Always the same pose."""

    def __init__(self, pose):
        self._pose = tuple(float(a) for a in pose)

    def pose(self):
        return self._pose

    def describe(self):
        return f"fixed pose {self._pose}"


class PoseFileSource:
    """The poses of a text file, one `x y z` (degrees) per line, in turn, starting over at the end.

    Blank lines and lines starting with '#' are skipped; a bad line is an error naming file and line.
    """

    def __init__(self, path):
        self.path = path
        poses = []
        try:
            with open(path, encoding="utf-8") as f:
                lines = f.read().splitlines()
        except OSError as e:
            raise ValueError(f"{path}: cannot read pose file: {e.strerror}") from None
        for n, line in enumerate(lines, 1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            parts = text.replace(",", " ").split()
            try:
                pose = tuple(float(p) for p in parts)
            except ValueError:
                pose = ()
            if len(pose) != 3 or not all(math.isfinite(a) for a in pose):
                raise ValueError(f"{path}:{n}: expected 'x y z' in degrees, got {text!r}")
            poses.append(pose)
        if not poses:
            raise ValueError(f"{path}: no poses in the file")
        self._poses = poses
        self._next = 0

    def pose(self):
        p = self._poses[self._next]
        self._next = (self._next + 1) % len(self._poses)
        return p

    def describe(self):
        return f"{len(self._poses)} poses from {self.path}"


class StageStateSource:
    """The stage's true angles from the stagesim state socket; reconnects after a failure."""

    def __init__(self, path):
        self.path = path
        self._sock = None
        self._buf = b""

    def _connect(self):
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.settimeout(STATE_TIMEOUT_S)
        try:
            s.connect(self.path)
        except OSError:
            s.close()
            raise
        self._sock, self._buf = s, b""

    def close(self):
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def pose(self):
        try:
            if self._sock is None:
                self._connect()
            self._sock.sendall(b"state\n")
            while b"\n" not in self._buf:
                chunk = self._sock.recv(4096)
                if not chunk:
                    raise ConnectionError("connection closed by the stage")
                self._buf += chunk
                if len(self._buf) > 1 << 16:
                    raise ValueError("state reply too long")
            line, self._buf = self._buf.split(b"\n", 1)
        except (OSError, ValueError) as e:
            self.close()
            why = e.strerror if isinstance(e, OSError) and e.strerror else (str(e) or type(e).__name__)
            raise SourceError(f"stage state {self.path}: {why}") from None
        try:
            state = json.loads(line)
            pose = tuple(float(state[k]) for k in ("x", "y", "z"))
        except (ValueError, KeyError, TypeError):
            raise SourceError(f"stage state {self.path}: reply is not JSON with x, y, z: "
                              f"{line[:200].decode(errors='replace')!r}") from None
        if not all(math.isfinite(a) for a in pose):
            raise SourceError(f"stage state {self.path}: non-finite angle in {pose}")
        return pose

    def describe(self):
        return f"stage state socket {self.path}"


class _Stop(Exception):
    """Raised from the signal handler to leave the serve loop."""


def _raise_stop(signum, frame):
    raise _Stop()


class FrameServer:
    """Serves rendered frames of `source`'s poses on Unix socket `path`."""

    def __init__(self, path, *, texture, camera, lights, background, source,
                 randomization=Randomization(), seed=0, log=None, frame_log=None, scene=None):
        self.path = path
        self.texture = texture
        self.camera = camera
        self.lights = lights
        self.background = background
        self.source = source
        self.randomization = randomization
        self.seed = seed
        self.scene = scene  # a sim.scene.Scene: frames of that rig (replaces background, lights, randomisation)
        self.frames = 0
        self.log = log or (lambda msg: print(f"sim vcam: {msg}", file=sys.stderr, flush=True))
        self._renderer = None
        self._frame_log = open(frame_log, "a", buffering=1) if frame_log else None

    def frame(self):
        """PNG bytes of the next frame (SourceError if the pose source fails)."""
        pose = self.source.pose()
        rng = np.random.default_rng([self.seed, self.frames])
        if self.scene is not None:
            png = encode_png(self._renderer.frame(pose, rng)[0])
        else:
            png = encode_png(render_frame(self._renderer, pose, self.randomization, rng))
        if self._frame_log:
            x, y, z = pose
            self._frame_log.write(json.dumps({"frame": self.frames, "x": x, "y": y, "z": z}) + "\n")
        self.frames += 1
        return png

    def _bind(self):
        if os.path.exists(self.path):
            if not stat.S_ISSOCK(os.lstat(self.path).st_mode):
                raise ValueError(f"--socket {self.path}: exists and is not a socket; not replacing it")
            probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                probe.connect(self.path)
                raise ValueError(f"--socket {self.path}: another server is listening there")
            except (ConnectionRefusedError, FileNotFoundError):
                os.unlink(self.path)  # stale socket of a server that died
            finally:
                probe.close()
        srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            srv.bind(self.path)
        except OSError as e:
            srv.close()
            raise ValueError(f"--socket {self.path}: cannot bind: {e.strerror or e}") from None
        srv.listen(8)
        return srv

    def _handle_line(self, conn, line):
        cmd = line.strip()
        if not cmd:
            return
        if cmd == b"grab":
            try:
                png = self.frame()
                reply = b"FRAME %d\n" % len(png) + png
            except SourceError as e:
                reply = f"ERROR {e}\n".encode()
        else:
            shown = cmd[:80].decode(errors="replace")
            reply = f"ERROR unknown request {shown!r}; send 'grab'\n".encode()
        conn.settimeout(SEND_TIMEOUT_S)
        conn.sendall(reply)

    def serve_forever(self):
        """Serve until SIGTERM or SIGINT; returns 0 (the exit status)."""
        from sim.render import Renderer
        old = {s: signal.signal(s, _raise_stop) for s in (signal.SIGTERM, signal.SIGINT)}
        srv = None
        sel = selectors.DefaultSelector()
        clients = {}
        try:
            srv = self._bind()  # first: a bad --socket fails before the renderer's set-up
            if self.scene is not None:
                from sim.scene_render import SceneRenderer
                self._renderer = SceneRenderer(self.texture, self.scene)
            else:
                self._renderer = Renderer(self.texture, self.camera, lights=self.lights,
                                          background=self.background)
            sel.register(srv, selectors.EVENT_READ)
            print(f"VCAM {self.path}", flush=True)
            self.log(f"serving {self.camera.width}x{self.camera.height} frames of {self.source.describe()}")
            while True:
                for key, _ in sel.select():
                    if key.fileobj is srv:
                        conn, _ = srv.accept()
                        sel.register(conn, selectors.EVENT_READ)
                        clients[conn] = b""
                        continue
                    conn = key.fileobj
                    try:
                        conn.settimeout(SEND_TIMEOUT_S)
                        data = conn.recv(4096)
                        if not data:
                            raise ConnectionError("closed")
                        buf = clients[conn] + data
                        while b"\n" in buf:
                            line, buf = buf.split(b"\n", 1)
                            self._handle_line(conn, line)
                        if len(buf) > MAX_LINE:
                            conn.sendall(b"ERROR request line too long\n")
                            raise ConnectionError("line too long")
                        clients[conn] = buf
                    except OSError:
                        sel.unregister(conn)
                        clients.pop(conn, None)
                        conn.close()
        except _Stop:
            self.log(f"stopping after {self.frames} frames")
        finally:
            for conn in list(clients):
                conn.close()
            if srv is not None:
                srv.close()
                try:
                    os.unlink(self.path)
                except OSError:
                    pass
            sel.close()
            if hasattr(self.source, "close"):
                self.source.close()
            if self._frame_log:
                self._frame_log.close()
            for s, h in old.items():
                signal.signal(s, h)
        return 0
