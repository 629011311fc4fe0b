"""The project's shared vocabulary: gesture classes and effect names.

One place for the names that the reference world, the simulator, the gap diagnosis and the
reports all use; a test ties the simulator's effect registry (handradar.sim.effects.REGISTRY) and
the world's effect switches (handradar.world.config) to these tuples.
"""

from __future__ import annotations

# The ten gestures of the recording format (``meta.json`` ``gesture``), in label order.
GESTURES: tuple[str, ...] = (
    "grasp", "finger_friction", "finger_wave", "circle", "slide", "finger_cross",
    "double_hand_clap", "double_hand_drumming", "hand_merge", "double_hand_circle",
)


# Effects the simulator can add to the paper's model: the diagnosis's candidate causes.
EFFECTS: tuple[str, ...] = ("occlusion", "palm", "forearm", "multipath", "antenna_pattern", "noise",
                            "sync_offset", "tracking_jitter")

# Effects that only the reference world renders (Leap and receiver details); iq_imbalance is the
# diagnosis's out-of-vocabulary control.
WORLD_ONLY_EFFECTS: tuple[str, ...] = ("dropouts", "calibration", "static_clutter", "iq_imbalance")

# The variants of a measured-radar job (handradar.tasks.measured) and their table columns (handradar.runs.tables),
# in the order of the tables.
MEASURED_VARIANTS: dict[str, str] = {
    "radar_only": "Radar only",
    "model_synth": "+ synthetic",
    "synth_pretrain": "synthetic pre-training, fine-tuned",
    "model_synth_only": "synthetic only",
}
