"""Layer 2, files: point files (markups JSON, fcsv, csv/txt, npy), surface files through VTK, numpy <-> VTK
arrays, the NDI tool geometries and ``.rom`` files shipped in ``data/``, the checks of input and output paths
and the commands' one-line argument errors. Imports only ``core``."""
