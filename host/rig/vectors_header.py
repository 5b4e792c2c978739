#!/usr/bin/env python3
"""Write a C header of the conventions' test vectors (pose -> R) for the rig's unit tests.

    python3 vectors_header.py tests/data/conventions_vectors.json > conv_vectors.h

tests/data/conventions_vectors.json is the one source (docs/conventions.md, "Test vectors"):
the C test reads its matrices from this header, made from that file at build time, instead of
keeping a copy. Standard library only, so the rig's tests build without the project's venv.
"""
import json
import math
import sys


def main(argv):
    if len(argv) != 2:
        sys.exit("usage: vectors_header.py VECTORS.json > HEADER.h")
    path = argv[1]
    try:
        with open(path, encoding="utf-8") as f:
            cases = json.load(f)["cases"]
        rows = []
        for i, c in enumerate(cases):
            pose, R = [float(v) for v in c["pose_deg"]], [[float(v) for v in r] for r in c["R"]]
            if len(pose) != 3 or len(R) != 3 or any(len(r) != 3 for r in R) or \
                    not all(math.isfinite(v) for v in pose + sum(R, [])):
                raise ValueError(f"case {i}: pose_deg must be 3 numbers and R 3 x 3")
            rows.append((pose, R))
        if not rows:
            raise ValueError("no cases")
    except (OSError, ValueError, KeyError, TypeError) as e:
        sys.exit(f"vectors_header.py: {path}: {e}")
    num = lambda v: repr(v)  # noqa: E731  (shortest exact decimal of the double)
    out = [f"/* Generated from {path} by host/rig/vectors_header.py; do not edit. */",
           "static const struct {", "    double pose[3];", "    double R[3][3];", "} conv_cases[] = {"]
    for pose, R in rows:
        out.append("    {{%s}, {%s}}," % (", ".join(map(num, pose)),
                                         ", ".join("{" + ", ".join(map(num, r)) + "}" for r in R)))
    out += ["};", f"#define CONV_N_CASES {len(rows)}", ""]
    sys.stdout.write("\n".join(out))


if __name__ == "__main__":
    main(sys.argv)
