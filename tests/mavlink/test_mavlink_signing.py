"""Who may fly the MAVLink simulator: it signs by default and obeys only signed frames,
``--insecure`` is for loopback only, and its connections are capped.

* ``uav-console sim --protocol mavlink`` as a real process: a pymavlink client without the key
  reads the telemetry but its arm is refused (and told why); pymavlink with the key from the
  passphrase file the simulator printed arms, takes off and lands; ``--insecure`` on loopback
  obeys unsigned frames, and off loopback it does not start.
* In this process, over real sockets: while flying, a force-disarm that is unsigned, signed
  with another key, carries a broken signature, or is a genuine frame replayed (on its own
  connection or a new one) does nothing; 300 connections of garbage and silence hold at most
  16 links and a signed client still flies through them.
* The admission rules and the passphrase file, alone.
* ``serve --drone sim-mavlink``: the console's driver signs with the data directory's key.

Each simulator on a loopback address of its own (``fresh_address``).
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import math
import os
import random
import stat
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from drone.mavlink import signing
from drone.mavlink.admission import Admission
from drone.mavlink.errors import InsecureLinkError, SigningKeyError
from drone.mavlink.sim.autopilot import SimAutopilot
from drone.mavlink.simserver import TCP_PORT, MavlinkSimServer
from drone.sim.world import load_world
from tests.support.loopback import fresh_address
from tests.support.polling import until_async, wait_for

ROOT = Path(__file__).resolve().parents[2]
KEY = bytes(range(1, 33))
FORCE = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: force, even in the air
REFUSED = "Refused: MAVLink 2 signing required"
SIM = (sys.executable, "-u", "-m", "server", "sim", "--protocol", "mavlink")


@pytest.fixture(scope="module")
def world() -> Any:
    return load_world("outdoor")


@pytest.fixture(scope="module", autouse=True)
def mavlink2() -> Iterator[None]:
    """mavutil in MAVLink 2 from the start (``MAVLINK20=1``, as pymavlink's docs say for
    signing): otherwise it starts in MAVLink 1, which cannot sign, and drops the signing set
    up on a connection when it switches to MAVLink 2 on the first frame it hears."""
    from pymavlink import mavutil

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("MAVLINK20", "1")
        mavutil.set_dialect("ardupilotmega")
        yield


# ---------------------------------------------------------------------- pymavlink clients
def connect(addr: str, *, key: bytes | None = None, hello: bool = True) -> Any:
    """A mavutil TCP client; with ``key`` it signs (pymavlink ``setup_signing``); ``hello``: a
    GCS heartbeat at once, as MAVSDK, QGroundControl and this console send on connecting."""
    from pymavlink import mavutil

    m = mavutil.mavlink_connection(f"tcp:{addr}:{TCP_PORT}", source_system=254, autoreconnect=False)
    if key is not None:
        m.setup_signing(key, sign_outgoing=True)
    if hello:
        m.mav.heartbeat_send(
            mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
        )
    return m


def command(m: Any, cmd: int, *params: float) -> int:
    """COMMAND_LONG to the vehicle; its COMMAND_ACK result."""
    p = list(params) + [0.0] * (7 - len(params))
    m.mav.command_long_send(1, 1, cmd, 0, *p)
    ack = m.recv_match(
        type="COMMAND_ACK", blocking=True, timeout=10, condition=f"COMMAND_ACK.command=={cmd}"
    )
    assert ack is not None, f"no COMMAND_ACK for {cmd}"
    return int(ack.result)


def statustext(m: Any, text: str, timeout: float = 10.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        st = m.recv_match(type="STATUSTEXT", blocking=True, timeout=1)
        if st is not None and st.text == text:
            return
    raise AssertionError(f"no STATUSTEXT {text!r}")


def heartbeat_armed(m: Any) -> bool:
    from pymavlink import mavutil

    hb = m.recv_match(type="HEARTBEAT", blocking=True, timeout=10)
    assert hb is not None
    return bool(hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)


def fly_up_and_land(m: Any) -> None:
    """Arm, take off (MIS_TAKEOFF_ALT), climb past 2 m, land and see the autopilot disarm."""
    assert command(m, 400, 1) == 0
    assert command(m, 22, 0, 0, 0, math.nan, math.nan, math.nan, math.nan) == 0
    wait_for(
        lambda: m.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=5),
        lambda gp: gp is not None and gp.relative_alt > 2000,
        30,
        "the signed client's take-off",
    )
    assert command(m, 21) == 0  # NAV_LAND
    wait_for(lambda: heartbeat_armed(m), lambda armed: not armed, 40, "landed and disarmed")


# ---------------------------------------------------------------------- the CLI, a process
@contextlib.contextmanager
def cli_sim(addr: str, data_dir: Path, *extra: str) -> Iterator[list[str]]:
    """``uav-console sim --protocol mavlink`` until its banner is out; yields the banner."""
    args = ["--addr", addr, "--world", "outdoor", "--speed", "4", "--data-dir", str(data_dir)]
    proc = subprocess.Popen(
        [*SIM, *args, *extra],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: list[str] = []
    try:
        assert proc.stdout is not None
        while not any(end in line for line in lines for end in ("MAVSDK", "signing is OFF")):
            line = proc.stdout.readline()
            assert line, f"the simulator exited: {''.join(lines)}"
            lines.append(line.rstrip("\n"))
        yield lines
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        if proc.stdout is not None:
            proc.stdout.close()


def test_cli_signs_by_default_refuses_unsigned_and_flies_signed(tmp_path: Path) -> None:
    addr = fresh_address()
    with cli_sim(addr, tmp_path) as banner:
        path = signing.key_path(tmp_path)
        assert any(str(path) in line for line in banner), banner
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
        assert stat.S_IMODE(path.parent.stat().st_mode) == 0o700
        # without the key: the telemetry is readable, the arm is refused and the reason told
        plain = connect(addr, hello=False)
        try:
            assert plain.wait_heartbeat(timeout=10) is not None
            plain.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
            statustext(plain, REFUSED)  # sent on the arm: the arm is decided
        finally:
            plain.close()
        # with the key, as the banner says to derive it (SHA-256 of the passphrase)
        key = hashlib.sha256(path.read_text().strip().encode()).digest()
        m = connect(addr, key=key)
        try:
            assert m.wait_heartbeat(timeout=10) is not None
            assert not heartbeat_armed(m)  # the unsigned arm did nothing
            fly_up_and_land(m)
        finally:
            m.close()


def test_cli_insecure_on_loopback_obeys_unsigned(tmp_path: Path) -> None:
    addr = fresh_address()
    with cli_sim(addr, tmp_path, "--insecure") as banner:
        assert any("signing is OFF" in line for line in banner), banner
        m = connect(addr)
        try:
            assert m.wait_heartbeat(timeout=10) is not None
            assert command(m, 400, 1) == 0  # armed, unsigned
            assert command(m, 400, 0) == 0
        finally:
            m.close()
    assert not signing.key_path(tmp_path).exists()  # no key was needed


def test_cli_insecure_off_loopback_does_not_start(tmp_path: Path) -> None:
    for addr in ("0.0.0.0", "192.0.2.7"):
        run = subprocess.run(
            [*SIM, "--insecure", "--addr", addr, "--data-dir", str(tmp_path)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert run.returncode == 2, run
        assert f"loopback only, and {addr} is not" in run.stderr
        assert "Traceback" not in run.stderr


def test_cli_print_key_is_the_passphrase_hash(tmp_path: Path) -> None:
    run = subprocess.run(
        [*SIM, "--print-key", "--data-dir", str(tmp_path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        env={k: v for k, v in os.environ.items() if k != "UAVC_MAVLINK_KEY"},
    )
    assert run.returncode == 0, run
    passphrase = signing.key_path(tmp_path).read_text().strip()
    assert run.stdout.strip() == hashlib.sha256(passphrase.encode()).hexdigest()


# ---------------------------------------------------------------------- in this process
async def test_forged_replayed_and_unsigned_disarms_do_nothing_in_flight(world: Any) -> None:
    from pymavlink.dialects.v20 import ardupilotmega as mav

    addr = fresh_address()
    ap = SimAutopilot(world, signing_key=KEY)
    patient = Admission(deadline_s=600.0)  # the thief is kept to try everything in turn
    async with MavlinkSimServer(addr, ap, udp_port=None, speed=4.0, admission=patient):

        def scenario() -> None:
            m = connect(addr, key=KEY)
            try:
                assert m.wait_heartbeat(timeout=10) is not None
                # a genuine signed force-disarm, sent on the ground (harmless there), kept
                genuine = m.mav.command_long_encode(1, 1, 400, 0, 0, FORCE, 0, 0, 0, 0, 0)
                recorded = bytes(genuine.pack(m.mav))
                m.write(recorded)
                assert m.recv_match(type="COMMAND_ACK", blocking=True, timeout=10) is not None
                assert command(m, 400, 1) == 0
                assert command(m, 22, 0, 0, 0, math.nan, math.nan, math.nan, math.nan) == 0
                wait_for(lambda: ap.physics.body.z, lambda z: z > 2.0, 30, "in the air")

                def refused_after(send: Any, what: str) -> None:
                    before = ap.rejected().get("bad_signature", 0)
                    send()
                    wait_for(
                        lambda: ap.rejected().get("bad_signature", 0),
                        lambda n: n > before,
                        10,
                        f"{what} refused",
                    )
                    assert ap.armed and ap.truth.flying, what

                # 1. the recorded frame, replayed on a new connection and on its own
                thief = connect(addr, hello=False)
                refused_after(lambda: thief.write(recorded), "a replay on a new connection")
                refused_after(lambda: m.write(recorded), "a replay on its own connection")
                # 2. signed with another key
                other = mav.MAVLink(None, 254, 190)
                other.signing.secret_key = bytes(32)
                other.signing.sign_outgoing = True
                other.signing.timestamp = ap._signing.timestamp + 1000
                forged = bytes(
                    other.command_long_encode(1, 1, 400, 0, 0, FORCE, 0, 0, 0, 0, 0).pack(other)
                )
                refused_after(lambda: thief.write(forged), "a frame signed with another key")
                # 3. the right key, a broken signature (CRC intact: it covers no signature)
                fresh = m.mav.command_long_encode(1, 1, 400, 0, 0, FORCE, 0, 0, 0, 0, 0)
                broken = bytearray(fresh.pack(m.mav))
                broken[-1] ^= 0x01
                refused_after(lambda: thief.write(bytes(broken)), "a broken signature")
                # 4. not signed at all
                unsigned = mav.MAVLink(None, 253, 190)
                plain = bytes(
                    unsigned.command_long_encode(1, 1, 400, 0, 0, FORCE, 0, 0, 0, 0, 0).pack(
                        unsigned
                    )
                )
                refused_after(lambda: thief.write(plain), "an unsigned force-disarm")
                statustext(thief, REFUSED)
                thief.close()
                # the signed client still commands: land, and the autopilot disarms
                assert command(m, 21) == 0
                wait_for(lambda: ap.armed, lambda armed: not armed, 40, "landed and disarmed")
            finally:
                m.close()

        await asyncio.wait_for(asyncio.to_thread(scenario), 150)
    assert 400 not in ap.commands_executed[2:]  # no disarm after the arm but the auto-disarm


async def test_connection_flood_is_capped_and_a_signed_client_still_flies(world: Any) -> None:
    addr = fresh_address()
    ap = SimAutopilot(world, signing_key=KEY)
    server = MavlinkSimServer(addr, ap, udp_port=None, speed=4.0)
    rng = random.Random(26)
    held: list[asyncio.StreamWriter] = []
    most_links = 0
    closed_by_server = 0

    async def open_one(garbage: bool) -> None:
        nonlocal closed_by_server
        reader, writer = await asyncio.open_connection(addr, TCP_PORT)
        held.append(writer)
        if garbage:  # MAVLink 2 magic and noise: parsed, never accepted
            writer.write(b"\xfd" + rng.randbytes(300))
        try:
            while await reader.read(65536):
                pass
            closed_by_server += 1
        except ConnectionError:
            closed_by_server += 1

    readers: list[asyncio.Task[None]] = []

    def watch() -> None:
        nonlocal most_links
        most_links = max(most_links, len(ap.links))

    async with server:
        for i in range(300):
            readers.append(asyncio.create_task(open_one(garbage=i % 2 == 0)))
            await asyncio.sleep(0)
            watch()

        def displaced() -> bool:
            watch()
            return closed_by_server >= 250

        await until_async(
            displaced, 30.0, "250 connections displaced by newer ones"
        )  # displaced as newer ones arrived

        stop = asyncio.Event()

        async def churn() -> None:  # the flood goes on while the signed client flies
            n = 0
            while not stop.is_set():
                readers.append(asyncio.create_task(open_one(garbage=n % 2 == 0)))
                n += 1
                await asyncio.sleep(0.01)  # the flood's pace: the test's input
                watch()

        churner = asyncio.create_task(churn())

        def legit() -> None:
            m = connect(addr, key=KEY)
            try:
                assert m.wait_heartbeat(timeout=10) is not None
                fly_up_and_land(m)
            finally:
                m.close()

        try:
            await asyncio.wait_for(asyncio.to_thread(legit), 120)
        finally:
            stop.set()
            await churner
            for w in held:
                w.close()
            for t in readers:
                t.cancel()
            await asyncio.gather(*readers, return_exceptions=True)
    assert most_links <= server.admission.max_trusted + server.admission.max_waiting
    assert server.admission.refused >= 300
    assert ap.commands_executed.count(22) == 1  # the signed client's take-off, flown


async def test_udp_peers_are_capped_too_and_a_signed_peer_commands(world: Any) -> None:
    """UDP peers are links (PX4 SITL's 14580): 60 addresses sending garbage hold at most 16."""
    import socket

    from pymavlink import mavutil

    addr = fresh_address()
    ap = SimAutopilot(world, signing_key=KEY)
    async with MavlinkSimServer(addr, ap, tcp_port=None, udp_port=0, speed=4.0) as sim:
        port = sim.udp_port
        socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(60)]
        try:
            for i, s in enumerate(socks):
                s.bind((addr, 0))
                s.sendto(b"\xfd" + bytes([i]) * 40, (addr, port))
                await asyncio.sleep(0)  # the simulator takes each datagram in turn
            await until_async(lambda: sim.admission.refused >= 50, 10.0, "50 peers refused")
            assert len(ap.links) <= 16

            def signed_peer() -> int:
                m = mavutil.mavlink_connection(f"udpout:{addr}:{port}", source_system=254)
                try:
                    m.setup_signing(KEY, sign_outgoing=True)
                    m.mav.heartbeat_send(6, 8, 0, 0, 0)
                    assert m.wait_heartbeat(timeout=10) is not None
                    return command(m, 400, 1)
                finally:
                    m.close()

            assert await asyncio.wait_for(asyncio.to_thread(signed_peer), 60) == 0
            assert ap.armed
        finally:
            for s in socks:
                s.close()


