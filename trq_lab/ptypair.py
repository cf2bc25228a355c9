"""A pair of pseudo-terminals joined back to back: a serial cable on one machine.

    with PtyPair() as pair:        # as `socat -d -d pty,raw,echo=0 pty,raw,echo=0`
        vehicle:    trq-sil-vehicle --offboard-serial {pair.a}
        controller: trq-offboard --connect serial://{pair.b}:921600

Two `os.openpty()`; each slave end (the device a program opens, `pair.a` and `pair.b`) is set
raw with echo off, and a copier thread moves the bytes between the master ends, both ways, as
they come; what an end cannot take is dropped (nothing is held back). The slave ends stay open
here too, so a program may close and reopen its device (a daemon restarting) without the pair
going away; pyserial empties an end's input queue when it opens it. A pty has no baud rate: the
line's pace, if any, is the writer's (the vehicle paces its writes in real time).
"""

from __future__ import annotations

import os
import selectors
import threading
import tty


class PtyPair:
    def __init__(self) -> None:
        self._fds: list[int] = []
        m_a, s_a = os.openpty()
        m_b, s_b = os.openpty()
        self._fds = [m_a, s_a, m_b, s_b]
        for fd in (s_a, s_b):
            tty.setraw(fd)                     # raw, and echo off (setraw clears ECHO)
        self.a, self.b = os.ttyname(s_a), os.ttyname(s_b)
        self._peer = {m_a: m_b, m_b: m_a}
        self.copied = {self.a: 0, self.b: 0}   # bytes written by the program on each end
        self.dropped = {self.a: 0, self.b: 0}  # bytes for an end that could not take them
        self._names = {m_a: self.a, m_b: self.b}
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._copy, name="ptypair", daemon=True)
        self._thread.start()

    def _copy(self) -> None:
        """Each read from one master is written to the other at once; what the other end's
        input queue cannot take (nobody has that end open, or its program has stalled) is
        dropped and counted, as a UART without flow control drops on overrun. No bytes are held
        here: a program that opens its end late reads the line from then on, not a backlog."""
        sel = selectors.DefaultSelector()
        for fd in self._peer:
            os.set_blocking(fd, False)
            sel.register(fd, selectors.EVENT_READ)
        sel.register(self._stop_r, selectors.EVENT_READ)
        try:
            while True:
                for key, _ in sel.select():
                    fd = key.fd
                    if fd == self._stop_r:
                        return
                    try:
                        data = os.read(fd, 65536)
                    except OSError:       # EAGAIN, or EIO: no program has this end open
                        continue
                    self.copied[self._names[fd]] += len(data)
                    try:
                        n = os.write(self._peer[fd], data)
                    except OSError:
                        n = 0
                    self.dropped[self._names[self._peer[fd]]] += len(data) - n
        finally:
            sel.close()

    def inject(self, end: str, data: bytes) -> None:
        """Bytes for the program on `end` (pair.a or pair.b) as if from the line: noise, a
        burst of garbage (tests). They may land between, or inside, the copier's frames."""
        master = next(m for m, name in self._names.items() if name == end)
        os.write(master, data)

    def close(self) -> None:
        if self._thread.is_alive():
            os.write(self._stop_w, b"x")
            self._thread.join(5)
        for fd in (*self._fds, self._stop_r, self._stop_w):
            try:
                os.close(fd)
            except OSError:
                pass
        self._fds = []

    def __enter__(self) -> "PtyPair":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
