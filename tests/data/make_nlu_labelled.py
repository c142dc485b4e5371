# ruff: noqa: E501  (a table of hand-written utterances reads best one per line)
"""Generate tests/data/nlu_labelled.jsonl: utterances with hand-specified expected commands.

The expected commands come from the templates below (written by hand from DESIGN §4), never
from running the NLU. Run: python tests/data/make_nlu_labelled.py
"""

from __future__ import annotations

import json
import random
from pathlib import Path

R = random.Random(5)
OUT = Path(__file__).with_name("nlu_labelled.jsonl")

WORDNUM = {
    1: "one",
    2: "two",
    3: "three",
    4: "four",
    5: "five",
    6: "six",
    7: "seven",
    8: "eight",
    9: "nine",
    10: "ten",
    12: "twelve",
    15: "fifteen",
    20: "twenty",
    25: "twenty five",
    30: "thirty",
    45: "forty five",
    60: "sixty",
    90: "ninety",
    120: "a hundred and twenty",
    180: "a hundred and eighty",
    270: "two hundred seventy",
    360: "three hundred sixty",
}
MOVE_DIRS = {
    "up": ["up", "upward", "higher"],
    "down": ["down", "downward", "lower"],
    "forward": ["forward", "ahead", "forwards"],
    "backward": ["back", "backward", "backwards"],
    "left": ["left", "to the left"],
    "right": ["right", "to the right"],
}
UNITS = [
    ("meters", 1.0),
    ("metres", 1.0),
    ("m", 1.0),
    ("meter", 1.0),
    ("cm", 0.01),
    ("centimeters", 0.01),
    ("feet", 0.3048),
    ("foot", 0.3048),
]
FILLERS = [
    "",
    "",
    "",
    "please ",
    "uh ",
    "drone, ",
    "okay ",
    "um, ",
    "can you ",
    "could you please ",
]
TAILS = ["", "", "", " please", " now", " for me"]


def num(v: float) -> int | float:
    r = round(v, 6)
    return int(r) if r == int(r) else r


def say(n: int) -> str:
    return WORDNUM[n] if n in WORDNUM and R.random() < 0.5 else str(n)


rows: list[tuple[str, list[dict]]] = []


def add(text: str, *cmds: dict) -> None:
    rows.append((text, list(cmds)))


# --- moves: verb + direction (+ distance) -------------------------------------------------------
verbs = ["go", "move", "fly", "head", "drift", "slide", "shift"]
for _ in range(70):
    d = R.choice(list(MOVE_DIRS))
    word = R.choice(MOVE_DIRS[d])
    verb = R.choice(verbs + (["strafe"] if d in ("left", "right") else []))
    if R.random() < 0.25:
        add(
            f"{R.choice(FILLERS)}{verb} {word}{R.choice(TAILS)}", {"action": "move", "direction": d}
        )
        continue
    unit, factor = R.choice(UNITS)
    n = R.choice([1, 2, 3, 4, 5, 10, 20, 30, 50]) if factor < 1 else R.choice([1, 2, 3, 4, 5, 6])
    spoken = say(n)
    if R.random() < 0.5:
        text = f"{verb} {word} {spoken} {unit}"
    else:
        text = f"{verb} {spoken} {unit} {word}"
    add(
        R.choice(FILLERS) + text + R.choice(TAILS),
        {"action": "move", "direction": d, "distance": num(n * factor)},
    )

