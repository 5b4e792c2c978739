"""stagesim itself, driven with the small test program (sim/stage/testfw):
pty integrity, STEP/DIR integration, enable, limit switches, EEPROM file,
state socket, clean stop. Needs no stage firmware."""
import json
import os
import random
import socket
import time

import pytest

import stagelib
from stagelib import TESTFW

READY = "testfw ready\r\n"
COMMAND_BYTES = set(b"abcABCedlwrtpz")


@pytest.fixture
def tfw(make_stage):
    def start(args=(), **kw):
        st = make_stage(elf=TESTFW, args=args, **kw)
        st.expect_raw(READY.encode())
        return st
    return start


def test_stdout_lines_and_clean_stop(tfw, tmp_path):
    link = tmp_path / "ttyStage"
    st = tfw(args=["--link", str(link)])
    assert st.pty.startswith("/dev/pts/")
    assert os.path.realpath(link) == st.pty
    assert st.close() == 0
    assert not link.exists()
    assert (tmp_path / "stage0.eeprom").stat().st_size == 1024


def test_echo_is_lossless_while_streaming(tfw):
    """20,000 bytes through the firmware's 128-byte interrupt-driven ring and
    back: every byte, in order (the bridge never overruns the UART)."""
    st = tfw()
    rnd = random.Random(7)
    alphabet = bytes(c for c in range(32, 127) if c not in COMMAND_BYTES)
    data = bytes(rnd.choice(alphabet) for _ in range(20000))
    st.write(data)
    while len(st.rx) < len(data):
        before = len(st.rx)
        st.pump(5.0)
        assert len(st.rx) > before, f"echo stalled after {len(st.rx)} bytes"
    assert st.rx == data
    uart = st.query("uart")
    assert uart["tx_dropped"] == 0
    # 115200 baud, 8N1, U2X: 8 * (16 + 1) * 10 cycles a character
    assert uart["cycles_per_byte"] == 1360


def test_steps_dir_enable(tfw):
    st = tfw()
    assert st.state()["enabled"] is False
    st.write(b"aaa")                  # drivers disabled: no motion
    st.write(b"e")
    st.write(b"a" * 10 + b"B" * 7 + b"c" * 3 + b"C" * 5)
    st.write(b"?")
    st.expect_raw(rb"\?")
    s = st.state()
    assert s["enabled"] is True
    assert s["steps"] == [10, -7, -2]
    assert s["x"] == pytest.approx(10 / 800)
    assert s["z"] == pytest.approx(-2 / 800)
    stats = st.query("stats")
    assert stats["axes"][0]["ignored"] == 3
    assert stats["axes"][1]["min_high"] >= 40          # 2.5 us pulses
    assert stats["axes"][1]["min_dir_setup"] >= 16


def test_timer_burst_and_isr_timing(tfw):
    """5,000 steps from Timer1 at 20 kHz: counted exactly, period 800 cycles,
    the step ISR's duration measured."""
    st = tfw()
    st.write(b"e")
    st.query("clear-stats")
    st.write(b"t5")
    st.run_cycles(5000 * 800 + 100_000)
    stats = st.query("stats")
    ax = stats["axes"][0]
    assert ax["steps"] == 5000 and ax["pulses"] == 5000
    assert 790 <= ax["min_period"] <= 800
    vec = stats["vectors"]["11"]                        # TIMER1_COMPA
    assert 40 < vec["max_cycles"] < 200
    # the ISR runs with interrupts off (no sei): that is the longest stretch
    assert vec["max_cycles"] <= stats["max_irq_off_cycles"] < 400


def test_warns_about_the_ctc_zero_trap(tfw):
    st = tfw()
    st.write(b"z")
    st.expect_raw(rb"Z")
    st.close()
    assert "timer1 in CTC mode with OCR1A = 0" in (st.tmp / "stage0.stderr").read_text()


def test_limit_switches(tfw):
    st = tfw(args=["--limits", "0.01,none,-0.005", "--limit-dir", "+,+,-"])
    st.write(b"el")
    st.expect_raw(rb"L111")
    st.write(b"a" * 8 + b"l")          # 8 steps = 0.01 deg: X switch closes
    st.expect_raw(rb"L011")
    st.write(b"C" * 4 + b"l")          # Z at -0.005: closes
    st.expect_raw(rb"L010")
    assert st.state()["limits"] == [1, 0, 1]
    st.write(b"A" + b"l")              # back 0.00125 deg, within the hysteresis
    st.expect_raw(rb"L010")
    st.write(b"A" * 40 + b"l")         # back 0.05 deg past it: released
    st.expect_raw(rb"L110")
    assert st.state()["limits"] == [0, 0, 1]


