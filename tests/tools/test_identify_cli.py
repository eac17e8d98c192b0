"""``dem-ros identify BAG`` on emulated rig runs: the rig emulator's board (sensors, ADC, PWM, bus, supervisor)
closed through the link's frames, the hardware driver and the graph's estimator, controller and reference
model one board tick at a time (no clock: the outcome does not depend on the machine's load), recorded as a
bag with the graph's topics and read back by the command (a real process). Truths away from the defaults: magnets
alike (one K) and magnets of different K (K1, K2)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dem_ros import contract
from dem_ros.core.identify import PARAMS, SPLIT, RunData
from dem_ros.core.params import load_params_file
from dem_ros.tools.identify import TOLERANCE, emulated_run, rig_config

ROOT = Path(__file__).resolve().parents[2]
#: a rig none of the defaults describe: coils of 24.1 and 16.2 ohm, K -14 %, m +17 %
TRUTH = {"R1": 24.1, "R2": 16.2, "K": 4.374e-4 * 0.86, "m": 14.852 * 1.17}
#: the same with magnets of different K: K1 -18 %, K2 -10 % (a split (K1 - K2)/(K1 + K2) of -4.7 %)
SPLIT_TRUTH = TRUTH | {"K1": 4.374e-4 * 0.82, "K2": 4.374e-4 * 0.90, "K": 4.374e-4 * 0.86}


def write_bag(d: RunData, cfg: dict, root: Path) -> Path:
    """The run as the graph records it: /dem/measurement, /dem/applied_voltage (stamps on the 1 kHz grid) and
    /dem/run_info with the configuration; t = 0 is the first sample (no pre-roll in the bag)."""
    from dem_ros.bag import BagWriter
    from dem_ros.nodes.common import joint_state
    from dem_ros.transport import serialize
    from dem_ros.transport.dds.msgs import message_class

    JS = message_class("sensor_msgs/msg/JointState")
    String = message_class("std_msgs/msg/String")
    path = root / "rig_run"
    epoch = 1_800_000_000 * 10**9
    meta = {"scenario": "S1", "controller": "adaptive", "transport": "rig (in process)", "config": cfg}
    with BagWriter(path, metadata=meta) as w:
        for t in (contract.MEASUREMENT, contract.APPLIED, contract.RUN_INFO):
            w.add_topic(t.name, t.type, t.qos)
        w.write(contract.RUN_INFO.name, epoch, serialize(String(data=json.dumps(meta))))
        for k in range(d.t.size):
            t_ns = epoch + round(d.t[k] * 1e9)
            w.write(contract.APPLIED.name, t_ns, serialize(joint_state(JS, t_ns, effort=d.voltage[k])))
            w.write(contract.MEASUREMENT.name, t_ns, serialize(joint_state(JS, t_ns, position=d.gap[k],
                                                                           effort=d.current[k])))
    return path


def identify_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "dem_ros.tools.cli", "identify", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=900)


@pytest.fixture(scope="module")
def excited_bag(tmp_path_factory):
    """S1's steps through the excitation reference model (the bring-up guide's run), 14 s on the rig."""
    cfg = rig_config(TRUTH, excite=True, rig_seed=11)
    d, err = emulated_run(cfg, 14.0)
    assert np.abs(err).max() < 0.5e-3  # it levitated and followed the steps
    return write_bag(d, cfg, tmp_path_factory.mktemp("excited")), cfg


def test_an_excited_rig_run_gives_R1_R2_K_m_within_tolerance_and_inside_the_intervals(excited_bag, tmp_path):
    bag, _cfg = excited_bag
    p = identify_cli(str(bag), "--json", str(tmp_path / "id.json"), "--params", str(tmp_path / "rig.yaml"),
                     "--plot", str(tmp_path / "figs"), cwd=tmp_path)
    print(p.stdout)
    assert p.returncode == 0, p.stdout + p.stderr
    res = json.loads((tmp_path / "id.json").read_text())
    assert res["complete"] and res["validation"]["current_rel"][0] < 0.01
    for k in PARAMS:
        e = res["estimates"][k]
        assert abs(e["value"] / TRUTH[k] - 1) <= TOLERANCE[k], (k, e, TRUTH[k])
        assert e["ci95"][0] <= TRUTH[k] <= e["ci95"][1], (k, e, TRUTH[k])
    # magnets alike: one K, the split's interval holds 0, and the line says so
    split = res["k_split"]
    assert split["verdict"] == "one K: agree" and abs(split["coils"]) <= split["coils_ci95"], split
    assert not any(res["estimates"][k]["determined"] for k in SPLIT)
    assert "K1, K2: not given: K1 and K2 agree within their intervals" in p.stdout
    # the params file: the project's names, loadable as a params file, the estimates in them
    cfg = load_params_file(tmp_path / "rig.yaml")
    assert cfg["controller"]["K_init"] == pytest.approx(res["estimates"]["K"]["value"], rel=1e-5)
    assert cfg["controller"]["m_init"] == pytest.approx(res["estimates"]["m"]["value"], rel=1e-5)
    assert cfg["plant_sim"]["R1"] == pytest.approx(res["estimates"]["R1"]["value"], rel=1e-5)
    assert cfg["hw_driver"]["K"] == cfg["controller"]["K_nominal"]  # the board's model: the driver sends it
    assert cfg["estimator"]["R"] == pytest.approx(0.5 * (TRUTH["R1"] + TRUTH["R2"]), rel=0.01)
    assert sorted(f.name for f in (tmp_path / "figs").iterdir()) == ["identify_estimates.png",
                                                                     "identify_validation.png"]
    assert "K1" not in cfg["plant_sim"] or cfg["plant_sim"]["K1"] == 0.0  # one K: no split written


def test_a_rig_whose_magnets_differ_gives_K1_K2_and_their_mean_for_the_single_K_parameters(tmp_path):
    """K1 != K2 on the rig (14 s of the excitation run): the coils tell them apart, each within tolerance and
    inside its interval, checked by the moment balance; the params file gives the laws, the estimator and the
    board their mean and the emulator's plant K1, K2."""
    cfg = rig_config(SPLIT_TRUTH, excite=True, rig_seed=11)
    assert (cfg["plant_sim"]["K1"], cfg["plant_sim"]["K2"]) == (SPLIT_TRUTH["K1"], SPLIT_TRUTH["K2"])
    d, err = emulated_run(cfg, 14.0)
    assert np.abs(err).max() < 0.5e-3
    bag = write_bag(d, cfg, tmp_path)
    p = identify_cli(str(bag), "--json", str(tmp_path / "id.json"), "--params", str(tmp_path / "rig.yaml"),
                     cwd=tmp_path)
    print(p.stdout)
    assert p.returncode == 0, p.stdout + p.stderr
    res = json.loads((tmp_path / "id.json").read_text())
    split = res["k_split"]
    assert split["verdict"] == "split" and split["consistent"], split
    s = (SPLIT_TRUTH["K1"] - SPLIT_TRUTH["K2"]) / (SPLIT_TRUTH["K1"] + SPLIT_TRUTH["K2"])
    assert abs(split["coils"] - s) <= split["coils_ci95"] and abs(split["moment"] - s) < 1e-3
    for k in ("R1", "R2", "K1", "K2", "K", "m"):
        e = res["estimates"][k]
        assert abs(e["value"] / SPLIT_TRUTH[k] - 1) <= TOLERANCE[k], (k, e, SPLIT_TRUTH[k])
        assert e["ci95"][0] <= SPLIT_TRUTH[k] <= e["ci95"][1], (k, e, SPLIT_TRUTH[k])
    est = {k: res["estimates"][k]["value"] for k in ("K1", "K2", "K")}
    assert est["K"] == pytest.approx(0.5 * (est["K1"] + est["K2"]), rel=1e-12)
    assert "K split (K1 - K2)/(K1 + K2): K1 and K2 differ (two K)" in p.stdout
    rig = load_params_file(tmp_path / "rig.yaml")
    for g, k in (("controller", "K_init"), ("controller", "K_nominal"), ("estimator", "K"), ("hw_driver", "K"),
                 ("plant_sim", "K")):
        assert rig[g][k] == pytest.approx(est["K"], rel=1e-5), (g, k)
    assert (rig["plant_sim"]["K1"], rig["plant_sim"]["K2"]) == pytest.approx((est["K1"], est["K2"]), rel=1e-5)


