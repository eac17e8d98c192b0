"""``dem-ros calibrate gaps``: fit the gap sensors from a shim session and write hw_driver's calibration.

The session: the plate rests on shims of known thickness under both magnets (coils off), and each sensor's
ADC counts are averaged; one placement per thickness, from the smallest to the largest gap the rig levitates
at (e.g. 4, 5, ..., 12 mm). Either from a CSV table (``--csv``: rows ``shim_mm, counts1, counts2``), or live
from the board over the device link (``--url``), prompting for each placement::

    place the 6 mm shims under both magnets, then press Enter

Fit (dem_ros.core.calibration): ``--fit poly`` (the driver's cubic ``gap{j}_c0..c3``) or ``--fit table``
(``gap_table``: a CSV the driver interpolates, written next to the params file). Printed: the residuals at
each shim and the monotonicity over the session's range. Written: ``--out`` a ROS 2 params file with the
``hw_driver`` calibration, ``--session`` the session's table (to fit again without the rig).
A fit whose RMS residual exceeds ``--max-rms`` or that is not monotonic is reported and exits 1.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

import numpy as np

from ..core.calibration import CalibrationError, SensorFit, ShimPoint, fit_sensor, points_from_rows, table_rows

__all__ = ["CalibrateOptions", "add_arguments", "cmd_calibrate", "live_session", "params_text"]


@dataclass(frozen=True)
class CalibrateOptions:
    what: str
    csv: Path | None
    url: str | None
    shims: tuple[float, ...]
    fit: str
    out: Path | None
    session: Path | None
    samples: int
    settle: int
    timeout: float
    max_rms: float
    json: Path | None

    @classmethod
    def from_args(cls, a: argparse.Namespace) -> CalibrateOptions:
        return cls(a.what, a.csv, a.url, tuple(a.shims), a.fit, a.out, a.session, a.samples, a.settle, a.timeout,
                   a.max_rms, a.json)


def _shim_list(text: str) -> list[float]:
    try:
        v = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        v = []
    if len(v) < 2 or not all(0 < x < 100 for x in v):
        raise argparse.ArgumentTypeError(f"expected shim thicknesses in mm, e.g. 4,5,6,7,8,9,10,11,12; got {text!r}")
    return v


def read_session(path: Path) -> list[ShimPoint]:
    """A session CSV: ``shim_mm, counts1, counts2`` rows (``#`` comments, an optional header line)."""
    from .common import UsageError

    try:
        lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path}: cannot read ({exc})") from None
    rows = []
    for i, ln in enumerate(lines):
        parts = [p.strip() for p in ln.split(",")]
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            if i == 0:
                continue  # a header
            raise UsageError(f"{path}: line {ln!r}: expected shim_mm, counts1, counts2") from None
        if len(vals) != 3:
            raise UsageError(f"{path}: line {ln!r}: expected 3 values (shim_mm, counts1, counts2)")
        rows.append([vals[0] * 1e-3, vals[1], vals[2]])
    try:
        return points_from_rows(rows)
    except CalibrationError as exc:
        raise UsageError(f"{path}: {exc}") from None


