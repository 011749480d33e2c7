"""Write docs/reproductions.md's summary from the verdict tables of ``navlab reproduce``.

    python -m navlab reproduce NAME --seeds 20 --outdir DIR -q      # for every NAME; writes NAME_verdicts.md
    python tools/readme_reproductions.py DIR                        # replaces the page's block

The block between the two markers below in docs/reproductions.md is replaced by DIR/NAME_verdicts.md of every
registered reproduction, in alphabetical order: the same rows the CLI prints, nothing edited.
"""

from __future__ import annotations

import sys
from pathlib import Path

from navlab.reproduce import REPRODUCTIONS

BEGIN, END = "<!-- reproductions:begin -->", "<!-- reproductions:end -->"
PAGE = Path(__file__).resolve().parents[1] / "docs" / "reproductions.md"


def block(outdir: Path) -> str:
    parts = []
    for name in sorted(REPRODUCTIONS):
        f = outdir / f"{name}_verdicts.md"
        if not f.is_file():
            sys.exit(f"{f} not found: run `python -m navlab reproduce {name} --seeds 20 --outdir {outdir}`")
        parts.append(f.read_text().strip())
    return "\n\n".join(parts)


def main(argv: list[str]) -> None:
    if len(argv) != 1:
        sys.exit(__doc__)
    text = PAGE.read_text()
    if BEGIN not in text or END not in text:
        sys.exit(f"{PAGE} lacks the markers {BEGIN} … {END}")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    PAGE.write_text(f"{head}{BEGIN}\n{block(Path(argv[0]))}\n{END}{tail}")
    print(f"{PAGE.name}: reproduction summary from {argv[0]}")


if __name__ == "__main__":
    main(sys.argv[1:])
