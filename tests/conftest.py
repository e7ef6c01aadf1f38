import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DESIGNS = REPO / "designs"

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture
def designs_dir() -> Path:
    return DESIGNS
