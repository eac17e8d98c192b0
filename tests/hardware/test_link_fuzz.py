"""Fuzz of the Python codec and Deframer: 10^4 random and 10^4 mutated frames, and a noisy stream.

Every input is either decoded or rejected with a :class:`LinkError` whose reason
is counted; nothing else may escape. The same seeded corpus is given to the C
codec in ``test_link_c.py``, which must reach the same verdict on every input.
"""

from __future__ import annotations

import random
import struct
import zlib
from collections import Counter

from dem_ros.hardware.framing import DEFRAME_REASONS, Deframer, wire_frame
from dem_ros.hardware.link import (
    CONFIG_KEYS,
    CONFIG_RESULTS,
    REASONS,
    CommandFrame,
    ConfigAck,
    ConfigFrame,
    Hello,
    LinkError,
    Mode,
    SensorFrame,
    decode,
    encode,
)

N = 10_000
SEED = 20261123


def valid_frame(rng: random.Random) -> bytes:
    """A random valid frame of any type (values as a board or PC would send)."""
    k = rng.randrange(5)
    if k == 3:
        return encode(ConfigFrame(tuple(rng.uniform(-5, 15) for _ in CONFIG_KEYS), rng.randrange(4)))
    if k == 4:
        return encode(ConfigAck(rng.getrandbits(32), rng.getrandbits(32), rng.randrange(len(CONFIG_RESULTS)),
                                rng.random() < 0.5, Mode(rng.randrange(6))))
    if k == 0:
        return encode(SensorFrame(
            rng.getrandbits(32), rng.getrandbits(64), (rng.getrandbits(16), rng.getrandbits(16)),
            (rng.getrandbits(16), rng.getrandbits(16)),
            (rng.uniform(-150, 150), rng.uniform(-150, 150)), rng.uniform(0, 200),
            rng.getrandbits(16), Mode(rng.randrange(6))))
    if k == 1:
        return encode(CommandFrame(rng.getrandbits(32), (rng.uniform(-150, 150), rng.uniform(-150, 150)),
                                   Mode(rng.randrange(4))))
    return encode(Hello(1, rng.getrandbits(32), rng.choice([0, 1000, 2000]), rng.randrange(17),
                        rng.uniform(0, 5), rng.getrandbits(16), rng.randrange(4)))


def _reseal(b: bytearray) -> bytes:
    b[-4:] = struct.pack("<I", zlib.crc32(bytes(b[:-4])))
    return bytes(b)


def random_frames(rng: random.Random, n: int = N) -> list[bytes]:
    """Half pure random bytes (0..63 long); half plausible: a right-looking header, random
    payload (often zero reserved bytes, now and then a NaN/inf, a bad mode or an ack's result/flag out of
    range) and a valid CRC (3 %: a wrong one), so the checks after the CRC are exercised too."""
    out = []
    for i in range(n):
        if i % 2 == 0:
            out.append(rng.randbytes(rng.randrange(64)))
            continue
        ftype = rng.choice([1, 2, 3, 4, 5, 1, 2, 3, 4, 5, 0, 9])
        size = {1: 24, 2: 48, 3: 24, 4: 128, 5: 20}.get(ftype, 24)
        if rng.random() < 0.1:
            size = rng.choice([24, 48, 12, 60, 128, 20])
        b = bytearray(rng.randbytes(size))
        b[0] = rng.choice([1, 1, 1, 1, 0, 2])
        b[1] = ftype
        b[2:4] = struct.pack("<H", size)
        if rng.random() < 0.75:  # zero the reserved bytes of the type
            for pos in {2: [41, 42, 43], 3: [17, 18, 19], 4: [121, 122, 123], 5: [15]}.get(ftype, []):
                if pos < size - 4:
                    b[pos] = 0
            if ftype == 2 and size == 48 and rng.random() < 0.8:
                b[40] = rng.choice([0, 1, 2, 3, 4, 5, 6, 200])
            if ftype == 3 and size == 24 and rng.random() < 0.8:
                b[16] = rng.choice([0, 1, 2, 3, 4, 5, 7])
            if ftype == 1 and size == 24 and rng.random() < 0.8:
                b[12] = rng.choice([0, 12, 16, 17, 255])
            if ftype == 5 and size == 20 and rng.random() < 0.8:
                b[12] = rng.choice([0, 4, 8, 9, 200])  # result
                b[13] = rng.choice([0, 1, 1, 2])  # configured
                b[14] = rng.choice([0, 1, 4, 5, 6])  # mode
        if rng.random() < 0.15 and size >= 20:  # a non-finite float where one lives
            pos = {1: 16, 2: rng.choice([24, 28, 32]), 3: rng.choice([8, 12]),
                   4: 4 + 4 * rng.randrange(len(CONFIG_KEYS))}.get(ftype, 8)
            if pos + 4 <= size - 4:
                b[pos:pos + 4] = struct.pack("<f", rng.choice([float("nan"), float("inf"), -float("inf")]))
        sealed = bytearray(_reseal(b))
        if rng.random() < 0.03:  # a plausible frame whose CRC does not match
            sealed[-1] ^= 1 << rng.randrange(8)
        out.append(bytes(sealed))
    return out