# fractions and word numbers
for text, dist, d in [
    ("rise by half a metre", 0.5, "up"),
    ("climb one and a half meters", 1.5, "up"),
    ("go up two and a half meters", 2.5, "up"),
    ("descend half a meter", 0.5, "down"),
    ("move forward zero point five meters", 0.5, "forward"),
    ("go left 1.5 m", 1.5, "left"),
    ("fly backward a meter", 1, "backward"),
    ("go down a quarter of a meter", 0.25, "down"),
    ("move right three quarters of a meter", 0.75, "right"),
    ("go forward 2.25 meters", 2.25, "forward"),
    ("climb 1 m", 1, "up"),
    ("move 50 centimetres to the left", 0.5, "left"),
    ("go up 2m", 2, "up"),
    ("fly forward 10 feet", 3.048, "forward"),
    ("go down twenty centimeters", 0.2, "down"),
    ("move back 6 inches", 0.1524, "backward"),
    ("advance 3 meters", 3, "forward"),
    ("retreat 2 meters", 2, "backward"),
    ("back up a meter", 1, "backward"),
    ("ascend 2 meters", 2, "up"),
    ("lower 1 meter", 1, "down"),
    ("gain altitude by one meter", 1, "up"),
    ("increase your altitude by 2 meters", 2, "up"),
    ("decrease altitude by half a meter", 0.5, "down"),
    ("drop 30 cm", 0.3, "down"),
    ("strafe right one metre", 1, "right"),
    ("go higher by 1 meter", 1, "up"),
]:
    add(text, {"action": "move", "direction": d, "distance": num(dist)})
for text, d in [
    ("ascend", "up"),
    ("climb", "up"),
    ("rise", "up"),
    ("descend", "down"),
    ("go back", "backward"),
    ("go forward", "forward"),
    ("move a bit to the left", "left"),
    ("go a little higher", "up"),
    ("come down", "down"),
    ("back up", "backward"),
    ("fly straight ahead", "forward"),
    ("go up", "up"),
    ("go down", "down"),
    ("move right", "right"),
    ("strafe left", "left"),
    ("advance", "forward"),
]:
    add(text, {"action": "move", "direction": d})

# --- turns -----------------------------------------------------------------------------------------
sides = {
    "left": ["left", "counter clockwise", "counterclockwise", "anticlockwise", "to the left"],
    "right": ["right", "clockwise", "to the right"],
}
tverbs = ["turn", "rotate", "spin", "yaw"]
for _ in range(45):
    side = R.choice(list(sides))
    w = R.choice(sides[side])
    v = R.choice(tverbs)
    a = R.choice([15, 30, 45, 60, 90, 120, 180, 270])
    deg = R.choice([" degrees", " degrees", "", " deg"])
    form = R.random()
    if form < 0.2:
        add(f"{R.choice(FILLERS)}{v} {w}", {"action": "turn", "direction": side})
    elif form < 0.6:
        add(
            f"{R.choice(FILLERS)}{v} {w} {say(a)}{deg}",
            {"action": "turn", "direction": side, "angle": a},
        )
    else:
        add(
            f"{v} {say(a)}{deg} {w}{R.choice(TAILS)}",
            {"action": "turn", "direction": side, "angle": a},
        )
for text, cmd in [
    ("turn around", {"action": "turn", "angle": 180}),
    ("spin around", {"action": "turn", "angle": 180}),
    ("rotate 90 degrees", {"action": "turn", "angle": 90}),
    ("turn by 45 degrees", {"action": "turn", "angle": 45}),
    ("do a 180", {"action": "turn", "angle": 180}),
    ("make a 90 degree turn to the right", {"action": "turn", "direction": "right", "angle": 90}),
    ("quarter turn to the left", {"action": "turn", "direction": "left", "angle": 90}),
    ("do a full turn", {"action": "turn", "angle": 360}),
    ("turn right by thirty degrees", {"action": "turn", "direction": "right", "angle": 30}),
    ("yaw left 10", {"action": "turn", "direction": "left", "angle": 10}),
    ("face left", {"action": "turn", "direction": "left"}),
    ("look right", {"action": "turn", "direction": "right"}),
    ("rotate clockwise", {"action": "turn", "direction": "right"}),
    ("turn counter-clockwise 45 degrees", {"action": "turn", "direction": "left", "angle": 45}),
    ("clockwise 90 degrees", {"action": "turn", "direction": "right", "angle": 90}),
    ("turn one eighty", {"action": "turn", "angle": 180}),
]:
    add(text, cmd)

