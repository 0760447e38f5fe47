"""Layer 2, files: point files (markups JSON, fcsv, csv/txt, npy), surface files through VTK, numpy <-> VTK
arrays, and the NDI tool geometries and ``.rom`` files shipped in ``data/``. Imports only ``core``."""
