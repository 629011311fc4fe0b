"""The world's Hydra config: conf/world.yaml and the conf/world/ group coexist and mirror WorldConfig."""

from __future__ import annotations

import dataclasses

import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from handradar.config import VERSION_BASE, config_dir
from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig
from handradar.vocab import EFFECTS as VOCABULARY
from handradar.world.config import EFFECTS, WorldConfig, world_config


def _compose(*overrides: str):
    with initialize_config_dir(str(config_dir()), version_base=VERSION_BASE):
        return compose("world", overrides=["out=/tmp/unused", *overrides])


def test_primary_config_and_group_coexist_and_match_the_defaults():
    cfg = _compose()
    assert {"out", "limit", "overwrite", "radar", "chain", "paths", "world"} <= set(cfg)
    assert world_config(cfg.world) == WorldConfig()  # the YAML mirrors the dataclass defaults
    assert isinstance(instantiate(cfg.radar), RadarConfig) and isinstance(instantiate(cfg.chain), ChainConfig)


def test_overrides_reach_the_world_and_typos_fail():
    cfg = _compose("world.effects.noise.snr_db=3", "world.effects.multipath.enabled=false", "world.subjects=2")
    w = world_config(cfg.world)
    assert w.effects.noise.snr_db == 3.0 and isinstance(w.effects.noise.snr_db, float)
    assert not w.effects.multipath.enabled and w.subjects == 2
    with pytest.raises(ValueError, match="snr"):
        world_config({"effects": {"noise": {"snr": 3}}})
    with pytest.raises(ValueError, match="gesture"):
        world_config({"gestures": ["wave"]})


def test_default_world_has_the_vocabulary_on_and_the_control_off():
    fx = WorldConfig().effects
    assert set(VOCABULARY) <= set(fx.enabled())
    assert "iq_imbalance" in EFFECTS and "iq_imbalance" not in fx.enabled()
    assert fx.only("palm").enabled() == ["palm"]
    assert dataclasses.asdict(fx.with_("noise", snr_db=5.0).noise)["snr_db"] == 5.0


def test_strong_jitter_preset_is_the_default_world_with_4_mm_jitter():
    """conf/world/strong_jitter.yaml keeps world/1's tracking jitter as a named option; the default
    is the Leap's reported ~1 mm."""
    strong = world_config(_compose("world=strong_jitter").world)
    assert WorldConfig().effects.tracking_jitter.rms_m == pytest.approx(0.001)
    assert strong.effects.tracking_jitter.rms_m == pytest.approx(0.004)
    assert dataclasses.replace(strong, effects=strong.effects.with_("tracking_jitter", rms_m=0.001)) == WorldConfig()
