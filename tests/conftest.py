"""Shared fixtures. Real MimicKit data comes from `$MIMICKIT_TEST_DATA` (CI: ../shared/data)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from mimickit.util.paths import PROJECT_DATA_DIR

PROJECT_HUMANOID = PROJECT_DATA_DIR / "assets" / "humanoid" / "humanoid.xml"
DEMO_CLIP = PROJECT_DATA_DIR / "motions" / "humanoid_demo_squat.pkl"


def test_data_dir() -> Path | None:
    value = os.environ.get("MIMICKIT_TEST_DATA")
    return Path(value).resolve() if value else None


@pytest.fixture(scope="session")
def test_data() -> Path:
    d = test_data_dir()
    if d is None:
        pytest.skip("MIMICKIT_TEST_DATA is not set: no MimicKit reference data to test against")
    if not d.is_dir():
        pytest.fail(f"MIMICKIT_TEST_DATA={d} is not a folder")
    return d


@pytest.fixture(scope="session")
def ref_humanoid_xml(test_data: Path) -> Path:
    return test_data / "assets" / "humanoid" / "humanoid.xml"
