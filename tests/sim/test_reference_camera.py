"""One reference camera: sim/camera.py's REFERENCE (the defaults of every camera file) is the
`camera` of tests/data/conventions_vectors.json, the numbers' one source (docs/conventions.md,
"Camera"). The C runtime's copy (host/libposeinfer/pp_v2.c) is held to the same file by
tests/host/unit/test_camera_ref.c; bench/raycast keeps its own on purpose and checks itself
against the vectors in tests/bench/test_raycast.py."""
import json
import os

from sim.camera import REFERENCE, Camera, camera_from_dict

VECTORS_FILE = os.path.join(os.path.dirname(__file__), "..", "data", "conventions_vectors.json")


def test_reference_camera_is_the_vectors():
    with open(VECTORS_FILE, encoding="utf-8") as f:
        vectors = json.load(f)["camera"]
    assert REFERENCE == vectors
    assert {k: type(v) for k, v in REFERENCE.items()} == {k: type(v) for k, v in vectors.items()}
    # what an empty camera file and the dataclass's defaults give
    assert camera_from_dict({}, "empty") == camera_from_dict(vectors, VECTORS_FILE) == Camera()
