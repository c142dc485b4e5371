"""Errors of the language package (XML grammars and the NLU).

LanguageError
├── GrammarError            a grammar file cannot be used; ``file``, ``line`` and ``rule`` say where
│   ├── GrammarSyntaxError  malformed XML, or XML that defusedxml refuses (entities, DTDs)
│   ├── GrammarSchemaError  a missing/unknown element or attribute, a bad priority or value
│   ├── UnknownSetError     a rule uses {NAME} but mappings.xml has no set NAME (or sets cycle)
│   ├── InvalidRegexError   a rule's pattern is not a valid regular expression
│   ├── DuplicateRuleError  two rules share an id
│   └── UnknownGrammarError states.xml names a grammar that rules.xml does not define
└── UnknownStateError       ``interpret(text, state)`` with a state states.xml does not list
                            (also a KeyError, so REST can answer 422)

Text the NLU cannot understand is not an error: it yields ``[]``.
"""

from __future__ import annotations


class LanguageError(Exception):
    """Base of the language package's errors."""


class GrammarError(LanguageError):
    """A grammar file is unusable. ``str()`` reads ``file:line: rule 'id': message``."""

    def __init__(
        self, message: str, *, file: str, line: int | None = None, rule: str | None = None
    ) -> None:
        self.message = message
        self.file = file
        self.line = line
        self.rule = rule
        where = file if line is None else f"{file}:{line}"
        who = f" rule '{rule}':" if rule else ""
        super().__init__(f"{where}:{who} {message}")


class GrammarSyntaxError(GrammarError):
    """The file is not well-formed XML, or uses XML features refused for safety."""


class GrammarSchemaError(GrammarError):
    """An element or attribute is missing, unknown or has an unusable value."""


class UnknownSetError(GrammarError):
    """A pattern refers to ``{NAME}`` and no set NAME exists (or sets refer to each other)."""


class InvalidRegexError(GrammarError):
    """A pattern does not compile as a Python regular expression."""


class DuplicateRuleError(GrammarError):
    """A rule id is used twice."""


class UnknownGrammarError(GrammarError):
    """states.xml names a grammar that rules.xml does not define."""


class UnknownStateError(LanguageError, KeyError):
    """The dialog state is not listed in states.xml."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else "unknown state"
