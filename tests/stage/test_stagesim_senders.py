"""The stage among GRBL senders written by others: their habits, in stagesim
with the firmware ELF. A sender that overfills the advertised 128-byte
buffer or polls '$G'/'$#'/'$$' mid-stream, real-time bytes sent UTF-8
encoded, a client that closes and reopens the port (the Uno's DTR
auto-reset), the flashing path through Optiboot, and the documented way out
of a soft-limit alarm."""
import os
import subprocess
import termios
import time
import tty

import pytest

import stagelib
from stagelib import RX_BUFFER_SIZE, StageError, deg_steps, parse_status

ROOT = stagelib.ROOT


def sloppy_stream(st, lines, room=RX_BUFFER_SIZE, extra_every=5, extras=("$G",),
                  overfill_by_a_line=False, poll_period=0.1, timeout=600):
    """Stream as the sloppy senders do: count `room` bytes (GRBL's ring holds
    only 127), send an uncounted query after every `extra_every` lines, and
    poll '?' at 10 Hz. With overfill_by_a_line the room is checked before the
    line is added, so the count overshoots by up to one line. Every reply is
    matched to what was sent, in order. Returns (oks, errors, replies): the
    bracketed lines each query got."""
    queue = []              # (kind, counted bytes) in the order sent
    pending = 0             # counted bytes not yet acknowledged
    sent = oks = n_extra = 0
    errors, replies, body = [], [], []
    next_poll = time.monotonic()
    t_end = time.monotonic() + timeout
    total = len(lines) + (len(lines) // extra_every if extra_every else 0)
    while oks + len(errors) < total:
        assert time.monotonic() < t_end, f"streaming stalled at {oks} ok of {total}"
        while sent < len(lines):
            data = lines[sent] + "\n"
            if overfill_by_a_line:
                if pending >= room:
                    break
            elif pending + len(data) > room:
                break
            st.write(data)
            queue.append(("line", len(data)))
            pending += len(data)
            sent += 1
            if extra_every and sent % extra_every == 0:
                q = extras[n_extra % len(extras)]
                n_extra += 1
                st.write(q + "\n")          # outside the count
                queue.append((q, 0))
        if time.monotonic() >= next_poll:
            st.write(b"?")
            next_poll += poll_period
        st.pump(0.005)
        while b"\n" in st.rx:
            line = st.readline(1)
            if line.startswith("<"):
                parse_status(line)
                continue
            if line.startswith("[") or line.startswith("$"):
                body.append(line)
                continue
            if not line.strip():
                continue
            kind, n = queue.pop(0)
            pending -= n
            if line == "ok":
                oks += 1
                if kind != "line":
                    replies.append((kind, body))
            else:
                errors.append((oks + len(errors), kind, line))
            body = []
    return oks, errors, replies


def stream_job(n):
    """n short moves that end where they began, plus now and then a Y step."""
    lines = []
    for i in range(1, n + 1):
        x = 0.0125 * (i % 40)                # 10 steps a line, back and forth
        y = 0.0125 * (i // 100)
        lines.append(f"N{i} G1 X{x:.4f} Y{y:.4f} F1500")
    return lines


def test_sender_counting_128_with_g_every_5_lines(grbl):
    """The sloppy sender of the issue: 128 bytes counted, '$G' every 5 lines
    outside the count, '?' at 10 Hz; 1,000 lines, nothing lost."""
    grbl.ok("$120=5000")
    grbl.ok("$121=5000")
    grbl.ok("G90")
    lines = stream_job(1000)
    oks, errors, replies = sloppy_stream(grbl, lines)
    assert errors == []
    assert oks == 1000 + 200
    assert len(replies) == 200
    assert all(len(b) == 1 and b[0].startswith("[GC:G1 G54") for _, b in replies)
    grbl.wait_idle()
    assert grbl.steps() == [0, deg_steps(0.0125 * 10), 0]
    assert grbl.query("uart")["rx_queued"] == 0


def test_sender_overfilling_by_a_line_with_queries(grbl):
    """A sender that checks its count before adding the line (one line past
    the 128) and interleaves '$G', '$#' and '$$': every line and every query
    answered, in order."""
    grbl.ok("$120=5000")
    grbl.ok("$121=5000")
    grbl.ok("G90")
    # lines of up to 80 characters: the overshoot is a full line
    lines = [f"G1 X{0.0125 * (i % 8):.4f} F1500 (" + "p" * 54 + ")" for i in range(1, 121)]
    assert max(len(l) for l in lines) <= 80
    oks, errors, replies = sloppy_stream(grbl, lines, overfill_by_a_line=True, extra_every=4,
                                         extras=("$G", "$#", "$$"))
    assert errors == []
    assert oks == 120 + 30
    for kind, body in replies:
        if kind == "$G":
            assert len(body) == 1 and body[0].startswith("[GC:")
        elif kind == "$#":
            assert body[0].startswith("[G54:") and body[-1].startswith("[PRB:")
        else:
            assert body[0] == "$0=10" and body[-1].startswith("$142=")
    grbl.wait_idle()
    assert grbl.steps() == [0, 0, 0]


def test_utf8_encoded_realtime_bytes(grbl):
    """C2 85 (U+0085, as a UTF-8 sender writes 0x85) cancels a jog; the
    continuation byte of another character (C3 85, 'Å') does not."""
    grbl.ok("$J=G91 X10 F150")                # 4 s: still jogging after a stall
    grbl.wait_state("Jog")
    grbl.write("Å".encode())                 # C3 85
    grbl.run_cycles(stagelib.F_CPU // 10)
    assert grbl.status()["state"] == "Jog"
    grbl.write("\u0085".encode())            # C2 85
    st = grbl.wait_state("Idle", timeout=30)
    assert 0 < st["mpos"][0] < 10
    assert round(st["mpos"][0] * 800) == grbl.steps()[0]


OPTIBOOT = ROOT / "sim" / "stage" / "build" / "optiboot_atmega328.hex"


def reopen(st):
    os.close(st.fd)
    st.rx = b""
    # no tcflush of the input here, though senders do one: stagesim's reset
    # on the open already drops what the old session left unread, and a
    # flush of ours could come after that reset and drop the new banner
    st.fd = os.open(st.pty, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(st.fd, termios.TCSANOW)


def test_reopening_the_port_resets_like_an_uno(grbl):
    """Open, close, reopen: a banner each time, as DTR resets an Uno; the
    stage keeps its angle, the firmware starts from zero."""
    grbl.ok("G0 X1")
    grbl.wait_idle()
    for n in range(2):
        reopen(grbl)
        grbl.banner()
        grbl.drain()
        assert grbl.status()["mpos"] == [0.0, 0.0, 0.0]
        assert grbl.steps()[0] == 800
        assert grbl.query("uart")["auto_resets"] == n + 1


def test_flush_after_open_with_optiboot(make_stage, firmware_elf):
    """With the Uno's bootloader in front of the firmware, a sender that flushes
    the port's input right after opening it (as senders do) still gets the
    banner: Optiboot waits about a second for an upload after the reset the
    open gives, and the firmware greets only then."""
    r = subprocess.run(["make", "-s", "-C", str(ROOT / "sim" / "stage"), "optiboot"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    st = make_stage(elf=firmware_elf, args=["--bootloader", str(OPTIBOOT)])
    st.start()
    t0 = time.monotonic()
    reopen(st)
    termios.tcflush(st.fd, termios.TCIFLUSH)
    st.banner()
    # the bootloader's wait (simulated time, kept no faster than the wall clock)
    assert time.monotonic() - t0 >= 0.5
    assert st.query("uart")["auto_resets"] == 1


def test_no_auto_reset(make_stage, firmware_elf):
    st = make_stage(elf=firmware_elf, args=["--no-auto-reset"])
    st.start()
    st.ok("G0 X1")
    st.wait_idle()
    reopen(st)
    assert st.status()["mpos"] == [1.0, 0.0, 0.0]
    assert st.query("uart")["auto_resets"] == 0


def test_flash_sim_optiboot_writes_verifies_and_keeps_eeprom(make_stage, firmware_elf, tmp_path):
    """`make -C firmware flash-sim`: Optiboot in stagesim, avrdude writes and
    verifies the HEX over the pty, the firmware greets; the EEPROM (a setting
    stored before) is the same file byte for byte afterwards."""
    hexfile = firmware_elf.with_suffix(".hex")
    if not hexfile.exists():
        pytest.skip(f"{hexfile} not built (run `make firmware`)")
    eeprom = tmp_path / "uno.eeprom"
    st = make_stage(elf=firmware_elf, eeprom=eeprom)
    st.start()
    st.ok("$110=1234")
    st.close()
    before = eeprom.read_bytes()
    r = subprocess.run(["make", "-s", "-C", str(ROOT / "firmware"), "flash-sim",
                        f"FLASH_SIM_EEPROM={eeprom}"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "bytes of flash verified" in r.stdout
    assert "BANNER  Grbl 1.1h" in r.stdout
    assert eeprom.read_bytes() == before
    st = make_stage(elf=firmware_elf, eeprom=eeprom)
    st.start()
    assert "$110=1234.000" in st.ok("$$")


STAGECTL = ROOT / "host" / "build" / "rig" / "stagectl"
STAGECTL_OPTS = ["--banner-timeout", "5000", "--timeout", "5000"]


def test_soft_limit_alarm_unlock_and_recover_with_stagectl(make_stage, firmware_elf):
    """ALARM:2 says the position is kept and unlocking is safe: `stagectl
    unlock` does it, and so does `stagectl recover` (reset, then unlock as
    the alarm, said again after the reset, allows)."""
    if not STAGECTL.exists():
        subprocess.run(["make", "-s", "-C", str(ROOT / "host" / "rig")], check=True)
    st = make_stage(elf=firmware_elf, args=["--no-auto-reset", "--limits", "20,none,none"])
    st.start()
    st.ok("$22=1")
    st.ok("$HX", timeout=120)
    st.ok("$20=1")
    st.ok("G0 X-5")
    st.wait_idle()
    os.close(st.fd)
    st.fd = None

    def stagectl(*args, check=True):
        r = subprocess.run([str(STAGECTL), "--port", st.pty, *STAGECTL_OPTS, *map(str, args)],
                           capture_output=True, text=True, timeout=60)
        if check:
            assert r.returncode == 0, f"stagectl {args}: {r.stdout}{r.stderr}"
        return r

    for way in ("unlock", "recover"):
        r = stagectl("send", "G0 X5", check=False)      # beyond machine space [-360, 0]
        assert "ALARM:2" in r.stdout + r.stderr or "Soft limit" in r.stdout + r.stderr \
            or stagectl("pos").stdout.split()[0] == "Alarm"
        stagectl(way)
        assert stagectl("pos").stdout.split()[0] == "Idle"
        r = stagectl("move", -6, 0, 0)
    steps = st.steps()
    assert steps[0] == deg_steps(20 - 6)     # MPos 0 is the switch (at 20) after homing