def mutate(rng: random.Random, frame: bytes) -> bytes:
    """A valid frame with 1-3 bit flips, a truncation, an extension, or a byte substituted."""
    b = bytearray(frame)
    k = rng.randrange(4)
    if k == 0:
        for _ in range(rng.randint(1, 3)):
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
    elif k == 1:
        del b[rng.randrange(len(b)):]
    elif k == 2:
        b += rng.randbytes(rng.randint(1, 16))
    else:
        b[rng.randrange(len(b))] = rng.randrange(256)
    return bytes(b)


def mutated_frames(rng: random.Random, n: int = N) -> list[bytes]:
    return [mutate(rng, valid_frame(rng)) for _ in range(n)]


def noisy_stream(rng: random.Random, n: int = N) -> tuple[bytes, int]:
    """n valid frames as a sender puts them on the line (0x00 COBS 0x00), with garbage between
    a quarter of them and a bit flipped inside the COBS bytes of 1/16 of them; returns (stream, n)."""
    out = bytearray()
    for _ in range(n):
        if rng.random() < 0.25:
            out += rng.randbytes(rng.randrange(60))
        w = bytearray(wire_frame(valid_frame(rng)))
        if rng.random() < 1 / 16:
            w[rng.randrange(1, len(w) - 1)] ^= 1 << rng.randrange(8)
        out += w
    return bytes(out), n


def verdict(data: bytes) -> str:
    """'ok <re-encoded hex>' or the rejection reason (the format host_test prints)."""
    try:
        return "ok " + encode(decode(data)).hex()
    except LinkError as e:
        return e.reason


def count_verdicts(frames: list[bytes]) -> Counter[str]:
    return Counter(v.split()[0] for v in map(verdict, frames))


def stream_counts(stream: bytes) -> tuple[Deframer, Counter[str]]:
    d = Deframer()
    counts: Counter[str] = Counter()
    for i in range(0, len(stream), 997):  # arbitrary chunking: results must not depend on it
        for f in d.feed(stream[i:i + 997]):
            counts[verdict(f).split()[0]] += 1
    return d, counts


def test_random_frames_counted_never_raise() -> None:
    """10^4 random byte strings: every one decoded or rejected with a known reason."""
    counts = count_verdicts(random_frames(random.Random(SEED)))
    assert sum(counts.values()) == N
    assert set(counts) <= {"ok", *REASONS}
    # the corpus reaches every check after the CRC, not only short/length/crc
    for reason in REASONS:
        assert counts[reason] > 0, (reason, counts)
    print(dict(counts))


def test_mutated_frames_counted_never_raise() -> None:
    """10^4 valid frames with flips, truncation, extension, substitution: all counted.

    CRC-32 detects every error of up to 3 bits in frames this short (Hamming distance ≥ 4
    up to 91607 bits, Koopman 2002), so no bit-flipped frame may decode."""
    rng = random.Random(SEED + 1)
    counts: Counter[str] = Counter()
    flipped_ok = 0
    for _ in range(N):
        good = valid_frame(rng)
        bad = mutate(rng, good)
        v = verdict(bad).split()[0]
        counts[v] += 1
        if v == "ok" and len(bad) == len(good) and bad != good and sum(
                bin(x ^ y).count("1") for x, y in zip(bad, good, strict=True)) <= 3:
            flipped_ok += 1
    assert sum(counts.values()) == N and set(counts) <= {"ok", *REASONS}
    assert flipped_ok == 0
    assert counts["crc"] > 2000 and counts["length"] > 2000 and counts["short"] > 0
    print(dict(counts))


def test_noisy_stream_deframer_counts() -> None:
    """10^4 frames on a stream with garbage between them: garbage costs no frame (each frame
    starts with a delimiter), so exactly the frames hit by a bit flip are lost, each counted
    (as COBS, oversize, or a link reason; CRC-32 lets no flipped frame through)."""
    stream, n = noisy_stream(random.Random(SEED + 2))
    d, counts = stream_counts(stream)
    assert set(d.dropped) == set(DEFRAME_REASONS)
    assert d.frames == sum(counts.values())
    rng = random.Random(SEED + 2)  # replay the generator to know how many frames were flipped
    flipped = 0
    for _ in range(n):
        if rng.random() < 0.25:
            rng.randbytes(rng.randrange(60))
        w = wire_frame(valid_frame(rng))
        if rng.random() < 1 / 16:
            rng.randrange(1, len(w) - 1), rng.randrange(8)
            flipped += 1
    assert counts["ok"] == n - flipped
    assert flipped > 0.05 * n
    print(dict(counts), dict(d.dropped), d.frames)
