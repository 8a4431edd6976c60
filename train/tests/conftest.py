"""Shared paths: the fixtures written by the Rust crate (tests/fixtures, see tests/fixtures.rs)."""

from pathlib import Path

import pytest

FIXTURES = Path(__file__).resolve().parents[2] / "tests" / "fixtures"


@pytest.fixture
def quick_dataset_dir() -> Path:
    return FIXTURES / "dataset_quick"
