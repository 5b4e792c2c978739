"""GRBL 1.1 features senders show as buttons and settings, in stagesim with
the firmware ELF: real-time feed and rapid overrides (the Ov field), the
$N0/$N1 startup blocks, and the hard-limit debounce against a bouncing
switch (stagesim --limit-bounce)."""
import time

from stagelib import F_CPU, deg_steps

SECOND = F_CPU


def send_rt(st, *codes):
    """Real-time bytes one at a time: each is a flag in the firmware (as in
    GRBL), so the same byte twice before the main loop looks counts once."""
    for c in codes:
        st.write(bytes([c]))
        st.run_cycles(SECOND // 200)


def run_report(st, timeout=30):
    t_end = time.monotonic() + timeout
    while True:
        s = st.status()
        if s["state"] == "Run":
            return s
        assert time.monotonic() < t_end, f"never Run: {s}"


def ov(st):
    """The Ov field of the next report that has one."""
    for _ in range(12):
        s = st.status()
        if "Ov" in s["fields"]:
            return [int(v) for v in s["fields"]["Ov"].split(",")]
    raise AssertionError("no Ov field in 12 reports")


def test_feed_and_rapid_overrides(grbl):
    send_rt(grbl, 0x92, 0x92, 0x92, 0x92, 0x92)         # feed -50 %
    assert ov(grbl) == [50, 100, 100]
    grbl.ok("G1 X10 F600")
    grbl.run_cycles(SECOND // 2)
    s = run_report(grbl)
    assert abs(float(s["fields"]["FS"].split(",")[0]) - 300) <= 1
    send_rt(grbl, 0x90)                                 # back to 100 % mid-move
    grbl.run_cycles(SECOND // 4)
    s = grbl.status()
    assert s["state"] == "Idle" or abs(float(s["fields"]["FS"].split(",")[0]) - 600) <= 1
    grbl.wait_idle()
    assert grbl.steps()[0] == deg_steps(10)
    send_rt(grbl, 0x97)                                 # rapid 25 %: 450 deg/min
    assert ov(grbl) == [100, 25, 100]
    grbl.ok("G0 X30")
    grbl.run_cycles(SECOND // 2)
    s = run_report(grbl)
    assert abs(float(s["fields"]["FS"].split(",")[0]) - 450) <= 1
    grbl.wait_idle()
    assert grbl.steps()[0] == deg_steps(30)
    grbl.write(b"\x18")                                 # a reset restores 100 %
    grbl.banner()
    grbl.drain()
    assert ov(grbl) == [100, 100, 100]


def test_startup_blocks_after_reset_reopen_and_restart(make_stage, firmware_elf, tmp_path):
    eeprom = tmp_path / "st.eeprom"
    st = make_stage(elf=firmware_elf, eeprom=eeprom)
    st.start()
    st.ok("$N0=G91")
    st.ok("$N1=G55")
    assert st.ok("$N") == ["$N0=G91", "$N1=G55"]
    st.write(b"\x18")
    st.banner()
    assert st.expect(r"^>G91:") .string == ">G91:ok"
    assert st.expect(r"^>G55:").string == ">G55:ok"
    assert "G91" in st.ok("$G")[0] and "G55" in st.ok("$G")[0]
    st.close()
    st = make_stage(elf=firmware_elf, eeprom=eeprom)    # a power cycle: kept in EEPROM
    st.banner()
    assert st.expect(r"^>G91:").string == ">G91:ok"
    assert st.expect(r"^>G55:").string == ">G55:ok"


def test_hard_limit_debounce_with_bouncing_switch(make_stage, firmware_elf):
    """A switch at X=5 whose contacts chatter 5 times (0.5 ms apart) on every
    transition: hitting it is ALARM:1 once it settles; moving off it after
    '$X' is no alarm, though the chatter closes the contact again and again."""
    st = make_stage(elf=firmware_elf, args=["--limits", "5,none,none", "--limit-bounce", "5",
                                           "--limit-bounce-us", "500"])
    st.start()
    st.ok("$21=1")
    st.ok("G1 X6 F300")
    st.expect(r"^ALARM:1$", timeout=60)
    assert st.state()["limits"][0] == 1
    hit = st.steps()[0]
    # 10 ms of debounce at 5 deg/s: at most 0.05 deg (40 steps) past the switch, plus a stop
    assert deg_steps(5) <= hit <= deg_steps(5) + 60
    st.write(b"\x18")
    st.banner()
    st.drain()
    st.ok("$X")
    st.ok("G1 X4 F300")
    st.wait_idle()
    assert st.steps()[0] == deg_steps(4)
    assert st.state()["limits"][0] == 0
    assert st.status()["state"] == "Idle"
    stats = st.query("stats")
    assert stats["vectors"]["3"]["count"] >= 10        # PCINT0: the chatter reached the firmware
