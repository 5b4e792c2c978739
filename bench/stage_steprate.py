#!/usr/bin/env python3
"""Stage firmware step-rate benchmark, in simulated cycles (never wall time).

Runs the firmware ELF in stagesim (--fast), and for a ladder of step rates
commands one long move on one axis, then on three axes at once, and checks:
  * no lost step: pulses counted on the STEP pins == commanded steps, and the
    firmware's reported position agrees;
  * the rate was really reached: cruise rate measured from (steps, cycle)
    samples of the state socket >= 97 % of the commanded rate;
  * legal pulses for A4988/DRV8825: high and low >= 1.9 us, DIR set >= 650 ns
    before the edge (the table also shows the shortest high time, to compare
    with the firmware's own $0 pulse width);
while a '?' status query goes out every few milliseconds, as senders poll,
and reports the worst-case duration of each interrupt vector in cycles
(entry to RETI, nested interrupts included) and flash/RAM from avr-size.

    .venv/bin/python bench/stage_steprate.py [--elf FILE] [--markdown FILE]
"""
import argparse
import datetime
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "stage"))
import stagelib  # noqa: E402

F_CPU = stagelib.F_CPU
VECTOR_NAMES = {3: "PCINT0 (limits)", 6: "WDT", 7: "TIMER2_COMPA", 8: "TIMER2_COMPB",
                9: "TIMER2_OVF", 11: "TIMER1_COMPA (step)", 12: "TIMER1_COMPB (pulse end)",
                13: "TIMER1_OVF", 14: "TIMER0_COMPA", 15: "TIMER0_COMPB", 16: "TIMER0_OVF",
                18: "USART_RX", 19: "USART_UDRE", 20: "USART_TX", 22: "EE_READY"}
AXES = "XYZ"


def get_args_parser():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--elf", default=str(stagelib.FIRMWARE), help="firmware ELF (default: %(default)s)")
    p.add_argument("--one", default="10000,20000,25000,30000,35000,40000",
                   help="one-axis step rates in Hz (default: %(default)s)")
    p.add_argument("--three", default="10000,15000,20000,25000,30000,35000,40000",
                   help="three-axis step rates in Hz, each axis (default: %(default)s)")
    p.add_argument("--steps", type=int, default=12000, help="steps per axis per move (default: %(default)s)")
    p.add_argument("--accel", type=float, default=3000.0,
                   help="acceleration $120-$122 in deg/s^2 (default: %(default)s)")
    p.add_argument("--markdown", help="also write the report to this file")
    p.add_argument("--label", help="how the report names the firmware (default: the ELF path "
                                   "inside the repository and the last commit of firmware/)")
    return p


def avr_size(elf):
    out = subprocess.run(["avr-size", "-A", str(elf)], capture_output=True, text=True, check=True).stdout
    sec = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].startswith(".") and parts[1].isdigit():
            sec[parts[0]] = int(parts[1])
    flash = sec.get(".text", 0) + sec.get(".data", 0)
    ram = sec.get(".data", 0) + sec.get(".bss", 0) + sec.get(".noinit", 0)
    return flash, ram, sec


def firmware_label(args, elf):
    if args.label:
        return args.label
    name = elf.relative_to(ROOT) if elf.is_relative_to(ROOT) else elf.name
    commit = subprocess.run(["git", "-C", str(ROOT), "log", "-1", "--format=%h", "--", "firmware"],
                            capture_output=True, text=True).stdout.strip()
    return f"`{name}`" + (f", firmware/ at commit {commit}" if commit else "")


