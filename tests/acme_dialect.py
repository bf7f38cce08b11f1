"""A controller family added the way CONTRIBUTING.md says: this one module (and its test).

ACME RC-1 is made up: it listens on 12000/12002, speaks big-endian with 8-byte reals, answers a
request header-only, takes one motion client and two state clients at a time, and otherwise moves
like the generic controller (it reuses the generic profile's behaviour). Importing the module
registers it: ``robot-server --import tests.acme_dialect --profile acme``; a client speaks it with
``RobotDriver(profile="acme")`` or ``Client.tcp(..., dialect=ACME)``.
"""

from __future__ import annotations

from robot_server.emulator import EmulatorProfile, GenericBehaviour, PortRules, register_profile
from simple_message.dialects import Dialect, ReplyStyle, register
from simple_message.wire import BE64

ACME = register(
    Dialect(
        name="acme",
        description="ACME RC-1 (an example family)",
        motion_port=12000,
        state_port=12002,
        io_port=None,
        wire=BE64,
        reply_style=ReplyStyle.HEADER_ONLY,
    )
)

ACME_PROFILE = register_profile(
    EmulatorProfile(
        ACME,
        GenericBehaviour,
        ports={"motion": PortRules(max_connections=1), "state": PortRules(max_connections=2)},
        description="ACME RC-1: the generic controller's motion, header-only replies, one motion client",
    )
)