async def test_garbage_senders_are_closed_after_the_deadline(world: Any) -> None:
    addr = fresh_address()
    ap = SimAutopilot(world, signing_key=KEY)
    admission = Admission(deadline_s=0.5)
    async with MavlinkSimServer(addr, ap, udp_port=None, speed=4.0, admission=admission):
        reader, writer = await asyncio.open_connection(addr, TCP_PORT)
        writer.write(b"\xfd\x09" + bytes(40))  # garbage, then nothing
        silent_r, silent_w = await asyncio.open_connection(addr, TCP_PORT)
        try:
            # closed by the simulator: the read ends (the telemetry it got until then drained)
            async def drained() -> None:
                while await reader.read(65536):
                    pass

            await asyncio.wait_for(drained(), 30)
            # the silent one (a script in wait_heartbeat) still gets telemetry
            assert await asyncio.wait_for(silent_r.read(100), 10)
            assert admission.waiting == 1
        finally:
            writer.close()
            silent_w.close()


async def test_an_unsigned_simulator_listens_on_loopback_only(world: Any) -> None:
    server = MavlinkSimServer("0.0.0.0", SimAutopilot(world), tcp_port=0, udp_port=None)
    with pytest.raises(InsecureLinkError, match="loopback only"):
        await server.start()
    signed = MavlinkSimServer(
        fresh_address(), SimAutopilot(world, signing_key=KEY), tcp_port=0, udp_port=None
    )
    async with signed:  # a signing one may listen anywhere (loopback here)
        assert signed.tcp_port


