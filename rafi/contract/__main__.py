"""``python -m rafi.contract [ROOT]``: rewrite the generated schema and settings tables."""

import sys
from pathlib import Path

from rafi.contract.generate import write_generated

root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[2]
for path in write_generated(root):
    print(f"rewrote {path}")
