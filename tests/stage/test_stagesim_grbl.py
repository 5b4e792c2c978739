"""The stage firmware ELF running in stagesim, driven over its pty as a GRBL
sender drives it. Positions are checked against the step counts integrated
from the STEP/DIR pins (state socket), never against wall time."""
import random
import re
import time

import pytest

from stagelib import BANNER_RE, F_CPU, RX_BUFFER_SIZE, deg_steps, parse_status

SETTING_RE = re.compile(r"^\$(\d+)=(-?\d+(?:\.\d+)?)$")
SECOND = F_CPU          # simulated cycles


def settings(st):
    out = {}
    for line in st.ok("$$"):
        m = SETTING_RE.match(line)
        assert m, f"not a setting line: {line!r}"
        out[int(m.group(1))] = float(m.group(2))
    return out


def test_banner_and_idle(grbl):
    assert any(BANNER_RE.match(line) for line in grbl.log)
    st = grbl.status()
    assert st["state"] == "Idle" and st["mpos"] == [0.0, 0.0, 0.0]
    assert grbl.state()["steps"] == [0, 0, 0]


def test_settings_dump_and_info(grbl):
    s = settings(grbl)
    for n in (0, 1, 2, 3, 4, 5, 10, 11, 13, 20, 21, 22, 23, 24, 25, 26, 27,
              100, 101, 102, 110, 111, 112, 120, 121, 122, 130, 131, 132):
        assert n in s, f"${n} missing from $$"
    assert s[100] == s[101] == s[102] == 800.0
    assert any(line.startswith("[VER:") for line in grbl.ok("$I"))
    gc = grbl.ok("$G")
    assert len(gc) == 1 and gc[0].startswith("[GC:") and "G90" in gc[0] and "G21" in gc[0]
    coords = grbl.ok("$#")
    assert any(line.startswith("[G54:") for line in coords)
    assert any(line.startswith("[G92:") for line in coords)
    assert grbl.command("$999=1")[1].startswith("error:")
    assert grbl.command("G5 X1")[1].startswith("error:")


def test_absolute_and_relative_moves_exact_steps(grbl):
    grbl.ok("G90 G0 X1.5 Y-0.75 Z0.25")
    st = grbl.wait_idle()
    assert grbl.steps() == [1200, -600, 200]
    assert st["mpos"] == [1.5, -0.75, 0.25]

    grbl.ok("G91 G1 X0.5 Y0.125 Z-1 F1200")
    grbl.wait_idle()
    assert grbl.steps() == [1600, -500, -600]

    grbl.ok("G1 X-0.0025")                        # two steps
    grbl.wait_idle()
    assert grbl.steps() == [1598, -500, -600]

    grbl.ok("G90 G0 X0 Y0 Z0")
    st = grbl.wait_idle()
    assert grbl.steps() == [0, 0, 0]
    assert st["mpos"] == [0.0, 0.0, 0.0]
    stats = grbl.query("stats")
    for ax in stats["axes"]:
        assert ax["ignored"] == 0 and ax["dir_violations"] == 0


def test_single_step_moves(grbl):
    """The smallest move, one step (1/800 deg), must move the motor."""
    grbl.ok("G91 G1 X0.5 F1200")
    grbl.wait_idle()
    for line, delta in (("G1 X-0.00125", [-1, 0, 0]), ("G1 X0.00125 Y0.00125", [1, 1, 0]),
                        ("G0 Z-0.00125", [0, 0, -1])):
        before = grbl.steps()
        grbl.ok(line)
        grbl.wait_idle()
        got = [a - b for a, b in zip(grbl.steps(), before)]
        assert got == delta, f"{line!r} moved {got} steps, not {delta}"


def test_work_offsets(grbl):
    grbl.ok("G10 L2 P1 X10")                      # G54 X origin at machine 10
    grbl.ok("G90 G54 G0 X-9")
    grbl.wait_idle()
    assert grbl.steps()[0] == deg_steps(1.0)
    grbl.ok("G92 X0")
    grbl.ok("G0 X0.5")
    grbl.wait_idle()
    assert grbl.steps()[0] == deg_steps(1.5)
    grbl.ok("G53 G0 X0")
    grbl.wait_idle()
    assert grbl.steps()[0] == 0