def run_move(st, rate_hz, axes, steps, spd):
    """One move at rate_hz on each of the given axes. Returns a result dict."""
    feed = rate_hz * 60.0 / spd                          # deg/min on each axis
    deg = steps / spd
    st.query("clear-stats")
    start = st.state()
    # a multi-axis G1 at feed F moves along the diagonal: scale F by sqrt(n)
    n = len(axes)
    words = " ".join(f"{a}{deg:.4f}" for a in axes)
    st.ok(f"G91 G1 {words} F{feed * n ** 0.5:.3f}")
    samples = []
    t_end = time.monotonic() + 120
    while True:
        s = st.state()
        samples.append((s["cycle"], s["steps"]))
        done = all(s["steps"][AXES.index(a)] - start["steps"][AXES.index(a)] == steps for a in axes)
        if done or time.monotonic() > t_end:
            break
        st.write(b"?")                     # senders poll while moving
        st.pump(0.002)
        st.rx = b""
    idle = st.wait_idle(60)
    end = st.state()
    stats = st.query("stats")
    # cruise rate: the best rate over windows of >= 20 ms of simulated time
    ai = AXES.index(axes[0])
    best = 0.0
    j = 0
    for i in range(len(samples)):
        while j < i and samples[i][0] - samples[j + 1][0] >= F_CPU // 50:
            j += 1
        dc = samples[i][0] - samples[j][0]
        if dc >= F_CPU // 50:
            best = max(best, (samples[i][1][ai] - samples[j][1][ai]) * F_CPU / dc)
    moved = [end["steps"][k] - start["steps"][k] for k in range(3)]
    want = [steps if AXES[k] in axes else 0 for k in range(3)]
    fw_pos = [round(v * spd) for v in idle["mpos"]]
    return {"rate": rate_hz, "axes": axes, "moved": moved, "want": want,
            "pulses": [stats["axes"][k]["pulses"] for k in range(3)],
            "fw_pos": fw_pos, "true_pos": end["steps"], "cruise": best, "stats": stats}


def verdict(r):
    problems = []
    if r["moved"] != r["want"]:
        problems.append(f"moved {r['moved']} != {r['want']}")
    if r["fw_pos"] != r["true_pos"]:
        problems.append(f"firmware position {r['fw_pos']} != pulses {r['true_pos']}")
    if r["cruise"] < 0.97 * r["rate"]:
        problems.append(f"cruise {r['cruise']:.0f} Hz")
    for k, ax in enumerate(r["stats"]["axes"]):
        if AXES[k] not in r["axes"]:
            continue
        if ax["min_high"] < 1.9e-6 * F_CPU or ax["min_low"] < 1.9e-6 * F_CPU:
            problems.append(f"{AXES[k]} pulse high {ax['min_high']} low {ax['min_low']} cycles")
        if ax["dir_violations"] or (ax["min_dir_setup"] and ax["min_dir_setup"] < 0.65e-6 * F_CPU):
            problems.append(f"{AXES[k]} DIR setup {ax['min_dir_setup']} cycles")
    return problems


