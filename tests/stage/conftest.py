"""Fixtures for the simulated-stage tests: a fresh stagesim per test."""
import pytest

import stagelib


@pytest.fixture(scope="session")
def stagesim_built():
    stagelib.build_stagesim()
    return stagelib.STAGESIM


@pytest.fixture
def firmware_elf():
    if not stagelib.FIRMWARE.exists():
        pytest.skip(f"firmware ELF not built ({stagelib.FIRMWARE}; run `make firmware`)")
    return stagelib.FIRMWARE


@pytest.fixture
def make_stage(stagesim_built, tmp_path):
    """make_stage(elf=..., args=[...], eeprom=..., name=...) -> started Stage; all closed at teardown."""
    stages = []

    def factory(elf=stagelib.FIRMWARE, args=(), eeprom=None, name=None):
        st = stagelib.Stage(tmp_path, elf=elf, args=args, eeprom=eeprom,
                            name=name or f"stage{len(stages)}")
        stages.append(st)
        return st

    yield factory
    for st in stages:
        if st.fd is not None or st.proc.poll() is None:
            st.close(check=False)


@pytest.fixture
def grbl(make_stage, firmware_elf):
    """The stage firmware, booted, banner read."""
    st = make_stage(elf=firmware_elf)
    st.start()
    return st
