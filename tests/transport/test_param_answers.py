"""Parameter services answer every request with a reason, and `dem-ros param` refuses arguments that are not
UTF-8 in one line (issue #21 item 3), on the DDS transport across real processes."""

import json
import os
import subprocess
import sys

from dem_ros.transport.dds import msgs
from dem_ros.transport.dds.client import call_service, param_get


def test_a_value_of_an_unknown_type_is_answered_with_a_reason(domain_id, spawn, wait_line):
    proc = spawn(domain_id, "params", "--ros-args", "-r", f"__node:=p_{domain_id}")
    fqn = json.loads(wait_line(proc, "READY ", timeout=60))["name"]
    bad = msgs.Parameter(name="k1", value=msgs.ParameterValue(type=99))
    good = msgs.Parameter(name="k1", value=msgs.ParameterValue(type=3, double_value=70.0))
    rep = call_service(fqn, "set_parameters", msgs.SetParameters_Request(parameters=[bad, good]),
                       domain_id=domain_id, timeout_s=20)
    assert [r.successful for r in rep.results] == [False, True]
    assert rep.results[0].reason == "parameter value type 99 is not a ROS parameter type (0..9)"
    rep = call_service(fqn, "set_parameters_atomically", msgs.SetParametersAtomically_Request(parameters=[good, bad]),
                       domain_id=domain_id, timeout_s=20)
    assert not rep.result.successful and "type 99" in rep.result.reason
    assert param_get(fqn, "k1", domain_id=domain_id, timeout_s=20) == 70.0  # the node kept serving
    assert proc.poll() is None


def test_a_parameter_name_that_is_not_utf8_is_one_line_and_exit_2():
    env = {**os.environ, "ROS_DOMAIN_ID": "0"}
    name = os.fsdecode(b"k\xff1")  # what the shell hands over for $'k\xff1'
    r = subprocess.run([sys.executable, "-m", "dem_ros.tools.cli", "param", "set", "controller", name, "70"],
                       capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 2 and r.stdout == "", (r.returncode, r.stdout, r.stderr)
    assert r.stderr.strip().count("\n") == 0 and "is not valid UTF-8" in r.stderr, r.stderr