def test_status_report_while_running(grbl):
    # a 2 s move: a test stalled on a busy machine (stagesim keeps to the wall
    # clock) must still find it running
    grbl.ok("G1 X10 F300")
    t_end = time.monotonic() + 20
    while True:
        st = grbl.status()
        if st["state"] == "Run" and st["mpos"][0] > 0:
            break
        assert time.monotonic() < t_end, st
        grbl.run_cycles(SECOND // 100)
    assert re.match(r"^<Run\|MPos:-?\d+\.\d{3},-?\d+\.\d{3},-?\d+\.\d{3}\|", st["text"])
    feed = float(st["fields"]["FS"].split(",")[0])
    assert 0 < feed <= 300
    assert 0 < st["mpos"][0] < 10
    # the reported position follows the real one (within what moved in between)
    true_deg = grbl.state()["x"]
    assert true_deg >= st["mpos"][0] - 0.01
    grbl.wait_idle()
    assert grbl.steps()[0] == deg_steps(10)


def test_step_pulses_are_legal(grbl):
    """A4988/DRV8825 need >= 1.9 us high and low and DIR set >= 650 ns before
    the edge; the firmware promises pulses of at least $0 us."""
    pulse_us = settings(grbl)[0]
    grbl.query("clear-stats")
    grbl.ok("G90 G0 X3 Y-2 Z1")
    grbl.wait_idle()
    grbl.ok("G0 X0 Y0 Z0")
    grbl.wait_idle()
    stats = grbl.query("stats")
    for i, ax in enumerate(stats["axes"]):
        assert ax["dir_violations"] == 0, f"axis {i}: {ax}"
        assert ax["min_low"] >= 1.9e-6 * F_CPU, f"axis {i}: {ax}"
        assert ax["min_dir_setup"] == 0 or ax["min_dir_setup"] >= 0.65e-6 * F_CPU, f"axis {i}: {ax}"
        assert ax["min_high"] >= pulse_us * 1e-6 * F_CPU, \
            f"axis {i}: pulse {ax['min_high']} cycles < $0={pulse_us} us; {ax}"


def test_homing(make_stage, firmware_elf):
    switches = [1.5, 2.0, 2.5]
    st = make_stage(elf=firmware_elf, args=["--limits", ",".join(map(str, switches))])
    st.start()
    st.ok("$22=1")
    s = settings(st)
    pulloff = s[27]
    assert s[23] == 0                                 # homes towards +
    st.write("$H\n")
    # a '?' during the cycle is answered and the cycle goes on (a status report alone: no alarm)
    assert st.wait_state("Home", timeout=30)["state"] == "Home"
    assert st.expect(r"^(ok|error:\d+|ALARM:\d+)$", timeout=60).group(0) == "ok"
    status = st.wait_idle()
    state = st.state()
    for i, sw in enumerate(switches):
        true = state[("x", "y", "z")[i]]
        # parked one pull-off back from the switch, to a few steps
        assert abs(true - (sw - pulloff)) <= 3 / 800, state
        # machine zero sits on the switch: MPos = true angle - switch position
        assert abs(status["mpos"][i] - (true - sw)) <= 3 / 800, (status, state)
    assert state["limits"] == [0, 0, 0]
    # after homing, moves are exact relative to the switch
    st.ok("G90 G0 X-0.5 Y-0.5 Z-0.5")
    st.wait_idle()
    for i, sw in enumerate(switches):
        assert abs(st.state()[("x", "y", "z")[i]] - (sw - 0.5)) <= 3 / 800


def test_homing_with_bouncing_switches(make_stage, firmware_elf):
    """Each switch transition chatters 4 times, 0.5 ms apart: the firmware's
    debounce must still home to the same place."""
    switches = [1.0, 1.25, 1.5]
    st = make_stage(elf=firmware_elf, args=["--limits", ",".join(map(str, switches)),
                                            "--limit-bounce", "4", "--limit-bounce-us", "500"])
    st.start()
    st.ok("$22=1")
    pulloff = settings(st)[27]
    st.ok("$H", timeout=60)
    st.wait_idle()
    state = st.state()
    for i, sw in enumerate(switches):
        assert abs(state[("x", "y", "z")[i]] - (sw - pulloff)) <= 3 / 800, state


def test_jog_and_jog_cancel(grbl):
    grbl.ok("$J=G91 X1 Y-0.5 F1200")
    grbl.wait_idle()
    assert grbl.steps() == [800, -400, 0]
    grbl.ok("$J=G91 X20 F300")                       # 4 s: still jogging after a stall
    grbl.run_cycles(SECOND // 4)
    assert grbl.status()["state"] == "Jog"
    grbl.write(b"\x85")                               # jog cancel
    st = grbl.wait_idle(timeout=20)
    stopped = grbl.steps()[0]
    assert deg_steps(1) < stopped < deg_steps(21)
    grbl.run_cycles(SECOND // 10)
    assert grbl.steps()[0] == stopped
    # the firmware knows where it stopped: its position is the pulses'
    assert round(st["mpos"][0] * 800) == stopped
    grbl.ok("G90 G0 X0 Y0")
    grbl.wait_idle()
    assert grbl.steps() == [0, 0, 0]
    assert grbl.command("$J=G0 X1")[1].startswith("error:")   # G0 is not a jog


def test_hard_limit_alarm_reset_and_unlock(make_stage, firmware_elf):
    st = make_stage(elf=firmware_elf, args=["--limits", "1,none,none"])
    st.start()
    st.ok("$21=1")
    st.ok("G0 X3")
    st.expect(r"^ALARM:1$", timeout=30)
    steps = st.steps()[0]
    # stopped once the switch still reads closed after the 10 ms debounce:
    # at most 10 ms of travel past it (13.4 deg/s here: 0.134 deg)
    assert deg_steps(1) <= steps <= deg_steps(1) + deg_steps(0.15)
    st.run_cycles(SECOND // 10)
    assert st.steps()[0] == steps
    assert st.status()["state"] == "Alarm"
    st.write(b"\x18")
    st.banner()
    st.drain()
    assert st.status()["state"] == "Alarm"
    assert st.command("G0 X0")[1] == "error:9"           # locked
    body = st.ok("$X")
    assert any("Unlocked" in line for line in body)
    assert st.status()["state"] == "Idle"


def test_position_exact_after_hard_limit(make_stage, firmware_elf):
    """GRBL may count a step it computed but never put out when a hard limit
    stops it; this firmware keeps its position exact after an abort."""
    st = make_stage(elf=firmware_elf, args=["--limits", "1,none,none"])
    st.start()
    st.ok("$21=1")
    st.ok("G0 X3")
    st.expect(r"^ALARM:1$", timeout=30)
    steps = st.steps()[0]
    status = st.status()
    assert round(status["mpos"][0] * 800) == steps, (status["text"], steps)


def test_settings_survive_restart_and_power_up_alarm(make_stage, firmware_elf, tmp_path):
    ee = tmp_path / "settings.eeprom"
    st = make_stage(elf=firmware_elf, eeprom=ee, name="first")
    st.start()
    st.ok("$110=1234.5")
    st.ok("$120=321")
    st.ok("G10 L2 P2 X1.25 Y-2 Z3")
    st.ok("$22=1")                                    # homing on: power-up alarm
    st.close()

    st = make_stage(elf=firmware_elf, eeprom=ee, name="second")
    st.banner()
    st.expect(r"\$X.*unlock", timeout=5)
    st.drain()
    assert st.status()["state"] == "Alarm"
    assert st.command("G0 X1")[1] == "error:9"
    st.ok("$X")
    s = settings(st)
    assert (s[110], s[120], s[22]) == (1234.5, 321.0, 1.0)
    assert "[G55:1.250,-2.000,3.000]" in st.ok("$#")
    st.ok("G0 X0.25")
    st.wait_idle()
    assert st.steps()[0] == 200


def test_feed_hold_and_resume(grbl):
    grbl.ok("G1 X20 F100")                            # 12 s: see test_reset_mid_move
    grbl.run_cycles(SECOND // 3)
    grbl.write(b"!")
    held = grbl.wait_state("Hold", timeout=10, poll=0.02)
    assert held["sub"] in ("0", "1")
    # decelerates to a stop and stays there, Hold:0, until '~'
    t_end = time.monotonic() + 20
    while True:
        st = grbl.status()
        assert st["state"] == "Hold", f"hold left without '~': {st['text']}"
        if st["sub"] == "0":
            break
        assert time.monotonic() < t_end, "hold never completes"
        grbl.run_cycles(SECOND // 50)
    stopped = grbl.steps()[0]
    assert 0 < stopped < deg_steps(20)
    grbl.run_cycles(SECOND // 2)
    assert grbl.steps()[0] == stopped
    st = grbl.status()
    assert (st["state"], st["sub"]) == ("Hold", "0")
    grbl.write(b"~")
    grbl.wait_idle()
    assert grbl.steps()[0] == deg_steps(20)


def test_reset_mid_move(grbl):
    # a 12 s move (the reset ends it, so the test does not wait for it):
    # stagesim paces simulated time to the wall clock, so a test process
    # stalled on a busy machine must not see the move end before its reset
    # arrives (a 3 s move did, once, under a load of about 5 on 2 CPUs)
    grbl.ok("G1 X20 F100")
    grbl.run_cycles(SECOND // 3)
    assert grbl.status()["state"] == "Run"
    grbl.write(b"\x18")
    grbl.expect(r"^ALARM:3$")                         # abort during a cycle
    grbl.banner()
    grbl.drain()
    stopped = grbl.steps()[0]
    assert 0 < stopped < deg_steps(20)
    grbl.run_cycles(SECOND // 5)
    assert grbl.steps()[0] == stopped                 # stopped at once, stays stopped
    st = grbl.status()
    assert st["state"] == "Alarm"
    # the firmware kept its position through the reset and it is the pulses'
    # (GRBL may count a step it computed but never put out; this firmware
    # must not)
    assert round(st["mpos"][0] * 800) == stopped
    grbl.ok("$X")
    grbl.ok("G90 G0 X0")
    grbl.wait_idle()
    assert grbl.steps()[0] == 0


def stream_lines(st, lines, poll_period=0.1, timeout=300):
    """GRBL's character-counting streaming (stream.py): keep the firmware's
    128-byte receive buffer full, never overfull, while a '?' status query
    goes out every poll_period seconds, one at a time: the next only after
    the report (two queries the firmware has not yet answered merge into one
    report, as in GRBL). It returns after the last query's report too, so that
    the next reader of the line neither takes nor drops it. Returns (oks,
    errors, reports, polls)."""
    pending = []            # lengths of lines sent and not yet acknowledged
    sent = oks = polls = 0
    errors, reports = [], []
    poll_outstanding = False
    next_poll = time.monotonic() + poll_period
    t_end = time.monotonic() + timeout
    while oks + len(errors) < len(lines) or poll_outstanding:
        assert time.monotonic() < t_end, f"streaming stalled at {oks} ok of {len(lines)}"
        while sent < len(lines) and sum(pending) + len(lines[sent]) + 1 <= RX_BUFFER_SIZE - 1:
            data = lines[sent] + "\n"
            st.write(data)
            pending.append(len(data))
            sent += 1
        if not poll_outstanding and time.monotonic() >= next_poll:
            st.write(b"?")
            polls += 1
            poll_outstanding = True
            next_poll = time.monotonic() + poll_period
        st.pump(0.005)
        while b"\n" in st.rx:
            line = st.readline(1)
            if line == "ok":
                pending.pop(0)
                oks += 1
            elif line.startswith("error:"):
                pending.pop(0)
                errors.append((oks + len(errors), line))
            elif line.startswith("<"):
                reports.append(parse_status(line))
                poll_outstanding = False
            elif line.strip():
                errors.append((oks + len(errors), line))   # ALARM, unexpected text
    return oks, errors, reports, polls


def test_stream_1000_lines_while_polling(grbl):
    grbl.ok("$120=5000")                  # short moves: let them reach speed
    grbl.ok("$121=5000")
    grbl.ok("G90")
    lines = []
    for i in range(1, 1001):
        x = i * 0.0125                    # 10 steps a line
        y = 0.0125 * (i // 100)           # and now and then one Y step
        word = "G1" if i % 7 else "G01"
        lines.append(f"N{i} {word} X{x:.4f} Y{y:.4f} F1500")
    # a query storm right before streaming must not confuse the line reader; its reports
    # (they may merge: '?' sets a flag, as in GRBL) are all in before streaming, so that
    # none comes late and lets the first periodic query be followed by another before its
    # own report
    grbl.write(b"?" * 20)
    storm = [line for line in grbl.drain(quiet=0.5) if line.startswith("<")]
    assert 1 <= len(storm) <= 20
    oks, errors, reports, polls = stream_lines(grbl, lines)
    assert errors == [] and oks == 1000
    grbl.wait_idle()
    assert grbl.steps() == [10000, deg_steps(0.0125 * 10), 0]
    # every periodic query answered by a report of its own
    t_end = time.monotonic() + 5
    while len(reports) < polls and time.monotonic() < t_end:
        grbl.pump(0.1)
        while b"\n" in grbl.rx:
            line = grbl.readline(1)
            if line.startswith("<"):
                reports.append(parse_status(line))
    assert len(reports) == polls
    assert any(r["state"] == "Run" for r in reports)
    uart = grbl.query("uart")
    assert uart["rx_queued"] == 0 and uart["tx_dropped"] == 0


def test_garbage_bytes_no_crash_no_hang(grbl):
    rnd = random.Random(20261122)
    garbage = bytes(rnd.randrange(256) for _ in range(20000))
    # no newline-terminated "$H", "$RST" or motion can be formed by chance
    # here that would take long; the seed is fixed, so this is reproducible
    for chunk in range(0, len(garbage), 1000):
        grbl.write(garbage[chunk:chunk + 1000])
        grbl.pump(0.01)
        grbl.rx = b""
    # wait until the firmware has taken every byte
    t_end = time.monotonic() + 60
    while grbl.query("uart")["rx_queued"]:
        assert time.monotonic() < t_end, "firmware stopped reading"
        grbl.pump(0.05)
        grbl.rx = b""
    assert grbl.alive()
    grbl.write(b"\x18")
    grbl.banner()
    grbl.drain()
    if grbl.status()["state"] == "Alarm":
        grbl.ok("$X")
    assert grbl.status()["state"] == "Idle"
    before = grbl.steps()
    grbl.ok("G91 G0 X0.5 Y-0.25 Z0.125")
    grbl.wait_idle()
    after = grbl.steps()
    assert [a - b for a, b in zip(after, before)] == [400, -200, 100]
