"""Importers of external skeleton sources into the canonical skeleton (docs/architecture.md, "Coordinates and units").

Each returns :class:`~handradar.hand.skeleton.HandSequence` objects in the *source's* frame
(made right-handed), with ``attrs["up_axis"]``; :func:`handradar.hand.placement.place_in_radar`
then puts them over the radar. Leap recordings are already in the radar frame (their meta.json
holds the calibration): see :mod:`handradar.hand.leap`.
"""

from handradar.hand.importers.dhg import iter_dhg, read_dhg, read_info
from handradar.hand.importers.mediapipe import mediapipe_sequence
from handradar.hand.importers.sfinge3d import iter_sfinge3d, read_sfinge3d

__all__ = ["iter_dhg", "iter_sfinge3d", "mediapipe_sequence", "read_dhg", "read_info", "read_sfinge3d"]
