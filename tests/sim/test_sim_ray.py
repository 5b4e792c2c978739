"""`sim dataset --engine ray`: a real Ray cluster on this machine (a head with 2 CPUs, started with
`ray start --head` as docs/cluster.md says) renders the same bytes as the local engine, and a
task whose worker is killed is run again."""
import importlib.util
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid

import pytest

from test_sim_dataset import tree_digest

pytest.importorskip("ray")

BIN = os.path.dirname(sys.executable)
SMALL = ["--train", "4", "--val", "2", "--test", "0", "--offgrid-test", "0", "--seed", "3", "--randomize"]


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def cluster():
    """A Ray head with 2 CPUs and its own token; yields (address, env for a driver, temp dir).

    Started with --block and stopped by signalling that process, which stops the processes it
    started (`ray stop` would stop every Ray instance on the machine)."""
    temp = tempfile.mkdtemp(prefix="ray", dir="/tmp")      # short: Ray's socket paths live under it
    env = dict(os.environ, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=uuid.uuid4().hex, RAY_ADDRESS="")
    port = free_port()
    # with ray[client] (grpc) installed the head also serves Ray clients, by
    # default on 10001, which another head on the machine may hold; without
    # it there is no such server and ray start refuses the option
    client_port = ["--ray-client-server-port", str(free_port())] if importlib.util.find_spec("grpc") else []
    log = open(os.path.join(temp, "head.log"), "w")
    head = subprocess.Popen(
        [os.path.join(BIN, "ray"), "start", "--head", "--block", "--port", str(port), "--num-cpus", "2",
         "--include-dashboard", "false", "--disable-usage-stats", "--temp-dir", temp,
         "--dashboard-agent-listen-port", str(free_port()), *client_port],
        env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    address = f"127.0.0.1:{port}"
    try:
        deadline = time.time() + 90
        while "This command will now block" not in open(log.name).read():
            assert head.poll() is None, open(log.name).read()[-3000:]
            assert time.time() < deadline, "ray head did not start in 90 s"
            time.sleep(0.5)
        yield address, env, temp
    finally:
        head.send_signal(signal.SIGTERM)
        try:
            head.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(head.pid, signal.SIGKILL)
        log.close()
        shutil.rmtree(temp, ignore_errors=True)


@pytest.fixture(scope="module")
def local_set(tmp_path_factory, texture_png, small_camera_json):
    out = str(tmp_path_factory.mktemp("local") / "set")
    r = subprocess.run([sys.executable, "-m", "sim.cli", "dataset", "--texture", texture_png, "--camera",
                        small_camera_json, "--out", out, "--workers", "2", "--quiet", *SMALL],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return out


def sim_ray(out, texture_png, camera, address, env):
    return [sys.executable, "-m", "sim.cli", "dataset", "--texture", texture_png, "--camera", camera,
            "--out", out, "--engine", "ray", "--ray-address", address, *SMALL]


def split_files(folder):
    return {s: sorted(os.listdir(os.path.join(folder, s))) for s in ("train", "val")}


@pytest.mark.slow
def test_ray_engine_renders_the_local_engines_bytes(cluster, local_set, texture_png, small_camera_json, tmp_path):
    address, env, _ = cluster
    out = str(tmp_path / "ray")
    r = subprocess.run(sim_ray(out, texture_png, small_camera_json, address, env), env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "on 2 CPUs" in r.stderr
    digest = tree_digest(out)
    assert len([k for k in digest if k.endswith(".png")]) == 6
    assert digest == tree_digest(local_set)             # the same names and bytes, truth.jsonl too
    assert split_files(out) == split_files(local_set)   # and nothing else (no temporaries)
    # A rerun finds every frame whole and renders nothing.
    r = subprocess.run(sim_ray(out, texture_png, small_camera_json, address, env), env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and "nothing left to render" in r.stderr, r.stderr


def _our_render_tasks(temp):
    """PIDs of Ray workers running render_shard whose raylet belongs to the test's cluster."""
    pids = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                cmd = f.read()
            with open(f"/proc/{pid}/stat") as f:
                ppid = f.read().rsplit(")", 1)[1].split()[1]
            with open(f"/proc/{ppid}/cmdline", "rb") as f:
                parent = f.read()
        except OSError:
            continue
        if cmd.startswith(b"ray::render_shard") and temp.encode() in parent:
            pids.append(int(pid))
    return pids


@pytest.mark.slow
def test_a_killed_task_is_run_again(cluster, local_set, texture_png, small_camera_json, tmp_path):
    address, env, temp = cluster
    out = str(tmp_path / "ray_killed")
    driver = subprocess.Popen(sim_ray(out, texture_png, small_camera_json, address, env), env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    killed = None
    deadline = time.time() + 120
    while killed is None and driver.poll() is None and time.time() < deadline:
        pids = _our_render_tasks(temp)
        if pids:
            os.kill(pids[0], signal.SIGKILL)     # a worker dies in the middle of its task
            killed = pids[0]
        time.sleep(0.01)
    _, err = driver.communicate(timeout=300)
    assert killed is not None, "no render task was seen running: " + err[-2000:]
    assert driver.returncode == 0, err
    assert tree_digest(out) == tree_digest(local_set)
    assert split_files(out) == split_files(local_set)


def test_bad_or_unreachable_address_is_a_clear_error(texture_png, small_camera_json, tmp_path):
    env = dict(os.environ, RAY_ADDRESS="")
    base = [sys.executable, "-m", "sim.cli", "dataset", "--texture", texture_png, "--camera", small_camera_json,
            "--engine", "ray", *SMALL]
    r = subprocess.run(base + ["--out", str(tmp_path / "a"), "--ray-address", "headnode"], env=env,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--ray-address headnode: expected HOST:PORT" in r.stderr, r.stderr
    assert not (tmp_path / "a").exists()
    with socket.socket() as s:      # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.time()
    r = subprocess.run(base + ["--out", str(tmp_path / "b"), "--ray-address", f"127.0.0.1:{port}"], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1 and f"no Ray cluster at 127.0.0.1:{port}" in r.stderr, r.stderr
    assert time.time() - t0 < 60
