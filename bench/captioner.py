"""Scene captioner on held-out simulator scenes: quality and latency vs a trivial baseline.

Renders new scenes (test seed range of ``tools/make_caption_dataset.py``: placements, poses and
lighting never trained on), captions the full 640×360 frames with the shipped ONNX model on one
onnxruntime thread, and prints BLEU-4, object-mention precision/recall/F1, attribute F1 (kind +
colour + side + marker id) and per-image latency, for beam 3, greedy and the most frequent
training caption, all measured in this run.

    .venv/bin/python bench/captioner.py [--quick] [--n 300] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drone.sim.world import load_world  # noqa: E402
from server.captioner import Captioner, CaptionerUnavailable  # noqa: E402
from server.captioner.eval import Report, evaluate  # noqa: E402
from tools.make_caption_dataset import (  # noqa: E402
    COLOUR_NAMES,
    KINDS,
    SEED_BASE,
    items_of,
    make_sample,
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--model", type=Path, default=ROOT / "models" / "captioner")
    ap.add_argument("--n", type=int, default=300, help="held-out scenes")
    ap.add_argument("--quick", action="store_true", help="60 scenes")
    ap.add_argument("--json", type=Path, help="also write the results here")
    args = ap.parse_args(argv)
    n = 60 if args.quick else args.n
    try:
        cap = Captioner.load(args.model)
    except CaptionerUnavailable as exc:
        print(f"captioner unavailable: {exc.reason}")
        return 1
    training = json.loads((args.model / "training.json").read_text())
    baseline = training["baseline_caption"]

    worlds = {"indoor": load_world("indoor"), "outdoor": load_world("outdoor")}
    t0 = time.perf_counter()
    frames, refs, scenes, seen = [], [], [], []
    # Offset into the test range so the bench does not reuse the stored test split either.
    for i in range(n):
        frame, _, rec = make_sample(SEED_BASE["test"] + 500_000 + i, worlds)
        frames.append(frame)
        refs.append(rec["refs"])
        scenes.append(items_of(rec))
        seen.append(items_of(rec, "seen"))
    render_s = time.perf_counter() - t0
    cap.caption(frames[0])  # warm-up (first-run allocations) outside the timings

    def run(beam: int):
        def fn(i: int) -> tuple[str, float]:
            c = cap.caption(frames[i], beam=beam)
            return c.text, c.ms

        return fn

    reports: list[Report] = [
        evaluate("model, beam 3", run(3), refs, scenes, KINDS, COLOUR_NAMES, seen=seen),
        evaluate("model, greedy", run(1), refs, scenes, KINDS, COLOUR_NAMES, seen=seen),
        evaluate(
            "baseline: most frequent caption",
            lambda i: (baseline, 0.0),
            refs,
            scenes,
            KINDS,
            COLOUR_NAMES,
            seen=seen,
        ),
    ]
    base = reports[-1]
    print(
        f"captioner: {n} held-out rendered scenes ({render_s:.1f} s to render), 640×360 frames, "
        f"onnxruntime 1 thread; baseline caption: {baseline!r}\n"
    )
    head = (
        f"| {'system':<32} | BLEU-4 | ×base | obj P | obj R | obj F1 | attr F1 "
        f"| ms median | ms p90 |"
    )
    print(head)
    print("|" + "|".join("-" * (len(c)) for c in head.split("|")[1:-1]) + "|")
    rows = []
    for r in reports:
        ms = sorted(r.ms)
        p90 = ms[int(0.9 * (len(ms) - 1))] if ms else 0.0
        ratio = r.bleu4 / base.bleu4 if base.bleu4 > 0 else None
        shown = f"{ratio:5.1f}" if ratio is not None else "  n/a"
        o, a = r.mentions.objects, r.mentions.attributes
        print(
            f"| {r.name:<32} | {r.bleu4:6.1f} | {shown} | {o.precision:5.2f} | "
            f"{o.recall:5.2f} | {o.f1:6.2f} | {a.f1:7.2f} | {r.median_ms:9.2f} | {p90:6.2f} |"
        )
        rows.append(
            {
                "system": r.name,
                "bleu4": r.bleu4,
                "bleu4_vs_baseline": ratio,
                "object_precision": o.precision,
                "object_recall": o.recall,
                "object_f1": o.f1,
                "attribute_f1": a.f1,
                "ms_median": statistics.median(r.ms) if r.ms else 0.0,
                "ms_p90": p90,
            }
        )
    beam_ms, greedy_ms = reports[0].median_ms, reports[1].median_ms
    print(
        f"\nbeam 3 / greedy latency: {beam_ms / greedy_ms:.2f}×; "
        f"×base n/a: the baseline's BLEU-4 is 0 (a caption shorter than 4 words has no 4-grams)"
        if base.bleu4 == 0
        else f"\nbeam 3 / greedy latency: {beam_ms / greedy_ms:.2f}×"
    )
    print("\nExamples (beam 3):")
    for i in range(min(5, n)):
        print(f"  model: {cap.caption(frames[i]).text}\n  truth: {refs[i][0]}")
    print("\nCIDEr-D: not reported (no maintained package provides it; pycocoevalcap: 2020).")
    if args.json:
        args.json.write_text(json.dumps({"n": n, "rows": rows}, indent=1) + "\n")
    cap.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