def main(args):
    elf = Path(args.elf)
    if not elf.exists():
        sys.exit(f"stage_steprate: {elf} not built (make firmware)")
    stagelib.build_stagesim()
    flash, ram, sections = avr_size(elf)
    tmp = tempfile.mkdtemp(prefix="stage-bench-")
    st = stagelib.Stage(tmp, elf=elf, args=["--fast"])
    rows, worst_vec = [], {}
    irq_off = (0, "")
    try:
        st.start()
        s = {}
        for line in st.ok("$$"):
            k, _, v = line[1:].partition("=")
            s[int(k)] = float(v)
        spd = s[100]
        pulse_us = s[0]
        for k in range(3):
            st.ok(f"$12{k}={args.accel:g}")
        for label, axes, ladder in (("one axis", "X", args.one), ("three axes", "XYZ", args.three)):
            for rate in (int(x) for x in ladder.split(",")):
                max_rate = rate * 60.0 / spd * 1.02
                body, end = st.command(f"$110={max_rate:.3f}")
                if end != "ok":         # at the firmware's ceiling: no margin
                    max_rate = rate * 60.0 / spd
                    body, end = st.command(f"$110={max_rate:.3f}")
                if end != "ok":
                    rows.append((label, rate, None, f"firmware refuses $110 for {rate} Hz ({end})", None))
                    continue
                for k in (1, 2):
                    st.ok(f"$11{k}={max_rate:.3f}")
                r = run_move(st, rate, axes, args.steps, spd)
                problems = verdict(r)
                rows.append((label, rate, r, "; ".join(problems) or "ok", r["stats"]["axes"][0]))
                if r["stats"]["max_irq_off_cycles"] > irq_off[0]:
                    irq_off = (r["stats"]["max_irq_off_cycles"], r["stats"]["max_irq_off_pc"])
                for v, d in r["stats"]["vectors"].items():
                    worst_vec[int(v)] = max(worst_vec.get(int(v), 0), d["max_cycles"])
                st.ok("G90 G0 X0 Y0 Z0")
                st.wait_idle(60)
    finally:
        st.close(check=False)

    best = {}
    for label, rate, r, verdict_text, _ in rows:
        if r is not None and verdict_text == "ok":
            best[label] = max(best.get(label, 0), rate)

    out = []
    out.append("| move | commanded rate (Hz/axis) | cruise reached (Hz) | steps counted / commanded | "
               "min high / low (cycles) | verdict |")
    out.append("| --- | ---: | ---: | --- | --- | --- |")
    for label, rate, r, text, ax in rows:
        if r is None:
            out.append(f"| {label} | {rate} | - | - | - | {text} |")
            continue
        counted = "/".join(str(abs(m)) for m, w in zip(r["moved"], r["want"]) if w)
        out.append(f"| {label} | {rate} | {r['cruise']:.0f} | {counted} / {args.steps} | "
                   f"{ax['min_high']} / {ax['min_low']} | {text} |")
    out.append("")
    out.append(f"Highest rate with no lost step, legal pulses and the rate reached: "
               f"one axis **{best.get('one axis', 0)} Hz**, three axes **{best.get('three axes', 0)} Hz each** "
               f"(targets: >= 30000 and >= 20000; $0={pulse_us:g} us, acceleration {args.accel:g} deg/s^2, "
               f"{args.steps} steps a move).")
    out.append("")
    out.append("| interrupt vector | worst case (cycles, entry to RETI, nested included) | (us) |")
    out.append("| --- | ---: | ---: |")
    for v in sorted(worst_vec):
        out.append(f"| {v} {VECTOR_NAMES.get(v, '')} | {worst_vec[v]} | {worst_vec[v] * 1e6 / F_CPU:.1f} |")
    out.append("")
    out.append(f"Longest stretch with interrupts disabled (SREG I clear, interrupt entry included) "
               f"while stepping: **{irq_off[0]} cycles** ({irq_off[0] * 1e6 / F_CPU:.1f} us), "
               f"starting at byte address {irq_off[1]}; one character at 115200 baud is 1360 "
               f"cycles and the UART holds two.")
    out.append("")
    out.append(f"Flash {flash} bytes (.text + .data), static RAM {ram} bytes (.data + .bss"
               f"{' + .noinit' if '.noinit' in sections else ''}), from `avr-size -A`.")
    report = "\n".join(out)
    print(report)
    if args.markdown:
        head = (f"Command: `.venv/bin/python bench/stage_steprate.py`  \n"
                f"Machine: {platform.machine()}, {platform.system()} {platform.release()}, "
                f"{subprocess.run(['nproc'], capture_output=True, text=True).stdout.strip()} cores  \n"
                f"Date: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC  \n"
                f"Firmware: {firmware_label(args, elf)}\n\n"
                "Method: the firmware ELF runs in `stagesim --fast` (simavr, atmega328p at 16 MHz); "
                "everything is measured in simulated cycles, so the host's speed does not enter. "
                "For each rate the bench sets $110-$112 to that rate (+2 % where the firmware accepts it), commands a "
                f"{args.steps}-step G1 on X (or on X, Y and Z at once, feed scaled by sqrt(3)) and "
                "sends `?` every few milliseconds while it runs. A rate passes when the pulses "
                "counted on the STEP pins equal the commanded steps, the firmware's reported "
                "position equals them, the best cruise rate over 20 ms windows (state socket "
                "samples) is >= 97 % of the commanded one, and pulses are legal for A4988/DRV8825 "
                "(high and low >= 1.9 us, DIR set >= 650 ns before the edge). Interrupt times are "
                "simavr's vector entry to RETI, nested interrupts included.\n\n")
        Path(args.markdown).write_text(head + report + "\n")
    return 0 if best.get("one axis", 0) >= 30000 and best.get("three axes", 0) >= 20000 else 1


if __name__ == "__main__":
    sys.exit(main(get_args_parser().parse_args()))
