"""Every family of the ray-caster (bench/raycast/families.py) keeps its seed stream: the scenes of a
few frames, and so every frame drawn before, stay what they were. Each family added to the
ray-caster (appended to EXTRA_FAMILIES) adds a row to STREAMS, its scenes' fingerprint as first
drawn; a row that no longer matches means that family's frames changed."""
import hashlib
import json
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "bench"))

from raycast import camera, families  # noqa: E402


def _rounded(v):
    """Floats to 6 decimals, so that a last-bit difference of another machine's libm does not count."""
    if isinstance(v, float):
        return round(v, 6)
    if isinstance(v, dict):
        return {k: _rounded(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_rounded(x) for x in v]
    return v


# Scenes of frames (0, 0), (0, 1), (111, 5) of each family at the reference camera: sha256 of their
# JSON, first 16 hex digits.
STREAMS = {
    "clean": "8eb13cd78e93d769",            # the evaluation's six: as drawn before two-edge (cbad8cf)
    "shifts": "1a6fdfd7720b2b61",
    "rig": "9a6e8804df1eff76",
    "rig-unseen": "b65aa2b2cf9e3c60",
    "edge": "e8db0219409bfea5",
    "refuse": "69007a6d43c322e0",
    "two-edge": "6e7d45688c06e70a",         # since its second sphere keeps off the top and bottom
    "rig-photo": "7af6df4b1f5354a6",        # as added (a19d18c)
    "rig-sensor": "5f1dd348ebd1b360",       # as added (5b15cbd)
    "rig-motion": "e6aa4d541bed4380",       # as added
}


def _fingerprint(family, cam):
    h = hashlib.sha256()
    for seed, i in ((0, 0), (0, 1), (111, 5)):
        h.update(json.dumps(_rounded(families.draw_scene(family, seed, i, cam)), sort_keys=True).encode())
    return h.hexdigest()[:16]


def test_families_keep_their_ids():
    assert families.FAMILIES == ("clean", "shifts", "rig", "rig-unseen", "edge", "refuse")
    assert families.EXTRA_FAMILIES[:3] == ("two-edge", "rig-photo", "rig-sensor")
    names = families.FAMILIES + families.EXTRA_FAMILIES
    assert [families._FAMILY_ID[f] for f in names] == list(range(1, len(names) + 1))
    assert set(STREAMS) == set(names)      # a new family adds its row


def test_families_keep_their_streams():
    cam = camera.Camera()
    for family, digest in STREAMS.items():
        assert _fingerprint(family, cam) == digest, family
        if family != "rig-sensor":
            assert "sensor" not in families.draw_scene(family, 0, 0, cam), family
