"""The matrix's helper modules (``matrix_checks``, ``matrix_video_rows``) import by name."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