def test_a_hover_only_run_names_what_it_cannot_identify_and_writes_no_number_for_it(tmp_path):
    cfg = rig_config(TRUTH, excite=False, rig_seed=12)
    cfg["reference"]["step_time_1"] = cfg["reference"]["step_time_2"] = 1e5  # no steps: hover only
    d, _ = emulated_run(cfg, 10.0)
    bag = write_bag(d, cfg, tmp_path)
    p = identify_cli(str(bag), "--json", str(tmp_path / "id.json"), "--params", str(tmp_path / "rig.yaml"),
                     cwd=tmp_path)
    print(p.stdout)
    assert p.returncode == 1, p.stdout + p.stderr
    assert "K  : not determined" in p.stdout and "m  : not determined" in p.stdout and "flux" in p.stdout
    assert "K1 : not determined" in p.stdout and "K split (K1 - K2)/(K1 + K2): not determined" in p.stdout
    res = json.loads((tmp_path / "id.json").read_text())
    for k in ("K", "m", "K1", "K2"):
        assert not res["estimates"][k]["determined"] and "value" not in res["estimates"][k]
    for k in ("R1", "R2"):  # the coil resistances need no excitation: u = R i at hover
        e = res["estimates"][k]
        assert e["determined"] and abs(e["value"] / TRUTH[k] - 1) < 0.01 and e["ci95"][0] <= TRUTH[k] <= e["ci95"][1]
    text = (tmp_path / "rig.yaml").read_text()
    assert "K_init" not in text and "m_init" not in text and "not determined by this run" in text
    assert load_params_file(tmp_path / "rig.yaml")["plant_sim"]["R2"] == pytest.approx(
        res["estimates"]["R2"]["value"], rel=1e-5)


def test_bad_input_is_one_line_and_exit_2(tmp_path):
    p = identify_cli(str(tmp_path / "nope"), cwd=tmp_path)
    assert p.returncode == 2 and "error:" in p.stderr and "Traceback" not in p.stderr
    p = identify_cli(cwd=tmp_path)
    assert p.returncode == 2 and "give a BAG, or --rigs N" in p.stderr
    p = identify_cli(str(tmp_path), "--holdout", "1.5", cwd=tmp_path)
    assert p.returncode == 2 and "--holdout" in p.stderr
