"""MAVLink 2 frames of the few messages a control period carries, unpacked and packed with one
struct each (issue 18: the wire's part of a period at the cost of a struct unpack).

pymavlink's generated dialect stays the authority: each message's field order, struct format,
CRC_EXTRA and id are read from its classes at import, and what is built is pymavlink's own
message object, so a consumer cannot tell the two paths apart.

- `decode(frame)`: one whole frame (bytes) to the message pymavlink's `MAVLink.decode` makes of
  it (the same class, fields, header, msgbuf, payload and crc, unsigned as a parser without a
  key sees it), or None when this path does not vouch for the frame: not MAVLink 2, incompat
  flags other than signed, a message outside `HOT`, a payload longer than the message's, a bad
  checksum or a length that does not match. The caller then takes pymavlink's path, which keeps
  every counter and every refusal as it was.
- `decode_leading(data)`: the frames at the start of a datagram that `decode` vouches for, and
  the offset where it stopped; pymavlink parses the rest (from a frame boundary a fresh parser
  is where a parser of the whole datagram would be).
- `wanted` (both): the message ids whose messages the receiver reads. A frame of any other
  message of the dialect, MAVLink 2 and checked as `decode` checks one (length, incompat flags,
  checksum with its CRC_EXTRA), comes out as an `Unread`: its bytes and header, its message
  never built (a companion's link carries telemetry it does not read, which a log still keeps).
- `Packer(message_class)`: packs a message's field values into the frame pymavlink's `pack`
  makes with the same encoder (seq, system, component, MAVLink 2 trailing-zero truncation of
  the payload, checksum, and the signature of trq_wire.signing when the encoder signs, with
  the encoder's signing timestamp advanced as pymavlink advances it). `ActuatorTarget` is
  SET_ACTUATOR_CONTROL_TARGET with that pack.
- `crc(data, crc_extra)`: the X.25 checksum (CRC-16/MCRF4XX) with the message's CRC_EXTRA.

What it never does: read a socket, keep state between frames (a stream's framing is
trq_wire.framing's), or check a signature (trq_wire.signing's SignatureCheck does, on the
frame bytes, as for every other message).
"""

from __future__ import annotations

import struct
from collections import namedtuple
from operator import itemgetter

from pymavlink.dialects.v20 import common as mavlink

from trq_wire.signing import append_signature

try:                                     # pymavlink's own accelerator (a declared dependency)
    from fastcrc.crc16 import mcrf4xx as _mcrf4xx
except ImportError:                      # pragma: no cover - without it, pymavlink's pure CRC
    _mcrf4xx = None

__all__ = ["HOT", "ActuatorTarget", "Packer", "Unread", "crc", "decode", "decode_leading"]

MAGIC_V2 = 0xFD
HEADER = struct.Struct("<BBBBBBBHB")        # magic, len, incompat, compat, seq, sys, comp, id
HEADER_LEN, CHECKSUM_LEN, SIGNATURE_LEN = HEADER.size, 2, 13
SIGNED = mavlink.MAVLINK_IFLAG_SIGNED
_BYTE = [bytes((k,)) for k in range(256)]
_pack_checksum = struct.Struct("<H").pack

# the vehicle's telemetry on the offboard link (params/sim: telemetry.offboard) and the raw
# sensors a companion's fused filter asks for every period (trq_offboard/fused.py: the IMU and
# the position source); any other message takes pymavlink's path
HOT = (mavlink.MAVLink_odometry_message, mavlink.MAVLink_actuator_output_status_message,
       mavlink.MAVLink_heartbeat_message, mavlink.MAVLink_sys_status_message,
       mavlink.MAVLink_attitude_message, mavlink.MAVLink_local_position_ned_message,
       mavlink.MAVLink_servo_output_raw_message, mavlink.MAVLink_highres_imu_message,
       mavlink.MAVLink_att_pos_mocap_message, mavlink.MAVLink_gps_raw_int_message,
       mavlink.MAVLink_extended_sys_state_message)


def crc(data, crc_extra: int) -> int:
    """X.25 of `data` (a bytes-like object: the frame after the magic, up to the checksum)
    followed by the byte `crc_extra`."""
    if _mcrf4xx is None:                                # pragma: no cover
        x = mavlink.x25crc(bytes(data))
        x.accumulate(bytes((crc_extra,)))
        return x.crc
    c = _mcrf4xx(data, 0xFFFF)
    t = (crc_extra ^ c) & 0xFF                          # one more byte, as x25crc.accumulate
    t = (t ^ (t << 4)) & 0xFF
    return (c >> 8) ^ (t << 8) ^ (t << 3) ^ (t >> 4)


