"""scripts/pip_steps.py: the install plan's steps keep large wheels apart and lose nothing."""
import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "pip_steps.py"


def _report(*pins):
    return {"install": [{"metadata": {"name": n, "version": v}} for n, v in pins]}


def _run(tmp_path, report):
    path = tmp_path / "report.json"
    path.write_text(json.dumps(report) if isinstance(report, dict) else report)
    return subprocess.run([sys.executable, str(SCRIPT), str(path)], capture_output=True, text=True)


def test_each_large_wheel_alone_small_ones_together(tmp_path):
    out = _run(tmp_path, _report(("numpy", "2.2.6"), ("torch", "2.15.0"), ("nvidia-cublas", "13.4.1.3"),
                                 ("tqdm", "4.67.1"), ("triton", "3.9.0"), ("cuda-bindings", "13.5.0")))
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines() == ["torch==2.15.0", "nvidia-cublas==13.4.1.3", "triton==3.9.0",
                                       "cuda-bindings==13.5.0", "numpy==2.2.6 tqdm==4.67.1"]


def test_nothing_to_install_gives_no_step(tmp_path):
    out = _run(tmp_path, {"install": []})
    assert out.returncode == 0 and out.stdout == ""


def test_unreadable_report_names_the_file(tmp_path):
    out = _run(tmp_path, "{not json")
    assert out.returncode == 1
    assert "report.json" in out.stderr


def test_help_and_usage():
    out = subprocess.run([sys.executable, str(SCRIPT), "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "usage: pip_steps.py REPORT.json" in out.stdout
    out = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True)
    assert out.returncode == 2 and "usage" in out.stderr
