"""Greedy and beam search over a one-step decoder, in numpy, with no model inside.

``step(tokens, state) -> (logits, state)`` advances a batch of hypotheses by one token
(tokens: int64 ``[B]``, state: float32 ``[B, S]``, logits: ``[B, V]``). The captioner wraps the
ONNX decoder in such a function; tests drive the searches with small hand-built decoders.

Scores are sums of natural-log probabilities (Show and Tell, Vinyals et al. 2015, §3: the
sentence maximising log p(S|I) is approximated by beam search).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float32]
IntArray = npt.NDArray[np.int64]
StepFn = Callable[[IntArray, FloatArray], tuple[npt.NDArray[np.floating], FloatArray]]


@dataclass(frozen=True)
class Hypothesis:
    """Token ids (without bos, without eos), total log-probability, whether eos was produced."""

    ids: tuple[int, ...]
    logprob: float
    finished: bool


def log_softmax(logits: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
    """Row-wise log-softmax in float64 (stable: subtract the row maximum first)."""
    x = np.asarray(logits, dtype=np.float64)
    x = x - x.max(axis=-1, keepdims=True)
    out: npt.NDArray[np.float64] = x - np.log(np.exp(x).sum(axis=-1, keepdims=True))
    return out


def greedy(step: StepFn, state0: FloatArray, *, bos: int, eos: int, max_len: int) -> Hypothesis:
    """Pick the most probable token at each step until eos or ``max_len`` tokens."""
    _check(max_len, 1)
    state = np.asarray(state0, dtype=np.float32).reshape(1, -1)
    token = np.array([bos], dtype=np.int64)
    ids: list[int] = []
    total = 0.0
    for _ in range(max_len):
        logits, state = step(token, state)
        logp = log_softmax(logits)[0]
        best = int(np.argmax(logp))
        total += float(logp[best])
        if best == eos:
            return Hypothesis(tuple(ids), total, True)
        ids.append(best)
        token = np.array([best], dtype=np.int64)
    return Hypothesis(tuple(ids), total, False)


def beam_search(
    step: StepFn, state0: FloatArray, *, bos: int, eos: int, max_len: int, beam: int = 3
) -> Hypothesis:
    """Keep the ``beam`` best prefixes at each step; return the best complete sentence.

    A hypothesis ends when it emits eos. Search stops when no live prefix can beat the best
    finished one (log-probabilities only fall as tokens are added) or after ``max_len`` tokens;
    if nothing finished, the best live prefix is returned with ``finished=False``.
    ``beam=1`` is exactly greedy search.
    """
    _check(max_len, beam)
    state = np.asarray(state0, dtype=np.float32).reshape(1, -1)
    tokens = np.array([bos], dtype=np.int64)
    prefixes: list[tuple[int, ...]] = [()]
    scores = np.zeros(1, dtype=np.float64)
    best_done: Hypothesis | None = None
    for _ in range(max_len):
        logits, new_state = step(tokens, state)
        logp = log_softmax(logits)
        vocab = logp.shape[1]
        total = scores[:, None] + logp  # [live, V]
        flat = total.ravel()
        # Candidates in descending score; ties broken by (row, token) index, so deterministic.
        k = min(len(flat), 2 * beam)
        top = np.argpartition(-flat, k - 1)[:k] if k < len(flat) else np.arange(len(flat))
        top = top[np.lexsort((top, -flat[top]))]
        keep_rows: list[int] = []
        keep_tokens: list[int] = []
        keep_scores: list[float] = []
        for rank, idx in enumerate(top):
            row, tok = divmod(int(idx), vocab)
            score = float(flat[idx])
            if tok == eos:
                # Only an eos ranked among this step's ``beam`` best ends a sentence (as in
                # fairseq's search), which makes beam=1 identical to greedy search.
                if rank < beam and (best_done is None or score > best_done.logprob):
                    best_done = Hypothesis(prefixes[row], score, True)
                continue
            if len(keep_rows) < beam:
                keep_rows.append(row)
                keep_tokens.append(tok)
                keep_scores.append(score)
        if not keep_rows:
            break
        if best_done is not None and keep_scores[0] <= best_done.logprob:
            break
        prefixes = [prefixes[r] + (t,) for r, t in zip(keep_rows, keep_tokens, strict=True)]
        scores = np.array(keep_scores, dtype=np.float64)
        state = np.ascontiguousarray(new_state[keep_rows])
        tokens = np.array(keep_tokens, dtype=np.int64)
    if best_done is not None:
        return best_done
    return Hypothesis(prefixes[0], float(scores[0]), False)


def _check(max_len: int, beam: int) -> None:
    if max_len < 1:
        raise ValueError(f"max_len must be >= 1, got {max_len}")
    if beam < 1:
        raise ValueError(f"beam must be >= 1, got {beam}")