# --- goto ------------------------------------------------------------------------------------------
gverbs = [
    "fly to",
    "go to",
    "navigate to",
    "head to",
    "move to",
    "proceed to",
    "find",
    "go find",
    "fly over to",
    "travel to",
    "search for",
    "approach",
]
for _ in range(40):
    m = R.choice([1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 12, 15, 20])
    noun = R.choice(
        ["marker", "marker", "tag", "the marker", "marker number", "waypoint", "the tag"]
    )
    # "waypoint N" names the world's numbered waypoint N (issue 16; a marker where there are none)
    slot = "waypoint" if noun == "waypoint" else "marker"
    add(
        f"{R.choice(FILLERS)}{R.choice(gverbs)} {noun} {say(m)}{R.choice(TAILS)}",
        {"action": "goto", slot: m},
    )
for text, m in [
    ("go to the third marker", 3),
    ("fly to the first tag", 1),
    ("marker 4", 4),
    ("go to marker #6", 6),
    ("fly to marker id 11", 11),
    ("head towards marker 2", 2),
    ("return to marker 1", 1),
    ("go back to marker 3", 3),
    ("fly to tag 42", 42),
]:
    add(text, {"action": "goto", "marker": m})

# --- patrol ----------------------------------------------------------------------------------------
for _ in range(25):
    k = R.choice([2, 3, 3, 4])
    ms = R.sample(range(1, 10), k)
    spoken = [say(x) for x in ms]
    if k == 2 and R.random() < 0.5:
        text = f"patrol between {'markers ' if R.random() < 0.5 else ''}{spoken[0]} and {spoken[1]}"
    else:
        text = "patrol markers " + ", ".join(spoken[:-1]) + " and " + spoken[-1]
    add(R.choice(FILLERS) + text, {"action": "patrol", "markers": ms})
for text, ms in [
    ("patrol", None),
    ("start patrolling", None),
    ("patrol 1 2 3", [1, 2, 3]),
    ("patrol from marker 2 to marker 5", [2, 5]),
    ("patrol markers 1 through 4", [1, 2, 3, 4]),
    ("visit markers 3, 1 and 2", [3, 1, 2]),
    ("fly back and forth between 1 and 6", [1, 6]),
]:
    add(text, {"action": "patrol", **({"markers": ms} if ms else {})})

# --- fixed-phrase commands ---------------------------------------------------------------------------
PHRASES = {
    "takeoff": [
        "take off",
        "takeoff",
        "take-off",
        "lift off",
        "launch",
        "get airborne",
        "start flying",
        "please take off",
        "drone, take off now",
        "okay take off",
    ],
    "land": [
        "land",
        "land now",
        "touch down",
        "land the drone",
        "please land",
        "set down",
        "land immediately",
        "go land",
        "initiate landing",
        "come down and land",
    ],
    "hover": [
        "stop",
        "hold position",
        "freeze",
        "hover",
        "halt",
        "stay there",
        "wait",
        "stay put",
        "hold still",
        "hover in place",
        "stop right there",
        "don't move",
    ],
    "emergency": [
        "emergency",
        "kill the motors",
        "emergency stop",
        "cut the motors",
        "kill switch",
        "stop the motors",
        "mayday",
    ],
    "return_home": [
        "come back",
        "return to base",
        "go home",
        "return home",
        "come home",
        "fly home",
        "return to launch",
        "head back to base",
        "back to base",
        "return to the starting point",
        "go back home",
        "RTL",
    ],
    "describe": [
        "what do you see",
        "describe the scene",
        "what can you see",
        "tell me what you see",
        "describe what you see",
        "what's in front of you",
        "describe your surroundings",
        "what are you looking at",
        "caption the image",
        "do you see anything",
    ],
    "cancel": [
        "cancel that",
        "never mind",
        "cancel",
        "forget it",
        "scratch that",
        "abort",
        "disregard that",
        "cancel the mission",
        "nevermind",
        "abort mission",
    ],
}
for action, texts in PHRASES.items():
    for t in texts:
        add(t, {"action": action})
