"""Train the scene captioner on the generated dataset and export it to ONNX.

Show and Tell (Vinyals et al., CVPR 2015): a CNN encodes the image; its embedding starts an LSTM
that is trained with teacher forcing to maximise log p(caption | image). Here the embedding both
initialises the LSTM state and is fed with every word (as in m-RNN, Mao et al. 2015), which keeps
the image in view for the whole sentence at almost no cost. Small on purpose: 19 000 96×160
images, one CPU thread, 24 epochs in about 55 minutes; the defaults reproduce the shipped model.

    .venv/bin/python tools/train_captioner.py --data data/captions --out models/captioner

Needs the ``[train]`` extra (torch, onnx). Exports ``encoder.onnx``, ``decoder.onnx``,
``vocab.json`` and ``training.json``; the I/O contract is in ``models/captioner/MODEL.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import random
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch
from torch import nn

from server.captioner.eval import mention_scores, most_frequent_caption
from server.captioner.model import to_input
from server.captioner.references import SIDES, SceneItem
from server.captioner.vocab import Vocab
from tools.make_caption_dataset import COLOUR_NAMES as CELL_COLOURS
from tools.make_caption_dataset import KINDS as CELL_KINDS

# ImageNet statistics (RGB); applied inside the encoder graph so the ONNX input stays [0, 1].
MEAN = (0.485, 0.456, 0.406)
STD = (0.229, 0.224, 0.225)


class Encoder(nn.Module):
    """Image [N, 3, 96, 160] in [0, 1] -> decoder state [N, 2H + C] = (h0, c0, context)."""

    def __init__(
        self, hidden: int, context: int, concepts: int = 0, grid: tuple[int, int] = (6, 10)
    ) -> None:
        super().__init__()

        def block(cin: int, cout: int, stride: int) -> list[nn.Module]:
            return [
                nn.Conv2d(cin, cout, 3, stride, 1, bias=False),
                nn.BatchNorm2d(cout),
                nn.ReLU(inplace=True),
            ]

        self.register_buffer("mean", torch.tensor(MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(STD).view(1, 3, 1, 1))
        self.trunk = nn.Sequential(
            *block(3, 24, 2),  # 48×80
            *block(24, 32, 2),  # 24×40
            *block(32, 48, 1),
            *block(48, 64, 2),  # 12×20
            *block(64, 64, 1),
        )
        self.last = nn.Sequential(*block(64, 64, 2))  # 6×10
        # Keep the spatial grid (no global pooling): left/right and near/far live in *where*
        # features fire, which a pooled vector would lose.
        self.pool = nn.AdaptiveAvgPool2d(grid)
        flat = 64 * grid[0] * grid[1]
        self.project = nn.Sequential(nn.Dropout(0.2), nn.Linear(flat, context), nn.ReLU())
        # LSTM-A (Yao et al. 2017): the concept head's probabilities join the image context
        # the decoder reads at every step; 0 keeps the plain NIC context.
        self.concepts = nn.Linear(context, concepts) if concepts else None
        width = context + concepts
        self.init_h = nn.Linear(width, hidden)
        self.init_c = nn.Linear(width, hidden)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.encode(image)[0]

    def encode(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(decoder state, 12×20 feature map, image context); the map feeds the training-only
        cell head, the context the concept head (or, with LSTM-A, its logits)."""
        fmap = self.trunk((image - self.mean) / self.std)
        ctx = self.project(self.pool(self.last(fmap)).flatten(1))
        if self.concepts is not None:
            logits = self.concepts(ctx)
            ctx, head_in = torch.cat([ctx, torch.sigmoid(logits)], dim=1), logits
        else:
            head_in = ctx
        state = torch.cat([torch.tanh(self.init_h(ctx)), self.init_c(ctx), ctx], dim=1)
        return state, fmap, head_in


