"""Typed, immutable simple_message messages and their exact wire encoding.

Each message type is a frozen dataclass whose fields are its body fields in wire order (names as in
docs/reference/protocol.md §2.2 and §8.1, in snake_case), followed by the keyword-only header fields
``comm_type`` and ``reply_code``. The class knows its ``MSG_TYPE``; the length prefix is computed.
Besides the standard and MotoROS messages there are the project's own two extension messages,
CARTESIAN_LINE (65001) and TOOL_POSE (65002), in the range REP-I0004 leaves freely assignable
(``docs/protocol.md``, "Project extensions").

Decoding is exact: for every accepted frame, :func:`encode` of the decoded message gives back the
same bytes (data in fields that ``valid_fields`` marks invalid is kept, not zeroed; the one exception,
float32 signalling NaNs before CPython 3.14, is below). Shapes that real peers send and that do not
fit a type's layout are still decoded (§3):

* :class:`HeaderOnly`: a SERVICE_REPLY (or anything) with an empty body, as ABB and the C++
  ``MessageManager`` send for acks and FAILURE replies;
* :class:`DummyReply`: a SERVICE_REPLY carrying REP-I0006's alternative ``dummy_data: real[10]``;
* :class:`RawMessage`: a message type this package does not know; it re-encodes byte for byte.

A known type whose body fits none of its layouts raises :class:`~..errors.MalformedMessage`.

Which classes decode which ``msg_type`` is kept in a public registry (:func:`register`,
:func:`unregister`, :func:`lookup`, :func:`type_name`, :func:`type_for_name`). The standard and
MotoROS messages and the project's extensions are registered at the end of this module, each with
the converters that turn its enum fields into enum members, in the order they always were (the
order of :data:`MESSAGE_CLASSES`, a public dict); a vendor message set is one module of
classes plus :func:`register` calls (see ``CONTRIBUTING.md`` and ``tests/test_sm_registry.py``).
Encoding, decoding, the JSON form (:mod:`..jsonio`) and the ``simple-message`` command all consult
the registry.

One bit pattern does not survive before CPython 3.14: a float32 *signalling* NaN (exponent all ones,
bit 22 clear, nonzero payload, e.g. ``0x7FA00000``) comes back quieted, with bit 22 set and every
other bit kept (``0x7FE00000``), because :mod:`struct` converts a float32 to a Python float (a C
double) with a C cast, which quiets it; CPython 3.14's :mod:`struct` keeps it signalling on 64-bit
builds (gh-130317). Keeping it on older versions would take a NaN check of every message decoded and
encoded (about a fifth of the time decoding one takes), for a value that is never a valid joint
value, so it is not done. float64 reals (every NaN included) and float32 quiet NaNs with any sign and
payload, infinities, subnormals and -0.0 re-encode exactly.

Joint arrays are 10 wide on the wire (§1.4); constructors accept any shorter sequence (list, tuple,
numpy array) and pad it with zeros.

This module is the catalogue: every name is imported from here, and the package's modules hold the
parts, by family. The machinery every type shares is :mod:`.base` (the :class:`Message` class, the
shapes, :func:`encode` and :func:`decode`), :mod:`.codec` (the precompiled structs of the fixed
layouts) and :mod:`.registry`; the messages themselves are :mod:`.standard` (docs/reference/protocol.md
§2.2), :mod:`.motoros` (§8.1) and :mod:`.extensions` (the project's own).
"""

from __future__ import annotations