# ---------------------------------------------------------------------- the rules, alone
def test_admission_keeps_trusted_links_and_displaces_the_longest_waiting() -> None:
    a = Admission(max_trusted=2, max_waiting=3, deadline_s=5.0)
    assert a.arrive("g1", 0.0) == []
    assert a.heard("g1", 0.1, accepted=True) and a.is_trusted("g1")
    for i, t in enumerate((1.0, 2.0, 3.0)):
        assert a.arrive(f"w{i}", t) == []
    assert a.arrive("w3", 4.0) == ["w0"]  # the longest waiting makes room
    assert a.arrive("w4", 4.5) == ["w1"]  # a trusted link is never displaced
    assert a.is_trusted("g1") and a.waiting == 3
    assert a.heard("w2", 5.0, accepted=True)  # proves itself: the second trusted place
    assert a.arrive("g3", 5.5) == []
    assert not a.heard("g3", 5.6, accepted=True)  # every trusted place taken: closed
    assert not a.heard("gone", 6.0, accepted=True)  # unknown: closed
    assert a.refused == 3


def test_admission_deadline_closes_only_links_that_sent_refused_bytes() -> None:
    a = Admission(deadline_s=5.0)
    a.arrive("garbage", 0.0)
    a.arrive("silent", 0.0)
    a.arrive("signed", 0.0)
    a.heard("garbage", 1.0, accepted=False)
    a.heard("signed", 1.0, accepted=True)
    assert a.expired(5.9) == []
    assert a.expired(6.0) == ["garbage"]
    assert a.expired(100.0) == []  # the silent one waits; the trusted one flies
    assert a.waiting == 1 and a.trusted == 1
    with pytest.raises(ValueError):
        Admission(max_trusted=0)


