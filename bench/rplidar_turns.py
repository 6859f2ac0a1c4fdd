"""RPLIDAR turns under damage at a turn boundary, offline and deterministic.

Run: python bench/rplidar_turns.py [--streams 300]

An RPLIDAR turn ends where the next one's start flag arrives and no checksum guards a node, so
damage at a turn boundary decides whether an intact turn survives and whether a made-up
distance gets through. Fed straight to :class:`drivers.rplidar_protocol.TurnAssembler` (the
test helpers' synthetic turns, no pty, no timing), this counts:

* **next head**: this turn intact (ending with or without 4 no-return nodes), the next turn's
  first 15 bytes hit one at a time (a byte lost, 00 or FF added, bit 0 or 1 flipped, 5 bytes
  lost), 6 seeds: the cases that cost this turn;
* **bursts**: the same with 8 random bytes written over the next turn's head, 5 a position,
  10 seeds: the cases that cost this turn;
* **last node**: this turn's last 10 bytes hit (a byte lost, 00 or FF added, bit 0, 1 or 7
  flipped), 30 seeds, both endings: the turns delivered that equal no turn sent (flipped
  distance bits pass every check; no rule should add to them);
* **streams**: ``--streams`` streams of 60 turns of 300-420 nodes, corrupted at 0.1 % as the
  simulated wire does (:class:`drivers.devices.pty_device.Corruption`) in pieces of 20-400
  bytes, fed in reads of 50-2,000: intact turns lost, wrong turns delivered.

Prints the figures and writes them to docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from report import machine, write_section
from serial_support import turn, wire

from drivers.devices.pty_device import Corruption
from drivers.rplidar_protocol import TurnAssembler

NEXT_HEAD = ("drop", "add 00", "add FF", "bit 0", "bit 1", "lose 5")
LAST_NODE = ("drop", "add 00", "add FF", "bit 0", "bit 1", "bit 7")


def damaged(data: bytes, at: int, change: str) -> bytes:
    """``data`` with one change at byte ``at``."""
    b = bytearray(data)
    if change == "drop":
        del b[at]
    elif change == "lose 5":
        del b[at:at + 5]
    elif change.startswith("add"):
        b.insert(at, int(change[-2:], 16))
    else:
        b[at] ^= 1 << int(change[-1])
    return bytes(b)


def turns_out(stream: bytes) -> list[bytes]:
    """The distance bytes of every turn the assembler delivers from ``stream``."""
    return [t.dist_q2.tobytes() for t in TurnAssembler().feed(stream)]


def first_turn(seed: int, no_returns_at_end: bool) -> tuple:
    s, a, d = (x.copy() for x in turn(seed=seed))
    if no_returns_at_end:
        d[-4:] = 0
    return s, a, d


def next_head(seeds: int, bursts: bool, rng: np.random.Generator) -> tuple[int, int]:
    """(cases that cost this turn, cases)."""
    lost = cases = 0
    for seed in range(seeds):
        for ending in (False, True):
            this = first_turn(3 * seed, ending)
            head, after = wire(*turn(seed=3 * seed + 1)), wire(*turn(seed=3 * seed + 2))
            for at in range(15):
                for change in (["burst"] * 5 if bursts else NEXT_HEAD):
                    if change == "burst":
                        hit = bytearray(head)
                        hit[at:at + 8] = rng.integers(0, 256, 8, dtype=np.uint8).tobytes()
                        hit = bytes(hit)
                    else:
                        hit = damaged(head, at, change)
                    stream = wire(*this) + hit + after + wire(*turn(seed=50))
                    lost += this[2].tobytes() not in turns_out(stream)
                    cases += 1
    return lost, cases


def last_node(seeds: int) -> tuple[int, int]:
    """(turns delivered that equal no turn sent, cases)."""
    wrong = cases = 0
    for seed in range(seeds):
        for ending in (False, True):
            sent = [first_turn(3 * seed, ending), turn(seed=3 * seed + 1),
                    turn(seed=3 * seed + 2)]
            known = {t[2].tobytes() for t in sent}
            this = wire(*sent[0])
            tail = wire(*sent[1]) + wire(*sent[2]) + wire(*turn(seed=50))
            for at in range(len(this) - 10, len(this)):
                for change in LAST_NODE:
                    got = turns_out(damaged(this, at, change) + tail)
                    wrong += sum(g not in known for g in got)
                    cases += 1
    return wrong, cases


def streams(count: int) -> tuple[int, int, int]:
    """(intact turns lost, intact turns, wrong turns delivered) over ``count`` streams."""
    wire_damage = Corruption(rate=0.001)
    lost = intact_total = wrong = 0
    for k in range(count):
        rng = np.random.default_rng(k)
        sent = [turn(n=int(rng.integers(300, 420)), seed=k * 1000 + j) for j in range(60)]
        pieces, intact, carry = [], [], 0
        for t in sent:
            raw, hit, i = wire(*t), False, 0
            while i < len(raw):  # in pieces, as a device streams a turn
                size = int(rng.integers(20, 400))
                out, changed, carry = wire_damage.corrupt(raw[i:i + size], rng, carry)
                pieces.append(out)
                hit |= changed
                i += size
            intact.append(not hit)
        data, asm, got = b"".join(pieces), TurnAssembler(), []
        i = 0
        while i < len(data):
            size = int(rng.integers(50, 2000))
            got += asm.feed(data[i:i + size])
            i += size
        got += asm.flush()
        keys = {g.dist_q2.tobytes() for g in got}
        known = {t[2].tobytes() for t in sent}
        wrong += len(keys - known)
        for t, ok in zip(sent[:-1], intact[:-1], strict=True):  # the last has no successor
            intact_total += ok
            lost += ok and t[2].tobytes() not in keys
    return lost, intact_total, wrong


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--streams", type=int, default=300, help="corrupted streams (default 300)")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    head = next_head(6, False, rng)
    burst = next_head(10, True, rng)
    last = last_node(30)
    lost, intact, wrong = streams(args.streams)
    rows = [("next head: cases that cost this turn", *head),
            ("bursts on the next head: cases that cost this turn", *burst),
            ("last node hit: turns delivered that equal no turn sent", *last),
            (f"{args.streams} streams at 0.1 %: intact turns lost", lost, intact)]
    lines = ["## RPLIDAR turns under damage at a turn boundary", "",
             f"`python bench/rplidar_turns.py --streams {args.streams}` on {machine()}: "
             "synthetic turns fed straight to the turn assembler (no pty, no timing); what "
             "each row counts: the script's docstring.", "",
             "| what | count | of |", "|---|---|---|"]
    lines += [f"| {what} | {n} | {of} |" for what, n, of in rows]
    lines += ["", f"The streams delivered {wrong} turns equal to no turn sent (flipped "
              "distance bits, which no check can see).", ""]
    text = "\n".join(lines)
    print(text)
    write_section("rplidar-turns", text)


if __name__ == "__main__":
    main()
