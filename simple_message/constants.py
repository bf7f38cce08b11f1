"""Every protocol constant of simple_message as an enum.

Values come from the reference C++ library (``simple_message.h``, ``joint_traj_pt.h``,
``robot_status.h``), REP-I0004/I0006 and the Yaskawa MotoROS sources; see
``docs/reference/protocol.md`` §2.1, §3, §4.1, §5 and §8.1. The project's own extension messages
(CARTESIAN_LINE, TOOL_POSE and :class:`LineResult`) use numbers of the range REP-I0004 leaves
freely assignable (65001-65535); ``docs/protocol.md`` describes them. No other module of the
project writes a protocol number as a literal.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag

__all__ = [
    "MsgType",
    "CommType",
    "ReplyCode",
    "SpecialSeq",
    "ValidFields",
    "TriState",
    "RobotMode",
    "MotoCommand",
    "MotoResult",
    "InvalidSubcode",
    "NotReadySubcode",
    "moto_subcode_name",
    "IoResult",
    "LineResult",
    "Port",
    "VendorRange",
    "MAX_JOINTS",
    "MOTO_MAX_GROUPS",
    "HEADER_SIZE",
    "LENGTH_SIZE",
]

#: Joint arrays are always this wide on the wire (``JointData::MAX_NUM_JOINTS``, §1.4).
MAX_JOINTS = 10
#: MotoROS carries at most this many motion groups (``MOT_MAX_GR``, §8.1).
MOTO_MAX_GROUPS = 4
#: Size of the length prefix; it is an int32 in every build, float64 included (§1.1, §1.3).
LENGTH_SIZE = 4
#: Size of the header: msg_type, comm_type, reply_code, three int32 (§1.1).
HEADER_SIZE = 12


class MsgType(IntEnum):
    """Message type IDs (§2.1 standard registry, §8.1 Motoman extensions and this project's own
    extensions).

    This enum names the numbers of the standard and MotoROS messages and of this project's two
    extension messages (CARTESIAN_LINE and TOOL_POSE, in the freely assignable range 65001-65535)
    only. Which class decodes a number is the message registry's business
    (:func:`simple_message.messages.register`): a vendor message set registers its own numbers and
    names without being added here, and :func:`simple_message.messages.type_name` names any number,
    registered or listed here.
    """

    INVALID = 0
    PING = 1
    GET_VERSION = 2
    JOINT_POSITION = 10
    JOINT_TRAJ_PT = 11
    JOINT_TRAJ = 12
    STATUS = 13
    JOINT_TRAJ_PT_FULL = 14
    JOINT_FEEDBACK = 15
    READ_INPUT = 20
    WRITE_OUTPUT = 21
    MOTO_MOTION_CTRL = 2001
    MOTO_MOTION_REPLY = 2002
    READ_SINGLE_IO = 2003
    READ_SINGLE_IO_REPLY = 2004
    WRITE_SINGLE_IO = 2005
    WRITE_SINGLE_IO_REPLY = 2006
    READ_GROUP_IO = 2007
    READ_GROUP_IO_REPLY = 2008
    WRITE_GROUP_IO = 2009
    WRITE_GROUP_IO_REPLY = 2010
    MOTO_IOCTRL_REPLY = 2011
    #: Request and reply both use 2012 (MotoROS >= 1.8; older MotoROS headers numbered the
    #: M-register messages 2012-2015 with separate reply IDs, which nothing on the wire uses now).
    READ_MREGISTER = 2012
    #: Request and reply both use 2013.
    WRITE_MREGISTER = 2013
    JOINT_TRAJ_PT_FULL_EX = 2016
    JOINT_FEEDBACK_EX = 2017
    SELECT_TOOL = 2018
    GET_DH_PARAMETERS = 2020

    # This project's extensions. REP-I0004 leaves 65001-65535 freely assignable: no vendor block
    # and no REP number lives there (1000-2999 are the vendor blocks, 3000-65000 are reserved).
    # A peer that does not know them answers FAILURE or its own "unknown type" reply (docs/protocol.md).
    #: A Cartesian straight line of the TCP (request :class:`~.messages.CartesianLine`, reply
    #: :class:`~.messages.CartesianLineReply` with a :class:`LineResult`).
    CARTESIAN_LINE = 65001
    #: The actual TCP pose, a state-port topic sent only to clients that asked for it.
    TOOL_POSE = 65002

    # Aliases used in the REPs, the C++ library and the MotoROS sources.
    JOINT = 10
    ROBOT_STATUS = 13
    MOTO_READ_IO_BIT = 2003
    MOTO_READ_IO_BIT_REPLY = 2004
    MOTO_WRITE_IO_BIT = 2005
    MOTO_WRITE_IO_BIT_REPLY = 2006
    MOTO_READ_IO_GROUP = 2007
    MOTO_READ_IO_GROUP_REPLY = 2008
    MOTO_WRITE_IO_GROUP = 2009
    MOTO_WRITE_IO_GROUP_REPLY = 2010
    MOTO_READ_MREGISTER = 2012
    MOTO_WRITE_MREGISTER = 2013
    MOTO_JOINT_TRAJ_PT_FULL_EX = 2016
    MOTO_JOINT_FEEDBACK_EX = 2017
    MOTO_SELECT_TOOL = 2018
    MOTO_GET_DH_PARAMETERS = 2020


class VendorRange(IntEnum):
    """First ID of each vendor's 100-ID block (§2.1)."""

    SWRI = 1000
    UR = 1100
    ADEPT = 1200
    ABB = 1300
    FANUC = 1400
    EPSON = 1500
    STAUBLI = 1600
    MOTOMAN = 2000