class Decoder(nn.Module):
    """One LSTM over [word embedding; image context]; the state vector is (h, c, context)."""

    def __init__(self, vocab: int, hidden: int, context: int, embed: int = 64) -> None:
        super().__init__()
        self.hidden = hidden
        self.context = context
        self.embed = nn.Embedding(vocab, embed)
        self.lstm = nn.LSTM(embed + context, hidden, batch_first=True)
        self.drop = nn.Dropout(0.2)
        self.out = nn.Linear(hidden, vocab)

    def split(self, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        h = self.hidden
        return state[:, :h], state[:, h : 2 * h], state[:, 2 * h :]

    def forward(self, tokens: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """Teacher forcing: tokens [N, T] -> logits [N, T, V]."""
        h, c, ctx = self.split(state)
        emb = self.embed(tokens)
        x = torch.cat([emb, ctx[:, None, :].expand(-1, tokens.shape[1], -1)], dim=2)
        y, _ = self.lstm(x, (h[None].contiguous(), c[None].contiguous()))
        return self.out(self.drop(y))

    def step(self, token: torch.Tensor, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One word: token [N] + state [N, S] -> logits [N, V], state_out [N, S]."""
        h, c, ctx = self.split(state)
        x = torch.cat([self.embed(token), ctx], dim=1)[:, None, :]
        y, (h2, c2) = self.lstm(x, (h[None].contiguous(), c[None].contiguous()))
        return self.out(y[:, 0]), torch.cat([h2[0], c2[0], ctx], dim=1)


class DecoderStep(nn.Module):
    def __init__(self, decoder: Decoder) -> None:
        super().__init__()
        self.decoder = decoder

    def forward(
        self, token: torch.Tensor, state: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return self.decoder.step(token, state)


def load_split(data: Path, split: str) -> tuple[np.ndarray, list[dict[str, Any]]]:
    images = np.load(data / f"{split}.npz")["images"]
    meta = [json.loads(line) for line in (data / f"{split}.jsonl").read_text().splitlines()]
    if len(meta) != len(images):
        raise SystemExit(f"{split}: {len(images)} images but {len(meta)} caption records")
    return images, meta


def encode_refs(vocab: Vocab, refs: list[str], max_len: int) -> list[list[int]]:
    out = []
    for r in refs:
        ids = vocab.encode(r)[: max_len - 1]
        out.append([vocab.bos, *ids, vocab.eos])
    return out


def batch_tokens(seqs: list[list[int]], pad: int) -> torch.Tensor:
    width = max(len(s) for s in seqs)
    arr = np.full((len(seqs), width), pad, dtype=np.int64)
    for i, s in enumerate(seqs):
        arr[i, : len(s)] = s
    return torch.from_numpy(arr)


def evaluate_loss(
    enc: Encoder, dec: Decoder, images: np.ndarray, refs: list[list[list[int]]], pad: int
) -> float:
    enc.eval()
    dec.eval()
    total, count = 0.0, 0
    loss_fn = nn.CrossEntropyLoss(ignore_index=pad, reduction="sum")
    with torch.no_grad():
        for start in range(0, len(images), 128):
            x = torch.from_numpy(to_input(images[start : start + 128]))
            seqs = [r[0] for r in refs[start : start + 128]]
            tok = batch_tokens(seqs, pad)
            logits = dec(tok[:, :-1], enc(x))
            total += float(loss_fn(logits.reshape(-1, logits.shape[-1]), tok[:, 1:].reshape(-1)))
            count += int((tok[:, 1:] != pad).sum())
    return total / max(count, 1)


def export(enc: Encoder, dec: Decoder, out: Path, hw: tuple[int, int]) -> None:
    enc.eval()
    dec.eval()
    image = torch.zeros(1, 3, *hw)
    state = enc(image)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the legacy exporter announces its own deprecation
        torch.onnx.export(
            enc,
            (image,),
            str(out / "encoder.onnx"),
            input_names=["image"],
            output_names=["state"],
            dynamic_axes={"image": {0: "batch"}, "state": {0: "batch"}},
            opset_version=17,
            dynamo=False,
        )
        torch.onnx.export(
            DecoderStep(dec),
            (torch.zeros(1, dtype=torch.long), state),
            str(out / "decoder.onnx"),
            input_names=["token", "state"],
            output_names=["logits", "state_out"],
            dynamic_axes={n: {0: "batch"} for n in ("token", "state", "logits", "state_out")},
            opset_version=17,
            dynamo=False,
        )


def attribute_targets(
    meta: list[dict[str, Any]], kinds: list[str], colours: list[str]
) -> np.ndarray:
    """Multi-hot concepts per image from the mentionable items: kind×side, colour×side,
    kind×near. An auxiliary loss on them makes the encoder learn *what* is where fast
    (attribute supervision, as in Yao et al., "Boosting Image Captioning with Attributes", 2017).
    """
    nk, nc = len(kinds), len(colours)
    out = np.zeros((len(meta), 3 * nk + 3 * nc + 2 * nk), np.float32)
    for i, m in enumerate(meta):
        for it in m["items"]:
            k = kinds.index(it["kind"])
            side = SIDES.index(it["side"])
            out[i, side * nk + k] = 1.0
            if it["colour"] in colours:
                out[i, 3 * nk + side * nc + colours.index(it["colour"])] = 1.0
            out[i, 3 * nk + 3 * nc + int(it["near"]) * nk + k] = 1.0
    return out


def flip_targets(t: torch.Tensor, nk: int, nc: int) -> torch.Tensor:
    """Swap the left and right blocks of the concept targets (mirror image)."""
    left, ahead, right = t[:, :nk], t[:, nk : 2 * nk], t[:, 2 * nk : 3 * nk]
    o = 3 * nk
    cl, ca, cr = t[:, o : o + nc], t[:, o + nc : o + 2 * nc], t[:, o + 2 * nc : o + 3 * nc]
    return torch.cat([right, ahead, left, cr, ca, cl, t[:, o + 3 * nc :]], dim=1)


def greedy_batch(
    enc: Encoder, dec: Decoder, x: torch.Tensor, vocab: Vocab, max_len: int
) -> list[str]:
    """Greedy captions for a batch (validation only; the server uses the ONNX files)."""
    state = enc(x)
    token = torch.full((x.shape[0],), vocab.bos, dtype=torch.long)
    out = torch.zeros((x.shape[0], max_len), dtype=torch.long)
    for t in range(max_len):
        logits, state = dec.step(token, state)
        token = logits.argmax(dim=1)
        out[:, t] = token
    return [" ".join(vocab.words(row.tolist())) for row in out]


def validate(
    enc: Encoder,
    dec: Decoder,
    images: np.ndarray,
    meta: list[dict[str, Any]],
    vocab: Vocab,
    kinds: list[str],
    colours: list[str],
    max_len: int,
) -> tuple[float, float]:
    """Object-mention F1 and attribute F1 of greedy captions on the validation split."""
    enc.eval()
    dec.eval()
    caps: list[str] = []
    with torch.no_grad():
        for start in range(0, len(images), 128):
            x = torch.from_numpy(to_input(images[start : start + 128]))
            caps += greedy_batch(enc, dec, x, vocab, max_len)
    scenes = [[SceneItem(**d) for d in m["items"]] for m in meta]
    seen = [[SceneItem(**d) for d in m["seen"]] for m in meta]
    sc = mention_scores(caps, scenes, kinds, colours, seen)
    return sc.objects.f1, sc.attributes.f1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--data", type=Path, default=Path("data/captions"))
    ap.add_argument("--train-splits", default="train,train2,train3", help="those present are used")
    ap.add_argument("--out", type=Path, default=Path("models/captioner"))
    ap.add_argument("--epochs", type=int, default=24)
    ap.add_argument(
        "--budget-min",
        type=float,
        default=0.0,
        help="wall-time budget: the learning rate follows a cosine over it and training stops at "
        "its end (0: no budget, the cosine runs over --epochs; exactly reproducible)",
    )
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--lr", type=float, default=3e-3)
    ap.add_argument("--hidden", type=int, default=256)
    ap.add_argument("--context", type=int, default=160)
    ap.add_argument(
        "--aux-weight", type=float, default=2.0, help="weight of the concept and cell losses"
    )
    ap.add_argument(
        "--attr-input",
        action="store_true",
        help="LSTM-A: feed the concept probabilities to the decoder with the image context",
    )
    ap.add_argument(
        "--colour-head", action="store_true", help="also supervise each cell's colour (try)"
    )
    ap.add_argument("--no-jitter", action="store_true", help="no brightness/contrast jitter")
    ap.add_argument("--max-len", type=int, default=40)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)

    torch.manual_seed(args.seed)
    random.seed(args.seed)
    torch.set_num_threads(args.threads)
    rng = random.Random(args.seed)
    t0 = time.perf_counter()

    parts = [
        load_split(args.data, name)
        for name in args.train_splits.split(",")
        if (args.data / f"{name}.npz").exists()
    ]
    train_x = np.concatenate([p[0] for p in parts])
    train_meta = [m for p in parts for m in p[1]]
    val_x, val_meta = load_split(args.data, "val")
    hw = (int(train_x.shape[1]), int(train_x.shape[2]))
    words = {w for m in train_meta for r in m["refs"] for w in r.split()}
    vocab = Vocab.build(words)
    train_refs = [encode_refs(vocab, m["refs"], args.max_len) for m in train_meta]
    val_refs = [encode_refs(vocab, m["refs"], args.max_len) for m in val_meta]
    kinds = sorted({it["kind"] for m in train_meta for it in m["seen"]})
    colours = sorted({it["colour"] for m in train_meta for it in m["seen"] if it["colour"]})
    concepts = torch.from_numpy(attribute_targets(train_meta, kinds, colours))
    cell_parts = [
        np.load(args.data / f"{name}_cells.npy")
        for name in args.train_splits.split(",")
        if (args.data / f"{name}.npz").exists()
    ]
    cells = torch.from_numpy(np.concatenate(cell_parts).astype(np.int64))  # [N, 2, 12, 20]
    cells[:, 1][cells[:, 1] == 255] = -100  # no colour: ignored by the colour loss
    if len(cells) != len(train_x):
        raise SystemExit("cell maps do not match the training images: run --cells again")
    # Mirror images swap left and right; markers would mirror into other ids, so scenes whose
    # references name a marker are never flipped.
    flippable = np.array([all(it["kind"] != "marker" for it in m["items"]) for m in train_meta])
    index = {t: i for i, t in enumerate(vocab.tokens)}
    lr_ids = (index.get("left", vocab.unk), index.get("right", vocab.unk))
    print(
        f"train {len(train_x)} val {len(val_x)} images {hw}, vocab {len(vocab)}, "
        f"concepts {concepts.shape[1]}, flippable {flippable.mean():.0%}",
        flush=True,
    )

    n_concepts = concepts.shape[1] if args.attr_input else 0
    enc = Encoder(args.hidden, args.context, n_concepts)
    dec = Decoder(len(vocab), args.hidden, args.context + n_concepts)
    # Training only, not exported; with LSTM-A the encoder's own concept layer is the head.
    aux: nn.Module = (
        nn.Identity() if args.attr_input else nn.Linear(args.context, concepts.shape[1])
    )
    # Dense supervision (training only): which kind covers each cell of the 12×20 feature map,
    # from the renderer's id buffer; teaches shapes far faster than a few caption words.
    cell_head = nn.Conv2d(64, len(CELL_KINDS) + 1, 1)
    params = [*enc.parameters(), *dec.parameters(), *aux.parameters(), *cell_head.parameters()]
    colour_head = nn.Conv2d(64, len(CELL_COLOURS), 1)  # and the colour of what covers it
    if args.colour_head:
        params += list(colour_head.parameters())
    n_export = sum(p.numel() for p in [*enc.parameters(), *dec.parameters()])
    print(f"parameters: {n_export:,} exported", flush=True)
    opt = torch.optim.AdamW(params, lr=args.lr, weight_decay=1e-4)
    steps_per_epoch = (len(train_x) + args.batch - 1) // args.batch
    total_steps = args.epochs * steps_per_epoch
    warmup = 150
    loss_fn = nn.CrossEntropyLoss(ignore_index=vocab.pad)
    bce = nn.BCEWithLogitsLoss()
    cell_weight = torch.ones(len(CELL_KINDS) + 1)
    cell_weight[0] = 0.2  # walls and floor dominate the cells
    cell_ce = nn.CrossEntropyLoss(weight=cell_weight)
    colour_ce = nn.CrossEntropyLoss(ignore_index=-100)
    history = []
    budget_s = args.budget_min * 60.0
    epochs_done = 0
    step = 0
    out_of_time = False
    best_score = -1.0
    best_state: dict[str, Any] | None = None
    for epoch in range(args.epochs):
        enc.train()
        dec.train()
        order = list(range(len(train_x)))
        rng.shuffle(order)
        running = 0.0
        for b in range(steps_per_epoch):
            # Warm-up, then a cosine decay over the wall-time budget (or over all steps), so the
            # rate anneals fully however busy the shared CPU is.
            frac = (time.perf_counter() - t0) / budget_s if budget_s > 0 else step / total_steps
            if frac >= 1.0:
                out_of_time = True
                break
            lr = args.lr * min(1.0, (step + 1) / warmup) * 0.5 * (1.0 + math.cos(math.pi * frac))
            for group in opt.param_groups:
                group["lr"] = lr
            step += 1
            idx = order[b * args.batch : (b + 1) * args.batch]
            x = torch.from_numpy(to_input(train_x[idx]))
            if not args.no_jitter:
                # Brightness/contrast jitter on top of the renderer's lighting variety.
                gain = torch.empty(len(idx), 1, 1, 1).uniform_(0.8, 1.2)
                bias = torch.empty(len(idx), 1, 1, 1).uniform_(-0.06, 0.06)
                x = (x * gain + bias).clamp(0.0, 1.0)
            target = concepts[idx]
            cell_target = cells[idx]
            flip = torch.from_numpy(flippable[idx] & (np.array([rng.random() for _ in idx]) < 0.5))
            seqs = [rng.choice(train_refs[i]) for i in idx]
            if flip.any():
                x[flip] = torch.flip(x[flip], dims=[3])
                cell_target = cell_target.clone()
                cell_target[flip] = torch.flip(cell_target[flip], dims=[3])
                target = torch.where(
                    flip[:, None], flip_targets(target, len(kinds), len(colours)), target
                )
                swap = {lr_ids[0]: lr_ids[1], lr_ids[1]: lr_ids[0]}
                seqs = [
                    [swap.get(t, t) for t in s] if f else s
                    for s, f in zip(seqs, flip.tolist(), strict=True)
                ]
            tok = batch_tokens(seqs, vocab.pad)
            state, fmap, head_in = enc.encode(x)
            logits = dec(tok[:, :-1], state)
            loss = loss_fn(logits.reshape(-1, logits.shape[-1]), tok[:, 1:].reshape(-1))
            loss = loss + args.aux_weight * bce(aux(head_in), target)
            loss = loss + args.aux_weight * cell_ce(cell_head(fmap), cell_target[:, 0])
            if args.colour_head:
                loss = loss + args.aux_weight * colour_ce(colour_head(fmap), cell_target[:, 1])
            opt.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(params, 5.0)
            opt.step()
            running += loss.item()
        epochs_done = epoch + 1
        val_loss = evaluate_loss(enc, dec, val_x, val_refs, vocab.pad)
        obj_f1, attr_f1 = validate(enc, dec, val_x, val_meta, vocab, kinds, colours, args.max_len)
        elapsed = time.perf_counter() - t0
        history.append(
            {
                "epoch": epochs_done,
                "steps": step,
                "train_loss": round(running / max(b, 1), 4),
                "val_loss": round(val_loss, 4),
                "val_object_f1": round(obj_f1, 4),
                "val_attribute_f1": round(attr_f1, 4),
            }
        )
        print(
            f"epoch {epochs_done:2d}  step {step}  train {running / max(b, 1):.3f}  "
            f"val {val_loss:.3f}  obj F1 {obj_f1:.3f}  attr F1 {attr_f1:.3f}  "
            f"{elapsed / 60:.1f} min",
            flush=True,
        )
        if obj_f1 + attr_f1 > best_score:
            best_score = obj_f1 + attr_f1
            best_state = {
                "enc": {k: v.clone() for k, v in enc.state_dict().items()},
                "dec": {k: v.clone() for k, v in dec.state_dict().items()},
                "epoch": epochs_done,
            }
        if out_of_time:
            print(f"stopping: the {args.budget_min} min budget is spent")
            break
    assert best_state is not None
    enc.load_state_dict(best_state["enc"])
    dec.load_state_dict(best_state["dec"])

    args.out.mkdir(parents=True, exist_ok=True)
    export(enc, dec, args.out, hw)
    vocab.save(args.out / "vocab.json")
    train_s = time.perf_counter() - t0
    record = {
        "command": "tools/train_captioner.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "seed": args.seed,
        "threads": args.threads,
        "torch": torch.__version__,
        "train_images": len(train_x),
        "val_images": len(val_x),
        "input_hw": list(hw),
        "vocab": len(vocab),
        "parameters": n_export,
        "epochs": epochs_done,
        "best_epoch": best_state["epoch"],
        "baseline_caption": most_frequent_caption([m["refs"] for m in train_meta]),
        "wall_time_s": round(train_s, 1),
        "history": history,
    }
    (args.out / "training.json").write_text(json.dumps(record, indent=1) + "\n")
    print(f"exported to {args.out} in {train_s / 60:.1f} min", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
