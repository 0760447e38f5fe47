"""Layer 1, the registration core: numpy, scipy and the standard library only (no VTK, no MRML, no Qt).

Paired-point SVD fit (eq. 5), ICP and RAMSICP (eqs. 6-10), the scale sweep, TRE/FRE metrics (eq. 11), the pose
constraint analysis, pivot and robot calibration (eqs. 3-4). Arrays in, arrays and frozen dataclasses out.
"""