def live_session(url: str, shims_mm: Sequence[float], samples: int, settle: int, timeout: float,
                 ask: Callable[[str], str], say: Callable[[str], None]) -> list[ShimPoint]:
    """Prompt for each shim placement and average ``samples`` sensor frames from the board after it (the frames
    queued while the operator worked are drained, then the first ``settle`` are dropped: the plate settling,
    frames already under way)."""
    from ..hardware.channel import open_channel
    from ..hardware.link import HELLO_REQUEST, Hello, LinkError, SensorFrame, Status, decode, encode
    from .common import UsageError

    ch = open_channel(url, "pc")
    try:
        ch.send(encode(HELLO_REQUEST))
        end = time.monotonic() + timeout
        hello = None
        while hello is None:
            if time.monotonic() > end:
                raise UsageError(f"no answer from a board at {url} within {timeout:g} s "
                                 "(is it powered, is the URL right?)")
            data = ch.recv(0.1)
            if data is None:
                ch.send(encode(HELLO_REQUEST))
                continue
            try:
                f = decode(data)
            except LinkError:
                continue
            if isinstance(f, Hello):
                hello = f
        say(f"board {hello.board_id} at {url}: {hello.rate_hz} Hz, {hello.adc_bits}-bit ADC")
        points = []
        for mm in shims_mm:
            ask(f"place the {mm:g} mm shims under both magnets (coils off), then press Enter")
            drained = 0
            while ch.recv(0.0) is not None and drained < 1_000_000:  # frames queued while the operator worked
                drained += 1
            got: list[tuple[int, int]] = []
            skipped = 0
            end = time.monotonic() + timeout
            while len(got) < samples:
                if time.monotonic() > end:
                    raise UsageError(f"{mm:g} mm: {len(got)} of {samples} sensor frames in {timeout:g} s; "
                                     "the link stopped")
                data = ch.recv(0.1)
                if data is None:
                    continue
                try:
                    f = decode(data)
                except LinkError:
                    continue
                if not isinstance(f, SensorFrame):
                    continue
                if skipped < settle:
                    skipped += 1
                    continue
                if f.status & (Status.GAP0_RANGE | Status.GAP1_RANGE):
                    raise UsageError(f"{mm:g} mm: a gap sensor is out of its range (status {f.status:#x}): "
                                     "unplugged, or the shim is beyond what it measures")
                got.append((int(f.gap_counts[0]), int(f.gap_counts[1])))
            c = np.array(got, float)
            p = ShimPoint(mm * 1e-3, (float(c[:, 0].mean()), float(c[:, 1].mean())),
                          (float(c[:, 0].std()), float(c[:, 1].std())), len(got))
            say(f"  {mm:g} mm: counts {p.counts[0]:.1f} (sd {p.std[0]:.2f}), {p.counts[1]:.1f} (sd {p.std[1]:.2f})")
            points.append(p)
        return points
    finally:
        ch.close()


def params_text(fits: Sequence[SensorFit], table: Path | None) -> str:
    lines = ["# dem-ros calibrate gaps: the gap sensors' calibration from a shim session", "hw_driver:",
             "  ros__parameters:"]
    if table is None:
        for f in fits:
            lines += [f"    gap{f.sensor}_c{p}: {float(f.coeffs[p])!r}" for p in range(4)]
        lines.append("    gap_table: ''")
    else:
        lines.append(f"    gap_table: {json.dumps(str(table.resolve()))}")  # the driver opens it from anywhere
    return "\n".join(lines) + "\n"


