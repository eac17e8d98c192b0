"""config/dem_ros.yaml is generated from the schema (the guard promised in tools/params_file.py)."""

from pathlib import Path

from dem_ros.core.params import SCHEMA, default_config, load_params_file
from dem_ros.tools.common import yaml_scalar
from dem_ros.tools.params_file import render_params_file

COMMITTED = Path(__file__).resolve().parents[2] / "config" / "dem_ros.yaml"


def test_committed_params_file_is_the_rendered_schema():
    assert COMMITTED.read_text() == render_params_file(), "regenerate: dem-ros config params > config/dem_ros.yaml"


def test_committed_params_file_loads_back_to_every_schema_default():
    assert load_params_file(COMMITTED) == default_config()
    assert set(load_params_file(COMMITTED)) == set(SCHEMA.groups)


def test_yaml_scalars_read_back_as_the_same_type_and_value(tmp_path):
    import yaml

    for v in (True, False, 0, -3, 1e-05, 2.5e10, 100.0, 0.1, "kf", 'a "quoted" \\ path'):
        back = yaml.safe_load(yaml_scalar(v))
        assert back == v and type(back) is type(v), (v, yaml_scalar(v), back)
