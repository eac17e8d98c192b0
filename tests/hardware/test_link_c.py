"""The C frame codec (firmware/) built with the host's compiler and held to the Python codec.

- the shared vectors pass in C (values, re-encoding, COBS, every rejection reason);
- on the seeded fuzz corpus of ``test_link_fuzz`` (10^4 random + 10^4 mutated frames)
  C and Python reach the same verdict for every input, and decode the same noisy
  stream to the same counts;
- the C program's own fuzz (10^4 random, 10^4 mutated, a noisy stream) runs under
  AddressSanitizer/UBSan (when the compiler has them) without a crash.
"""

from __future__ import annotations

import random
import shutil
import subprocess
from collections import Counter
from pathlib import Path

import pytest
from test_link import RECORDS
from test_link_fuzz import SEED, N, mutated_frames, noisy_stream, random_frames, stream_counts, verdict

from dem_ros.hardware.link import REASONS

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE = ROOT / "firmware"
VECTORS = ROOT / "tests" / "hardware" / "vectors" / "frames.txt"
WARNINGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wconversion", "-Wshadow", "-O2"]
SANITIZE = ["-fsanitize=address,undefined", "-fno-sanitize-recover=all"]


def _compile(cc: str, out: Path, flags: list[str], sources: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([cc, *flags, "-o", str(out), *sources], cwd=FIRMWARE, capture_output=True,
                          text=True, timeout=120, check=False)


@pytest.fixture(scope="module")
def host_test(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """firmware/host_test built with sanitizers if the compiler has them, else without."""
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        pytest.skip("no C compiler (cc/gcc/clang) on PATH: the C codec cannot be built here")
    out = tmp_path_factory.mktemp("firmware") / "host_test"
    r = _compile(cc, out, WARNINGS + SANITIZE, ["host_test.c", "dem_link.c"])
    if r.returncode != 0:
        probe = _compile(cc, out.with_name("probe"), SANITIZE, ["-x", "c", "/dev/null"])
        if "sanitize" not in (probe.stderr + r.stderr):
            pytest.fail(f"firmware does not build with {cc}:\n{r.stderr}")
        r = _compile(cc, out, WARNINGS, ["host_test.c", "dem_link.c"])  # no sanitizer runtime here
        assert r.returncode == 0, f"firmware does not build with {cc}:\n{r.stderr}"
    return out


def test_codec_uses_only_string_and_stdint(host_test: Path) -> None:
    """The board's codec needs no libc beyond string.h (memcpy) and stdint/stddef, no malloc."""
    src = (FIRMWARE / "dem_link.c").read_text() + (FIRMWARE / "dem_link.h").read_text()
    includes = {line.split()[1] for line in src.splitlines() if line.startswith("#include")}
    assert includes == {'"dem_link.h"', "<string.h>", "<stddef.h>", "<stdint.h>"}
    for banned in ("malloc(", "free(", "printf", "math.h", "float.h"):
        assert banned not in src
    # and it compiles freestanding, without the hosted library
    cc = shutil.which("cc") or "cc"
    r = _compile(cc, host_test.with_name("freestanding.o"), [*WARNINGS, "-ffreestanding", "-c"], ["dem_link.c"])
    assert r.returncode == 0, r.stderr


def test_c_vectors(host_test: Path) -> None:
    r = subprocess.run([str(host_test), "vectors", str(VECTORS)], capture_output=True, text=True, timeout=60,
                       check=False)
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"vectors: {len(RECORDS)} passed, 0 failed" in r.stdout, r.stdout


def test_c_vectors_catch_a_wrong_file(host_test: Path, tmp_path: Path) -> None:
    """The C check can fail: a vector whose stated value is wrong is reported by name."""
    text = VECTORS.read_text().replace("bus_v 150.0", "bus_v 150.5", 1)
    bad = tmp_path / "frames.txt"
    bad.write_text(text)
    r = subprocess.run([str(host_test), "vectors", str(bad)], capture_output=True, text=True, timeout=60, check=False)
    assert r.returncode == 1 and "FAIL sensor_hover" in r.stdout
    assert f"vectors: {len(RECORDS) - 1} passed, 1 failed" in r.stdout


@pytest.mark.parametrize("corpus", ["random", "mutated"])
def test_c_and_python_agree_on_fuzz_corpus(host_test: Path, tmp_path: Path, corpus: str) -> None:
    """10^4 inputs: the C verdict (ok + re-encoded bytes, or the reason) equals Python's, input by input."""
    frames = (random_frames(random.Random(SEED)) if corpus == "random"
              else mutated_frames(random.Random(SEED + 1)))
    path = tmp_path / "corpus.txt"
    path.write_text("".join(f.hex() + "\n" for f in frames))
    r = subprocess.run([str(host_test), "verdicts", str(path)], capture_output=True, text=True, timeout=120,
                       check=False)
    assert r.returncode == 0, r.stderr
    c_verdicts = r.stdout.splitlines()
    py_verdicts = [verdict(f) for f in frames]
    assert len(c_verdicts) == N
    diffs = [(i, frames[i].hex(), c, p) for i, (c, p) in enumerate(zip(c_verdicts, py_verdicts, strict=True))
             if c != p]
    assert not diffs, f"{len(diffs)} disagreements, first: {diffs[:3]}"
    print(corpus, dict(Counter(v.split()[0] for v in c_verdicts)))


def test_c_and_python_agree_on_noisy_stream(host_test: Path, tmp_path: Path) -> None:
    stream, _ = noisy_stream(random.Random(SEED + 2))
    path = tmp_path / "stream.bin"
    path.write_bytes(stream)
    r = subprocess.run([str(host_test), "stream", str(path)], capture_output=True, text=True, timeout=120,
                       check=False)
    assert r.returncode == 0, r.stderr
    c = {k: int(v) for k, v in (line.split() for line in r.stdout.splitlines())}
    d, counts = stream_counts(stream)
    assert c["frames"] == d.frames and c["cobs"] == d.dropped["cobs"] and c["oversize"] == d.dropped["oversize"]
    assert {k.removeprefix("decode_"): v for k, v in c.items() if k.startswith("decode_") and v} == {
        k: v for k, v in counts.items() if v}


def test_c_own_fuzz_never_crashes(host_test: Path) -> None:
    """host_test's own seeded fuzz under the sanitizers: exit 0, every input counted by reason."""
    r = subprocess.run([str(host_test), "fuzz", "7", str(N)], capture_output=True, text=True, timeout=300,
                       check=False)
    assert r.returncode == 0, r.stdout + r.stderr
    c = {k: int(v) for k, v in (line.split() for line in r.stdout.splitlines())}
    for corpus in ("random", "mutated"):
        assert sum(c[f"{corpus}_{k}"] for k in ("ok", *REASONS)) == N
    assert c["mutated_crc"] > 0 and c["random_length"] > 0 and c["random_mode"] > 0
    assert c["stream_frames"] + c["stream_cobs"] + c["stream_oversize"] > N * 0.9
    print({k: v for k, v in c.items() if v})
