"""The mapping configuration: defaults, YAML round trip, and one-line errors naming the key."""

import dataclasses

import pytest

from vmp.config import MappingConfig, config_to_dict, load_config, save_config
from vmp.errors import InputError


def test_saved_configuration_loads_back_equal(tmp_path):
    config = MappingConfig()
    config = dataclasses.replace(config, loops=dataclasses.replace(config.loops, separation=7),
                                 milestones=dataclasses.replace(config.milestones,
                                                                method="hwt"))
    save_config(tmp_path / "c.yaml", config)
    assert load_config(tmp_path / "c.yaml") == config
    assert config_to_dict(load_config(tmp_path / "c.yaml"))["loops"]["separation"] == 7


def test_keys_left_out_keep_their_defaults(tmp_path):
    (tmp_path / "c.yaml").write_text("motion: {trans_per_m: 0.1}\n")
    config = load_config(tmp_path / "c.yaml")
    assert config.motion.trans_per_m == 0.1
    assert config.motion.rot_per_m == MappingConfig().motion.rot_per_m
    assert config.registration == MappingConfig().registration


@pytest.mark.parametrize("text, message", [
    ("registration: {max_iteration: 3}\n", "registration.max_iteration: unknown key"),
    ("loops: {separation: 2.5}\n", "loops.separation: expected a whole number"),
    ("matching: {enabled: 1}\n", "matching.enabled: expected true or false"),
    ("motion: {trans_per_m: .nan}\n", "motion.trans_per_m: expected a number"),
    ("milestones: {method: xyz}\n", "milestones: method must be one of"),
    ("milestones: 3\n", "milestones: expected a mapping of keys"),
    ("[1, 2\n", "not valid YAML"),
])
def test_mistakes_name_the_file_and_key(tmp_path, text, message):
    (tmp_path / "c.yaml").write_text(text)
    with pytest.raises(InputError, match=message) as err:
        load_config(tmp_path / "c.yaml")
    assert str(err.value).startswith(str(tmp_path / "c.yaml"))
