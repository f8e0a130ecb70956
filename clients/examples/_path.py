"""Let the examples run from a checkout: find ``sdfclient`` (clients/) and ``sdfserver`` (the root)."""

import sys
from pathlib import Path

_clients = Path(__file__).resolve().parents[1]
for _p in (str(_clients), str(_clients.parent)):
    if _p not in sys.path:
        sys.path.append(_p)
