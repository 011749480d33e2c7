"""``python -m navlab``."""

from navlab.cli import main

raise SystemExit(main())
