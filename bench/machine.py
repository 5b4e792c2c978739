"""The machine a benchmark ran on, recorded beside its numbers (docs/benchmarks.md: command,
machine, date): one helper for the bench scripts, so their records say it alike.

    from machine import machine, load_1min       # a bench script: bench/ is its sys.path[0]
    result = {**machine(), ...}
"""
import os
import platform
import time


def cpu_model():
    """The CPU's model name (/proc/cpuinfo), else what platform knows, else "unknown"."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def load_1min():
    """The 1-minute load average now (what else the machine runs moves the numbers)."""
    return os.getloadavg()[0]


def machine():
    """{"date_utc", "nproc", "cpu"}: when (UTC, now) and on what a benchmark ran."""
    return {"date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "nproc": os.cpu_count(),
            "cpu": cpu_model()}
