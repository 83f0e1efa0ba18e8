"""GET /api/bench's ``engine.safe_start`` tells the truth about the amplifiers: disabled during every
safe open; enabled again at 0 V on a first start (a last step says so), kept disabled after a restart
until the operator's reset (service.runtime.engine_process._open_at_zero)."""

from __future__ import annotations

import pytest

from service.runtime.engine_process import _open_at_zero


@pytest.mark.parametrize("restart", [False, True], ids=["first_start", "restart"])
def test_safe_start_says_whether_the_amplifiers_are_disabled_and_why(restart):
    bench, safe = _open_at_zero("default", 0, None, None, restart=restart)
    try:
        enabled = [amp.status().enabled for amp in bench.parts.amplifiers.values()]
        assert enabled == [not restart] * 2  # y and z
        assert safe["amplifiers_disabled"] is restart
        steps = [what for what, _ in safe["order"]]
        assert steps[:5] == [
            "DAQ opened",
            "DAQ outputs at 0 V",
            "amplifiers opened",
            "amplifiers disabled",
            "sensors opened",
        ]
        assert steps[5:] == ([] if restart else ["amplifiers enabled at 0 V"])
        assert ("until the operator's reset" if restart else "a first start has no fault") in safe["amplifiers_note"]
        assert max(abs(v) for v in bench.output_v().values()) < 0.01  # enabled or not, at 0 V
    finally:
        bench.close()
