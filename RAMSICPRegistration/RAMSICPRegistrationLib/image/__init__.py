"""Layer 3, the image side: CT volumes (NRRD, NIfTI, DICOM, Slicer volume nodes) to the bone's surface (the IPC)
and the marker-sphere centres. Imports only ``core`` and ``io``."""
