"""The ``dem-ros`` command line (one namespaced entry point for users without ROS).

    dem-ros sim       offline closed-loop run of one scenario and controller
    dem-ros report    controller x scenario matrix, figures and a markdown report
    dem-ros bench     sim | loop | record benchmarks
    dem-ros launch    the node graph, each node its own process, recorded to a bag
    dem-ros node      run one node (plant_sim, estimator, controller, reference, recorder),
                      or ``container``: all of them in one process
    dem-ros replay    metrics, plots and what-if re-runs from a bag
    dem-ros bag       check a bag
    dem-ros param     get/set a parameter of a running node
    dem-ros rig       the DEM rig and its I/O board, emulated behind the device link
    dem-ros hw        arm | disarm | estop | status of the running hardware driver
    dem-ros config    print the parameter schema or the default params file
    dem-ros study     robustness over plant truth x controllers, on Dask distributed
    dem-ros faults    the fault catalogue (#12) injected into the real graph: outcome per fault
    dem-ros view      the running graph live in Foxglove (a WebSocket server)
    dem-ros identify  R1, R2, K (K1, K2) and m of a rig from a recorded run (or --rigs N: on emulated rigs)
    dem-ros calibrate the gap sensors' calibration from a shim session (calibrate gaps; CSV or live)

Bad input ends with a one-line error and exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NoReturn

from .progress import Progress

# Only the standard library and the progress line above are imported with this module: the rest (numpy,
# the schema, the commands' modules) loads in main() under a progress line, so that a loaded machine,
# where that takes seconds, never shows a silent start. Each command imports what it runs (numba,
# scipy, cyclonedds) itself, under its own progress.

__all__ = ["build_parser", "main"]

#: commands that join a DDS domain (and so read ROS_DOMAIN_ID)
_DDS_COMMANDS = ("launch", "node", "param", "hw", "bench", "replay", "faults", "view")
_TRANSPORTS = ("auto", "rclpy", "dds")


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        v = 0
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return v


def cmd_sim(args: argparse.Namespace) -> int:
    from ..core.params import SCHEMA
    from .common import load_config, warm_kernels, write_json
    from .runmetrics import RunMetrics

    cfg, sc = load_config(args.scenario, args.params, args.set or ())
    duration = args.duration if args.duration is not None else sc.duration
    if args.delay is not None:  # checked here, before the kernels load (simulate checks it again)
        SCHEMA.spec("controller", "command_delay").coerce(args.delay, "--delay (controller.command_delay)")
    print(f"dem-ros sim: {sc.name} ({sc.description}), {duration:g} s", flush=True)
    # numba loads (or compiles) here, under a progress line, with the offline loop of this run's laws
    warm_kernels("dem-ros sim", offline=[(args.controller or cfg["controller"]["type"],
                                          args.estimator or cfg["estimator"]["type"])])
    from ..core.simulate import simulate

    res = simulate(cfg, controller=args.controller, estimator=args.estimator, duration=duration,
                   seed=args.seed, delay=args.delay, scenario=sc.name)
    m = RunMetrics.from_sim(res)
    m.print()
    if args.json:
        write_json(args.json, m.to_dict())
        print(f"  metrics written to {args.json}")
    if args.plot:
        from .plots import plot_run

        files = plot_run(res, Path(args.plot))
        print(f"  {len(files)} figures written to {args.plot}")
    if args.record:
        from .offline_bag import record_result

        path = record_result(res, Path(args.record))
        print(f"  bag written to {path}")
    if m.failed:
        at = f" at t = {m.fail_time_s:.3f} s" if m.fail_time_s is not None else ""
        pc = cfg["plant_sim"]
        print(f"dem-ros sim: FAILED{at}: {sc.name} with {m.controller}: a gap left "
              f"({pc['gap_min']:g}, {pc['gap_max']:g}] m (rail contact or drop) or the state went non-finite",
              file=sys.stderr)
    return m.exit_code  # the verdict's (dem_ros.tools.verdict)


def cmd_report(args) -> int:
    from .report import make_report

    path = make_report(Path(args.out), duration=args.duration, jobs=args.jobs)
    print(f"report written to {path}")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from . import bench
    from .common import write_json

    result = bench.run(args.what, args)
    if args.json:
        write_json(args.json, result)
        print(f"written to {args.json}")
    return 0


def cmd_config(args: argparse.Namespace) -> int:
    from ..core.params import SCHEMA
    from .common import UsageError

    if args.what == "schema":
        for g, specs in SCHEMA.groups.items():
            if args.group and g != args.group:
                continue
            print(f"[{g}]")
            for p in specs:
                ro = " (read-only)" if p.read_only else ""
                print(f"  {p.name:<24} {p.type.__name__:<5} default {p.default!r:<12} {p.allowed()}{ro}"
                      f"  -- {p.description}")
        return 0
    if args.group:
        raise UsageError("config params takes no GROUP (it writes every group's defaults)")
    from .params_file import render_params_file

    sys.stdout.write(render_params_file())
    return 0


def cmd_node(args: argparse.Namespace) -> int:
    from . import node_main
    from .common import UsageError

    transport, rest = args.transport, list(args.ros_args)
    # argparse's REMAINDER takes everything after NAME: our own --transport may stand there (before --ros-args)
    head = rest.index("--ros-args") if "--ros-args" in rest else len(rest)
    for i, tok in enumerate(rest[:head]):
        if tok == "--transport" or tok.startswith("--transport="):
            value = tok.partition("=")[2] if "=" in tok else (rest[i + 1] if i + 1 < head else "")
            if value not in _TRANSPORTS:
                raise UsageError(f"--transport: got {value!r}, expected one of {', '.join(_TRANSPORTS)}")
            transport = value
            del rest[i:i + (1 if "=" in tok else 2)]
            break
    return node_main.run(args.name, rest, transport)


def cmd_param(args: argparse.Namespace) -> int:
    from ..transport import param_get, param_set
    from .common import UsageError, check_param_value

    for what, text in (("node name", args.node), ("parameter name", args.name), ("value", args.value)):
        try:
            (text or "").encode("utf-8")
        except UnicodeEncodeError:  # a byte that is not UTF-8 in the argument (the shell passed it as it was)
            shown = (text or "").encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
            raise UsageError(f"{what} '{shown}' is not valid UTF-8 (ROS names and strings are UTF-8)") from None
    if args.action == "set" and args.value is not None:
        check_param_value(args.node, args.name, args.value)
    if args.action == "set" and args.value is None:
        raise UsageError("param set needs a VALUE")
    if _param_transport(args) == "rclpy":
        return _param_rclpy(args)
    if args.action == "get":
        print(param_get(args.node, args.name, domain_id=args.domain_id, timeout_s=args.timeout))
        return 0
    ok, reason = param_set(args.node, args.name, args.value, domain_id=args.domain_id, timeout_s=args.timeout)
    if ok:
        print("Set parameter successful")
        return 0
    print(f"Setting parameter failed: {reason}", file=sys.stderr)
    return 1


def _param_transport(args: argparse.Namespace) -> str:
    """Whose clients reach the node: ``auto`` asks the DDS graph which vendor serves the node's parameter service
    (Fast DDS, the registry's rclpy: rclpy's clients; else the dds transport's); rclpy asked for without it: one
    line."""
    from ..transport import rclpy_available
    from .common import UsageError

    if args.transport == "rclpy" and not rclpy_available():
        raise UsageError("--transport rclpy needs a sourced ROS 2 (import rclpy failed); use dds")
    if args.transport != "auto":
        return str(args.transport)
    if not rclpy_available():
        return "dds"
    from ..transport.dds.client import FASTDDS_VENDOR, service_vendor

    vendor = service_vendor(args.node, domain_id=args.domain_id, timeout_s=args.timeout)
    return "rclpy" if vendor == FASTDDS_VENDOR else "dds"


def _param_rclpy(args: argparse.Namespace) -> int:
    """``dem-ros param`` to a graph on rclpy, through rclpy's own parameter clients (the dds transport's speak
    rmw_cyclonedds' request header, which rclpy's Fast DDS services do not read)."""
    import os

    import rclpy

    from ..transport import TransportError
    from ..transport.rclpy.client import RclpyServiceClient
    from .common import UsageError

    if args.domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)
    # what dem-ros launch gives its nodes unless told otherwise: Fast DDS finds no LOCALHOST participant from SUBNET
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    rclpy.init(args=[])
    client = None
    try:
        client = RclpyServiceClient("dem_ros_param")
        if args.action == "get":
            values = client.param_values(args.node, [args.name], timeout_s=args.timeout)
            if args.name not in values:
                raise UsageError(f"/{args.node.lstrip('/')} has no parameter {args.name!r}")
            print(values[args.name])
            return 0
        ok, reason = client.param_set(args.node, args.name, args.value, timeout_s=args.timeout)
    except TransportError as exc:
        raise UsageError(str(exc)) from None
    finally:
        if client is not None:
            client.close()
        rclpy.try_shutdown()
    if ok:
        print("Set parameter successful")
        return 0
    print(f"Setting parameter failed: {reason}", file=sys.stderr)
    return 1


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``dem-ros sim: error: ...``); the usage is one ``--help`` away."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _add_sim(s: argparse.ArgumentParser) -> None:
    from ..core.params import SCHEMA
    from ..core.scenarios import load_scenarios
    from .common import CONTROLLER_TYPES, ESTIMATOR_TYPES, out_dir, out_file, seconds, seed

    s.add_argument("--scenario", default="S1",
                   help=f"scenario from config/scenarios.yaml: {', '.join(load_scenarios())}"
                   " (default S1; docs/manual/scenarios.md)")
    s.add_argument("--controller", default=None, choices=CONTROLLER_TYPES,
                   help="control law (default: config, 'adaptive')")
    s.add_argument("--estimator", default=None, choices=ESTIMATOR_TYPES, help="state estimator (default: config, 'kf')")
    s.add_argument("--duration", type=seconds, default=None, help="seconds (default: the scenario's, 100)")
    s.add_argument("--seed", type=seed, default=None, help="seed of noise and perturbation (default: config)")
    s.add_argument("--delay", type=int, default=None,
                   help="command delay in samples for plant and controller (default: config, plant_sim.command_delay = "
                   f"{SCHEMA.spec('plant_sim', 'command_delay').default}, as in the node graph)")
    s.add_argument("--params", default=None, help="ROS 2 params file to load on top of the defaults")
    s.add_argument("--set", action="append", metavar="GROUP.NAME=VALUE",
                   help="override a parameter, e.g. k1=60 or plant_sim.m=16")
    s.add_argument("--json", type=out_file, default=None, help="write the metrics as JSON")
    s.add_argument("--plot", type=out_dir, default=None, metavar="DIR", help="write figures (PNG) to DIR")
    s.add_argument("--record", type=out_dir, default=None, metavar="DIR",
                   help="also write the run as a rosbag2 MCAP bag under DIR")
    s.set_defaults(func=cmd_sim)


def _add_report(r: argparse.ArgumentParser) -> None:
    from .common import out_dir, seconds

    r.add_argument("--out", type=out_dir, default="report", help="output directory (default ./report)")
    r.add_argument("--duration", type=seconds, default=None, help="override every scenario's duration (s)")
    r.add_argument("--jobs", type=_positive_int, default=None, help="parallel processes (default: cores)")
    r.set_defaults(func=cmd_report)


def _add_bench(b: argparse.ArgumentParser) -> None:
    from .common import out_file, seconds

    b.add_argument("what", choices=["sim", "loop", "record"],
                   help="sim: offline simulator speed; loop: the 1 kHz node graph's timing; "
                        "record: the bag writer's throughput")
    b.add_argument("--json", type=out_file, default=None, help="write the figures as JSON")
    b.add_argument("--batch", type=_positive_int, default=64, help="bench sim: plants in the batch (default 64)")
    b.add_argument("--peer-duration", type=seconds, default=5.0,
                   help="bench sim: seconds simulated by the peer (default 5)")
    b.add_argument("--duration", type=seconds, default=None, help="bench loop/record: seconds (default 60 / 10)")
    b.add_argument("--transport", default="dds", choices=["auto", "rclpy", "dds"],
                   help="bench loop: node transport (default dds; auto: rclpy when it imports)")
    b.add_argument("--compose", action="store_true",
                   help="bench loop: all nodes in one process (see dem-ros launch --compose)")
    b.add_argument("--free-run", action="store_true",
                   help="bench loop: the plant does not wait for late commands (plant_sim.lockstep=false)")
    b.add_argument("--load", type=int, default=0, metavar="N",
                   help="bench loop: N busy processes beside the graph (default 0)")
    b.add_argument("--rt", action=argparse.BooleanOptionalAction, default=True,
                   help="bench loop: real-time process settings for the nodes (SCHED_FIFO, mlockall; default on)")
    b.set_defaults(func=cmd_bench)


def _add_config(c: argparse.ArgumentParser) -> None:
    from ..core.params import SCHEMA

    c.add_argument("what", choices=["schema", "params"],
                   help="schema: every parameter with type, default, range, unit and meaning; params: a ROS 2 params "
                        "file of the defaults (config/dem_ros.yaml)")
    c.add_argument("group", nargs="?", choices=list(SCHEMA.groups), metavar="GROUP",
                   help=f"schema: only this group ({', '.join(SCHEMA.groups)})")
    c.set_defaults(func=cmd_config)


def _add_launch(lg: argparse.ArgumentParser) -> None:
    from . import launcher

    launcher.add_arguments(lg)
    lg.set_defaults(func=launcher.cmd_launch)


def _add_rig(rg: argparse.ArgumentParser) -> None:
    from ..hardware import rig

    rig.build_parser(rg)
    rg.set_defaults(func=rig.cmd_rig)


def _add_hw(hw: argparse.ArgumentParser) -> None:
    from . import hw as hw_tool

    hw_tool.add_arguments(hw)
    hw.set_defaults(func=hw_tool.cmd_hw)


def _add_node(nd: argparse.ArgumentParser) -> None:
    from ..nodes import NODES

    nd.add_argument("name", choices=NODES, help="the node; container: several in one process (--nodes a,b,...)")
    nd.add_argument("--transport", default="auto", choices=_TRANSPORTS,
                    help="auto (rclpy when it imports) | rclpy | dds; before or after NAME")
    nd.add_argument("ros_args", nargs=argparse.REMAINDER,
                    help="node options, then --ros-args ... (params file, remaps)")
    nd.set_defaults(func=cmd_node)


def _add_replay(rp: argparse.ArgumentParser) -> None:
    from . import replay
    from .common import CONTROLLER_TYPES, out_dir, out_file

    rp.add_argument("bag", help="a bag directory (dem-ros launch, dem-ros sim --record) or its .mcap file")
    rp.add_argument("--json", type=out_file, default=None, help="write the metrics as JSON")
    rp.add_argument("--plot", type=out_dir, default=None, metavar="DIR", help="write figures (PNG) to DIR")
    rp.add_argument("--controller", default=None, choices=CONTROLLER_TYPES,
                    help="what-if: re-run this controller on the recorded measurements")
    rp.add_argument("--set", action="append", metavar="NAME=VALUE", help="what-if: change a controller parameter")
    rp.add_argument("--publish", action="store_true", help="play the bag back onto the graph at its recorded rate")
    rp.set_defaults(func=replay.cmd_replay)


def _add_faults(ft: argparse.ArgumentParser) -> None:
    from . import faults

    faults.add_arguments(ft)
    ft.set_defaults(func=faults.cmd_faults)


def _add_bag(bg: argparse.ArgumentParser) -> None:
    from . import replay

    bg.add_argument("action", choices=["check", "info"],
                    help="info: what the bag holds (topics, types, counts, the run); check: its integrity "
                         "(summary, chunks, sample gaps, rates, problems; exit 1 if any)")
    bg.add_argument("bag", help="a bag directory or its .mcap file")
    bg.set_defaults(func=replay.cmd_bag)


def _add_param(pm: argparse.ArgumentParser) -> None:
    from .common import domain_id

    pm.add_argument("action", choices=["get", "set"])
    pm.add_argument("node", help="node name, e.g. controller or /controller")
    pm.add_argument("name", help="parameter name, e.g. k1 (dem-ros config schema lists them)")
    pm.add_argument("value", nargs="?", help="set: the new value, e.g. 60 (validated before the node is asked)")
    pm.add_argument("--domain-id", type=domain_id, default=None,
                    help="ROS_DOMAIN_ID of the node (default: the environment's)")
    pm.add_argument("--timeout", type=float, default=5.0, help="seconds to find the node and get its reply (default 5)")
    pm.add_argument("--transport", default="auto", choices=_TRANSPORTS,
                    help="whose service clients reach the node: auto (rclpy's for a node on Fast DDS, the registry's "
                         "rclpy; else the dds transport's), rclpy or dds")
    pm.set_defaults(func=cmd_param)


def _add_view(vw: argparse.ArgumentParser) -> None:
    from . import view

    view.add_arguments(vw)
    vw.set_defaults(func=view.cmd_view)


def _add_study(sy: argparse.ArgumentParser) -> None:
    from . import study

    study.add_arguments(sy)
    sy.set_defaults(func=study.cmd_study)


def _add_identify(p: argparse.ArgumentParser) -> None:
    from . import identify

    identify.add_arguments(p)
    p.set_defaults(func=identify.cmd_identify)


def _add_calibrate(p: argparse.ArgumentParser) -> None:
    from . import calibrate

    calibrate.add_arguments(p)
    p.set_defaults(func=calibrate.cmd_calibrate)


#: each command: (its line in ``dem-ros --help``, the function that adds its options, importing what they need)
_COMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None]]] = {
    "sim": ("offline closed-loop simulation of one scenario", _add_sim),
    "report": ("controller x scenario matrix with figures and a markdown report", _add_report),
    "bench": ("benchmarks: sim | loop | record", _add_bench),
    "config": ("print the parameter schema or a params file of the defaults", _add_config),
    "launch": ("run the node graph (each node its own process), record a bag, print a summary", _add_launch),
    "rig": ("emulate the DEM rig and its I/O board behind the device link (free-running 1 kHz)", _add_rig),
    "hw": ("the hardware driver: arm | disarm (a controlled landing) | estop | status", _add_hw),
    "node": ("run one node of the graph", _add_node),
    "replay": ("metrics, figures and what-if re-runs from a recorded bag", _add_replay),
    "faults": ("inject the fault catalogue into the real graph; a table of outcomes", _add_faults),
    "bag": ("inspect bags", _add_bag),
    "param": ("get or set a parameter of a running node (its parameter services)", _add_param),
    "view": ("watch the running graph live in Foxglove (a WebSocket server; docs/manual/live-view.md)", _add_view),
    "study": ("robustness study: plant truth (grid or Monte Carlo) x controllers on Dask distributed", _add_study),
    "identify": ("R1, R2, K (K1, K2) and m of a rig from a recorded run, with 95 %% intervals", _add_identify),
    "calibrate": ("calibrate the gap sensors from a shim session (CSV, or live over the link)", _add_calibrate),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``dem-ros`` parser: every command, or (``command``) only that command's options.

    A command's options import what they need (the schema, numpy; the rig's the board's kernels), so
    ``main`` builds only the options of the command it runs; every command is listed either way.
    """
    from .. import __version__

    p = _Parser(prog="dem-ros",
                description="DEM maglev adaptive control: simulation, ROS 2 graph, recording and analysis.",
                epilog="first steps: 'dem-ros launch --duration 30' (the node graph, recorded to bags/), "
                       "'dem-ros replay BAG --plot figs/' (its figures), 'dem-ros sim --scenario S2 --plot figs/' "
                       "(offline); 'dem-ros COMMAND --help' for each command; the manual is docs/manual/README.md. "
                       "A mistake ends with one line and exit status 2.")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    for name, (text, add) in _COMMANDS.items():
        sp = sub.add_parser(name, help=text)
        if command is None or command == name:
            add(sp)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in argv if not a.startswith("-")), "")
    prefix = f"dem-ros {command}" if command in _COMMANDS else "dem-ros"
    # a cold start on a loaded machine reads numpy and the package for seconds: say so after 2 s (and every
    # 5 s), so that no command starts silently; a warm start prints nothing here
    with Progress(prefix, stage="starting: loading numpy and the dem_ros modules", quiet=2.0):
        parser = build_parser(command)  # only this command's options (none for --help, --version, a typo)
        from ..core.params import ConfigError
        from .common import UsageError, env_domain_id
    args = parser.parse_args(argv)
    try:
        if args.command in _DDS_COMMANDS:
            env_domain_id()  # a malformed ROS_DOMAIN_ID is one line, before any participant is made
        return int(args.func(args) or 0)
    except (ConfigError, UsageError) as exc:
        print(f"dem-ros {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"dem-ros {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # package errors from the bag layer etc.
        name = type(exc).__name__
        if name.endswith("Error") and type(exc).__module__.startswith("dem_ros"):
            print(f"dem-ros {args.command}: error: {exc}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