def test_limit_switch_bounce(tfw):
    """--limit-bounce N: each transition chatters N times before it settles,
    as a real contact does (pin-change interrupts counted by the program)."""
    st = tfw(args=["--limits", "0.01,none,none", "--limit-bounce", "3", "--limit-bounce-us", "100"])
    st.write(b"e" + b"a" * 8)
    st.run_cycles(16_000_000 // 100)
    st.write(b"lp")
    st.expect_raw(rb"L011P007")          # closed, after 1 + 2 * 3 edges
    st.write(b"A" * 50)
    st.run_cycles(16_000_000 // 100)
    st.write(b"lp")
    st.expect_raw(rb"L111P014")          # open again, 7 more edges


def test_realtime_pacing_never_runs_ahead(tfw):
    st = tfw()
    c0, t0 = st.cycle(), time.monotonic()
    time.sleep(1.0)
    c1, t1 = st.cycle(), time.monotonic()
    assert c1 - c0 <= 16_000_000 * (t1 - t0) * 1.02 + 16_000_000 * 0.05


def test_eeprom_saved_while_running(tfw, tmp_path):
    """The EEPROM file follows the chip while running (atomic rename), so
    even a killed simulator keeps the settings."""
    ee = tmp_path / "live.eeprom"
    st = tfw(eeprom=ee, name="live")
    st.write(b"wZr")
    st.expect_raw(rb"RZ")
    t_end = time.monotonic() + 10
    while not (ee.exists() and ee.read_bytes()[:1] == b"Z"):
        assert time.monotonic() < t_end, "EEPROM file not updated while running"
        time.sleep(0.1)
    st.proc.kill()
    st.proc.wait()
    assert not (tmp_path / "live.eeprom.tmp").exists()
    st.close(check=False)
    st = tfw(eeprom=ee, name="again")
    st.write(b"r")
    st.expect_raw(rb"RZ")


def test_eeprom_survives_restart(tfw, tmp_path):
    ee = tmp_path / "kept.eeprom"
    st = tfw(eeprom=ee, name="first")
    st.write(b"wQr")
    st.expect_raw(rb"RQ")
    assert st.close() == 0
    data = ee.read_bytes()
    assert len(data) == 1024 and data[0:1] == b"Q" and data[1:] == b"\xff" * 1023
    st = tfw(eeprom=ee, name="second")
    st.write(b"r")
    st.expect_raw(rb"RQ")


def test_state_socket_protocol(tfw):
    st = tfw(args=["--steps-per-deg", "400,800,1600", "--start", "1,2,-3"])
    s = st.state()
    assert set(s) == {"x", "y", "z", "steps", "enabled", "cycle", "limits"}
    assert s["steps"] == [400, 1600, -4800]
    assert (s["x"], s["y"], s["z"]) == (1.0, 2.0, -3.0)
    # several requests on one connection, and a second client at once
    c2 = socket.socket(socket.AF_UNIX)
    c2.connect(st.sock_path)
    c2.sendall(b"state\nstate\nbogus\n")
    f = c2.makefile("r")
    a, b, err = (json.loads(f.readline()) for _ in range(3))
    assert b["cycle"] >= a["cycle"]
    assert "error" in err
    c2.close()
    st.write(b"e")
    st.write(b"aa")
    st.write(b"?")
    st.expect_raw(rb"\?")
    assert st.state()["x"] == pytest.approx(1.0 + 2 / 400)


def test_bad_arguments(stagesim_built, tmp_path):
    import subprocess
    for args in (["--steps-per-deg", "0"], ["--limits", "1,2"], ["--nope"], []):
        r = subprocess.run([str(stagesim_built), *args] + ([str(TESTFW)] if args else []),
                           capture_output=True, text=True, timeout=10)
        assert r.returncode != 0 and r.stdout == "" and "stagesim:" in r.stderr
    r = subprocess.run([str(stagesim_built), str(tmp_path / "missing.elf")],
                       capture_output=True, text=True, timeout=10)
    assert r.returncode != 0 and "missing.elf" in r.stderr
