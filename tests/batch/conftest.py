"""The batch tests import their helpers as ``from batch_stubs import ...``."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
