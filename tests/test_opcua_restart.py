"""rafi deploy stopped and started again against the real local OPC UA server
(tests/opcua_server.py): in every phase - referencing, ok, hold, ramp, and after an outage -
the value on the server goes on within the rate limit from what it held, and the warm offset
is kept (docs/deploy.md, "A restart").

Every value the two processes wrote is read back from the server and compared with the oracle
of the limit rules (tests/test_live.py ``expected_commands`` with ``restarts``). The processes
run with injected clocks: the second one's loop clock starts elsewhere (a new process), the
wall clock of the session file goes on, and the "sleep" between cycles puts the next sample on
the server, so nothing depends on timing.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("asyncua")

from opcua_server import SinumerikLikeServer, as_read  # noqa: E402
from test_live import DEPLOY, DT, artefact, expected_commands, make_registry, scenario  # noqa: E402
from test_opcua import ENV, INCR, SIGN, sd_writes, write_config  # noqa: E402

from rafi.deploy import live_cli  # noqa: E402

WALL0 = 1_800_000_000.0


def _phase_cut(phase: str) -> int:
    """A sample index of the scenario well inside ``phase`` (by the oracle, not the code)."""
    rows = scenario()
    statuses = [s for _, s in expected_commands([(DT * i, n, t) for i, (n, t) in enumerate(rows)])]
    return next(
        i for i in range(3, len(statuses)) if statuses[i] == statuses[i - 1] == statuses[i - 2] == phase
    )


class _Process:
    """One ``rafi deploy`` process (built as the CLI builds it) with its own loop clock."""

    def __init__(self, args, server, wall: list, origin: float, feed):
        self.log: list[str] = []
        self.loop, self.link = live_cli.build(args, log=self.log.append, environ=ENV)
        self.clock = [origin]
        self.loop.clock = self.link.clock = lambda: self.clock[0]
        self.loop.session.wall = lambda: wall[0]
        self.wall, self.feed, self.server = wall, feed, server

    def run(self, cycles: int, *, on_cycle=None) -> None:
        count = [0]

        def sleep(seconds):
            self.clock[0] += seconds
            self.wall[0] += seconds
            count[0] += 1
            if on_cycle is not None:
                on_cycle(count[0])
            else:
                self.feed()

        self.loop.sleep = sleep
        try:
            self.link.connect()
            self.loop.run(max_cycles=cycles)
        finally:
            self.link.close()


@pytest.mark.parametrize("phase", ["referencing", "ok", "hold", "ramp", "after an outage"])
def test_a_restart_goes_on_from_the_value_on_the_server_with_the_kept_reference(tmp_path, phase):
    rows = scenario()
    outage = 4 if phase == "after an outage" else 0
    cut = _phase_cut("ok") + 6 if outage else _phase_cut(phase)
    srv = SinumerikLikeServer(axis=3).start()
    wall = [WALL0]
    delivered: list = []
    fed = [0]

    def feed():
        if fed[0] < len(rows):
            speed, temps = rows[fed[0]]
            srv.set_inputs(speed, temps)
            delivered.append((wall[0] - WALL0, speed, as_read(temps)))
            fed[0] += 1

    try:
        make_registry(tmp_path / "results" / "m1" / "registry", artefact())
        # the scenario's rises are tenths of a K (its model has 30 um/K): a narrow cold band
        args = write_config(tmp_path, srv, deploy={"cold_band_k": 0.05})
        first = _Process(args, srv, wall, origin=5000.0, feed=feed)
        feed()

        def first_cycles(count):
            if count < cut:
                feed()
            elif count == cut:
                srv.stop()  # the outage: the process ends while the controller is away

        if outage:
            first.run(cut + outage, on_cycle=first_cycles)
            srv.start()
            assert first.loop.outage_cycles == outage
        else:
            first.run(cut)
        written_first = [SIGN * v * 1000 for v in sd_writes(srv)]
        held = written_first[-1]
        wall[0] += DT  # the new process starts one period later
        second = _Process(args, srv, wall, origin=9.0e4, feed=feed)
        feed()
        second.run(len(rows) - cut)
        got = [SIGN * v * 1000 for v in sd_writes(srv)]
    finally:
        srv.close()
    assert len(written_first) == cut and len(got) == len(rows) == len(delivered)
    expected = expected_commands(delivered, restarts={cut: held})
    assert got == pytest.approx([c for c, _ in expected], abs=0.5e3 / INCR + 1e-9)
    # bumpless across the restart: the first write is the value held, every step within the rate
    assert got[cut] == pytest.approx(held, abs=1e-9)
    assert np.abs(np.diff([0.0, *got])).max() <= DEPLOY["rate_um_per_s"] * DT + 1e3 / INCR
    kept = [line for line in second.log if line.startswith("reference kept from the session of")]
    assert len(kept) == 1, second.log
    if phase != "referencing":  # the warm offset is kept: no second reference window
        assert expected[cut][1] != "referencing" and "the machine is warm" in kept[0]
        assert all(s != "referencing" for _, s in expected[cut:])
    if phase in ("ok", "after an outage"):
        assert abs(held) > 3.0 and abs(got[cut + 3] - held) <= 3 * DEPLOY["rate_um_per_s"] * DT + 1e-6
