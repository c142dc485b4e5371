"""Greedy and beam search on small hand-built decoders (bigram tables; no model needed)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.captioner.search import beam_search, greedy, log_softmax

BOS, EOS = 1, 2


def bigram(table: np.ndarray):
    """A decoder whose next-token distribution depends only on the last token."""

    def step(tokens: np.ndarray, state: np.ndarray):
        return np.log(table[tokens] + 1e-12), state

    return step


def chain() -> np.ndarray:
    # tokens: 0 pad, 1 bos, 2 eos, 3 a, 4 b, 5 c, 6 d
    t = np.zeros((7, 7))
    t[BOS, 3], t[BOS, 4] = 0.55, 0.45  # greedy takes "a" ...
    t[3, 5], t[3, 6] = 0.5, 0.5  # ... then a coin flip: 0.55 * 0.5 = 0.275
    t[4, EOS], t[4, 3] = 0.95, 0.05  # "b <eos>" is better: 0.45 * 0.95 = 0.4275
    t[5, EOS] = t[6, EOS] = 1.0
    t[0, EOS] = t[EOS, EOS] = 1.0
    return t


def test_beam_finds_the_better_sentence_greedy_misses() -> None:
    step, s0 = bigram(chain()), np.zeros((1, 1), np.float32)
    g = greedy(step, s0, bos=BOS, eos=EOS, max_len=5)
    b = beam_search(step, s0, bos=BOS, eos=EOS, max_len=5, beam=2)
    assert g.ids == (3, 5) and g.finished
    assert math.isclose(g.logprob, math.log(0.275), rel_tol=1e-6)
    assert b.ids == (4,) and b.finished
    assert math.isclose(b.logprob, math.log(0.4275), rel_tol=1e-6)


def test_max_len_stops_an_endless_sentence() -> None:
    t = np.full((4, 4), 1e-6)
    t[:, 3] = 1.0  # always "3", never eos
    step, s0 = bigram(t), np.zeros((1, 1), np.float32)
    g = greedy(step, s0, bos=BOS, eos=EOS, max_len=4)
    b = beam_search(step, s0, bos=BOS, eos=EOS, max_len=4, beam=3)
    assert g.ids == (3, 3, 3, 3) and not g.finished
    assert len(b.ids) <= 4


@pytest.mark.parametrize("bad", [{"beam": 0}, {"max_len": 0}])
def test_bad_arguments_raise_value_error(bad: dict[str, int]) -> None:
    kwargs = {"bos": BOS, "eos": EOS, "max_len": 3, "beam": 2, **bad}
    with pytest.raises(ValueError):
        beam_search(bigram(chain()), np.zeros((1, 1), np.float32), **kwargs)


tables = st.integers(0, 2**31 - 1).map(
    lambda seed: np.random.default_rng(seed).dirichlet(np.full(5, 0.5), size=5)
)


@settings(max_examples=60, deadline=None)
@given(tables)
def test_beam_of_one_is_greedy(table: np.ndarray) -> None:
    step, s0 = bigram(table), np.zeros((1, 1), np.float32)
    g = greedy(step, s0, bos=BOS, eos=EOS, max_len=6)
    b = beam_search(step, s0, bos=BOS, eos=EOS, max_len=6, beam=1)
    assert (g.ids, g.finished) == (b.ids, b.finished)
    assert math.isclose(g.logprob, b.logprob, rel_tol=1e-9, abs_tol=1e-9)


@settings(max_examples=40, deadline=None)
@given(tables)
def test_wide_beam_finds_the_exhaustive_optimum(table: np.ndarray) -> None:
    """With a beam wider than every prefix set, beam search is exact (max_len 3, 5 tokens)."""
    step, s0 = bigram(table), np.zeros((1, 1), np.float32)
    logp = np.log(table + 1e-12)
    best = -math.inf
    for n in range(0, 3):  # n words then eos, within 3 steps
        for words in itertools.product(range(5), repeat=n):
            if EOS in words:
                continue
            seq = [BOS, *words, EOS]
            best = max(best, sum(logp[a, b] for a, b in itertools.pairwise(seq)))
    b = beam_search(step, s0, bos=BOS, eos=EOS, max_len=3, beam=200)
    assert b.finished
    assert math.isclose(b.logprob, best, rel_tol=1e-9, abs_tol=1e-9)


def test_log_softmax_is_stable_for_huge_logits() -> None:
    out = log_softmax(np.array([[1e4, 0.0, -1e4]]))
    assert np.all(np.isfinite(out[0, :2])) and math.isclose(out[0, 0], 0.0, abs_tol=1e-12)
