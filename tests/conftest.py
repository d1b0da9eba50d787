"""Shared fixtures: where the real public data lives, and small generated inputs."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def shared_file(relative: str) -> Path:
    """Path of a file in ../shared/data; skips the test with the reason when it is absent."""
    path = SHARED_DATA / relative
    if not path.exists():
        pytest.skip(f"real data {relative} not found: ../shared/data is absent on this machine")
    return path


@pytest.fixture
def shared():
    return shared_file


@pytest.fixture(scope="session")
def generated_lod2(tmp_path_factory):
    """The generated city (seed 0) at LoD2, parsed once per test session."""
    # Imported here: conftest is loaded before any test module, keep its import light.
    from semcityloc.citymodel.citygml import read_citygml
    from semcityloc.citymodel.generator import generate_city

    paths = generate_city(tmp_path_factory.mktemp("generated_city"), seed=0)
    return read_citygml(paths[2])