class CommType(IntEnum):
    """Header ``comm_type`` (§3)."""

    INVALID = 0
    TOPIC = 1
    SERVICE_REQUEST = 2
    SERVICE_REPLY = 3


class ReplyCode(IntEnum):
    """Header ``reply_code`` (§3). ``INVALID`` also means "unused" (TOPIC and REQUEST)."""

    INVALID = 0
    SUCCESS = 1
    FAILURE = 2


class SpecialSeq(IntEnum):
    """Special ``sequence`` values of JOINT_TRAJ_PT and JOINT_TRAJ_PT_FULL (§4.1)."""

    START_TRAJECTORY_DOWNLOAD = -1
    START_TRAJECTORY_STREAMING = -2
    END_TRAJECTORY = -3
    STOP_TRAJECTORY = -4


class ValidFields(IntFlag):
    """``valid_fields`` bits of JOINT_TRAJ_PT_FULL, JOINT_FEEDBACK and the EX messages (§2.2)."""

    NONE = 0
    TIME = 0x01
    POSITION = 0x02
    VELOCITY = 0x04
    ACCELERATION = 0x08


class TriState(IntEnum):
    """STATUS tristate fields (§5)."""

    UNKNOWN = -1
    FALSE = 0
    TRUE = 1

    OFF = 0
    DISABLED = 0
    LOW = 0
    ON = 1
    ENABLED = 1
    HIGH = 1


class RobotMode(IntEnum):
    """STATUS ``mode`` (§5)."""

    UNKNOWN = -1
    MANUAL = 1
    AUTO = 2


class MotoCommand(IntEnum):
    """MOTO_MOTION_CTRL ``command`` values (§8.1)."""

    CHECK_MOTION_READY = 200101
    CHECK_QUEUE_CNT = 200102
    STOP_MOTION = 200111
    START_SERVOS = 200112
    STOP_SERVOS = 200113
    RESET_ALARM = 200114
    START_TRAJ_MODE = 200121
    STOP_TRAJ_MODE = 200122
    DISCONNECT = 200130


class MotoResult(IntEnum):
    """MOTO_MOTION_REPLY ``result`` (§8.1). Note that 0 means success, unlike ReplyCode."""

    SUCCESS = 0
    BUSY = 1
    FAILURE = 2
    INVALID = 3
    ALARM = 4
    NOT_READY = 5
    MP_FAILURE = 6

    TRUE = 0
    FALSE = 2


