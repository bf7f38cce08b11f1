"""``python -m client``: the ``robot-client`` command."""

import sys

from .cli import main

sys.exit(main())
