"""Radar configuration, DCA1000 raw data and the shared processing chain."""

from handradar.radar.chain import ChainConfig
from handradar.radar.config import RadarConfig

__all__ = ["ChainConfig", "RadarConfig"]
