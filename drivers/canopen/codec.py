"""The PDO codec both sides of the link share: which objects the host maps into which PDO, how a
mapped object is packed (``struct`` codes: the signed objects of CiA 402 signed, everything else
unsigned, little-endian as CiA 301 sends it), one mapped PDO as one ``struct`` (the whole frame
packed or unpacked in one call) and the drive side's view of the same mapping, read back from its
object dictionary.

The host (drivers.canopen.backend) maps :data:`RPDO_TARGET` and :data:`TPDO_MAPS` over SDO
at start-up; the simulated drive (drivers.canopen.drive_sim) reads back what was mapped
(:func:`pdo_plan`) and packs its TPDOs from its data store (:func:`stored_bytes`). Nothing here
talks to a bus or allocates per cycle beyond what ``struct`` returns.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

__all__ = ["RPDO_TARGET", "TPDO_MAPS", "SYNC_ECHO", "SYNC_OVERFLOW", "TIP_KEY", "TIP_FMT", "TIP_PROFILE",
           "SIGNED", "struct_code", "pdo_struct", "pdo_plan", "stored_bytes", "store", "Scaling", "NM", "PER_MILLE"]

# the target object of each mode in RPDO1 (after the controlword 0x6040)
RPDO_TARGET = {"csp": (0x607A, 0, 32), "csv": (0x60FF, 0, 32), "cst": (0x6071, 0, 16)}
# the host's TPDO mapping: statusword, position and torque actual; velocity actual and the linear
# encoder 0x60E4.1; the tip 0x60E4.2, the error code and the SYNC counter echo
TPDO_MAPS = [
    [(0x6041, 0, 16), (0x6064, 0, 32), (0x6077, 0, 16)],
    [(0x606C, 0, 32), (0x60E4, 1, 32)],
    [(0x60E4, 2, 32), (0x603F, 0, 16), (0x2001, 0, 8)],
]
SYNC_ECHO = 0x2001          # the drive's copy of the SYNC counter, in the last TPDO of each answer
SYNC_OVERFLOW = 240         # 0x1019: the SYNC carries a counter 1..240

TIP_PROFILE = 406            # 0x1000 bits 0..15 of the tip sensor node
TIP_KEY = "tip"              # the tip sensor's position value in the received values
TIP_FMT = struct.Struct("<i")  # the tip sensor's TPDO1: position value 0x6004

# the objects of the PDOs that are signed (positions, speeds, torques); every other one is unsigned
SIGNED = frozenset({0x6064, 0x606C, 0x60E4, 0x6077, 0x6071, 0x607A, 0x60FF})
_SIZE_CODE = {1: "b", 2: "h", 4: "i"}

NM = 1e-9           # m per count of 0x60E4 (additional position actual values: the linear scales, nm)
PER_MILLE = 1e-3    # 0x6071 / 0x6077 are per mille of the rated torque


@dataclass(frozen=True)
class Scaling:
    """The drive's units against SI, the one place the host converts them (real-time: plain
    arithmetic, nothing allocated beyond the float returned). ``counts_per_m``: motor encoder
    counts per metre of the load (0x6064, 0x606C, 0x607A); ``rated``: the rated torque (N m, or N on
    a linear motor), the unit of 0x6071/0x6077 in per mille; ``speed_scale``: controller speed units
    per m/s (the velocity target of csv)."""
    counts_per_m: float
    rated: float
    speed_scale: float

    def position(self, counts) -> float:
        """0x6064 / 0x606C (counts, counts/s) -> m, m/s."""
        return counts / self.counts_per_m

    def table(self, counts) -> float:
        """0x60E4.1 / .2 (nm) -> m."""
        return counts * NM

    def torque(self, per_mille) -> float:
        """0x6077 (per mille of the rated torque) -> N m (N)."""
        return per_mille * PER_MILLE * self.rated

    def position_target(self, position: float) -> int:
        """m -> 0x607A (counts)."""
        return int(round(position * self.counts_per_m))

    def speed_target(self, speed: float) -> int:
        """controller speed units -> 0x60FF (counts/s)."""
        return int(round(speed / self.speed_scale * self.counts_per_m))

    def torque_target(self, output: float) -> int:
        """N m (N) -> 0x6071 (per mille of the rated torque, within its 16 bits)."""
        return max(-32768, min(32767, int(round(output / self.rated * 1e3))))


def struct_code(index: int, bits: int) -> str:
    """The ``struct`` code of a mapped object of ``bits`` bits (8, 16 or 32)."""
    code = _SIZE_CODE[bits // 8]
    return code if index in SIGNED else code.upper()


def pdo_struct(entries) -> tuple[struct.Struct, tuple]:
    """One mapped PDO (``[(index, sub, bits)]``, as the host maps it) as one ``struct`` and the keys
    of its values (the index; ``(index, sub)`` for the two inputs of 0x60E4)."""
    fmt = "<" + "".join(struct_code(i, b) for i, _, b in entries)
    return struct.Struct(fmt), tuple(i if i != 0x60E4 else (i, s) for i, s, _ in entries)


def pdo_plan(node, comm_base: int, map_base: int, n: int):
    """The drive side: (COB-ID or None when disabled, [(index, sub, bytes, struct code)]) of PDO
    ``n`` as mapped in ``node``'s object dictionary (communication ``comm_base``, mapping
    ``map_base``: 0x1400/0x1600 receive, 0x1800/0x1A00 transmit)."""
    comm, mapping = node.sdo[comm_base + n], node.sdo[map_base + n]
    cob = comm[1].raw
    entries = []
    for k in range(1, mapping[0].raw + 1):
        entry = mapping[k].raw
        index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        entries.append((index, sub, bits // 8, struct_code(index, bits)))
    return (None if cob & 0x80000000 or not entries else cob & 0x7FF), entries


def stored_bytes(node, index: int, sub: int) -> bytes:
    """The stored bytes of an object of a ``canopen.LocalNode`` (its data store, else the
    dictionary's default)."""
    try:
        return node.data_store[index][sub]
    except KeyError:
        return node.get_data(index, sub)


def store(node, index: int, sub: int, code: str, value: int) -> None:
    """Write an object straight into a ``canopen.LocalNode``'s data store (no SDO layer: the objects
    a drive updates every cycle)."""
    node.data_store.setdefault(index, {})[sub] = struct.pack("<" + code, value)
