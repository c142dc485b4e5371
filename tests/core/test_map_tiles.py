"""The map's tile URL setting and the CSP source it allows (server/http/map_tiles.py)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.http.http_guard import content_security_policy
from server.http.map_tiles import DEFAULT_TILE_URL, TileUrlError, check_tile_url, tile_source
from server.settings import Settings, SettingsError


@pytest.mark.parametrize(
    ("url", "source"),
    [
        (DEFAULT_TILE_URL, "https://tile.openstreetmap.org"),
        ("https://{s}.tiles.example.org/osm/{z}/{x}/{y}{r}.png", "https://*.tiles.example.org"),
        ("http://10.0.0.5:8080/tiles/{z}/{x}/{y}.png", "http://10.0.0.5:8080"),
        ("  http://[fd00::5]:8080/{z}/{x}/{y}.png ", "http://[fd00::5]:8080"),
        ("", None),
    ],
)
def test_good_templates_and_their_sources(url: str, source: str | None) -> None:
    assert check_tile_url(url) == url.strip()
    assert tile_source(url) == source


@pytest.mark.parametrize(
    "url",
    [
        "ftp://tiles.example.org/{z}/{x}/{y}.png",
        "javascript:alert(1)//{z}/{x}/{y}",
        "https://tiles.example.org/{z}/{x}.png",
        "https://tiles.example.org/{z}/{x}/{y}/{s}.png",
        "https://tiles.example.org/{z}/{x}/{y}.png?key={apikey}",
        "https://ti les.example.org/{z}/{x}/{y}.png",
        "https:///{z}/{x}/{y}.png",
        "https://tiles{s}.example.org/{z}/{x}/{y}.png",
    ],
)
def test_bad_templates_are_refused_with_the_reason(url: str) -> None:
    with pytest.raises(TileUrlError):
        check_tile_url(url)
    assert tile_source(url) is None
    with pytest.raises((SettingsError, ValueError)):
        Settings(tile_url=url)


def test_the_page_policy_names_exactly_the_tile_host() -> None:
    csp = content_security_policy(images=["https://tile.openstreetmap.org"])
    assert "img-src 'self' data: blob: https://tile.openstreetmap.org;" in csp
    assert "img-src 'self' data: blob:;" in content_security_policy()
    # a source a policy cannot carry is left out, never spliced in
    bad = content_security_policy(images=["https://x.org; script-src *", "https://x.org/path"])
    assert "img-src 'self' data: blob:;" in bad and "script-src *" not in bad


@settings(deadline=None)
@given(st.text(max_size=200))
def test_any_text_is_a_template_or_a_clear_error(text: str) -> None:
    try:
        checked = check_tile_url(text)
    except TileUrlError as exc:
        assert str(exc)
        return
    source = tile_source(checked)
    if checked:
        assert source is not None
        csp = content_security_policy(images=[source])
        assert f"img-src 'self' data: blob: {source};" in csp


@settings(deadline=None)
@given(
    st.sampled_from(["http", "https", "ftp", ""]),
    st.from_regex(r"(\{s\}\.)?[a-z0-9.:\[\]@-]{0,24}", fullmatch=True),
    st.text(alphabet="/{}zxysr.png?=&ab", max_size=30),
)
def test_url_like_text_is_a_template_or_a_clear_error(scheme: str, host: str, path: str) -> None:
    test_any_text_is_a_template_or_a_clear_error.hypothesis.inner_test(  # type: ignore[attr-defined]
        f"{scheme}://{host}/{path}"
    )
