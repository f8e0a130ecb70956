"""Let the examples run from a checkout without installing the client: find ``sdfclient`` beside them."""

import sys
from pathlib import Path

_client = str(Path(__file__).resolve().parents[1])
if _client not in sys.path:
    sys.path.append(_client)
