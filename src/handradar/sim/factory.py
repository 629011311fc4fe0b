"""The one place simulators are built: :class:`SimFactory`, from the ``sim`` config.

Every setting (the hand model, the skeleton rate, amplitudes, the cylinder RCS aspect exponent,
the effects with their parameters, the draws a noise effect averages) is fixed when a simulator is
constructed; nothing mutates a built simulator. A variant with other settings is a new factory
(:meth:`SimFactory.replace`), so every simulator passes the constructor's checks and its
:meth:`~handradar.sim.simulator.Simulator.key` (which the caches use) says what it is.

    factory = SimFactory.from_config(cfg.sim, radar, chain)       # conf/sim/*.yaml
    sim = factory()                                               # the configured effects
    sim = factory({"palm": {"radius_m": 0.03}})                   # these effects instead
    calibrated = factory.replace(rcs_exponent=0.1, noise_draws=4)
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from handradar.config import read_yaml
from handradar.errors import FormatError
from handradar.hand.model import HandModelConfig
from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig
from handradar.sim.simulator import Simulator

# Effects with their parameters: {effect name: {parameter: value}} (also the gap diagnosis's variants).
EffectSet = Mapping[str, Mapping[str, Any]]

SETTINGS = ("hand", "skeleton_rate_hz", "tx_power_w", "gain_tx_dbi", "gain_rx_dbi", "rcs_exponent",
            "metacarpal_gain", "coherence", "compile_combine")
# settings judged and removed (docs/gap_validation.md), with their off value: a fitted_sim.yaml or a job
# state written before their removal still holds them at it, and reads as it did
REMOVED = {"bone_extent": 0.0, "doppler_spread": 0.0}
# keys of a sim config that are not settings: Hydra's, and the two that become ``effects``
_NOT_SETTINGS = {"_target_", "_partial_", "_recursive_", "_convert_", "effects", "effect_params", "noise_draws",
                 "from_report"}


def without_removed(settings: Mapping[str, Any]) -> dict[str, Any]:
    """``settings`` without the REMOVED ones at their off value (another value stays, and is refused
    as unknown by the caller)."""
    return {k: v for k, v in settings.items() if not (k in REMOVED and v is not None and float(v) == REMOVED[k])}


def _read_fitted(path: Path) -> dict[str, Any]:
    """The settings of a fitted_sim.yaml (checked: known settings, an effect list, parameter mappings)."""
    if not path.is_file():
        raise FormatError(path, "fitted simulator not found (sim.from_report: the fitted_sim.yaml a diagnose.py run wrote)")
    fitted = read_yaml(path)
    if not isinstance(fitted, dict) or not isinstance(fitted.get("effects", []), list):
        raise FormatError(path, "expected a mapping of simulator settings with an 'effects' list")
    fitted = without_removed(fitted)
    unknown = set(fitted) - set(SETTINGS) - {"effects", "effect_params"}
    if unknown:
        raise FormatError(path, f"unknown simulator setting(s) {sorted(unknown)}; expected some of "
                                f"{[*SETTINGS, 'effects', 'effect_params']}")
    return fitted


def _plain(cfg: DictConfig | Mapping | None) -> dict[str, Any]:
    if cfg is None:
        return {}
    return dict(OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else cfg)


class SimFactory:
    """Simulators of one radar and chain with fixed settings; ``factory(effects)`` builds one."""

    def __init__(self, radar: RadarConfig, chain: ChainConfig, *, effects: EffectSet | None = None,
                 noise_draws: int = 1, **settings: Any) -> None:
        settings = without_removed(settings)
        unknown = set(settings) - set(SETTINGS)
        if unknown:
            raise ValueError(f"unknown simulator setting(s) {sorted(unknown)}; expected some of {list(SETTINGS)}")
        if int(noise_draws) < 0:
            raise ValueError(f"noise_draws must be >= 0 (0: the expectation in closed form), found {noise_draws}")
        self.radar, self.chain = radar, chain
        self.settings = {k: v for k, v in settings.items() if v is not None}
        self.effects = {str(k): dict(v or {}) for k, v in (effects or {}).items()}
        self.noise_draws = int(noise_draws)

    @classmethod
    def from_config(cls, sim_cfg: DictConfig | Mapping | None, radar: RadarConfig, chain: ChainConfig,
                    **overrides: Any) -> SimFactory:
        """A factory of the ``sim`` config (``effects`` list + ``effect_params``); ``overrides`` win.
        ``from_report``: a fitted simulator written by diagnose.py (fitted_sim.yaml), whose settings,
        effects and parameters replace the config's (conf/sim/fitted.yaml)."""
        c = _plain(sim_cfg)
        fitted = c.pop("from_report", None)
        if fitted:
            c.update(_read_fitted(Path(str(fitted))))
        params = c.get("effect_params") or {}
        effects = {str(n): dict(params.get(n) or {}) for n in (c.get("effects") or [])}
        settings = {k: v for k, v in c.items() if k not in _NOT_SETTINGS}
        if isinstance(settings.get("hand"), Mapping):  # the hand group's node (its _target_ dropped)
            settings["hand"] = HandModelConfig(**{k: v for k, v in settings["hand"].items() if not k.startswith("_")})
        kw: dict[str, Any] = {"effects": effects, "noise_draws": c.get("noise_draws", 1), **settings}
        kw.update(overrides)
        return cls(radar, chain, **kw)

    def replace(self, **overrides: Any) -> SimFactory:
        """The same factory with other settings (e.g. ``rcs_exponent``, ``noise_draws``, ``effects``)."""
        kw: dict[str, Any] = {"effects": self.effects, "noise_draws": self.noise_draws, **self.settings}
        kw.update(overrides)
        return SimFactory(self.radar, self.chain, **kw)

    @property
    def rcs_exponent(self) -> float:
        return float(self.settings.get("rcs_exponent", 1.0))

    def __call__(self, effects: EffectSet | None = None) -> Simulator:
        """A new simulator with ``effects`` (default: the factory's own) and the factory's settings."""
        chosen = self.effects if effects is None else {str(k): dict(v or {}) for k, v in effects.items()}
        params = {k: dict(v) for k, v in chosen.items()}
        if "noise" in params and self.noise_draws != 1:
            params["noise"].setdefault("draws", self.noise_draws)
        return Simulator(self.radar, self.chain, effects=list(chosen), effect_params=params, **self.settings)

    def __repr__(self) -> str:
        return f"SimFactory(effects={self.effects}, noise_draws={self.noise_draws}, settings={self.settings})"