class _Unpacker:
    """One message class: its struct, and where each field's values sit in the unpacked tuple."""

    def __init__(self, cls) -> None:
        if "char" in cls.fieldtypes:
            raise ValueError(f"{cls.msgname}: text fields are left to pymavlink's decode")
        self.cls = cls
        self.struct = cls.unpacker
        self.size = cls.unpacker.size
        self.crc_extra = cls.crc_extra
        self.zeros = [bytes(self.size - n) for n in range(self.size + 1)]
        scalars: list[tuple[str, int]] = []
        self.arrays: list[tuple[str, int, int]] = []
        for name in cls.fieldnames:                    # declaration order, as pymavlink's init
            wire = cls.ordered_fieldnames.index(name)  # position in the size-sorted payload
            start = sum(cls.lengths[:wire])
            length = cls.lengths[wire]
            if length == 1:
                scalars.append((name, start))
            else:
                self.arrays.append((name, start, start + length))
        self.scalar_names = tuple(n for n, _ in scalars)
        get = itemgetter(*(i for _, i in scalars))
        self.scalars = get if len(scalars) > 1 else (lambda t: (get(t),))
        self.constant = {"_fieldnames": cls.fieldnames, "_type": cls.msgname, "_signed": False,
                         "_link_id": None, "_instances": None,
                         "_instance_field": cls.instance_field,
                         "_instance_offset": cls.instance_offset}


_UNPACKERS = {cls.id: _Unpacker(cls) for cls in HOT}
# every message of the dialect: what checking its frame needs, for the frames of `Unread`
_Check = namedtuple("_Check", "crc_extra size name")
_CHECKS = {i: _Check(cls.crc_extra, cls.unpacker.size, cls.msgname)
           for i, cls in mavlink.mavlink_map.items()}
_Header = mavlink.MAVLink_header
_unpack_header = HEADER.unpack_from


class Unread:
    """A whole, checked MAVLink 2 frame of a message its receiver does not read (`wanted`):
    what a link's checks and its log ask of a message (system, component, id, type name, the
    frame's bytes, signature included), its fields never unpacked."""
    __slots__ = ("_msgbuf", "_id", "_system", "_component", "_type")

    def __init__(self, msgbuf: bytearray, msg_id: int, system: int, component: int,
                 name: str) -> None:
        self._msgbuf, self._id, self._system, self._component, self._type = \
            msgbuf, msg_id, system, component, name

    def get_msgbuf(self) -> bytearray:
        return self._msgbuf

    def get_msgId(self) -> int:
        return self._id

    def get_srcSystem(self) -> int:
        return self._system

    def get_srcComponent(self) -> int:
        return self._component

    def get_type(self) -> str:
        return self._type


def _frame_at(data, i: int, n: int, mlen: int, flags: int, crc_extra: int):
    """The bytes of the frame at data[i:] (its header read: payload length, incompat flags)
    when it is whole and its checksum right with `crc_extra`, else None."""
    body = HEADER_LEN + mlen                # the checksum's offset in the frame
    end = body + CHECKSUM_LEN + (SIGNATURE_LEN if flags else 0)
    if i + end > n:
        return None
    msgbuf = bytearray(data[i:i + end] if i or end != n else data)
    if crc(msgbuf[1:body], crc_extra) != msgbuf[body] | msgbuf[body + 1] << 8:
        return None
    return msgbuf


