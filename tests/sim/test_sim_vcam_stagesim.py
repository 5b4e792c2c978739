"""`sim vcam` on the real simulated stage: frames show the stage's true mechanical angles.

Needs the built stagesim (sim/stage/build/stagesim, or $STAGESIM) and the firmware ELF
(firmware/build/spherepose-stage.elf, or $STAGE_ELF); skipped when they are not built.
"""
import os
import signal
import socket
import subprocess
import sys
import tempfile
import termios
import time

import cv2
import numpy as np
import pytest

from sim.camera import load_camera
from sim.render import Renderer

ROOT = os.path.join(os.path.dirname(__file__), "..", "..")
STAGESIM = os.environ.get("STAGESIM", os.path.join(ROOT, "sim", "stage", "build", "stagesim"))
STAGE_ELF = os.environ.get("STAGE_ELF", os.path.join(ROOT, "firmware", "build", "spherepose-stage.elf"))

pytestmark = pytest.mark.skipif(not (os.access(STAGESIM, os.X_OK) and os.path.isfile(STAGE_ELF)),
                                reason="stagesim or the firmware ELF is not built")


def read_header(proc, prefix):
    line = proc.stdout.readline()
    assert line.startswith(prefix + " "), f"expected '{prefix} <path>', got {line!r}"
    return line.split(" ", 1)[1].strip()


def state(sock):
    import json
    sock.sendall(b"state\n")
    buf = b""
    while not buf.endswith(b"\n"):
        buf += sock.recv(4096)
    return json.loads(buf)


def grab(sock):
    sock.sendall(b"grab\n")
    f = sock.makefile("rb")
    kind, _, rest = f.readline().decode().rstrip("\n").partition(" ")
    assert kind == "FRAME", rest
    data = f.read(int(rest))
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]


def test_vcam_follows_the_simulated_stage(texture_png, small_camera_json):
    d = tempfile.mkdtemp(prefix="vs", dir="/tmp")
    state_path, cam_path = os.path.join(d, "state"), os.path.join(d, "cam")
    stage = subprocess.Popen([STAGESIM, "--state-socket", state_path, "--start", "7.5,-3.25,12", STAGE_ELF],
                             stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    vcam = None
    try:
        pty = read_header(stage, "PTY")
        assert read_header(stage, "STATE") == state_path
        vcam = subprocess.Popen([sys.executable, "-m", "sim.cli", "vcam", "--texture", texture_png,
                                 "--camera", small_camera_json, "--stage-state", state_path, "--socket", cam_path],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        assert read_header(vcam, "VCAM") == cam_path
        direct = Renderer(texture_png, load_camera(small_camera_json))
        with socket.socket(socket.AF_UNIX) as st, socket.socket(socket.AF_UNIX) as cam:
            st.settimeout(10)
            cam.settimeout(30)
            st.connect(state_path)
            cam.connect(cam_path)
            # Power-up: the mechanical angles given to the simulator.
            assert np.array_equal(grab(cam), direct.render((7.5, -3.25, 12.0)))

            # Move the stage through the firmware: G0 X10 Y-5 from where it thinks zero is.
            fd = os.open(pty, os.O_RDWR | os.O_NOCTTY)
            try:
                attrs = termios.tcgetattr(fd)
                attrs[3] &= ~(termios.ECHO | termios.ICANON)
                attrs[1] &= ~termios.OPOST
                termios.tcsetattr(fd, termios.TCSANOW, attrs)
                os.write(fd, b"\n$X\nG90 G0 X10 Y-5\n")
                deadline = time.time() + 60
                while True:
                    s = state(st)
                    if abs(s["x"] - 17.5) < 1e-6 and abs(s["y"] + 8.25) < 1e-6:
                        break
                    assert time.time() < deadline, f"stage did not arrive: {s}"
                    time.sleep(0.1)
            finally:
                os.close(fd)
            # The frame shows the true mechanical angles (start + move), not the commanded ones.
            assert np.array_equal(grab(cam), direct.render((17.5, -8.25, 12.0)))
    finally:
        for p in (vcam, stage):
            if p is not None and p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in (vcam, stage):
            if p is not None:
                try:
                    p.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    p.kill()
        for name in os.listdir(d):
            os.unlink(os.path.join(d, name))
        os.rmdir(d)
    assert vcam.returncode == 0
