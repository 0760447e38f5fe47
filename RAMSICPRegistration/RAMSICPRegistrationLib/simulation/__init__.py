"""Layer 4, simulated patients: the virtual patient (bone, reference body, probe points, targets), CT phantoms,
and the bone meshes shipped in ``data/``. Imports only ``core``, ``io`` and ``image``."""