class InvalidSubcode(IntEnum):
    """MOTO_MOTION_REPLY subcodes that go with ``MotoResult.INVALID`` (§8.1)."""

    UNSPECIFIED = 3000
    MSGSIZE = 3001
    MSGHEADER = 3002
    MSGTYPE = 3003
    GROUPNO = 3004
    SEQUENCE = 3005
    COMMAND = 3006
    DATA = 3010
    DATA_START_POS = 3011
    DATA_POSITION = 3012
    DATA_SPEED = 3013
    DATA_ACCEL = 3014
    DATA_INSUFFICIENT = 3015
    DATA_TIME = 3016
    DATA_TOOLNO = 3017


class NotReadySubcode(IntEnum):
    """MOTO_MOTION_REPLY subcodes that go with ``MotoResult.NOT_READY`` (§8.1)."""

    UNSPECIFIED = 5000
    ALARM = 5001
    ERROR = 5002
    ESTOP = 5003
    NOT_PLAY = 5004
    NOT_REMOTE = 5005
    SERVO_OFF = 5006
    HOLD = 5007
    NOT_STARTED = 5008
    WAITING_ROS = 5009
    SKILLSEND = 5010
    PFL_ACTIVE = 5011
    INC_MOVE_ERROR = 5012


class IoResult(IntEnum):
    """``result_code`` of the MotoROS IO replies (§8.1, IoServer.h)."""

    OK = 0
    READ_ADDRESS_INVALID = 1001
    WRITE_ADDRESS_INVALID = 1002
    WRITE_VALUE_INVALID = 1003
    READ_API_ERROR = 1004
    WRITE_API_ERROR = 1005


class LineResult(IntEnum):
    """``result`` of a CARTESIAN_LINE (65001) reply (a project extension). 0 means accepted, like
    ``MotoResult``; 1-4 refuse the request itself, 10 and up the line's geometry or speed."""

    #: The line was accepted: queued, or for sequence -4 the stop was obeyed.
    ACCEPTED = 0
    #: The robot cannot move now: alarm, e-stop, drives off or the wrong mode.
    NOT_READY = 1
    #: A joint trajectory is under way.
    BUSY = 2
    #: A bad field: NaN or inf, quaternion norm not 1 within 1e-3, speed <= 0, blend radius < 0, unknown
    #: robot_id; or no speed profile can be made for the line.
    INVALID = 3
    #: A sequence number the controller does not accept (out of order, or a negative other than -4).
    SEQUENCE = 4
    #: No inverse kinematics solution reaches the target (or a point of the line).
    UNREACHABLE = 10
    #: The line passes through or too near a singularity.
    SINGULAR = 11
    #: The line would take a joint beyond its position limits, or the joints cannot follow it.
    JOINT_LIMIT = 12
    #: The line leaves the allowed workspace of the cell.
    WORKSPACE = 13
    #: The requested TCP speed is more than the controller allows.
    TCP_SPEED = 14


class Port(IntEnum):
    """Well-known TCP ports (§6)."""

    MOTION = 11000
    SYSTEM = 11001
    STATE = 11002
    IO = 11003
    MOTOROS_MOTION = 50240
    MOTOROS_STATE = 50241
    MOTOROS_IO = 50242


def moto_subcode_name(result: int, subcode: int) -> str | None:
    """The name of a MOTO_MOTION_REPLY ``subcode``, which depends on its ``result`` (INVALID and
    NOT_READY have their own tables); ``None`` when it has none (0, or an unknown value)."""
    kinds: tuple[type[IntEnum], ...] = (InvalidSubcode, NotReadySubcode)
    if result == MotoResult.INVALID:
        kinds = (InvalidSubcode,)
    elif result == MotoResult.NOT_READY:
        kinds = (NotReadySubcode,)
    for kind in kinds:
        try:
            return kind(subcode).name
        except ValueError:
            continue
    return None
