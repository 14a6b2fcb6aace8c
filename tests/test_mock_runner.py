"""MockRunner: many UDP mock vehicles in one thread, each as alive as in a thread of its own; a mock
stopped, or one whose step fails, leaves the others flying."""

from __future__ import annotations

import threading
import time

from swarmctl.mavlink.network import MavlinkLink
from swarmctl.sim.autopilot import MockAutopilot
from swarmctl.sim.mock_runner import MockRunner
from tests.mavlink_support import FAST, HOME, our_threads, run, until


def _heard(link: MavlinkLink, sysid: int, since: float) -> bool:
    peer = link.peers.get(sysid)
    return peer is not None and peer.received_at.get("HEARTBEAT", 0.0) > since


def test_mocks_in_one_runner_all_answer_and_one_failing_or_stopped_leaves_the_rest():
    runner = MockRunner()
    mocks = [MockAutopilot(sysid=i, connect="udpin:127.0.0.1:0", home=HOME, **FAST).start(runner) for i in (1, 2, 3)]

    def broken(mock, dt):
        raise RuntimeError("a step hook's bug")

    async def scenario():
        links = [await MavlinkLink(f"udpout:127.0.0.1:{m.local_port}").open() for m in mocks]
        try:
            await until(lambda: all(_heard(link, m.sysid, 0.0) for link, m in zip(links, mocks)), timeout=10.0)
            threads = [t for t in our_threads() if t.startswith("mock-autopilot")]
            mocks[1].stop()
            mocks[2].step_hooks.append(broken)
            await until(lambda: mocks[2] not in runner._mocks)
            after = time.monotonic()
            await until(lambda: _heard(links[0], 1, after), timeout=10.0)
            silent = [not _heard(links[i], i + 1, after) for i in (1, 2)]
            return threads, silent
        finally:
            for link in links:
                await link.close()

    try:
        threads, silent = run(scenario())
    finally:
        for m in mocks:
            m.stop()
        runner.stop()
    assert threads == ["mock-autopilots"]
    assert silent == [True, True]
    assert "mock-autopilots" not in [t.name for t in threading.enumerate()]