def test_passphrase_file_is_made_once_private_and_shared(tmp_path: Path) -> None:
    code = (
        "import sys; from pathlib import Path; from drone.mavlink import signing; "
        "print(signing.load_or_create(Path(sys.argv[1]))[0].hex())"
    )
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", code, str(tmp_path)], cwd=ROOT, stdout=subprocess.PIPE, text=True
        )
        for _ in range(4)
    ]
    keys = {p.communicate(timeout=60)[0].strip() for p in procs}
    assert len(keys) == 1  # four processes at once, one key
    path = signing.key_path(tmp_path)
    assert sorted(os.listdir(path.parent)) == ["signing-passphrase"]  # no temporary file left
    passphrase = path.read_text().strip()
    assert len(passphrase) == 43 and keys == {hashlib.sha256(passphrase.encode()).hexdigest()}
    assert signing.load_or_create(tmp_path) == (bytes.fromhex(keys.pop()), path)
    path.chmod(0o644)
    with pytest.raises(SigningKeyError, match="chmod 600"):
        signing.load_or_create(tmp_path)
    path.chmod(0o600)
    path.write_text("short\n")
    with pytest.raises(SigningKeyError, match="at least 8 printable ASCII"):
        signing.load_or_create(tmp_path)


# ---------------------------------------------------------------------- serve's stack
async def test_serve_sim_mavlink_signs_the_console_link_with_the_data_dir_key(
    tmp_path: Path, world: Any
) -> None:
    from server.settings import Settings
    from server.vehicles.mavlink_stack import start_mavlink

    settings = Settings(data_dir=tmp_path, sim_base_addr=fresh_address(), world="outdoor")
    parts = await start_mavlink("uav1", "sim-mavlink", 0, world, settings)
    try:
        key, _ = signing.load_or_create(tmp_path)
        assert parts.sim is not None and parts.sim.autopilot.signing_key == key
        assert parts.driver.protocol.codec.signed
        await until_async(lambda: parts.driver.protocol.connected, 20.0, "the driver connected")
        token = parts.driver.protocol.command(400, 1.0)
        parts.driver.flush()
        await until_async(  # the console's signed command is obeyed
            lambda: parts.sim is not None and parts.sim.autopilot.armed, 10.0, f"armed ({token})"
        )
        assert parts.sim.autopilot.rejected().get("bad_signature", 0) == 0
    finally:
        await parts.vehicle.stop(land=False)
        await parts.driver.stop()
        if parts.sim is not None:
            await parts.sim.stop()
