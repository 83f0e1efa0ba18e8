"""A bench engine's first act (issue 42): the DAQ's outputs at 0 V and the amplifiers disabled as
each opens, before any sensor is opened (drivers.safe_state.SafeOpen, called by the factory)."""

from __future__ import annotations

import threading

from drivers.emulated.output_stage import ZERO_V
from drivers.factory import open_bench
from drivers.safe_state import SafeOpen

#: the threads that serve the wire bench's emulated devices: each exists once its device is open
SERIAL, CAN = "mdt693b-emulator", "can-gauge-emulator"


def _serving() -> dict[str, int]:
    names = [t.name for t in threading.enumerate()]
    return {SERIAL: names.count(SERIAL), CAN: names.count(CAN)}


class _Watching(SafeOpen):
    """A SafeOpen that also notes which emulated devices were serving at each step."""

    def __init__(self):
        super().__init__()
        self.serving: dict[str, dict[str, int]] = {}

    def _note(self, what: str) -> float:
        self.serving[what] = _serving()
        return super()._note(what)


def test_the_wire_bench_opens_output_first_and_its_first_write_is_0v():
    before = _serving()
    safe = _Watching()
    bench = open_bench("default_wire", seed=0, safe_open=safe)
    try:
        steps = [what for what, _ in safe.order]
        assert steps == [
            "DAQ opened",
            "DAQ outputs at 0 V",
            "amplifiers opened",
            "amplifiers disabled",
            "sensors opened",
        ]
        times = [at for _, at in safe.order]
        assert times == sorted(times) and safe.zero_monotonic_s == times[1]
        # at the 0 V write neither the amplifier's serial port nor the gauges' CAN bus was open
        assert safe.serving["DAQ outputs at 0 V"] == before
        assert safe.serving["amplifiers disabled"] == {SERIAL: before[SERIAL] + 1, CAN: before[CAN]}
        assert _serving() == {SERIAL: before[SERIAL] + 1, CAN: before[CAN] + 1}
        first = bench.parts.world.output_log.entries()[0]  # the world's first write: the 0 V
        assert first["event"] == "idle" and max(abs(v) for v in first["amplifier_v"].values()) < ZERO_V
        for amp in bench.parts.amplifiers.values():
            assert amp.status().enabled is False and abs(amp.status().output_v) < ZERO_V  # set-point 0 V
        assert safe.notes == []
    finally:
        bench.close()


def test_the_in_process_emulator_takes_the_same_order():
    safe = SafeOpen()
    bench = open_bench("default", seed=0, safe_open=safe)
    try:
        assert [what for what, _ in safe.order][1] == "DAQ outputs at 0 V"
        assert all(not amp.status().enabled for amp in bench.parts.amplifiers.values())
        assert bench.parts.world.output_log.entries()[0]["event"] == "idle"
    finally:
        bench.close()
    plain = open_bench("default", seed=0)  # without SafeOpen nothing is written at open
    try:
        assert plain.parts.world.output_log.entries() == []
    finally:
        plain.close()
