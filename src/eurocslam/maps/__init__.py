"""Maps that persist: a run's keyframes and landmarks on disk, for later sessions to localize in
and map on (`store`)."""

from eurocslam.maps.store import MapKeyframe, SavedMap, load_map, save_map

__all__ = ["MapKeyframe", "SavedMap", "load_map", "save_map"]