QUERIES = {
    "battery": [
        "how much battery is left",
        "battery level",
        "what's your battery",
        "battery",
        "how much battery do you have",
        "check the battery",
        "what is the battery level",
        "how is the battery",
        "are you low on battery",
        "battery status",
    ],
    "altitude": [
        "what's your altitude",
        "how high are you",
        "altitude",
        "what is your height",
        "tell me your altitude",
        "how high are you flying",
        "current altitude",
    ],
    "position": [
        "where are you",
        "what's your position",
        "position",
        "where are you now",
        "tell me your location",
        "what is your location",
        "report position",
    ],
    "state": [
        "status",
        "what are you doing",
        "what's your status",
        "status report",
        "what is your state",
        "are you flying",
    ],
}
for item, texts in QUERIES.items():
    for t in texts:
        add(t, {"action": "query", "item": item})

# --- compound sentences ------------------------------------------------------------------------------
T, L = {"action": "takeoff"}, {"action": "land"}
add("take off and go to marker 2 then land", T, {"action": "goto", "marker": 2}, L)
add(
    "take off, climb one meter and then fly to marker 3",
    T,
    {"action": "move", "direction": "up", "distance": 1},
    {"action": "goto", "marker": 3},
)
add("take off then hover", T, {"action": "hover"})
add(
    "go up 2 meters and turn left",
    {"action": "move", "direction": "up", "distance": 2},
    {"action": "turn", "direction": "left"},
)
add(
    "turn right 90 degrees, then move forward 3 meters and land",
    {"action": "turn", "direction": "right", "angle": 90},
    {"action": "move", "direction": "forward", "distance": 3},
    L,
)
add(
    "fly to marker 1, then marker 2 and then come back",
    {"action": "goto", "marker": 1},
    {"action": "goto", "marker": 2},
    {"action": "return_home"},
)
add("take off and patrol markers 1, 2 and 3", T, {"action": "patrol", "markers": [1, 2, 3]})
add(
    "patrol between 2 and 4 then return home",
    {"action": "patrol", "markers": [2, 4]},
    {"action": "return_home"},
)
add("stop and tell me your battery", {"action": "hover"}, {"action": "query", "item": "battery"})
add(
    "what is your altitude and battery",
    {"action": "query", "item": "altitude"},
    {"action": "query", "item": "battery"},
)
add(
    "first take off, then go forward two meters, after that land",
    T,
    {"action": "move", "direction": "forward", "distance": 2},
    L,
)
add(
    "go to marker five and describe what you see",
    {"action": "goto", "marker": 5},
    {"action": "describe"},
)
add("land. take off.", L, T)
add(
    "climb half a meter; turn around; come back",
    {"action": "move", "direction": "up", "distance": 0.5},
    {"action": "turn", "angle": 180},
    {"action": "return_home"},
)
for _ in range(25):
    a = R.choice(
        [
            (f"go up {say(n)} meters", {"action": "move", "direction": "up", "distance": n})
            for n in (1, 2, 3)
        ]
        + [
            ("take off", T),
            ("hover", {"action": "hover"}),
            ("turn left", {"action": "turn", "direction": "left"}),
        ]
    )
    b = R.choice(
        [(f"fly to marker {say(m)}", {"action": "goto", "marker": m}) for m in (1, 2, 3, 4, 7)]
        + [
            ("land", L),
            ("return home", {"action": "return_home"}),
            ("what do you see", {"action": "describe"}),
        ]
    )
    sep = R.choice([" and ", " then ", ", ", " and then ", ", then ", " after that "])
    add(a[0] + sep + b[0], a[1], b[1])

# --- nonsense: nothing understood ------------------------------------------------------------------
for t in [
    "",
    "   ",
    "hello there",
    "blah blah blah",
    "what is the meaning of life",
    "sing a song",
    "the quick brown fox",
    "please",
    "uh um",
    "42",
    "marker",
    "go",
    "turn",
    "fly",
    "make me a sandwich",
    "how are the markets doing",
    "open the pod bay doors",
    "climb to the moon",
    "!!!???",
    "the",
    "and then",
    "go to the kitchen",
    "order pizza",
    "play some music",
    "fly to marker",
    "patrol the kitchen",
]:
    add(t)

with OUT.open("w") as f:
    for text, cmds in rows:
        f.write(json.dumps({"text": text, "commands": cmds}) + "\n")
print(f"{len(rows)} rows -> {OUT}")
