"""The CT numbers (Hounsfield units) the image side decides by: what is bone and what is metal.

Kept apart from the modules that use them, which need scipy and VTK, so that the command line can show them in
its help without loading either.
"""

#: Default bone threshold (HU): above fat, marrow and soft tissue, below cancellous bone.
DEFAULT_THRESHOLD_HU = 200.0
#: Brighter than any bone (HU, after denoising): metal.
METAL_HU = 2500.0
#: Lowest bone threshold taken (HU): water is 0, muscle and blood 40-80, fat about -100; below 100 HU a threshold
#: takes soft tissue for bone and the IPC becomes the skin.
MIN_BONE_THRESHOLD_HU = 100.0
#: Highest bone threshold taken (HU): cortical bone reaches about 1,500-2,000 HU; above it the surface falls apart.
MAX_BONE_THRESHOLD_HU = 2000.0
#: A CT whose lowest value is above this (HU) holds no air and no fat: its values are not Hounsfield units.
MIN_AIR_HU = -200.0


def check_bone_threshold(value_hu):
    """Raise ValueError unless ``value_hu`` can separate bone from soft tissue; returns it as a float.

    Numbers between 0 and 1 are named as fractions (a threshold is in HU, not a fraction of the range)."""
    value = float(value_hu)
    if 0.0 < value < 1.0:
        raise ValueError(
            f"threshold {value:g} HU looks like a fraction; the threshold is in Hounsfield units (bone from "
            f"{MIN_BONE_THRESHOLD_HU:g} HU; default 200, or 'auto')"
        )
    if not MIN_BONE_THRESHOLD_HU <= value <= MAX_BONE_THRESHOLD_HU:
        below = "below bone: soft tissue (0-80 HU) and fat would count as bone and the IPC would be the skin"
        above = "above most cortical bone: the bone's surface would fall apart"
        raise ValueError(
            f"threshold {value:g} HU is {below if value < MIN_BONE_THRESHOLD_HU else above}; give "
            f"{MIN_BONE_THRESHOLD_HU:g} to {MAX_BONE_THRESHOLD_HU:g} HU (default 200, or 'auto')"
        )
    return value


def check_hounsfield_units(voxels, threshold_hu):
    """Raise ValueError when a CT's values cannot be Hounsfield units: no air or fat in it (its lowest value above
    ``MIN_AIR_HU``) while some voxels pass ``threshold_hu`` (a number), as when raw scanner values are stored
    without their rescale slope and intercept (air 0, water 1024): the threshold would then take soft tissue."""
    if isinstance(threshold_hu, str):
        return
    lowest, highest = float(voxels.min()), float(voxels.max())
    if lowest > MIN_AIR_HU and highest > threshold_hu:
        raise ValueError(
            f"the CT's values do not look like Hounsfield units: the lowest is {lowest:g} (air is -1000 HU, fat "
            f"-100 HU), so a threshold of {threshold_hu:g} HU would take soft tissue for bone. Stored without its "
            "rescale slope and intercept? Convert it to HU (e.g. load the DICOM series itself)"
        )
