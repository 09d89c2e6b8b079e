"""Where the tests find the repository's parts and the shared real data."""

from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"
PACKAGE = SRC / "agrislam"
SHARED_DATA = REPO.parent / "shared" / "data"
