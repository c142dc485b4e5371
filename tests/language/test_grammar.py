"""Grammar files: each bad file gives the documented error naming file, line and rule."""

from __future__ import annotations

import io
import json
import re
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from server.language.cli import interpret_main
from server.language.errors import (
    DuplicateRuleError,
    GrammarError,
    GrammarSchemaError,
    GrammarSyntaxError,
    InvalidRegexError,
    UnknownGrammarError,
    UnknownSetError,
)
from server.language.grammar import first_tokens, load_grammar, trie_regex
from server.language.nlu import DEFAULT_GRAMMAR_DIR, NLU

RULES = """<?xml version="1.0"?>
<rules>
  <grammar name="g">
    <rule id="up" action="move" priority="5">
      <const name="direction" value="up"/>
      <pattern><![CDATA[go up]]></pattern>
    </rule>
    {extra}
  </grammar>
</rules>
"""
STATES = '<states><state name="LANDED" refuse="No."><grammar ref="g"/></state></states>'
MAPPINGS = '<mappings><set name="DIRECTION"><item label="up">up, roof</item></set></mappings>'


def make(tmp: Path, rules_extra: str = "", states: str = STATES, mappings: str = MAPPINGS) -> Path:
    (tmp / "rules.xml").write_text(RULES.replace("{extra}", rules_extra))
    (tmp / "states.xml").write_text(states)
    (tmp / "mappings.xml").write_text(mappings)
    return tmp


def test_minimal_grammar_loads(tmp_path: Path) -> None:
    nlu = NLU(make(tmp_path))
    assert nlu.interpret("go up") == [{"action": "move", "direction": "up"}]


@pytest.mark.parametrize(
    ("extra", "error", "line", "rule", "words"),
    [
        (
            '<rule id="x" action="move"><pattern><![CDATA[go {NOPE}]]></pattern></rule>',
            UnknownSetError,
            9,
            "x",
            "NOPE",
        ),
        (
            '<rule id="x" action="move"><pattern><![CDATA[go (up]]></pattern></rule>',
            InvalidRegexError,
            9,
            "x",
            "invalid regex",
        ),
        (
            '<rule id="up" action="move"><pattern><![CDATA[up]]></pattern></rule>',
            DuplicateRuleError,
            9,
            "up",
            "line 4",
        ),
        (
            '<rule id="x"><pattern><![CDATA[up]]></pattern></rule>',
            GrammarSchemaError,
            9,
            "x",
            "action",
        ),
        (
            '<rule id="x" action="a" priority="high"><pattern>u</pattern></rule>',
            GrammarSchemaError,
            9,
            "x",
            "priority",
        ),
        (
            '<rule id="x" action="a"><slot name="s" set="DIRECTION"/><pattern>up</pattern></rule>',
            GrammarSchemaError,
            9,
            "x",
            "no group",
        ),
        (
            '<rule id="x" action="a"><slot name="s" type="weird"/><pattern>(?P&lt;s&gt;up)</pattern></rule>',  # noqa: E501
            GrammarSchemaError,
            9,
            "x",
            "unknown type",
        ),
        (
            '<rule id="x" action="a"><pattern>up</pattern><pattern>down</pattern></rule>',
            GrammarSchemaError,
            9,
            "x",
            "exactly one",
        ),
    ],
)
def test_bad_rules(
    tmp_path: Path, extra: str, error: type, line: int, rule: str, words: str
) -> None:
    make(tmp_path, "\n" + extra)
    with pytest.raises(error) as exc:
        load_grammar(tmp_path)
    assert exc.value.file == "rules.xml"
    assert exc.value.line == line
    assert exc.value.rule == rule
    assert words in str(exc.value)
    assert str(exc.value).startswith(f"rules.xml:{line}: rule '{rule}':")


def test_chain_attribute(tmp_path: Path) -> None:
    rules = RULES.replace("{extra}", "").replace(
        '<grammar name="g">',
        '<grammar name="g">'
        '<rule id="land" action="land"><pattern>land</pattern></rule>'
        '<rule id="hover" action="hover"><pattern>hover</pattern></rule>',
    )
    rules = rules.replace(
        "</rules>",
        '<grammar name="q" chain="no">'
        '<rule id="help" action="help"><pattern>help</pattern></rule></grammar></rules>',
    )
    (tmp_path / "rules.xml").write_text(rules)
    (tmp_path / "states.xml").write_text(STATES)
    (tmp_path / "mappings.xml").write_text(MAPPINGS)
    nlu = NLU(tmp_path)
    assert nlu.interpret("land hover") == [{"action": "land"}, {"action": "hover"}]
    assert nlu.interpret("land help") == []  # a chain="no" grammar's command is never a part
    assert nlu.interpret("help") == [{"action": "help"}]
    (tmp_path / "rules.xml").write_text(rules.replace('chain="no"', 'chain="maybe"'))
    with pytest.raises(GrammarSchemaError, match='chain must be "yes" or "no"'):
        load_grammar(tmp_path)


def test_malformed_xml_names_file_and_line(tmp_path: Path) -> None:
    make(tmp_path, "\n\n<rule id='x' action='a'><pattern>up</patern></rule>")
    with pytest.raises(GrammarSyntaxError) as exc:
        load_grammar(tmp_path)
    assert exc.value.file == "rules.xml" and exc.value.line == 10


