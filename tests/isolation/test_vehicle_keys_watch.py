"""How the console notices that its vehicle keys changed (``server.vehicles.keys``): the key
directory's signature, a scan that says which files hold no key, and the debounce that makes
one ``vehicle-key a b c`` one router restart. No sleeps: time is passed in."""

from __future__ import annotations

from pathlib import Path

from drone.bus.credentials import Credentials
from server.cli import main as cli_main
from server.vehicles.keys import WATCH_QUIET_S, KeyWatch, VehicleKeys


def test_the_signature_changes_with_each_key_made_rotated_or_revoked(tmp_path: Path) -> None:
    keys = VehicleKeys(tmp_path)
    seen = [keys.signature()]
    assert seen[0] == ()  # no directory yet
    for argv in (["uav7"], ["uav7", "--rotate"], ["uav8"], ["uav7", "--revoke"]):
        assert cli_main(["vehicle-key", *argv, "--data-dir", str(tmp_path)]) == 0
        seen.append(keys.signature())
        assert seen[-1] != seen[-2], argv
    assert keys.signature() == seen[-1]  # nothing changed: the same
    assert set(keys.scan().keys) == {"uav8"}


def test_a_scan_names_each_file_that_holds_no_key(tmp_path: Path) -> None:
    keys = VehicleKeys(tmp_path)
    good = keys.ensure("uav7")
    (keys.directory / "uav5.key").write_text("my pilot token, pasted\n")
    (keys.directory / "uav6.key").write_text("")
    (keys.directory / "not-a-name.key").write_text(good.secret + "\n")
    (keys.directory / ".uav9.key.tmp1234").write_text("half written")  # not a key file
    scan = keys.scan()
    assert dict(scan.keys) == {"uav7": good.secret}
    assert len(scan.problems) == 3
    uav5, uav6, bad_name = sorted(scan.problems, key=lambda p: ("uav5" not in p, "uav6" not in p))
    assert "uav5.key holds not a vehicle key" in uav5
    assert "uav6.key is empty" in uav6
    assert "'not-a-name' cannot name a vehicle" in bad_name
    assert good.secret not in "".join(scan.problems)  # a log line never shows a key


def test_a_burst_of_changes_is_read_once_after_it_keeps_still() -> None:
    watch = KeyWatch(quiet_s=0.5)
    assert not watch.observe((("a", 1, 1, 1),), 0.0)  # the first look counts as a change
    assert watch.observe((("a", 1, 1, 1),), 0.5)  # still for 0.5 s: read it (the start's)
    assert not watch.observe((("a", 1, 1, 1),), 0.75)  # unchanged since: nothing to read
    t, sig = 1.0, (("a", 1, 1, 1),)
    for n in range(5):  # `vehicle-key b c d e f`: a file every 50 ms
        sig = (*sig, (f"k{n}", 2, 2, 2))
        assert not watch.observe(sig, t)
        t += 0.05
    reads = [watch.observe(sig, t + dt) for dt in (0.0, 0.25, 0.5, 0.75, 1.0, 5.0)]
    assert reads == [False, False, True, False, False, False]


def test_what_could_not_be_applied_is_read_again_after_the_quiet_time() -> None:
    watch = KeyWatch(quiet_s=WATCH_QUIET_S)
    sig = (("a", 1, 1, 1),)
    watch.observe(sig, 0.0)
    assert watch.observe(sig, WATCH_QUIET_S)
    watch.again(10.0)  # the router did not restart
    assert not watch.observe(sig, 10.0 + WATCH_QUIET_S / 2)
    assert watch.observe(sig, 10.0 + WATCH_QUIET_S)


def test_a_revoked_vehicle_leaves_the_dictionary_but_not_one_this_console_runs(
    tmp_path: Path,
) -> None:
    first = Credentials.load_or_create(tmp_path, ["uav1"], {"uav7": "uavk_7", "uav8": "uavk_8"})
    assert first.vehicles() == ["uav1", "uav7", "uav8"]
    after = Credentials.load_or_create(
        tmp_path, ["uav1"], {"uav8": "uavk_8"}, revoked=["uav7", "uav1"]
    )
    assert after.vehicles() == ["uav1", "uav8"]  # uav1: spawned by this console, kept
    assert after.password("vehicle-uav1") == first.password("vehicle-uav1")
    assert Credentials.load_or_create(tmp_path, [], {"uav8": "uavk_8"}).users == after.users
