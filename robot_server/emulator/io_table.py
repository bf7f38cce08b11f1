"""An emulated Yaskawa IO table: the addresses and result codes of the MotoROS IO server.

MotoROS (``IoServer.c``/``IoServer.h`` of ros-industrial/motoman, docs/reference/protocol.md §8.1) reads and
writes the controller's IO through MotoPlus. Addresses are decimal with the bit number as the last
digit, which must be 0-7 (so 10017 is bit 7 of byte 1001); a group (byte) address is the bit address
divided by ten. M registers are M000-M999, given as 1000000 + n (or just n). Readable: the ranges
below; writable: universal outputs, network inputs, the interface panel and M000-M559. Values: a
bit is 0 or 1, a group 0-255, a register 0-65535. The ranges are the DX200/YRC1000 ones.

Everything starts at 0; a written value reads back. Inputs other than network inputs cannot be
written over the protocol, as on the real controller; the emulator's own :meth:`IoTable.set` can set
any of them (a test standing in for a sensor).
"""

from __future__ import annotations

from simple_message.constants import IoResult

__all__ = ["IoTable", "REGISTER_BASE"]

#: M registers are addressed as REGISTER_BASE + n
REGISTER_BASE = 1_000_000

_READABLE = (
    (10, 5127),  # universal inputs
    (10010, 15127),  # universal outputs
    (20010, 25127),  # external inputs
    (27010, 29567),  # network inputs
    (37010, 39567),  # network outputs
    (30010, 35127),  # external outputs
    (40010, 42567),  # specific inputs
    (50010, 55127),  # specific outputs
    (60010, 60647),  # interface panel
    (70010, 79997),  # auxiliary relays
    (80010, 85127),  # control status
    (87010, 87207),  # pseudo inputs
)
_WRITABLE = ((10010, 15127), (27010, 29567), (60010, 60647))
_REGISTER_READ_MAX = REGISTER_BASE + 999
_REGISTER_WRITE_MAX = REGISTER_BASE + 559


def _bit_ok(address: int, ranges: tuple[tuple[int, int], ...]) -> bool:
    return address % 10 <= 7 and any(lo <= address <= hi for lo, hi in ranges)


class IoTable:
    """Bits and M registers, with MotoROS's address checks (see the module doc)."""

    def __init__(self) -> None:
        self._bits: dict[int, int] = {}
        self._registers: dict[int, int] = {}

    # -- bits --------------------------------------------------------------------------------------

    def read_bit(self, address: int) -> tuple[int, IoResult]:
        if not _bit_ok(address, _READABLE):
            return 0, IoResult.READ_ADDRESS_INVALID
        return self._bits.get(address, 0), IoResult.OK

    def write_bit(self, address: int, value: int) -> IoResult:
        if not _bit_ok(address, _WRITABLE):
            return IoResult.WRITE_ADDRESS_INVALID
        if value not in (0, 1):
            return IoResult.WRITE_VALUE_INVALID
        self._bits[address] = value
        return IoResult.OK

    # -- groups (8 bits) ---------------------------------------------------------------------------

    def read_group(self, address: int) -> tuple[int, IoResult]:
        base = address * 10
        if not _bit_ok(base, _READABLE):
            return 0, IoResult.READ_ADDRESS_INVALID
        return sum(self._bits.get(base + i, 0) << i for i in range(8)), IoResult.OK

    def write_group(self, address: int, value: int) -> IoResult:
        base = address * 10
        if not _bit_ok(base, _WRITABLE):
            return IoResult.WRITE_ADDRESS_INVALID
        if not 0 <= value <= 0xFF:
            return IoResult.WRITE_VALUE_INVALID
        for i in range(8):
            self._bits[base + i] = (value >> i) & 1
        return IoResult.OK

    # -- M registers -------------------------------------------------------------------------------

    def read_register(self, number: int) -> tuple[int, IoResult]:
        address = number + REGISTER_BASE if number < REGISTER_BASE else number
        if not REGISTER_BASE <= address <= _REGISTER_READ_MAX:
            return 0, IoResult.READ_ADDRESS_INVALID
        return self._registers.get(address, 0), IoResult.OK

    def write_register(self, number: int, value: int) -> IoResult:
        address = number + REGISTER_BASE if number < REGISTER_BASE else number
        if not REGISTER_BASE <= address <= _REGISTER_WRITE_MAX:
            return IoResult.WRITE_ADDRESS_INVALID
        if not 0 <= value <= 0xFFFF:
            return IoResult.WRITE_VALUE_INVALID
        self._registers[address] = value
        return IoResult.OK

    def set(self, address: int, value: int) -> None:
        """Set any bit or register directly (the emulator's side: a sensor, a PLC)."""
        if address >= REGISTER_BASE:
            self._registers[address] = value
        else:
            self._bits[address] = value