def test_entities_are_refused(tmp_path: Path) -> None:
    bomb = '<?xml version="1.0"?><!DOCTYPE m [<!ENTITY a "aaaa">]><mappings>&a;</mappings>'
    make(tmp_path, mappings=bomb)
    with pytest.raises(GrammarSyntaxError, match="refused"):
        load_grammar(tmp_path)


def test_unknown_grammar_in_states(tmp_path: Path) -> None:
    make(tmp_path, states='<states>\n<state name="LANDED">\n<grammar ref="nope"/></state></states>')
    with pytest.raises(UnknownGrammarError) as exc:
        load_grammar(tmp_path)
    assert (exc.value.file, exc.value.line) == ("states.xml", 3)


def test_set_cycles_and_unknown_sets(tmp_path: Path) -> None:
    make(
        tmp_path,
        mappings='<mappings><set name="A"><pattern>{B}</pattern></set>'
        '<set name="B"><pattern>{A}</pattern></set></mappings>',
    )
    with pytest.raises(UnknownSetError, match="refer to each other"):
        load_grammar(tmp_path)
    make(tmp_path, mappings='<mappings>\n<set name="lower"/></mappings>')
    with pytest.raises(GrammarSchemaError, match="upper case"):
        load_grammar(tmp_path)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(GrammarSyntaxError, match="cannot read"):
        load_grammar(tmp_path)


def test_reload_keeps_last_good_grammar(tmp_path: Path) -> None:
    make(tmp_path)
    nlu = NLU(tmp_path)
    # a good edit takes effect without a restart
    make(
        tmp_path,
        '<rule id="down" action="move"><const name="direction" value="down"/>'
        "<pattern>go down</pattern></rule>",
    )
    nlu.reload()
    assert nlu.interpret("go down") == [{"action": "move", "direction": "down"}]
    # a bad edit is refused and the last good grammar stays
    (tmp_path / "rules.xml").write_text("<rules><grammar name='g'>")
    with pytest.raises(GrammarError):
        nlu.reload()
    assert isinstance(nlu.last_error, GrammarSyntaxError)
    assert nlu.interpret("go down") == [{"action": "move", "direction": "down"}]


def test_shipped_grammar_copy_reloads(tmp_path: Path) -> None:
    for f in DEFAULT_GRAMMAR_DIR.glob("*.xml"):
        shutil.copy(f, tmp_path / f.name)
    nlu = NLU(tmp_path)
    before = nlu.interpret("take off")
    nlu.reload()
    assert nlu.interpret("take off") == before == [{"action": "takeoff"}]


def test_trie_regex_and_first_tokens() -> None:
    import re

    rx = re.compile(trie_regex(["go", "got", "going", "g o"]))
    assert all(rx.fullmatch(w) for w in ["go", "got", "going", "g o"])
    assert rx.fullmatch("goi") is None
    assert first_tokens("(?:go|fly) up") == {"go", "fly"}
    assert first_tokens("(?:go )?up") == {"go", "up"}
    assert first_tokens(r"\d+ m") == {"#"}
    assert first_tokens("a?") is None  # may match the empty string: tried for every clause
    assert first_tokens(r"\w+") is None


def test_cli_one_text_and_stdin_lines() -> None:
    out = io.StringIO()
    assert interpret_main(["take", "off"], io.StringIO(), out) == 0
    assert json.loads(out.getvalue()) == {"text": "take off", "commands": [{"action": "takeoff"}]}
    out = io.StringIO()
    assert interpret_main(None, io.StringIO("land\n\nfly to marker 2\n"), out) == 0
    lines = [json.loads(x) for x in out.getvalue().splitlines()]
    assert [x["commands"] for x in lines] == [
        [{"action": "land"}],
        [],
        [{"action": "goto", "marker": 2}],
    ]


def test_cli_bad_grammar_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    make(tmp_path, '<rule id="x" action="a"><pattern>(</pattern></rule>')
    assert interpret_main(["land"], io.StringIO(), io.StringIO(), grammar_dir=tmp_path) == 2
    assert "rules.xml:8: rule 'x'" in capsys.readouterr().err


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    data=st.binary(max_size=300), which=st.sampled_from(["rules.xml", "states.xml", "mappings.xml"])
)
def test_arbitrary_file_bytes_load_or_raise_grammar_error(
    tmp_path: Path, data: bytes, which: str
) -> None:
    make(tmp_path)
    (tmp_path / which).write_bytes(data)
    try:
        load_grammar(tmp_path)
    except GrammarError as exc:
        assert exc.file == which or exc.file in ("rules.xml", "states.xml")


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(pattern=st.text(alphabet="ab (){}?*+|[]^$\\<>PU=:", max_size=30))
def test_arbitrary_patterns_load_or_raise_grammar_error(tmp_path: Path, pattern: str) -> None:
    escaped = pattern.replace("]]>", "")
    make(tmp_path, f'<rule id="h" action="a"><pattern><![CDATA[{escaped}]]></pattern></rule>')
    try:
        NLU(tmp_path).interpret("a b")
    except GrammarError as exc:
        assert exc.file == "rules.xml"


def test_ambiguous_regex_syntax_is_a_load_error() -> None:
    """``[[`` compiles in Python today but is warned to change meaning: refused at load."""
    from server.language.grammar import compile_strict

    with pytest.raises(re.error, match="ambiguous"):
        compile_strict("[[a]")
    assert compile_strict("[a]").fullmatch("a")
