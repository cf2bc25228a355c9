"""trq_wire: the arithmetic and file formats both daemons share, in one place each.

`sil_vehicle` (the simulated vehicle) and `trq_offboard` (the controller) are coupled only by
the wire: MAVLink over UDP, and the log files each writes beside the other. Whatever both ends
must compute identically lives here, once:

- `signing`: MAVLink 2 signing. In: a key file (64 hexadecimal characters), a pymavlink encoder,
  received frames as bytes. Out: the 32-byte secret (or `SigningKeyError`, naming the file but
  never the key), an encoder that signs what it packs, the signature appended to a frame
  packed by `frames` (the same bytes), a yes/no per received frame. Also the signing clock (10-microsecond units since 2015-01-01 UTC, from the wall clock).
- `actuators`: the scaling of throttles (percent) and tilts (rad) to and from the normalised
  values of SET_ACTUATOR_CONTROL_TARGET and ACTUATOR_OUTPUT_STATUS and the PWM microseconds of
  SERVO_OUTPUT_RAW, both directions, and the servo half-range a normalised tilt of 1 stands for.
- `logfile`: the CSV log format of flight.csv and controller.csv ('# key: value' header lines,
  a column-name line, one row per tick), its reader, and the MAVLink .tlog writer.
- `frames`: the MAVLink 2 frames of a control period's hot messages (the vehicle's telemetry
  in, SET_ACTUATOR_CONTROL_TARGET out) unpacked and packed with one struct each, into and from
  pymavlink's own message objects and byte for byte as pymavlink packs them; what it does not
  vouch for (another message, MAVLink 1, a bad checksum) is left to pymavlink. Also the frame
  checksum (X.25 with CRC_EXTRA) that `framing` checks.
- `cache`: the folder of generated and compiled code ($TRQ_CACHE_DIR, else ~/.cache/trq-ftc),
  the C compiler found on PATH, and the build of a shared library into it under a temporary
  name renamed into place.

What it never does: import either daemon package (tests/meta/test_boundaries.py reads the
imports), open a socket, hold a simulation clock, or pack or parse a MAVLink message other than
`frames`' few (pymavlink's generated dialect does that, and gives `frames` each message's layout;
each daemon's codec picks the fields). The wall clock is read only for MAVLink signing and the
.tlog time stamps, as those formats ask.
"""
