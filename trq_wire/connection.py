"""Connection strings, as the MAVLink ecosystem writes them, parsed in one place.

Every program of this project that talks to a vehicle (the controller's `--connect`, the
ground-station tools' `--connect`) reads its string with `Connection.parse`:

    MAVSDK                     pymavlink / MAVProxy        meaning
    udpin://HOST:PORT          udpin:HOST:PORT, udp:H:P    listen for datagrams on HOST:PORT
    udpout://HOST:PORT         udpout:HOST:PORT            send datagrams to HOST:PORT
    tcpin://HOST:PORT          tcpin:HOST:PORT             accept a TCP connection on HOST:PORT
    tcpout://HOST:PORT         tcp:HOST:PORT               connect to the TCP server HOST:PORT
    serial://DEVICE[:BAUD]     DEVICE[,BAUD]               a serial line (BAUD default 921600)

A serial DEVICE is a path (`/dev/ttyUSB0`, so MAVSDK's `serial:///dev/ttyUSB0:921600`) or a
Windows port name (`COM3`). The result is a frozen record; a string of no accepted form raises
ValueError naming the string and listing the forms.
"""

from __future__ import annotations

from dataclasses import dataclass

DEFAULT_BAUD = 921600
NET_MODES = ("udpin", "udpout", "tcpin", "tcpout")
MODES = (*NET_MODES, "serial")

FORMS = ("udpin://HOST:PORT", "udpout://HOST:PORT", "tcpin://HOST:PORT", "tcpout://HOST:PORT",
         "serial://DEVICE[:BAUD]", "udpin:HOST:PORT", "udpout:HOST:PORT", "udp:HOST:PORT",
         "tcpin:HOST:PORT", "tcp:HOST:PORT", "DEVICE[,BAUD]")

# pymavlink's prefixes and what they mean in MAVSDK's terms
_SHORT = {"udpin": "udpin", "udpout": "udpout", "udp": "udpin", "tcpin": "tcpin", "tcp": "tcpout"}


@dataclass(frozen=True)
class Connection:
    """mode: udpin | udpout | tcpin | tcpout | serial. A network mode has host and port; serial
    has device and baud (8N1)."""
    mode: str
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 0

    @property
    def is_stream(self) -> bool:
        """A byte stream (TCP, serial): frames may span reads; a datagram holds whole frames."""
        return self.mode in ("tcpin", "tcpout", "serial")

    @property
    def listens(self) -> bool:
        """Waits for its peer to speak first (udpin) or to connect (tcpin)."""
        return self.mode in ("udpin", "tcpin")

    def __str__(self) -> str:
        """pymavlink's spelling (tcp: for tcpout), MAVSDK's for a serial line."""
        if self.mode == "serial":
            return f"serial://{self.device}:{self.baud}"
        return f"{'tcp' if self.mode == 'tcpout' else self.mode}:{self.host}:{self.port}"

    @staticmethod
    def parse(text: str) -> "Connection":
        result = _parse(text) if isinstance(text, str) else None
        if result is None:
            raise ValueError(f"connection {text!r}: expected one of " + ", ".join(FORMS)
                             + " (PORT 1..65535, BAUD a positive integer)")
        return result


def _port(text: str) -> int | None:
    if not (text.isascii() and text.isdigit()) or not 1 <= int(text) <= 65535:
        return None
    return int(text)


def _baud(text: str) -> int | None:
    if not (text.isascii() and text.isdigit()) or int(text) < 1:
        return None
    return int(text)


def _net(mode: str, rest: str) -> Connection | None:
    host, sep, port = rest.rpartition(":")
    if not sep or not host or "/" in host or any(c.isspace() for c in host):
        return None
    if host.startswith("[") and host.endswith("]"):      # [::1]:14540
        host = host[1:-1]
    p = _port(port)
    return None if p is None else Connection(mode, host=host, port=p)


def _serial(device: str, baud: str | None) -> Connection | None:
    if not device or any(c.isspace() for c in device) or ":" in device or "," in device:
        return None
    b = DEFAULT_BAUD if baud is None else _baud(baud)
    return None if b is None else Connection("serial", device=device, baud=b)


def _parse(text: str) -> Connection | None:
    scheme, sep, rest = text.partition("://")
    if sep:
        if scheme in NET_MODES:
            return _net(scheme, rest)
        if scheme == "serial":
            device, colon, baud = rest.rpartition(":")
            return _serial(device, baud) if colon else _serial(rest, None)
        return None
    prefix, colon, rest = text.partition(":")
    if colon and prefix in _SHORT:
        return _net(_SHORT[prefix], rest)
    # pymavlink's serial form: a device path (or COMn), an optional ",BAUD"
    device, comma, baud = text.partition(",")
    if device.startswith("/") or (device[:3].upper() == "COM" and device[3:].isdigit()):
        return _serial(device, baud if comma else None)
    return None
