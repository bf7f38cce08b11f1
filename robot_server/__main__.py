"""``python -m robot_server``: the ``robot-server`` command (see :mod:`robot_server.cli`)."""

import sys

from .cli import main

sys.exit(main())
