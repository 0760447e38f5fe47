"""The CT numbers (Hounsfield units) the image side decides by: what is bone and what is metal.

Kept apart from the modules that use them, which need scipy and VTK, so that the command line can show them in
its help without loading either.
"""

#: Default bone threshold (HU): above fat, marrow and soft tissue, below cancellous bone.
DEFAULT_THRESHOLD_HU = 200.0
#: Brighter than any bone (HU, after denoising): metal.
METAL_HU = 2500.0
