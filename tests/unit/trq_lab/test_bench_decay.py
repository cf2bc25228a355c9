"""trq_lab.bench.decay: the waits between calls (asleep or spinning, on an injected clock), the
order of the curves, the ratios to the call at once, and the command line's refusals."""

from __future__ import annotations

import pytest

from trq_lab.bench import decay


class _Clock:
    """A wall clock that advances 1 us per reading and by what `sleep` is given."""

    def __init__(self):
        self.t, self.readings, self.slept = 0.0, 0, []

    def __call__(self):
        self.readings += 1
        self.t += 1e-6
        return self.t

    def sleep(self, s):
        self.slept.append(s)
        self.t += s


def test_each_call_follows_its_wait_asleep_or_spinning():
    clock = _Clock()
    calls = []

    def step():                                 # 50 us a call, its start kept
        calls.append(clock.t)
        clock.t += 50e-6

    got = decay.after_wait(step, 1e-3, "sleep", 5, clock=clock, sleep=clock.sleep)
    assert len(calls) == 6 and clock.slept == [1e-3] * 5     # one untimed call first
    assert got == pytest.approx(51e-6)                       # the call and one clock reading
    calls.clear()
    before = clock.readings
    got = decay.after_wait(step, 1e-3, "spin", 3, clock=clock, sleep=clock.sleep)
    assert clock.readings - before > 3 * 900                 # the spin read the clock meanwhile
    assert all(b - a >= 1e-3 for a, b in zip(calls, calls[1:]))
    assert len(clock.slept) == 5                             # and never slept
    assert decay.after_wait(step, 0.0, "spin", 2, clock=clock, sleep=clock.sleep) == \
        pytest.approx(51e-6)
    with pytest.raises(ValueError, match="wait mode 'nap'"):
        decay.after_wait(step, 0.0, "nap", 1)
    with pytest.raises(ValueError, match="expected >= 0 and >= 1"):
        decay.after_wait(step, -1.0, "sleep", 1)


def test_the_curves_take_every_piece_mode_and_wait_within_each_repeat():
    order = []

    def measure(step, w, mode, samples):
        order.append((step(), mode, w))
        return (1.0 + 10 * w) * (2.0 if mode == "spin" else 1.0)

    pieces = {"a": lambda: "a", "b": lambda: "b"}
    got = decay.curves(pieces, [0.0, 0.003], samples=7, repeat=2, measure=measure)
    one = [(p, m, w) for p in "ab" for m in decay.WAIT_MODES for w in (0.0, 0.003)]
    assert order == one + one
    assert got["a"]["spin"][3.0] == [2.06, 2.06]
    text = decay.table(got)
    assert "| a | 3 | 1030000.0 | 1.03 | 2060000.0 | 1.03 |" in text
    assert "| b | 0 | 1000000.0 | 1.00 | 2000000.0 | 1.00 |" in text


@pytest.mark.parametrize("argv, said", [
    (["--waits-ms", "1,3"], "0 among them"),
    (["--waits-ms=-1,0"], "0 among them"),
    (["--waits-ms", "0,a"], "expected numbers"),
    (["--samples", "0"], "at least 1"),
    (["--controller", "nope"], "no params/controller/nope.yaml"),
])
def test_the_command_refuses_what_it_cannot_measure(argv, said, capsys):
    with pytest.raises(SystemExit) as exc:
        decay.main(argv)
    assert exc.value.code == 2 and said in capsys.readouterr().err


def test_a_controller_without_compiled_pieces_is_said(monkeypatch, capsys):
    def none(controller):
        raise RuntimeError(f"{controller}: no compiled piece to time")
    monkeypatch.setattr(decay, "_pieces", none)
    monkeypatch.setattr("trq_lab.bench.nmpc.machine_line", lambda: "machine")
    assert decay.main(["--controller", "trq_nmpc_eso"]) == 2
    assert "trq_nmpc_eso: no compiled piece" in capsys.readouterr().err
