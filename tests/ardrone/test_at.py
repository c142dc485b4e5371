"""AT codec: golden strings from the Developer Guide SDK 2.0 §6, errors, Hypothesis round trips."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drone.ardrone import at
from drone.ardrone.errors import ATEncodeError, ATParseError


@pytest.mark.parametrize(
    ("command", "wire"),
    [
        (at.Ref.takeoff(), b"AT*REF=1,290718208\r"),  # Guide §6.6: take-off
        (at.Ref.land(), b"AT*REF=1,290717696\r"),  # 0x11540000
        (at.Ref.emergency(), b"AT*REF=1,290717952\r"),  # bit 8
        (at.Pcmd(1, -0.8, 0.0, 0.0, 0.0), b"AT*PCMD=1,1,-1085485875,0,0,0\r"),  # Guide §6.2
        (at.Pcmd(1, 0.0, 0.5, -0.5, 0.25), b"AT*PCMD=1,1,0,1056964608,-1090519040,1048576000\r"),
        (at.Pcmd.hover(), b"AT*PCMD=1,0,0,0,0,0\r"),
        (
            at.PcmdMag(1, 0.0, 0.0, 0.0, 0.0, -0.5, 0.25),
            b"AT*PCMD_MAG=1,1,0,0,0,0,-1090519040,1048576000\r",
        ),
        (at.Ftrim(), b"AT*FTRIM=1\r"),
        (at.Config("general:navdata_demo", "TRUE"), b'AT*CONFIG=1,"general:navdata_demo","TRUE"\r'),
        (
            at.ConfigIds("ad1efdac", "992f7f4f", "510acf97"),
            b'AT*CONFIG_IDS=1,"ad1efdac","992f7f4f","510acf97"\r',
        ),
        (at.Comwdg(), b"AT*COMWDG=1\r"),
        (at.Ctrl(5, 0), b"AT*CTRL=1,5,0\r"),
        (at.Calib(0), b"AT*CALIB=1,0\r"),
        (at.Led(2, 2.0, 3), b"AT*LED=1,2,1073741824,3\r"),  # 2.0f = 0x40000000
        (at.Anim(3, 2), b"AT*ANIM=1,3,2\r"),
    ],
)
def test_golden_strings(command: at.ATCommand, wire: bytes) -> None:
    assert at.encode_command(command, 1) == wire
    (packet,) = at.parse_at(wire)
    assert packet.seq == 1
    assert type(packet.command) is type(command)
    assert at.encode_command(packet.command, 1) == wire  # floats come back as their float32


def test_float_bits_match_the_guide() -> None:
    assert at.float_to_int(-0.8) == -1085485875
    assert at.float_to_int(-0.5) == -1090519040
    assert at.float_to_int(0.25) == 1048576000
    assert at.int_to_float(1056964608) == 0.5


def test_encoder_owns_sequence_and_packs_1024_byte_datagrams() -> None:
    enc = at.ATEncoder()
    cmds = [at.Config(f"custom:key_{i:03d}", "x" * 20) for i in range(60)]
    datagrams = enc.pack(cmds)
    assert len(datagrams) > 1
    assert all(len(d) <= at.MAX_DATAGRAM for d in datagrams)
    seqs = [p.seq for d in datagrams for p in at.parse_at(d)]
    assert seqs == list(range(1, 61))
    assert enc.next_seq == 61
    enc.reset()
    assert enc.encode(at.Comwdg()) == b"AT*COMWDG=1\r"


@pytest.mark.parametrize(
    "bad",
    [
        lambda: at.encode_command(at.Pcmd(1, float("nan"), 0, 0, 0), 1),
        lambda: at.encode_command(at.Pcmd(1, float("inf"), 0, 0, 0), 1),
        lambda: at.encode_command(at.Pcmd(1, 1e40, 0, 0, 0), 1),
        lambda: at.encode_command(at.Config('a"b', "1"), 1),
        lambda: at.encode_command(at.Config("a", "1\r"), 1),
        lambda: at.encode_command(at.Config("a", "é"), 1),
        lambda: at.encode_command(at.Ref(2**32), 1),
        lambda: at.encode_command(at.Comwdg(), 0),
        lambda: at.ATEncoder(max_datagram=10).pack([at.Config("general:navdata_demo", "TRUE")]),
    ],
)
def test_unencodable_arguments_raise_at_encode_error(bad: object) -> None:
    with pytest.raises(ATEncodeError):
        bad()  # type: ignore[operator]


@pytest.mark.parametrize(
    "garbage",
    [
        b"",  # empty
        b"AT*REF=1,290718208",  # no CR
        b"AT*REF=1\r",  # wrong arity
        b"AT*REF=0,290718208\r",  # seq 0
        b"AT*REF=1,abc\r",  # not an int
        b"at*ref=1,2\r",  # lower case
        b"AT*CONFIG=1,5,6\r",  # ints where strings go
        b"AT*PCMD=1,1,0,0,0,4294967296\r",  # not int32
        b"\xff\xfe\r",  # binary
        b"AT*COMWDG=1\r" * 100,  # > 1024 bytes
    ],
)
def test_garbage_raises_at_parse_error(garbage: bytes) -> None:
    with pytest.raises(ATParseError):
        at.parse_at(garbage)


def test_unknown_command_parses_as_unknown_and_crlf_is_tolerated() -> None:
    packets = at.parse_at(b'AT*FOO=7,1,"x"\r\nAT*COMWDG=8\r\n')
    assert packets == [at.ATPacket(7, at.Unknown("FOO", ("1", '"x"'))), at.ATPacket(8, at.Comwdg())]


fractions = st.floats(-1.0, 1.0, width=32)
ascii_text = st.text(
    alphabet=st.characters(min_codepoint=32, max_codepoint=126, blacklist_characters='"'),
    max_size=40,
)
commands = st.one_of(
    st.builds(at.Ref, st.integers(0, 2**31 - 1)),
    st.builds(at.Pcmd, st.integers(0, 7), fractions, fractions, fractions, fractions),
    st.builds(at.PcmdMag, st.integers(0, 7), *[fractions] * 6),
    st.just(at.Ftrim()),
    st.just(at.Comwdg()),
    st.builds(at.Config, ascii_text, ascii_text),
    st.builds(at.ConfigIds, ascii_text, ascii_text, ascii_text),
    st.builds(at.Ctrl, st.integers(0, 6), st.integers(-5, 5)),
    st.builds(at.Calib, st.integers(0, 3)),
    st.builds(at.Led, st.integers(0, 20), st.floats(0, 100, width=32), st.integers(0, 60)),
    st.builds(at.Anim, st.integers(0, 20), st.integers(0, 60)),
)


@settings(deadline=None)  # shared, loaded CI machine: no per-example deadline
@given(st.lists(commands, min_size=1, max_size=30), st.integers(1, 2**31 - 100))
def test_encode_then_parse_is_identity(cmds: list[at.ATCommand], first: int) -> None:
    enc = at.ATEncoder(first_seq=first)
    parsed = [p for d in enc.pack(cmds) for p in at.parse_at(d)]
    assert [p.command for p in parsed] == cmds
    assert [p.seq for p in parsed] == list(range(first, first + len(cmds)))


@settings(deadline=None)  # shared, loaded CI machine: no per-example deadline
@given(st.binary(max_size=300))
def test_arbitrary_bytes_parse_or_raise_at_parse_error(data: bytes) -> None:
    try:
        packets = at.parse_at(data)
    except ATParseError:
        return
    assert all(p.seq >= 1 for p in packets)


@settings(deadline=None)  # shared, loaded CI machine: no per-example deadline
@given(st.text(alphabet='AT*REFPCMD=,-0123456789"\r', max_size=80))
def test_near_miss_text_parses_or_raises_at_parse_error(text: str) -> None:
    try:
        packets = at.parse_at(text.encode())
    except ATParseError:
        return
    assert all(isinstance(p, at.ATPacket) for p in packets)


@pytest.mark.parametrize(
    "data",
    [
        # found by bench/fuzz.py (issue 14): non-ASCII bytes inside a quoted argument raised
        # UnicodeDecodeError instead of the documented ATParseError
        b'AT*CONFIG=3,"general\xff:navm","TRUE"\r',
        b'AT*CONFIG=3,"general:navdata_demo","\xadRUE"\r',
    ],
)
def test_fuzz_found_non_ascii_argument(data: bytes) -> None:
    with pytest.raises(ATParseError, match="non-ASCII"):
        at.parse_at(data)
