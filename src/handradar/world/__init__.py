"""The reference world: a finer, independent generator of paired radar + Leap recordings.

It stands in for a capture rig (docs/architecture.md, "Reference world"): gesture kinematics on per-subject skeletons
(:mod:`.kinematics`); a radar scene with palm, forearm, multipath and an antenna pattern, built from
the hands' smooth surfaces (:mod:`.geometry`), their scattering (:mod:`.scattering`, closed forms in
:mod:`.optics`, or bone point scatterers, :mod:`.points`), burial and shadowing (:mod:`.shadowing`)
into scatterer tracks (:mod:`.tracks`) per recording (:mod:`.scene`); ADC and fast signal paths
(:mod:`.render`), a Leap sensor model (:mod:`.sensor`) and the drivers that write recordings and
datasets (:mod:`.generate`). It never imports handradar.sim: the simulator is measured against it.
"""

from handradar.world.config import EFFECTS, WorldConfig, world_config
from handradar.world.generate import (
    RecordingSpec,
    build_world_dataset,
    fast_example,
    recording_specs,
    simulate,
    write_recording,
    write_world_recordings,
)

__all__ = ["EFFECTS", "RecordingSpec", "WorldConfig", "build_world_dataset", "fast_example",
           "recording_specs", "simulate", "world_config", "write_recording", "write_world_recordings"]
