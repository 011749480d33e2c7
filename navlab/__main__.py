"""``python -m navlab``."""

import os
import sys

# A CLI process touches each of its large arrays once, in fresh memory. numpy marks every array of
# 4 MB or more for transparent huge pages (madvise), and where the kernel's THP defrag setting is
# "madvise" (a common default) a fault on such memory may stall on synchronous compaction
# (numpy/numpy#31590); benchmarks/throughput.py measures the CLI with and without. An explicit
# NUMPY_MADVISE_HUGEPAGE wins; the app (a long-lived server that reuses its memory) keeps numpy's.
if sys.argv[1:2] != ["app"]:
    os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")

from navlab.cli import main  # after the setting: numpy reads it when it is imported

raise SystemExit(main())
