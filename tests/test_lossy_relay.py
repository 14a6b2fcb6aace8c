"""The lossy UDP relay (swarmctl.sim.relay) over real sockets with real MAVLink frames: exactly once
without faults, loss and duplicate rates within their bounds for a fixed seed (and the same fates for
the same seed), delays applied (and reordering), the sockets closed at stop; `swarmctl mock-relay`."""

from __future__ import annotations

import math
import select
import socket
import threading
import time
from collections import Counter

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from swarmctl.cli import main
from swarmctl.sim.relay import LinkFaults, LossyRelay

MAV = mavlink2
WAIT_S = 5.0  # the longest any condition here is waited for


def frame(n: int, size: int = 16) -> bytes:
    """A real MAVLink 2 TUNNEL frame numbered n (its payload starts with n), of `size` payload bytes."""
    mav = MAV.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.seq = n % 256
    body = n.to_bytes(4, "little") + bytes(max(0, size - 4))
    msg = mav.tunnel_encode(0, 0, 32800, len(body), list(body) + [0] * (128 - len(body)))
    return bytes(msg.pack(mav))


def number(data: bytes) -> int:
    """The n of frame(n), parsed back with pymavlink."""
    msg = MAV.MAVLink(None).parse_char(data)
    assert msg is not None and msg.get_type() == "TUNNEL"
    return int.from_bytes(bytes(msg.payload[:4]), "little")


def udp() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)  # a busy test reader loses nothing to the kernel
    s.bind(("127.0.0.1", 0))
    s.setblocking(False)
    return s


def drain(sock: socket.socket, into: list, stamps: list | None = None, wait: float = 0.0) -> None:
    """Read what the socket holds (waiting up to `wait` for the first datagram)."""
    ready, _, _ = select.select([sock], [], [], wait)
    while ready:
        try:
            data, _ = sock.recvfrom(65535)
        except BlockingIOError:
            return
        into.append(data)
        if stamps is not None:
            stamps.append(time.monotonic())


def until(condition, what: str, read=None) -> None:
    """Wait for condition() (calling read() meanwhile); AssertionError naming `what` after WAIT_S."""
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        if read is not None:
            read()
        else:
            time.sleep(0.002)


def push(relay: LossyRelay, sender: socket.socket, frames: list[bytes], receiver: socket.socket, got: list) -> None:
    """Send frames to the relay in batches it has read before the next (the kernel's buffers stay
    small), reading the receiver meanwhile; returns once the relay holds none back."""
    for start in range(0, len(frames), 50):
        batch = frames[start : start + 50]
        for f in batch:
            sender.sendto(f, relay.address)
        expected = start + len(batch)
        until(
            lambda e=expected: relay.counts().forward.received >= e, "the relay to read", lambda: drain(receiver, got)
        )
        drain(receiver, got)  # each batch, so the receiver's buffer never holds more than a few
    until(lambda: relay.counts().held == 0, "the relay to send what it holds", lambda: drain(receiver, got, wait=0.01))
    drain(receiver, got)


@pytest.fixture(autouse=True)
def no_leftover_relays():
    yield
    assert [t.name for t in threading.enumerate() if t.name.startswith("lossy-relay")] == []


# --- exactly once ----------------------------------------------------------------------------------------