def _decode_at(data, i: int, n: int, wanted=None):
    """The frame at data[i:] and the offset after it, or (None, i)."""
    if n - i < HEADER_LEN + CHECKSUM_LEN or data[i] != MAGIC_V2:
        return None, i
    _, mlen, flags, compat, seq, system, component, id_low, id_high = _unpack_header(data, i)
    msg_id = id_low | id_high << 16
    unread = wanted is not None and msg_id not in wanted  # checked as the others, not unpacked
    u = _CHECKS.get(msg_id) if unread else _UNPACKERS.get(msg_id)
    if u is None or flags & ~SIGNED or mlen > u.size:
        return None, i
    msgbuf = _frame_at(data, i, n, mlen, flags, u.crc_extra)
    if msgbuf is None:
        return None, i
    if unread:
        return Unread(msgbuf, msg_id, system, component, u.name), i + len(msgbuf)
    body = HEADER_LEN + mlen
    if mlen == u.size:
        values = u.struct.unpack_from(msgbuf, HEADER_LEN)
    else:                                   # MAVLink 2 dropped the payload's trailing zeros
        values = u.struct.unpack(msgbuf[HEADER_LEN:body] + u.zeros[mlen])
    fields = u.constant.copy()
    fields.update(zip(u.scalar_names, u.scalars(values)))
    for name, a, b in u.arrays:
        fields[name] = list(values[a:b])
    # pymavlink's MAVLink_header with its attributes in its __init__'s order, without the
    # Python call
    header = object.__new__(_Header)
    header.__dict__ = {"mlen": mlen, "seq": seq, "srcSystem": system,
                       "srcComponent": component, "msgId": u.cls.id,
                       "incompat_flags": flags, "compat_flags": compat}
    fields["_header"] = header
    fields["_msgbuf"] = msgbuf
    fields["_payload"] = msgbuf[6:body]     # as pymavlink's decode sets it
    fields["_crc"] = msgbuf[body] | msgbuf[body + 1] << 8
    msg = object.__new__(u.cls)
    msg.__dict__ = fields
    return msg, i + len(msgbuf)


def decode(frame: bytes, wanted=None):
    """The message of one whole frame (an `Unread` for an id outside `wanted`), or None if
    this path does not vouch for it."""
    msg, end = _decode_at(frame, 0, len(frame), wanted)
    return msg if end == len(frame) else None


def decode_leading(data: bytes, wanted=None) -> tuple[list, int]:
    """The messages of the frames at the start of `data` that `decode` vouches for (an
    `Unread` for an id outside `wanted`), and the offset of the first byte it did not take."""
    out = []
    i, n = 0, len(data)
    while i < n:
        msg, i2 = _decode_at(data, i, n, wanted)
        if msg is None:
            break
        out.append(msg)
        i = i2
    return out, i


class Packer:
    """Frames of one message class, packed as pymavlink's `pack` packs them (MAVLink 2)."""

    def __init__(self, cls) -> None:
        self.cls = cls
        self.size = cls.unpacker.size
        self.crc_extra = cls.crc_extra
        # header and the whole payload in one struct; the length byte is set after truncation
        self.struct = struct.Struct(HEADER.format + cls.unpacker.format.lstrip("<"))
        self.id_low, self.id_high = cls.id & 0xFFFF, cls.id >> 16

    def pack(self, mav: mavlink.MAVLink, *payload) -> bytes:
        """The frame of these field values in wire (size-sorted) order, arrays flattened, with
        `mav`'s seq, system, component and signing (which advances its signing timestamp)."""
        signing = mav.signing
        signed = signing.sign_outgoing
        frame = self.struct.pack(MAGIC_V2, self.size, SIGNED if signed else 0, 0, mav.seq,
                                 mav.srcSystem, mav.srcComponent, self.id_low, self.id_high,
                                 *payload)
        # MAVLink 2 drops the payload's trailing zeros (pymavlink keeps at least one byte)
        plen = len(frame.rstrip(b"\x00")) - HEADER_LEN
        if plen < self.size:
            plen = plen if plen > 1 else 1
            frame = b"\xfd" + _BYTE[plen] + frame[2:HEADER_LEN + plen]
        frame += _pack_checksum(crc(frame[1:], self.crc_extra))
        if signed:
            signed_frame = bytearray(frame)
            append_signature(signed_frame, signing.secret_key, signing.link_id,
                             signing.timestamp)
            signing.timestamp += 1
            return bytes(signed_frame)
        return frame


class ActuatorTarget(mavlink.MAVLink_set_actuator_control_target_message):
    """pymavlink's SET_ACTUATOR_CONTROL_TARGET (the same fields, type and checks on pack), packed
    by one prebuilt struct: the same bytes as pymavlink's own pack. After a pack its msgbuf and
    crc are the frame's, as pymavlink leaves them."""

    _packer = Packer(mavlink.MAVLink_set_actuator_control_target_message)

    def pack(self, mav: mavlink.MAVLink, force_mavlink1: bool = False) -> bytes:
        if force_mavlink1:
            return super().pack(mav, force_mavlink1)
        c = self.controls
        data = self._packer.pack(mav, self.time_usec, c[0], c[1], c[2], c[3], c[4], c[5], c[6],
                                 c[7], self.group_mlx, self.target_system, self.target_component)
        self._msgbuf = bytearray(data)
        checksum = HEADER_LEN + data[1]
        self._crc = data[checksum] | data[checksum + 1] << 8
        return data
