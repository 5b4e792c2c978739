#!/usr/bin/env python3
"""Split pip's resolved install plan into steps that keep the disk's peak low.

pip downloads every wheel of one command before it installs any, so a single
`pip install -r requirements.txt` holds PyTorch's CUDA wheels (about 3.3 GB)
on disk beside their unpacked copies (about 5 GB). Installing each of those
large wheels in a step of its own keeps only one download on disk at a time:
measured without pip's cache, the peak falls from 10.5 GB to 7.4 GB, and a
small CI disk decides between the two (scripts/deps.sh).

Input: the JSON that `pip install --dry-run --report FILE` writes. Output: one
line per pip step, the `name==version` pins of that step separated by spaces;
the small packages share the last line.

usage: pip_steps.py REPORT.json
"""
import json
import re
import sys

# Wheels of hundreds of MB: PyTorch, its compiler and NVIDIA's CUDA libraries.
LARGE_PREFIXES = ("torch", "triton", "nvidia-", "cuda-")


def steps(report):
    pins = [f"{p['metadata']['name']}=={p['metadata']['version']}" for p in report.get("install", [])]
    # names compared as PEP 503 normalises them (nvidia_cublas is nvidia-cublas)
    large = [p for p in pins if re.sub(r"[-_.]+", "-", p.lower()).startswith(LARGE_PREFIXES)]
    small = [p for p in pins if p not in large]
    return [[p] for p in large] + ([small] if small else [])


def main(argv):
    if len(argv) == 2 and argv[1] in ("-h", "--help"):
        print(__doc__.strip())
        return 0
    if len(argv) != 2:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    try:
        with open(argv[1]) as f:
            report = json.load(f)
    except (OSError, ValueError) as e:
        print(f"pip_steps: {argv[1]}: {e}", file=sys.stderr)
        return 1
    for step in steps(report):
        print(" ".join(step))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
