"""The emulated output stage (drivers/emulated/output_stage.py): it holds what was last driven, and its
watchdog drives every output to 0 V by itself when no pet comes within the timeout."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time

from drivers.emulated.output_stage import ZERO_V, OutputStageLink, StageState, _take
from drivers.safe_state import zero_outputs
from tests.support.live_server import ROOT


def test_the_stage_holds_levels_until_its_watchdog_expires():
    s = StageState()
    s.set(10.0, [2.5, 3.0], [50.0, 60.0])
    assert s.amp_v == [50.0, 60.0] and s.zero_since_s is None
    assert s.arm(10.0, 0.5) == 0.5
    s.tick(10.49)
    assert s.amp_v == [50.0, 60.0] and s.expired is None  # 0.49 s without a pet: still held
    assert s.pet(10.49) is None
    s.tick(10.98)
    assert s.expired is None
    s.tick(11.0)  # noticed 0.51 s after the last pet: the device's timer fired at 10.99
    assert s.amp_v == [0.0, 0.0] and s.ao_v == [0.0, 0.0] and s.zero_since_s == 10.99
    assert s.expired_at_s == 10.99 and abs(s.acted_late_s - 0.01) < 1e-9
    assert "no pet within 0.5 s" in s.expired and s.pet(11.1) == s.expired
    s.set(11.2, [1.0, 1.0], [20.0, 20.0])  # an expired watchdog holds the expiration states
    assert s.amp_v == [0.0, 0.0]
    assert s.clear(11.3) is True
    s.set(11.3, [1.0, 1.0], [20.0, 20.0])
    assert s.amp_v == [20.0, 20.0] and s.zero_since_s is None


def _backlog(messages: list[dict]) -> socket.socket:
    """A stage's socket with ``messages`` waiting on it, as after the stage was starved of the core."""
    stage = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    stage.bind(("127.0.0.1", 0))
    stage.setblocking(False)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as host:
        for message in messages:
            host.sendto(json.dumps(message).encode(), stage.getsockname())
    time.sleep(0.02)  # loopback delivers at once; the margin is for a loaded machine
    return stage


def test_a_starved_stage_counts_each_pet_when_it_was_sent():
    """The stage reads a 1.2 s backlog at once: pets 0.4 s apart keep it alive; a 0.6 s gap expires
    it at exactly the last pet + 0.5 s, and the later pet does not undo it."""
    t0 = time.monotonic() - 5.0
    arm = {"op": "arm", "timeout_s": 0.5, "at": t0}
    setting = {"op": "set", "ao": [2.0, 2.0], "amp": [40.0, 40.0], "at": t0 + 0.1}
    kept = [arm, setting] + [{"op": "pet", "at": t0 + 0.4 * k} for k in (1, 2, 3)]
    state = StageState()
    with _backlog(kept) as sock:
        _take(sock, state)
    state.tick(t0 + 1.6)  # 0.4 s after the last pet
    assert state.expired is None and state.amp_v == [40.0, 40.0]
    state.tick(t0 + 1.7)
    assert state.expired_at_s == state.zero_since_s and abs(state.expired_at_s - (t0 + 1.7)) < 1e-9
    late = [arm, setting, {"op": "pet", "at": t0 + 0.4}, {"op": "pet", "at": t0 + 1.0}]
    state = StageState()
    with _backlog(late) as sock:
        _take(sock, state)
    assert abs(state.expired_at_s - (t0 + 0.9)) < 1e-9 and state.amp_v == [0.0, 0.0]
    assert abs(state.acted_late_s - 0.1) < 1e-9  # noticed with the late pet, dated at the deadline


def test_a_stage_without_a_watchdog_holds_for_ever():
    s = StageState(honour_watchdog=False)
    s.set(0.0, [2.0, 2.0], [40.0, 40.0])
    assert s.arm(0.0, 0.5) == 0.5  # the driver arms it, but its expiry never acts
    s.tick(1000.0)
    assert s.amp_v == [40.0, 40.0] and s.expired is None


def test_the_stage_process_zeroes_by_itself_and_takes_a_zero_from_another_process():
    proc = subprocess.Popen(
        [sys.executable, "-m", "drivers.emulated.output_stage"], cwd=ROOT, stdout=subprocess.PIPE, text=True
    )
    try:
        address = proc.stdout.readline().strip()
        link = OutputStageLink(address)
        link.send_levels([3.0, 3.0], [60.0, 60.0])
        time.sleep(0.05)
        assert link.call("state")["amplifier_v"] == [60.0, 60.0]
        sent_at = time.monotonic()
        assert link.call("arm", timeout_s=0.2)["armed_s"] == 0.2
        armed_at = time.monotonic()
        deadline = armed_at + 3.0
        while (state := link.call("state"))["zero_since_monotonic_s"] is None:
            assert time.monotonic() < deadline, state
            time.sleep(0.01)
        # nobody wrote it: the stage did, at its deadline, 0.2 s after the arm was sent
        assert sent_at + 0.2 <= state["zero_since_monotonic_s"] <= armed_at + 0.2, state
        assert "watchdog expired" in state["events"][-1][1]
        link.call("clear")
        link.send_levels([3.0, 3.0], [60.0, 60.0])
        link.call("honour", on=False)
        time.sleep(0.05)
        notes = zero_outputs({"emulator": {"output_stage": address}})
        state = link.call("state")
        assert notes == [f"emulated output stage at {address}: 0 V written"]
        assert max(state["amplifier_v"]) < ZERO_V and state["events"][-1][1] == "0 V (written by the supervisor)"
    finally:
        proc.kill()
        proc.wait(10)


def test_zero_outputs_says_why_it_could_not_write():
    notes = zero_outputs({"emulator": {"output_stage": "127.0.0.1:9"}})  # nothing answers there
    assert len(notes) == 1 and notes[0].startswith("emulated output stage: 0 V not written from here")
    assert zero_outputs({"emulator": {}}) == []  # the in-process emulator: nothing outlives the engine