@settings(max_examples=15)
@given(
    sizes=st.lists(st.integers(4, 120), min_size=1, max_size=40),
    delay_ms=st.integers(0, 15),
    jitter_share=st.floats(0.0, 1.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_without_loss_or_duplicates_every_datagram_arrives_exactly_once_each_way(sizes, delay_ms, jitter_share, seed):
    faults = LinkFaults(delay=delay_ms / 1000, jitter=delay_ms / 1000 * jitter_share)
    target, client = udp(), udp()
    try:
        with LossyRelay(target.getsockname(), faults, seed=seed) as relay:
            frames = [frame(n, size) for n, size in enumerate(sizes)]
            got: list[bytes] = []
            push(relay, client, frames, target, got)
            assert Counter(got) == Counter(frames)
            c = relay.counts()
            assert (c.forward.received, c.forward.sent, c.forward.lost, c.forward.duplicated) == (len(sizes),) * 2 + (
                0,
                0,
            )
            # the way back: the target answers the relay's socket for this client, the client gets it
            back = [frame(1000 + n) for n in range(len(sizes))]
            source = relay_source(relay)
            for f in back:
                target.sendto(f, source)
            returned: list[bytes] = []
            until(lambda: relay.counts().back.sent == len(back), "the answers", lambda: drain(client, returned))
            drain(client, returned)
            assert Counter(returned) == Counter(back) and relay.counts().clients == 1
    finally:
        target.close()
        client.close()


def relay_source(relay: LossyRelay) -> tuple[str, int]:
    """The address the relay forwards its one client's datagrams from."""
    (source,) = relay.forwarders().values()
    return source


# --- loss and duplicates ---------------------------------------------------------------------------------


def within(count: int, n: int, p: float, sds: float = 4.5) -> bool:
    """count is within `sds` standard deviations of a binomial(n, p)'s mean."""
    return abs(count - n * p) <= sds * math.sqrt(n * p * (1 - p))


def lossy_run(seed: int, n: int = 2000) -> tuple[set[int], Counter, object]:
    target, client = udp(), udp()
    try:
        with LossyRelay(target.getsockname(), LinkFaults(loss=0.2, duplicate=0.05), seed=seed) as relay:
            got: list[bytes] = []
            push(relay, client, [frame(i) for i in range(n)], target, got)
            counts = relay.counts()
    finally:
        target.close()
        client.close()
    arrived = Counter(number(g) for g in got)
    return set(arrived), arrived, counts


def test_loss_and_duplicates_stay_within_their_bounds_and_a_seed_gives_the_same_fates():
    n = 2000
    kept, arrived, c = lossy_run(seed=7, n=n)
    assert c.forward.received == n and c.forward.sent == sum(arrived.values())
    lost = n - len(kept)
    assert c.forward.lost == lost and within(lost, n, 0.2)
    twice = sum(1 for k in arrived.values() if k == 2)
    assert c.forward.duplicated == twice and within(twice, len(kept), 0.05)
    assert max(arrived.values()) <= 2 and c.back.received == 0
    again, _, _ = lossy_run(seed=7, n=n)
    other, _, _ = lossy_run(seed=8, n=n)
    assert again == kept  # the n-th datagram meets the same fate with the same seed
    assert other != kept


def test_each_direction_has_its_own_faults():
    target, client = udp(), udp()
    try:
        relay = LossyRelay(target.getsockname(), LinkFaults(), LinkFaults(loss=0.5), seed=3)
        with relay:
            got: list[bytes] = []
            push(relay, client, [frame(i) for i in range(400)], target, got)
            assert len(got) == 400
            source = relay_source(relay)
            for i in range(400):
                target.sendto(frame(i), source)
                if i % 50 == 49:
                    until(lambda i=i: relay.counts().back.received > i, "the relay to read", lambda: drain(client, []))
            until(lambda: relay.counts().back.received == 400 and relay.counts().held == 0, "the way back")
            c = relay.counts()
        assert c.forward.lost == 0 and within(c.back.lost, 400, 0.5) and c.back.sent == 400 - c.back.lost
    finally:
        target.close()
        client.close()


def test_fates_follow_the_draws():
    f = LinkFaults(loss=0.2, delay=0.03, jitter=0.02, duplicate=0.05)
    assert f.fate([0.1, 0.5, 0.0, 0.0]) == ()  # lost, whatever the other draws
    assert f.fate([0.2, 0.5, 0.9, 0.0]) == (pytest.approx(0.03),)
    assert f.fate([0.5, 0.0, 0.01, 1.0]) == (pytest.approx(0.01), pytest.approx(0.05))  # duplicated
    assert f.describe() == "loss 20 %, delay 30 +- 20 ms, 5 % duplicates"


# --- delays ----------------------------------------------------------------------------------------------


def test_delays_are_applied_and_reorder_the_datagrams():
    target, client = udp(), udp()
    try:
        with LossyRelay(target.getsockname(), LinkFaults(delay=0.04, jitter=0.02), seed=11) as relay:
            sent_at = {}
            for i in range(100):
                sent_at[i] = time.monotonic()
                client.sendto(frame(i), relay.address)
            got: list[bytes] = []
            stamps: list[float] = []
            until(lambda: len(got) == 100, "every datagram", lambda: drain(target, got, stamps, wait=0.005))
    finally:
        target.close()
        client.close()
    order = [number(g) for g in got]
    latency = [t - sent_at[i] for i, t in zip(order, stamps)]
    assert min(latency) >= 0.02  # never before delay - jitter
    assert 0.035 < sum(latency) / len(latency) < 0.2  # about the 40 ms asked (and the test's own reading)
    assert sorted(order) == list(range(100)) and order != sorted(order)  # all there, some overtaken


# --- life cycle and bounds -------------------------------------------------------------------------------


def test_stop_closes_every_socket_and_frees_the_port():
    target, client = udp(), udp()
    relay = LossyRelay(target.getsockname()).start()
    try:
        client.sendto(frame(0), relay.address)
        until(lambda: relay.counts().clients == 1, "the client")
        sockets = relay.sockets()
        assert len(sockets) == 4  # listening, the wake-up pair, the client's
        port = relay.port
    finally:
        relay.stop()
        target.close()
        client.close()
    assert all(s.fileno() == -1 for s in sockets) and relay.sockets() == []
    assert relay.counts().clients == 1  # what it did is still there to read
    relay.stop()  # again: nothing left to do
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as again:
        again.bind(("127.0.0.1", port))  # the port is free again
    with pytest.raises(RuntimeError):
        relay.start()
    LossyRelay(("127.0.0.1", 9)).stop()  # never started


def test_a_port_in_use_fails_start_with_nothing_left_open():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        relay = LossyRelay(("127.0.0.1", 9), listen=taken.getsockname())
        with pytest.raises(OSError):
            relay.start()
        assert relay.sockets() == []


def test_clients_beyond_the_limit_are_refused_and_counted():
    target, first, second = udp(), udp(), udp()
    try:
        with LossyRelay(target.getsockname(), max_clients=1) as relay:
            first.sendto(frame(0), relay.address)
            until(lambda: relay.counts().clients == 1, "the first client")
            second.sendto(frame(1), relay.address)
            until(lambda: relay.counts().refused == 1, "the refusal")
            got: list[bytes] = []
            until(lambda: got, "the first client's datagram", lambda: drain(target, got, wait=0.01))
            assert [number(g) for g in got] == [0] and relay.counts().forward.received == 1
    finally:
        for s in (target, first, second):
            s.close()


@pytest.mark.parametrize(
    "kwargs, needle",
    [
        (dict(loss=1.5), "loss"),
        (dict(loss=math.nan), "loss"),
        (dict(duplicate=-0.1), "duplicate"),
        (dict(delay=math.inf), "delay"),
        (dict(delay=11.0), "delay"),
        (dict(delay=0.01, jitter=0.02), "jitter"),
        (dict(loss=True), "loss"),
    ],
)
def test_bad_faults_are_refused_naming_the_field(kwargs, needle):
    with pytest.raises(ValueError, match=needle):
        LinkFaults(**kwargs)


@pytest.mark.parametrize(
    "args, needle",
    [
        (dict(target=("127.0.0.1", 0)), "target"),
        (dict(target=("", 14550)), "target"),
        (dict(target="127.0.0.1:14550"), "target"),
        (dict(target=("127.0.0.1", 14550), listen=("127.0.0.1", 70000)), "listen"),
        (dict(target=("127.0.0.1", 14550), seed=-1), "seed"),
        (dict(target=("127.0.0.1", 14550), max_clients=0), "max_clients"),
    ],
)
def test_bad_relay_settings_are_refused_naming_the_field(args, needle):
    with pytest.raises(ValueError, match=needle):
        LossyRelay(**args)


# --- swarmctl mock-relay ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "argv, needle",
    [
        ([], "--to"),
        (["--to", "127.0.0.1"], "--to"),
        (["--to", "127.0.0.1:0"], "--to"),
        (["--to", "127.0.0.1:http"], "--to"),
        (["--to", "127.0.0.1:14550", "--listen", "127.0.0.1:65536"], "--listen"),
        (["--to", "127.0.0.1:14550", "--loss", "nan"], "--loss"),
        (["--to", "127.0.0.1:14550", "--loss", "1.5"], "--loss"),
        (["--to", "127.0.0.1:14550", "--duplicate", "-1"], "--duplicate"),
        (["--to", "127.0.0.1:14550", "--delay-ms", "inf"], "--delay-ms"),
        (["--to", "127.0.0.1:14550", "--delay-ms", "10", "--jitter-ms", "20"], "--jitter-ms"),
        (["--to", "127.0.0.1:14550", "--seed", "-1"], "--seed"),
        (["--to", "127.0.0.1:14550", "--duration", "nan"], "--duration"),
        (["--to", "no-such-host.invalid:14550"], "--to"),
    ],
)
def test_mock_relay_refuses_bad_input_in_one_line_with_exit_2(argv, needle, capsys):
    assert main(["mock-relay", "--duration", "0.01", *argv]) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("swarmctl: error: ") and needle in lines[0], lines


def test_mock_relay_refuses_a_port_in_use(capsys):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        assert main(["mock-relay", "--to", "127.0.0.1:14550", "--listen", f"127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err
    assert "--listen" in err and str(port) in err and "Traceback" not in err


def test_mock_relay_forwards_until_its_duration_and_says_what_it_did(capsys):
    target, client = udp(), udp()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]  # free a moment ago: the relay listens there
    try:
        result: dict[str, int] = {}
        argv = ["mock-relay", "--to", f"127.0.0.1:{target.getsockname()[1]}", "--listen", f"127.0.0.1:{port}"]
        runner = threading.Thread(target=lambda: result.update(code=main([*argv, "--duration", "1.5"])))
        runner.start()
        got: list[bytes] = []

        def send_and_read() -> None:
            client.sendto(frame(5), ("127.0.0.1", port))  # lost while the relay is not up yet
            drain(target, got, wait=0.02)

        until(lambda: got, "a datagram through the relay", send_and_read)
        runner.join(WAIT_S)
        assert not runner.is_alive() and result == {"code": 0}
    finally:
        target.close()
        client.close()
    assert number(got[0]) == 5
    err = capsys.readouterr().err
    assert f"relay 127.0.0.1:{port} -> 127.0.0.1:" in err
    assert "loss 0 %, delay 0 +- 0 ms, 0 % duplicates" in err and "relay: 1 sender(s); forward" in err
