"""The lab's tests import its modules as ``lab.NAME``, as a run config's ``hooks.modules`` names them."""

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))
