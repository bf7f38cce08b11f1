"""``python -m bench.fuzz``, from the repository's root: the fuzz tool's command (see :mod:`bench.fuzz.cli`)."""

import sys

from .cli import main

sys.exit(main())
