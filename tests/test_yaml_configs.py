"""Reading one YAML config against its schema (pipeline/yaml_configs.py): the merged config
is remembered per process, and every caller still gets its own copy of what the file and
the overrides say now."""

import shutil

import pytest

from pipeline import yaml_configs
from pipeline.domains import domain_config, domain_schema


def test_each_caller_gets_its_own_copy_of_a_remembered_config():
    first = domain_config("planar", {"obstacles_max": 5})
    first.obstacles_max = 99  # a caller changing its copy
    again = domain_config("planar", {"obstacles_max": 5})
    assert again.obstacles_max == 5 and again is not first
    assert domain_config("planar").obstacles_max == 12  # conf/domain/planar.yaml
    assert domain_config("planar", {"obstacles_max": 7}).obstacles_max == 7


def test_an_edited_yaml_file_is_read_again(tmp_path, monkeypatch):
    conf = tmp_path / "conf"
    shutil.copytree(yaml_configs.CONF_DIR / "domain", conf / "domain")
    monkeypatch.setattr(yaml_configs, "CONF_DIR", conf)
    schema = domain_schema("planar")
    assert yaml_configs.load_yaml_config("domain", "planar", schema).obstacles_max == 12
    path = conf / "domain" / "planar.yaml"
    path.write_text(path.read_text().replace("obstacles_max: 12", "obstacles_max: 6"))
    assert yaml_configs.load_yaml_config("domain", "planar", schema).obstacles_max == 6
    path.write_text(path.read_text().replace("obstacles_max: 6", "obstacles_max: many"))
    with pytest.raises(ValueError, match="domain config 'planar'"):
        yaml_configs.load_yaml_config("domain", "planar", schema)