def report_text(fits: Sequence[SensorFit], max_rms: float) -> str:
    out = []
    for f in fits:
        out.append(f"sensor {f.sensor} ({f.kind}): RMS residual {f.rms * 1e6:.3g} um, largest {f.max_abs * 1e6:.3g} um "
                   f"over {f.gaps.min() * 1e3:g}-{f.gaps.max() * 1e3:g} mm; "
                   + ("monotonic" if f.monotonic else f"NOT monotonic (slope down to {f.min_slope:.3g} m/count)")
                   + ("" if f.rms <= max_rms
                      else f"; RMS above {max_rms * 1e6:g} um: a shim misplaced, or use --fit table"))
        out += [f"    {g * 1e3:7.3f} mm  counts {n:9.1f}  residual {r * 1e6:+8.3f} um"
                for g, n, r in zip(f.gaps, f.counts, f.residuals, strict=True)]
    return "\n".join(out)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from .common import out_file

    p.add_argument("what", choices=["gaps"], help="gaps: the two gap sensors from a shim session")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--csv", type=Path, default=None, help="the session as a table: shim_mm, counts1, counts2 rows")
    src.add_argument("--url", default=None, help="live from the board: udp://HOST:PORT or serial:///dev/PATH")
    p.add_argument("--shims", type=_shim_list, default=[4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0],
                   metavar="MM,MM,...", help="--url: the shims to place, in mm (default 4,5,...,12)")
    p.add_argument("--fit", choices=["poly", "table"], default="poly",
                   help="poly: the driver's cubic gap{j}_c0..c3 (default); table: a gap_table CSV")
    p.add_argument("--out", type=out_file, default=None, metavar="PARAMS.yaml", help="write the hw_driver calibration "
                   "as a ROS 2 params file (--fit table: the table is written beside it, PARAMS.gap_table.csv)")
    p.add_argument("--session", type=out_file, default=None, metavar="CSV", help="--url: save the session's table")
    p.add_argument("--samples", type=int, default=500, help="--url: frames averaged per placement (default 500)")
    p.add_argument("--settle", type=int, default=200, help="--url: frames dropped after Enter (default 200)")
    p.add_argument("--timeout", type=float, default=10.0, help="--url: seconds to wait for the board's frames")
    p.add_argument("--max-rms", type=float, default=10e-6, help="largest acceptable RMS residual [m] (default 10e-6)")
    p.add_argument("--json", type=out_file, default=None, help="write the fits as JSON")


def cmd_calibrate(args: argparse.Namespace, stdin: IO[str] | None = None) -> int:
    from .common import UsageError, write_json

    o = CalibrateOptions.from_args(args)
    if o.samples < 1 or o.settle < 0 or o.timeout <= 0 or o.max_rms <= 0:
        raise UsageError("--samples >= 1, --settle >= 0, --timeout > 0 and --max-rms > 0 are required")
    if o.session and not o.url:
        raise UsageError("--session saves a live session (--url); a --csv session is already a table")
    inp = stdin or sys.stdin

    def ask(prompt: str) -> str:
        print(prompt, flush=True)
        line = inp.readline()
        if not line:
            raise UsageError("input ended before the session did (no Enter for the next placement)")
        return line

    if o.csv is not None:
        points = read_session(o.csv)
    else:
        assert o.url is not None
        from ..hardware.channel import ChannelError

        try:
            points = live_session(o.url, o.shims, o.samples, o.settle, o.timeout, ask, lambda s: print(s, flush=True))
        except ChannelError as exc:
            raise UsageError(str(exc)) from None
        if o.session:
            o.session.write_text("# shim_mm, counts1, counts2 (dem-ros calibrate gaps)\nshim_mm,counts1,counts2\n" +
                                 "".join(f"{p.gap * 1e3:g},{p.counts[0]:.3f},{p.counts[1]:.3f}\n" for p in points))
            print(f"session written to {o.session}")
    try:
        fits = [fit_sensor(points, j, o.fit) for j in (1, 2)]
    except CalibrationError as exc:
        raise UsageError(str(exc)) from None
    print(report_text(fits, o.max_rms))
    if o.out:
        table = None
        if o.fit == "table":
            table = o.out.with_suffix(".gap_table.csv")
            np.savetxt(table, table_rows(fits), delimiter=",", fmt=["%.1f", "%.9e", "%.9e"],
                       header="counts, gap1_m, gap2_m (dem-ros calibrate gaps)")
            print(f"table written to {table}")
        o.out.write_text(params_text(fits, table))
        print(f"hw_driver calibration written to {o.out}")
    if o.json:
        write_json(o.json, {"fits": [{"sensor": f.sensor, "kind": f.kind, "coeffs": f.coeffs.tolist(),
                                      "rms_m": f.rms, "max_abs_m": f.max_abs, "monotonic": f.monotonic,
                                      "residuals_m": f.residuals.tolist(), "gaps_m": f.gaps.tolist(),
                                      "counts": f.counts.tolist()} for f in fits]})
    return 0 if all(f.monotonic and f.rms <= o.max_rms for f in fits) else 1
