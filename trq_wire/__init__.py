"""trq_wire: the arithmetic and file formats both daemons share, in one place each.

`sil_vehicle` (the simulated vehicle) and `trq_offboard` (the controller) are coupled only by
the wire: MAVLink over UDP, a serial line or TCP, and the log files each writes beside the other.
Whatever both ends must compute identically lives here, once:

    signing     MAVLink 2 signing. In: a key file (64 hexadecimal characters), a pymavlink
                encoder, received frames as bytes. Out: the 32-byte secret (or
                `SigningKeyError`, naming the file but never the key), an encoder that signs
                what it packs, the signature appended to a frame packed by `frames` (the same
                bytes), a yes/no per received frame; the signing clock (10-microsecond units
                since 2015-01-01 UTC, from the wall clock)
    actuators   the scaling of throttles (percent) and tilts (rad) to and from the normalised
                values of SET_ACTUATOR_CONTROL_TARGET and ACTUATOR_OUTPUT_STATUS and the PWM
                microseconds of SERVO_OUTPUT_RAW, both directions
    logfile     the CSV log format of flight.csv and controller.csv ('# key: value' header
                lines, a column-name line, one row per tick), its reader, the .tlog writer
    ulog        a CSV log's rows as PX4's ULog (controller.ulg: packed on board, not
                formatted) and its conversion to the same CSV on the ground (pyulog)
    frames      the MAVLink 2 frames of a control period's hot messages (the telemetry in,
                SET_ACTUATOR_CONTROL_TARGET out), unpacked and packed with one struct each,
                byte for byte as pymavlink packs them; the frame checksum (X.25, CRC_EXTRA)
    framing     MAVLink over a byte stream: the persistent frame parser that re-synchronises
                after garbage or a cut, frame sizes, a serial line's pace
    stream      the byte-stream transports on asyncio: a serial line (pyserial, driven with
                add_reader) and a TCP connection
    geodetic    the local NED frame around home and lat, lon degE7 / alt mm (flat earth): the
                vehicle forms a fix's fields with it, a companion turns them back into NED
    connection  connection strings as MAVSDK and pymavlink write them, parsed in one place
    mocap       the simulated motion-capture system's MAVLink identity (its system and
                component ids) and the estimator type the companion forwards its pose with
    cache       the folder of generated and compiled code ($TRQ_CACHE_DIR, else
                ~/.cache/trq-ftc), the C compiler found on PATH, and a shared library built
                into it under a temporary name renamed into place

What it never does: import either daemon package (tests/meta/test_imports.py reads the
imports), hold a simulation clock, or pack or parse a MAVLink message other than `frames'` few
(pymavlink's generated dialect does that, and gives `frames` each message's layout; each
daemon's codec picks the fields). The wall clock is read only for MAVLink signing and the .tlog
time stamps, as those formats ask.
"""