# The names imported "as" themselves are importable from here, as they were before the package was
# split, though not public (__all__): the joint-array type, the families' limits, the fast decoding
# tables (.framing) and a class's codec (tests).
from ..constants import LineResult, MotoResult, RobotMode, TriState, ValidFields
from .base import ZEROS, DummyReply, Header, HeaderOnly, Message, RawMessage, decode, encode, read_header
from .base import Floats as Floats
from .codec import MESSAGE_CLASSES
from .codec import _codec as _codec
from .codec import fast_decoders as fast_decoders
from .extensions import CartesianLine, CartesianLineReply, ToolPose
from .motoros import DH_AXES as DH_AXES
from .motoros import (
    DhLink,
    ExGroup,
    GetDhParameters,
    GetDhParametersReply,
    IoCtrlReply,
    JointFeedbackEx,
    JointTrajPtFullEx,
    MotoMotionCtrl,
    MotoMotionReply,
    ReadGroupIo,
    ReadGroupIoReply,
    ReadMRegister,
    ReadMRegisterReply,
    ReadSingleIo,
    ReadSingleIoReply,
    SelectTool,
    WriteGroupIo,
    WriteGroupIoReply,
    WriteMRegister,
    WriteMRegisterReply,
    WriteSingleIo,
    WriteSingleIoReply,
)
from .registry import (
    Converter,
    MessageSpec,
    RegistrationError,
    lookup,
    message_class,
    message_types,
    register,
    scoped_registry,
    type_for_name,
    type_name,
    unregister,
)
from .standard import JOINT_TRAJ_MAX_POINTS as JOINT_TRAJ_MAX_POINTS
from .standard import (
    GetVersion,
    GetVersionReply,
    JointFeedback,
    JointPosition,
    JointTraj,
    JointTrajPt,
    JointTrajPtFull,
    Ping,
    Status,
    TrajPoint,
)

__all__ = [
    "Message",
    "Ping",
    "GetVersion",
    "GetVersionReply",
    "JointPosition",
    "JointTrajPt",
    "TrajPoint",
    "JointTraj",
    "Status",
    "JointTrajPtFull",
    "JointFeedback",
    "MotoMotionCtrl",
    "MotoMotionReply",
    "ReadSingleIo",
    "ReadSingleIoReply",
    "WriteSingleIo",
    "WriteSingleIoReply",
    "ReadGroupIo",
    "ReadGroupIoReply",
    "WriteGroupIo",
    "WriteGroupIoReply",
    "IoCtrlReply",
    "ReadMRegister",
    "ReadMRegisterReply",
    "WriteMRegister",
    "WriteMRegisterReply",
    "ExGroup",
    "JointTrajPtFullEx",
    "JointFeedbackEx",
    "SelectTool",
    "GetDhParameters",
    "GetDhParametersReply",
    "DhLink",
    "CartesianLine",
    "CartesianLineReply",
    "ToolPose",
    "HeaderOnly",
    "DummyReply",
    "RawMessage",
    "Header",
    "encode",
    "decode",
    "read_header",
    "message_class",
    "MESSAGE_CLASSES",
    "ZEROS",
    "Converter",
    "MessageSpec",
    "RegistrationError",
    "register",
    "unregister",
    "lookup",
    "message_types",
    "type_name",
    "type_for_name",
    "scoped_registry",
]


# ---------------------------------------------------------------------------------------------
# The standard and MotoROS messages and the project's extensions, with their enum fields' converters,
# in the order of registration they always had
# ---------------------------------------------------------------------------------------------

register(Ping)
register(JointPosition)
register(JointTrajPt)
register(JointTraj)
register(
    Status,
    converters={
        "drives_powered": TriState,
        "e_stopped": TriState,
        "in_error": TriState,
        "in_motion": TriState,
        "mode": RobotMode,
        "motion_possible": TriState,
    },
)
register(JointTrajPtFull, converters={"valid_fields": ValidFields})
register(JointFeedback, converters={"valid_fields": ValidFields})
register(MotoMotionCtrl)
register(MotoMotionReply, converters={"result": MotoResult})
register(ReadSingleIo)
register(ReadSingleIoReply)
register(WriteSingleIo)
register(WriteSingleIoReply)
register(ReadGroupIo)
register(ReadGroupIoReply)
register(WriteGroupIo)
register(WriteGroupIoReply)
register(IoCtrlReply)
register(JointTrajPtFullEx)
register(JointFeedbackEx)
register(SelectTool)
register(GetVersion, GetVersionReply)
register(ReadMRegister, ReadMRegisterReply)
register(WriteMRegister, WriteMRegisterReply)
register(GetDhParameters, GetDhParametersReply)

# The project's extensions (65001-65535, freely assignable)
register(CartesianLine, CartesianLineReply, converters={"result": LineResult})
register(ToolPose)
