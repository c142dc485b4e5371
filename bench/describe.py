"""Are descriptions true? Held-out simulator frames scored against the simulator's truth.

Renders ``--n`` held-out frames (``server.captioner.evalset``: both worlds, as shipped and with
randomised objects, seeded random poses, lighting, noise, half through JPEG), describes each
with every system below in the same run, and prints object-kind precision and recall, colour
accuracy, the rate of naming something not in view, marker figures and latency:

* baseline: the captioner's sentence with marker ids from the ArUco detector (the describer
  before grounding);
* grounded: the sentence checked against the image (``server.captioner.service.ground``);
* detector only: the grounded describer with an empty caption (what the image alone names).

The truth is read only here, to score; the describers see nothing but the frame.

    .venv/bin/python bench/describe.py [--n 400] [--quick] [--by-kind] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drone.sim.world import COLOURS, OBJECT_KINDS  # noqa: E402
from server.captioner import Captioner, CaptionerUnavailable  # noqa: E402
from server.captioner.eval import (  # noqa: E402
    DescriptionScores,
    TruthItem,
    recall_by_kind,
    score_descriptions,
)
from server.captioner.evalset import SEED_BASE, Sample, samples  # noqa: E402
from server.captioner.grounding import ground_marker_ids, ground_objects, sentence  # noqa: E402
from server.captioner.markers import MarkerDetector  # noqa: E402
from server.captioner.scene import parse  # noqa: E402
from server.captioner.service import ground  # noqa: E402

KINDS = (*sorted(OBJECT_KINDS), "marker")
TARGETS = {"kind P": 0.90, "kind R": 0.80, "colour": 0.90, "absent": 0.02}


def truth_items(s: Sample) -> list[TruthItem]:
    return [
        TruthItem(t.kind, t.colour, t.side, t.area, t.marker_id, t.mentionable) for t in s.truth
    ]


def run(
    name: str, fn: Callable[[Sample], str], frames: Sequence[Sample]
) -> tuple[str, list[str], list[float]]:
    texts, ms = [], []
    for s in frames:
        t0 = time.perf_counter()
        texts.append(fn(s))
        ms.append((time.perf_counter() - t0) * 1000.0)
    return name, texts, ms


def row(name: str, r: DescriptionScores, ms: list[float] | None) -> str:
    lat = f"{statistics.median(ms):7.1f}" if ms else "      –"
    return (
        f"| {name:<22} | {r.frames:4d} | {r.kind_precision:6.3f} | {r.kind_recall:6.3f} "
        f"| {r.colour_accuracy:6.3f} | {r.named_but_absent:6.3f} | {r.frames_with_absent:6.3f} "
        f"| {r.marker_with_id:5.3f} | {r.marker_id_correct:5.3f} | {r.marker_recall:5.3f} "
        f"| {r.side_accuracy:5.3f} | {lat} |"
    )


HEAD = (
    "| system                 |    n | kind P | kind R | colour | absent | frames "
    "| m.id  | id ok | m. R  | side  | ms med. |\n"
    "|------------------------|------|--------|--------|--------|--------|--------"
    "|-------|-------|-------|-------|---------|"
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--model", type=Path, default=ROOT / "models" / "captioner")
    ap.add_argument("--n", type=int, default=400, help="held-out frames (even: both worlds)")
    ap.add_argument("--quick", action="store_true", help="80 frames")
    ap.add_argument("--start", type=int, default=SEED_BASE, help="first seed")
    ap.add_argument("--json", type=Path, help="also write the results here")
    ap.add_argument("--examples", type=int, default=6)
    ap.add_argument(
        "--by-kind", action="store_true", help="the grounded recall per kind in each world"
    )
    args = ap.parse_args(argv)
    n = 80 if args.quick else args.n
    try:
        cap = Captioner.load(args.model)
    except CaptionerUnavailable as exc:
        print(f"captioner unavailable: {exc.reason}")
        return 1
    if cap.regions is None:
        print(f"no regions.json in {args.model}: nothing to ground with")
        return 1
    t0 = time.perf_counter()
    frames = list(samples(n, args.start))
    render_s = time.perf_counter() - t0
    detector = MarkerDetector()

    def baseline(s: Sample) -> str:
        seen = [m.seen() for m in detector.detect(s.frame)]
        return ground_marker_ids(cap.caption(s.frame).text, seen)

    def detector_only(s: Sample) -> str:
        markers = detector.detect(s.frame)
        scene = parse(s.frame, cap.regions, [m.box for m in markers])
        return sentence(ground_objects("", scene.regions), [m.seen() for m in markers])

    ground(cap, frames[0].frame)  # warm-up outside the timings
    systems = [
        run("baseline: captioner", baseline, frames),
        run("grounded", lambda s: ground(cap, s.frame).text, frames),
        run("detector only", detector_only, frames),
    ]
    truths = [truth_items(s) for s in frames]
    subsets = {
        "all": list(range(n)),
        "indoor": [i for i, s in enumerate(frames) if s.world == "indoor"],
        "outdoor": [i for i, s in enumerate(frames) if s.world == "outdoor"],
        "shipped worlds": [i for i, s in enumerate(frames) if s.variant == "world"],
        "randomised objects": [i for i, s in enumerate(frames) if s.variant == "random"],
    }
    print(
        f"describe: {n} held-out frames from seed {args.start} ({render_s:.1f} s to render), "
        f"640×360, captioner beam 3 on one onnxruntime thread\n"
        f"targets: kind P ≥ {TARGETS['kind P']}, kind R ≥ {TARGETS['kind R']}, colour ≥ "
        f"{TARGETS['colour']}, absent ≤ {TARGETS['absent']}; 'frames' = share of descriptions "
        f"naming something absent; m.id = marker mentions with an id; id ok = those ids in view;"
        f" m. R = mentionable markers named\n"
    )
    out: dict[str, object] = {"n": n, "start": args.start, "subsets": {}}
    for sub, idx in subsets.items():
        print(f"{sub} ({len(idx)} frames)\n{HEAD}")
        rows = {}
        for name, texts, ms in systems:
            r = score_descriptions(
                [texts[i] for i in idx], [truths[i] for i in idx], KINDS, list(COLOURS)
            )
            print(row(name, r, [ms[i] for i in idx]))
            rows[name] = {
                **{k: v for k, v in r.__dict__.items() if k != "counts"},
                "ms_median": statistics.median(ms[i] for i in idx),
                "counts": r.counts,
            }
        print()
        out["subsets"][sub] = rows  # type: ignore[index]
    if args.by_kind:
        for world in ("indoor", "outdoor"):
            idx = subsets[world]
            r = score_descriptions(
                [systems[1][1][i] for i in idx], [truths[i] for i in idx], KINDS, list(COLOURS)
            )
            per = ", ".join(
                f"{k} {named}/{gold}"
                + (f" ({r.counts[f'absent:{k}']} absent)" if r.counts.get(f"absent:{k}") else "")
                for k, (named, gold) in recall_by_kind(r).items()
            )
            print(f"grounded, {world}: salient kinds named/salient: {per}")
        print()
    base, grounded = systems[0][1], systems[1][1]
    print("Examples (truth: mentionable things):")
    for i in range(min(args.examples, n)):
        s = frames[i]
        truth = ", ".join(
            f"{t.colour + ' ' if t.colour else ''}{t.kind}"
            f"{' ' + str(t.marker_id) if t.marker_id is not None else ''} {t.side}"
            for t in s.truth
            if t.mentionable
        )
        print(f"  {s.seed} {s.world}/{s.variant}\n    truth:    {truth or 'nothing'}")
        print(f"    baseline: {base[i]}\n    grounded: {grounded[i]}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    cap.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
