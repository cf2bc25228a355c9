"""Connection strings (trq_wire.connection): every form MAVSDK and pymavlink write, their
meaning, and bad strings refused with the string and the accepted forms named."""

from __future__ import annotations

import pytest

from trq_wire.connection import DEFAULT_BAUD, FORMS, Connection


def net(mode, host, port):
    return Connection(mode, host=host, port=port)


def ser(device, baud=DEFAULT_BAUD):
    return Connection("serial", device=device, baud=baud)


@pytest.mark.parametrize("text, expected", [
    # MAVSDK
    ("udpin://0.0.0.0:14540", net("udpin", "0.0.0.0", 14540)),
    ("udpout://192.168.1.10:14580", net("udpout", "192.168.1.10", 14580)),
    ("tcpin://127.0.0.1:5760", net("tcpin", "127.0.0.1", 5760)),
    ("tcpout://companion.local:5760", net("tcpout", "companion.local", 5760)),
    ("serial:///dev/ttyUSB0:921600", ser("/dev/ttyUSB0", 921600)),
    ("serial:///dev/ttyAMA0:57600", ser("/dev/ttyAMA0", 57600)),
    ("serial:///dev/ttyACM0", ser("/dev/ttyACM0")),
    ("serial://COM3:115200", ser("COM3", 115200)),
    ("udpin://[::1]:14540", net("udpin", "::1", 14540)),
    # pymavlink / MAVProxy
    ("udpin:127.0.0.1:14540", net("udpin", "127.0.0.1", 14540)),
    ("udpout:192.168.1.10:14580", net("udpout", "192.168.1.10", 14580)),
    ("udp:0.0.0.0:14550", net("udpin", "0.0.0.0", 14550)),
    ("tcp:127.0.0.1:5760", net("tcpout", "127.0.0.1", 5760)),
    ("tcpin:0.0.0.0:5760", net("tcpin", "0.0.0.0", 5760)),
    ("udpin:0.0.0.0:1", net("udpin", "0.0.0.0", 1)),
    ("udpout:localhost:65535", net("udpout", "localhost", 65535)),
    ("/dev/ttyUSB0,921600", ser("/dev/ttyUSB0", 921600)),
    ("/dev/serial/by-id/usb-Holybro_Pixhawk6C-if00,57600",
     ser("/dev/serial/by-id/usb-Holybro_Pixhawk6C-if00", 57600)),
    ("/dev/ttyACM0", ser("/dev/ttyACM0")),
    ("COM4,115200", ser("COM4", 115200)),
])
def test_every_form_parses_to_its_meaning(text, expected):
    assert Connection.parse(text) == expected


def test_the_positional_form_of_a_network_connection_still_works():
    assert Connection("udpin", "127.0.0.1", 14540) == net("udpin", "127.0.0.1", 14540)


@pytest.mark.parametrize("text, shown", [
    ("udpin:127.0.0.1:14540", "udpin:127.0.0.1:14540"),
    ("udp:127.0.0.1:14540", "udpin:127.0.0.1:14540"),
    ("tcpout://10.0.0.2:5760", "tcp:10.0.0.2:5760"),
    ("tcpin://0.0.0.0:5760", "tcpin:0.0.0.0:5760"),
    ("/dev/ttyUSB0", "serial:///dev/ttyUSB0:921600"),
    ("serial://COM3:57600", "serial://COM3:57600"),
])
def test_str_is_a_connection_string_that_parses_back(text, shown):
    c = Connection.parse(text)
    assert str(c) == shown and Connection.parse(str(c)) == c


def test_kinds():
    assert [Connection.parse(t).is_stream for t in
            ("udpin:h:1", "udpout:h:1", "tcp:h:1", "tcpin:h:1", "/dev/tty0")] == \
        [False, False, True, True, True]
    assert [Connection.parse(t).listens for t in
            ("udpin:h:1", "udpout:h:1", "tcp:h:1", "tcpin:h:1", "/dev/tty0")] == \
        [True, False, False, True, False]


@pytest.mark.parametrize("text", [
    "", "udpin", "udpin:", "udpin:127.0.0.1", "udpin::14540", "udpin:127.0.0.1:port",
    "udpin:127.0.0.1:-1", "udpin:127.0.0.1:0", "udpin:127.0.0.1:65536", "udpin:127.0.0.1:14540x",
    "udpin:127.0.0.1:\u00b2", "127.0.0.1:14540", "udpin://127.0.0.1", "udpin://:14540",
    "tcpout://127.0.0.1:99999", "tcp://127.0.0.1:5760", "udp://127.0.0.1:14540",
    "serial://", "serial:///dev/ttyUSB0:fast", "serial:///dev/ttyUSB0:0",
    "serial:///dev/ttyUSB0:-9600", "/dev/ttyUSB0,", "/dev/ttyUSB0,abc", "/dev/tty USB0",
    "/dev/ttyUSB0,921600,8N1", "ttyUSB0", "COM", "COMX,9600", "http://127.0.0.1:80",
    "udpin:127.0.0.1:14540 ", "udpin://host/x:1",
])
def test_bad_strings_are_refused_naming_the_string_and_the_forms(text):
    with pytest.raises(ValueError) as exc:
        Connection.parse(text)
    message = str(exc.value)
    assert repr(text) in message
    assert all(form in message for form in FORMS)


def test_not_a_string_is_refused():
    with pytest.raises(ValueError, match="expected one of"):
        Connection.parse(14540)
