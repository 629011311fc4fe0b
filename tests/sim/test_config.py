"""The sim and hand config groups compose with Hydra and instantiate a working simulator."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir

from handradar.config import VERSION_BASE
from handradar.hand.model import HandModelConfig
from handradar.sim.factory import SimFactory
from handradar.sim.simulator import Simulator
from handradar.vocab import EFFECTS as EFFECT_NAMES
from tests.conftest import REPO


def _compose(overrides):
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base=VERSION_BASE):
        return compose(config_name="ingest", overrides=overrides)


def test_paper_and_all_effects_presets(radar, chain):
    cfg = _compose(["+sim=paper", "+hand=default", "root=x", "out=y"])
    sim = SimFactory.from_config(cfg.sim, radar, chain)()
    assert isinstance(sim, Simulator) and len(sim.effects) == 0
    assert isinstance(sim.hand, HandModelConfig) and sim.hand.retarget
    cfg = _compose(["+sim=all_effects", "+hand=default", "root=x", "out=y", "+sim.effect_params.noise.snr_db=15"])
    sim = SimFactory.from_config(cfg.sim, radar, chain)()
    assert sorted(e.name for e in sim.effects) == sorted(EFFECT_NAMES)
    assert sim.effect("noise").values() == {"snr_db": 15.0}
    cfg = _compose(["+sim=paper", "root=x", "out=y", "sim.effects=[noise,occlusion]"])  # without a hand group
    sim = SimFactory.from_config(cfg.sim, radar, chain)()
    assert [e.name for e in sim.effects] == ["occlusion", "noise"] and sim.hand == HandModelConfig()


def test_instantiated_simulator_runs(radar, chain):
    cfg = _compose(["+sim=paper", "+hand=default", "root=x", "out=y"])
    sim = SimFactory.from_config(cfg.sim, radar, chain)()
    sk = torch.zeros(1, 160, 2, 21, 3)
    sk[:, :, 0] = torch.as_tensor(np.linspace(0.2, 0.3, 21))[:, None] * torch.tensor([0.1, 0.1, 1.0])
    sk[:, :, 0, :, 2] += torch.linspace(0, 0.1, 160)[:, None]
    mk = torch.zeros(1, 160, 2, dtype=torch.bool)
    mk[..., 0] = True
    spec = sim(sk, mk)
    assert spec.shape == (1, 64, 32) and torch.isfinite(spec).all()


def test_factory_builds_with_overrides_and_never_mutates(radar, chain):
    cfg = _compose(["+sim=paper", "+hand=default", "root=x", "out=y", "sim.effects=[noise]",
                    "+sim.effect_params.noise.snr_db=15"])
    factory = SimFactory.from_config(cfg.sim, radar, chain)
    base = factory()
    calibrated = factory.replace(rcs_exponent=0.25, noise_draws=4)
    sim = calibrated({"noise": {"snr_db": 10.0}, "palm": {}})
    assert sim.rcs_exponent == 0.25 and sim.effect("noise").draws == 4 and sim.effect("noise").values() == {"snr_db": 10.0}
    assert base.rcs_exponent == 1.0 and base.effect("noise").draws == 1  # the first simulator is untouched
    assert factory().key() == base.key() != calibrated().key()  # the key says what a simulator is
    with pytest.raises(ValueError, match="rcs_exponent must be in"):
        factory.replace(rcs_exponent=2.0)()  # overrides pass the constructor's checks
    with pytest.raises(ValueError, match="unknown simulator setting"):
        factory.replace(rcs_exponnet=0.5)
