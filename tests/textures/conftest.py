"""Shared fixtures: the six textures generated once per session at a small size."""
import numpy as np
import pytest

from textures import generate
from textures.criteria import check_texture

from texhelpers import TEST_HEIGHT, TEST_STEP


@pytest.fixture(scope="session")
def texture_dir(tmp_path_factory):
    """Folder holding the six generated textures at TEST_HEIGHT."""
    out = tmp_path_factory.mktemp("textures")
    generate.generate_all(str(out), 2 * TEST_HEIGHT, TEST_HEIGHT)
    return out


@pytest.fixture(scope="session")
def six_reports():
    """{name: {criterion name: check dict}} for the six textures, computed once."""
    reports = {}
    for level in generate.LEVELS:
        for version in generate.VERSIONS:
            rgb = generate.render(level, version, 2 * TEST_HEIGHT, TEST_HEIGHT)
            checks, _ = check_texture(rgb, step=TEST_STEP, progress=False)
            reports[generate.texture_name(level, version)] = {c["name"]: c for c in checks}
    return reports
