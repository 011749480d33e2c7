"""Write docs/CLAIMS.md (the claims register) from the claims the reproductions declare.

python tools/claims_register.py          # rewrites docs/CLAIMS.md
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from navlab.reproduce.report import register_markdown

PATH = pathlib.Path(__file__).resolve().parents[1] / "docs" / "CLAIMS.md"

if __name__ == "__main__":
    PATH.write_text(register_markdown(), encoding="utf-8")
    print(f"{PATH}: written")
