"""The bench scripts record their machine through one helper, bench/machine.py: render_fps.py and
scale_bench.py use it and keep no copy of their own, so their records say it alike."""
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "bench"))

import machine  # noqa: E402

USERS = ("render_fps.py", "scale_bench.py")


def test_machine_record():
    m = machine.machine()
    assert list(m) == ["date_utc", "nproc", "cpu"]
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", m["date_utc"])
    assert m["nproc"] == os.cpu_count() and m["cpu"]
    assert machine.load_1min() >= 0


def test_bench_scripts_use_the_helper():
    for name in USERS:
        with open(os.path.join(ROOT, "bench", name), encoding="utf-8") as f:
            src = f.read()
        assert re.search(r"^from machine import .*\bmachine\b", src, re.M), name
        # no copy of the machine block: the CPU, the date format, the load average
        for copy in ("/proc/cpuinfo", "def cpu_model", "%Y-%m-%dT", "getloadavg", "os.cpu_count()"):
            assert copy not in src, f"bench/{name} keeps its own {copy!r}; use bench/machine.py"
